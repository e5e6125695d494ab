//! Index-to-world transforms.  Only linear maps exist here: a non-linear
//! (frustum) map is refused by the reader.

/// The OpenVDB map type a transform was stored as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapType {
    UniformScale,
    UniformScaleTranslate,
    Scale,
    ScaleTranslate,
    Translation,
    Affine,
    Unitary,
}

impl MapType {
    /// The map's registered OpenVDB name.
    pub fn vdb_name(self) -> &'static str {
        match self {
            MapType::UniformScale => "UniformScaleMap",
            MapType::UniformScaleTranslate => "UniformScaleTranslateMap",
            MapType::Scale => "ScaleMap",
            MapType::ScaleTranslate => "ScaleTranslateMap",
            MapType::Translation => "TranslationMap",
            MapType::Affine => "AffineMap",
            MapType::Unitary => "UnitaryMap",
        }
    }

    pub fn from_vdb_name(s: &str) -> Option<MapType> {
        Some(match s {
            "UniformScaleMap" => MapType::UniformScale,
            "UniformScaleTranslateMap" => MapType::UniformScaleTranslate,
            "ScaleMap" => MapType::Scale,
            "ScaleTranslateMap" => MapType::ScaleTranslate,
            "TranslationMap" => MapType::Translation,
            "AffineMap" => MapType::Affine,
            "UnitaryMap" => MapType::Unitary,
            _ => return None,
        })
    }
}

/// A linear index-to-world transform.
///
/// `matrix` follows OpenVDB's row-vector convention: a world position is
/// `[i, j, k, 1] * matrix`, so the translation is the last row.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    pub map_type: MapType,
    pub matrix: [[f64; 4]; 4],
}

impl Transform {
    pub fn identity() -> Transform {
        Transform::scale_translate(MapType::UniformScale, [1.0; 3], [0.0; 3])
    }

    /// A scale followed by a translation, recorded as `map_type`.
    pub fn scale_translate(map_type: MapType, scale: [f64; 3], translation: [f64; 3]) -> Transform {
        let mut m = [[0.0; 4]; 4];
        for (a, s) in scale.iter().enumerate() {
            m[a][a] = *s;
        }
        m[3] = [translation[0], translation[1], translation[2], 1.0];
        Transform { map_type, matrix: m }
    }

    /// Maps an index-space position to world space.
    pub fn index_to_world(&self, p: [f64; 3]) -> [f64; 3] {
        let m = &self.matrix;
        let mut out = [0.0; 3];
        for (c, o) in out.iter_mut().enumerate() {
            *o = p[0] * m[0][c] + p[1] * m[1][c] + p[2] * m[2][c] + m[3][c];
        }
        out
    }

    /// World-space length of one voxel step along each index axis (OpenVDB's `voxelSize()`).
    pub fn voxel_size(&self) -> [f64; 3] {
        let m = &self.matrix;
        let len = |r: usize| (m[r][0] * m[r][0] + m[r][1] * m[r][1] + m[r][2] * m[r][2]).sqrt();
        [len(0), len(1), len(2)]
    }

    /// The translation part (world position of index (0, 0, 0)).
    pub fn translation(&self) -> [f64; 3] {
        [self.matrix[3][0], self.matrix[3][1], self.matrix[3][2]]
    }

    /// Where `other`'s voxels are in this transform's index space, when its
    /// voxels are 2^k times as wide (k = 0 to 3) along the same axes and its
    /// index origin sits on a whole or half voxel of this one: `(k, o)`, `o`
    /// the position of `other`'s index (0, 0, 0) in this index space, in half
    /// voxels. `None` for anything else (a rotation, another ratio, any other offset).
    pub fn relative_scale(&self, other: &Transform) -> Option<(u32, [i32; 3])> {
        let (m, n) = (&self.matrix, &other.matrix);
        let len = |r: &[f64; 4]| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
        let ratio = len(&n[0]) / len(&m[0]);
        let k = (0..4u32).find(|&k| (ratio / f64::from(1u32 << k) - 1.0).abs() < 1e-6)?;
        let r = f64::from(1u32 << k);
        let scale = (0..3).map(|a| len(&m[a])).fold(0.0, f64::max);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * r * scale;
        if !(0..3).all(|a| (0..3).all(|c| close(n[a][c], r * m[a][c]))) || n.iter().take(3).any(|row| row[3] != 0.0) || n[3][3] != 1.0 {
            return None;
        }
        // The offset in this index space: solve o · M3 = t_other − t (Cramer's rule).
        let d = [0, 1, 2].map(|c| n[3][c] - m[3][c]);
        let det3 = |a: [[f64; 3]; 3]| a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
        let m3 = [0, 1, 2].map(|a| [m[a][0], m[a][1], m[a][2]]);
        let det = det3(m3);
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let mut half = [0i32; 3];
        for (row, h) in half.iter_mut().enumerate() {
            let mut a = m3;
            a[row] = d;
            let o = det3(a) / det;
            let twice = (2.0 * o).round();
            if (2.0 * o - twice).abs() > 1e-3 || twice.abs() > 1e9 {
                return None;
            }
            *h = twice as i32;
        }
        Some((k, half))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_translate_maps_points() {
        let t = Transform::scale_translate(MapType::ScaleTranslate, [0.5, 2.0, -1.0], [1.0, 2.0, 3.0]);
        assert_eq!(t.index_to_world([2.0, 1.0, 4.0]), [2.0, 4.0, -1.0]);
        assert_eq!(t.voxel_size(), [0.5, 2.0, 1.0]);
        assert_eq!(t.translation(), [1.0, 2.0, 3.0]);
    }

    #[test]
    fn relative_scales() {
        let fine = Transform::scale_translate(MapType::UniformScale, [0.1; 3], [0.0; 3]);
        let vel = Transform::scale_translate(MapType::UniformScale, [0.2; 3], [0.0; 3]);
        assert_eq!(fine.relative_scale(&vel), Some((1, [0, 0, 0])));
        let half = Transform::scale_translate(MapType::UniformScaleTranslate, [0.4; 3], [0.05, -0.1, 0.3]);
        assert_eq!(fine.relative_scale(&half), Some((2, [1, -2, 6])));
        assert_eq!(fine.relative_scale(&fine), Some((0, [0; 3])));
        // Not a power of two, not uniform, a finer grid, a third of a voxel off.
        for t in [
            Transform::scale_translate(MapType::UniformScale, [0.3; 3], [0.0; 3]),
            Transform::scale_translate(MapType::Scale, [0.2, 0.2, 0.4], [0.0; 3]),
            Transform::scale_translate(MapType::UniformScale, [0.05; 3], [0.0; 3]),
            Transform::scale_translate(MapType::UniformScaleTranslate, [0.2; 3], [0.0333, 0.0, 0.0]),
            Transform::scale_translate(MapType::UniformScale, [1.6; 3], [0.0; 3]),
        ] {
            assert_eq!(fine.relative_scale(&t), None, "{t:?}");
        }
    }

    #[test]
    fn map_names_round_trip() {
        for m in [MapType::UniformScale, MapType::UniformScaleTranslate, MapType::Scale, MapType::ScaleTranslate, MapType::Translation, MapType::Affine, MapType::Unitary] {
            assert_eq!(MapType::from_vdb_name(m.vdb_name()), Some(m));
        }
        assert_eq!(MapType::from_vdb_name("NonlinearFrustumMap"), None);
    }
}
