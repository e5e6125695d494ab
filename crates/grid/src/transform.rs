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
    fn map_names_round_trip() {
        for m in [MapType::UniformScale, MapType::UniformScaleTranslate, MapType::Scale, MapType::ScaleTranslate, MapType::Translation, MapType::Affine, MapType::Unitary] {
            assert_eq!(MapType::from_vdb_name(m.vdb_name()), Some(m));
        }
        assert_eq!(MapType::from_vdb_name("NonlinearFrustumMap"), None);
    }
}
