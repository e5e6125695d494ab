//! Grid transforms: a map type name followed by that map's doubles.
//!
//! | map                                   | payload (f64 little-endian)                                   |
//! |---------------------------------------|---------------------------------------------------------------|
//! | ScaleMap, UniformScaleMap             | scale, voxelSize, 1/scale, 1/scale², 1/(2·scale)  (5 × vec3d)  |
//! | ScaleTranslateMap, UniformScaleTranslateMap | translation, then the five ScaleMap vectors (6 × vec3d)  |
//! | TranslationMap                        | translation (vec3d)                                           |
//! | AffineMap, UnitaryMap                 | 4×4 matrix, row-major, row-vector convention (16 × f64)       |
//!
//! Only the first vectors carry information; the rest are caches that
//! OpenVDB recomputes, so they are read and ignored.

use crate::cursor::Cursor;
use crate::Error;
use vdbcook_grid::{MapType, Transform};

/// Why a transform could not be used.  The map's size is unknown for
/// non-linear maps, so the caller skips the whole grid.
pub(crate) enum MapError {
    NonLinear(String),
    Read(Error),
}

impl From<Error> for MapError {
    fn from(e: Error) -> Self {
        MapError::Read(e)
    }
}

pub(crate) fn read_transform(cur: &mut Cursor<'_>) -> Result<Transform, MapError> {
    let start = cur.pos();
    let name = cur.string("transform map type")?;
    let Some(map_type) = MapType::from_vdb_name(&name) else {
        if name.contains("Frustum") || name.starts_with("Nonlinear") {
            return Err(MapError::NonLinear(name));
        }
        return Err(MapError::Read(Error::invalid("transform", start, format!("unknown map type \"{}\"", name.escape_debug()))));
    };
    let transform = match map_type {
        MapType::Scale | MapType::UniformScale => {
            let scale = cur.vec3d("scale map")?;
            for _ in 0..4 {
                cur.vec3d("scale map")?;
            }
            Transform::scale_translate(map_type, scale, [0.0; 3])
        }
        MapType::ScaleTranslate | MapType::UniformScaleTranslate => {
            let translation = cur.vec3d("scale-translate map")?;
            let scale = cur.vec3d("scale-translate map")?;
            for _ in 0..4 {
                cur.vec3d("scale-translate map")?;
            }
            Transform::scale_translate(map_type, scale, translation)
        }
        MapType::Translation => Transform::scale_translate(map_type, [1.0; 3], cur.vec3d("translation map")?),
        MapType::Affine | MapType::Unitary => {
            let mut matrix = [[0.0; 4]; 4];
            for row in matrix.iter_mut() {
                for v in row.iter_mut() {
                    *v = cur.f64("affine map")?;
                }
            }
            Transform { map_type, matrix }
        }
    };
    if transform.matrix.iter().flatten().any(|v| !v.is_finite()) {
        return Err(MapError::Read(Error::invalid("transform", start, "non-finite matrix entry")));
    }
    Ok(transform)
}
