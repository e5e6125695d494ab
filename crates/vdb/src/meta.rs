//! Typed metadata (file-level and grid-level `MetaMap`s).
//!
//! Layout: `u32 count`, then per entry `string name`, `string type name`,
//! `u32 byte size`, value bytes.  The declared size is always used to step
//! over the value, so unknown types (and known types with a surprising size)
//! are kept as [`MetaValue::Other`] without desynchronising the stream.

use crate::cursor::Cursor;
use crate::Error;

#[derive(Clone, Debug, PartialEq)]
pub enum MetaValue {
    String(String),
    Bool(bool),
    Int32(i32),
    Int64(i64),
    Float(f32),
    Double(f64),
    Vec2i([i32; 2]),
    Vec2s([f32; 2]),
    Vec2d([f64; 2]),
    Vec3i([i32; 3]),
    Vec3s([f32; 3]),
    Vec3d([f64; 3]),
    Vec4i([i32; 4]),
    Vec4s([f32; 4]),
    Vec4d([f64; 4]),
    Mat4s([f32; 16]),
    Mat4d([f64; 16]),
    /// A type this reader does not interpret (e.g. `__delayedload`), or a
    /// known type whose stored size does not match it.
    Other {
        type_name: String,
        size: u32,
    },
}

impl MetaValue {
    pub fn as_str(&self) -> Option<&str> {
        match self {
            MetaValue::String(s) => Some(s),
            _ => None,
        }
    }
    /// A number (an integer or a float).
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            MetaValue::Int32(v) => Some(f64::from(*v)),
            MetaValue::Int64(v) => Some(*v as f64),
            MetaValue::Float(v) => Some(f64::from(*v)),
            MetaValue::Double(v) => Some(*v),
            _ => None,
        }
    }
    pub fn as_bool(&self) -> Option<bool> {
        match self {
            MetaValue::Bool(b) => Some(*b),
            _ => None,
        }
    }
}

/// Named metadata in file order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MetaMap(pub Vec<(String, MetaValue)>);

impl MetaMap {
    pub fn get(&self, name: &str) -> Option<&MetaValue> {
        self.0.iter().find(|(n, _)| n == name).map(|(_, v)| v)
    }
}

fn words<const N: usize>(b: &[u8]) -> [[u8; 4]; N] {
    let mut out = [[0u8; 4]; N];
    for (o, c) in out.iter_mut().zip(b.chunks_exact(4)) {
        o.copy_from_slice(c);
    }
    out
}

fn dwords<const N: usize>(b: &[u8]) -> [[u8; 8]; N] {
    let mut out = [[0u8; 8]; N];
    for (o, c) in out.iter_mut().zip(b.chunks_exact(8)) {
        o.copy_from_slice(c);
    }
    out
}

fn parse_value(type_name: &str, b: &[u8]) -> Option<MetaValue> {
    let n = b.len();
    Some(match (type_name, n) {
        ("string", _) => MetaValue::String(String::from_utf8_lossy(b).into_owned()),
        ("bool", 1) => MetaValue::Bool(b[0] != 0),
        ("int32", 4) => MetaValue::Int32(i32::from_le_bytes(words::<1>(b)[0])),
        ("int64", 8) => MetaValue::Int64(i64::from_le_bytes(dwords::<1>(b)[0])),
        ("float", 4) => MetaValue::Float(f32::from_le_bytes(words::<1>(b)[0])),
        ("double", 8) => MetaValue::Double(f64::from_le_bytes(dwords::<1>(b)[0])),
        ("vec2i", 8) => MetaValue::Vec2i(words::<2>(b).map(i32::from_le_bytes)),
        ("vec2s", 8) => MetaValue::Vec2s(words::<2>(b).map(f32::from_le_bytes)),
        ("vec2d", 16) => MetaValue::Vec2d(dwords::<2>(b).map(f64::from_le_bytes)),
        ("vec3i", 12) => MetaValue::Vec3i(words::<3>(b).map(i32::from_le_bytes)),
        ("vec3s", 12) => MetaValue::Vec3s(words::<3>(b).map(f32::from_le_bytes)),
        ("vec3d", 24) => MetaValue::Vec3d(dwords::<3>(b).map(f64::from_le_bytes)),
        ("vec4i", 16) => MetaValue::Vec4i(words::<4>(b).map(i32::from_le_bytes)),
        ("vec4s", 16) => MetaValue::Vec4s(words::<4>(b).map(f32::from_le_bytes)),
        ("vec4d", 32) => MetaValue::Vec4d(dwords::<4>(b).map(f64::from_le_bytes)),
        ("mat4s", 64) => MetaValue::Mat4s(words::<16>(b).map(f32::from_le_bytes)),
        ("mat4d", 128) => MetaValue::Mat4d(dwords::<16>(b).map(f64::from_le_bytes)),
        _ => return None,
    })
}

pub(crate) fn read_meta_map(cur: &mut Cursor<'_>) -> Result<MetaMap, Error> {
    let count = cur.u32("metadata count")?;
    // Each entry holds at least two empty strings and a size: 12 bytes.
    cur.check_count("metadata count", u64::from(count), 12)?;
    let mut entries = Vec::with_capacity(count as usize);
    for _ in 0..count {
        let name = cur.string("metadata name")?;
        let type_name = cur.string("metadata type")?;
        let size = cur.u32("metadata size")?;
        let bytes = cur.take(size as usize, "metadata value")?;
        let value = parse_value(&type_name, bytes).unwrap_or(MetaValue::Other { type_name, size });
        entries.push((name, value));
    }
    Ok(MetaMap(entries))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(out: &mut Vec<u8>, name: &str, ty: &str, val: &[u8]) {
        for s in [name, ty] {
            out.extend((s.len() as u32).to_le_bytes());
            out.extend(s.as_bytes());
        }
        out.extend((val.len() as u32).to_le_bytes());
        out.extend(val);
    }

    #[test]
    fn reads_every_standard_type() {
        let mut b = 6u32.to_le_bytes().to_vec();
        entry(&mut b, "class", "string", b"fog volume");
        entry(&mut b, "half", "bool", &[1]);
        entry(&mut b, "bbox", "vec3i", &[1, 0, 0, 0, 255, 255, 255, 255, 3, 0, 0, 0]);
        entry(&mut b, "mem", "int64", &7i64.to_le_bytes());
        entry(&mut b, "weird", "__delayedload", &[9; 5]);
        entry(&mut b, "short", "double", &[0; 4]);
        let m = read_meta_map(&mut Cursor::new(&b)).unwrap();
        assert_eq!(m.get("class").and_then(MetaValue::as_str), Some("fog volume"));
        assert_eq!(m.get("half").and_then(MetaValue::as_bool), Some(true));
        assert_eq!(m.get("bbox"), Some(&MetaValue::Vec3i([1, -1, 3])));
        assert_eq!(m.get("mem"), Some(&MetaValue::Int64(7)));
        assert_eq!(m.get("weird"), Some(&MetaValue::Other { type_name: "__delayedload".into(), size: 5 }));
        assert_eq!(m.get("short"), Some(&MetaValue::Other { type_name: "double".into(), size: 4 }));
    }

    #[test]
    fn huge_count_is_refused_before_allocating() {
        let b = u32::MAX.to_le_bytes();
        let e = read_meta_map(&mut Cursor::new(&b)).unwrap_err();
        assert!(matches!(e, Error::Implausible { .. }), "{e}");
    }
}
