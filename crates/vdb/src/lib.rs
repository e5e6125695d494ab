//! OpenVDB file reader.
//!
//! Reads what OpenVDB 3 to 12, Houdini, Blender, EmberGen and friends write
//! (file format versions 220 to 224) into [`vdbcook_grid::Grid`]s.  Nothing
//! in the file is trusted: every count and length is checked against the
//! bytes that remain before anything is allocated for it, and every failure
//! is an [`Error`] (never a panic).
//!
//! ```text
//! header   i64 magic 0x56444220, u32 file version, u32 library major, u32 minor,
//!          u8 has grid offsets, [u8 compressed: versions 220-221 only],
//!          36-byte ASCII UUID
//! metadata file MetaMap (see meta.rs)
//! i32 grid count, then per grid:
//!   descriptor  string unique name ("name\x1eN" for duplicates), string tree type
//!               ("Tree_float_5_4_3", "_HalfFloat" suffix when stored as half),
//!               string instance parent, i64 grid pos, i64 block pos, i64 end pos
//!   grid        [u32 compression flags: version >= 222], grid MetaMap, transform
//!               (map.rs), then unless an instance: tree topology and buffers (tree.rs)
//! ```
//! [`VdbFile::parse`] reads the header, the descriptors, and every grid's
//! metadata and transform; [`VdbFile::read_grid`] reads one scalar grid's
//! tree, [`VdbFile::read_vec3`] a vec3 grid's tree as three scalar grids
//! (`NAME.x`, `NAME.y`, `NAME.z`), and [`VdbFile::read_channels`] either.

mod cursor;
mod error;
mod map;
mod meta;
mod tree;
mod values;
mod write;

pub use error::Error;
pub use meta::{MetaMap, MetaValue};
pub use values::ScalarType;
pub use write::{write_vdb, write_vdb_grids, WriteGrid, WriteOptions};

use cursor::Cursor;
use std::path::Path;
use values::{Ctx, COMPRESS_ACTIVE_MASK, COMPRESS_BLOSC, COMPRESS_ZIP, MAX_COMPONENTS};
use vdbcook_grid::{Grid, GridClass, Transform};

const MAGIC: u64 = 0x5644_4220;
/// Oldest file version read (OpenVDB 2.x and later write 220+).
pub const MIN_FILE_VERSION: u32 = 220;
const VERSION_BLOSC_COMPRESSION: u32 = 223;
const HALF_SUFFIX: &str = "_HalfFloat";
const UNIQUE_SEP: char = '\u{1e}';

/// The tree's value type, from the descriptor's type name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ValueType {
    /// `float`, `double` or `half`.
    Scalar(ScalarType),
    /// `vec3s` (`Vec3(Float)`) or `vec3d` (`Vec3(Double)`): three components per value.
    Vec3(ScalarType),
    /// Any other type (`int32`, `bool`, `mask`, `vec3i`, `ptdataidx32`, …): listed, not read.
    Other(String),
}

impl ValueType {
    /// OpenVDB's name of the type: `float`, `double`, `half`, `vec3s`, `vec3d`, ….
    pub fn name(&self) -> &str {
        match self {
            ValueType::Scalar(s) => s.name(),
            ValueType::Vec3(ScalarType::Double) => "vec3d",
            ValueType::Vec3(ScalarType::Half) => "vec3h",
            ValueType::Vec3(ScalarType::Float) => "vec3s",
            ValueType::Other(s) => s,
        }
    }

    /// Components per value: 1 for scalars, 3 for vec3, 0 for types not read.
    pub fn components(&self) -> usize {
        match self {
            ValueType::Scalar(_) => 1,
            ValueType::Vec3(_) => 3,
            ValueType::Other(_) => 0,
        }
    }
}

/// Suffixes of a vec3 grid's component channels, in component order.
pub const VEC3_SUFFIXES: [&str; 3] = [".x", ".y", ".z"];

/// Why [`VdbFile::read_grid`] does not return a grid as one scalar [`Grid`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Unsupported {
    ValueType(String),
    TreeLayout(String),
    NonLinearMap(String),
    /// A vec3 grid (`vec3s`, `vec3d`): readable, but as three scalar grids
    /// ([`VdbFile::read_vec3`], [`VdbFile::read_channels`]).
    Vector(String),
}

impl std::fmt::Display for Unsupported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unsupported::ValueType(t) => write!(f, "value type {t} is not supported (only float, double, half and vec3 grids are read)"),
            Unsupported::TreeLayout(t) => write!(f, "tree type {t} is not a 5-4-3 tree"),
            Unsupported::NonLinearMap(m) => write!(f, "non-linear transform {m} is not supported (only linear maps are)"),
            Unsupported::Vector(t) => write!(f, "value type {t} holds vectors: it is read as three scalar channels (.x, .y, .z), not as one scalar grid"),
        }
    }
}

/// One grid's descriptor, metadata and transform.
#[derive(Clone, Debug)]
pub struct GridInfo {
    /// Name without the uniqueness suffix OpenVDB adds to duplicates.
    pub name: String,
    /// The descriptor's name (`name\x1eN` for duplicates and unnamed grids).
    pub unique_name: String,
    /// Tree type as stored, without the `_HalfFloat` suffix.
    pub tree_type: String,
    pub value_type: ValueType,
    pub half_float: bool,
    /// Unique name of the grid whose tree this one shares.
    pub instance_parent: Option<String>,
    /// Compression flags (zip 1, active-mask 2, blosc 4).
    pub compression: u32,
    pub class: GridClass,
    pub metadata: MetaMap,
    /// `None` when the grid is unsupported for a reason that stops its transform from being read.
    pub transform: Option<Transform>,
    /// `Some` when [`VdbFile::read_grid`] cannot read the grid's tree as one
    /// scalar grid; `Some(Unsupported::Vector)` for a vec3 grid, which
    /// [`VdbFile::read_vec3`] reads (see [`GridInfo::is_readable`]).
    pub unsupported: Option<Unsupported>,
    /// Byte offset of the grid's tree (after the transform).
    tree_pos: usize,
}

impl GridInfo {
    /// Display name: the grid's name, or `(unnamed)`.
    pub fn display_name(&self) -> String {
        if self.name.is_empty() {
            "(unnamed)".to_string()
        } else {
            self.name.clone()
        }
    }

    /// Compression flags as words: `blosc`, `zip`, `active-mask`, or `none`.
    pub fn compression_names(&self) -> Vec<&'static str> {
        let mut v = Vec::new();
        if self.compression & COMPRESS_BLOSC != 0 {
            v.push("blosc");
        }
        if self.compression & COMPRESS_ZIP != 0 {
            v.push("zip");
        }
        if self.compression & COMPRESS_ACTIVE_MASK != 0 {
            v.push("active-mask");
        }
        if v.is_empty() {
            v.push("none");
        }
        v
    }

    /// True for a float, double or half grid with a 5-4-3 tree and a linear map
    /// (what [`VdbFile::read_grid`] reads).
    pub fn is_readable_scalar(&self) -> bool {
        self.unsupported.is_none()
    }

    /// True for a vec3s or vec3d grid with a 5-4-3 tree and a linear map
    /// (what [`VdbFile::read_vec3`] reads).
    pub fn is_readable_vec3(&self) -> bool {
        matches!(self.unsupported, Some(Unsupported::Vector(_)))
    }

    /// True for every grid this reader reads: float, double, half and vec3
    /// grids ([`VdbFile::read_channels`]).
    pub fn is_readable(&self) -> bool {
        self.is_readable_scalar() || self.is_readable_vec3()
    }

    /// Names of the scalar channels [`VdbFile::read_channels`] returns: the
    /// grid's name, or for a vec3 grid `NAME.x`, `NAME.y`, `NAME.z`; empty
    /// for grids that are not read.
    pub fn channel_names(&self) -> Vec<String> {
        if self.is_readable_scalar() {
            vec![self.name.clone()]
        } else if self.is_readable_vec3() {
            VEC3_SUFFIXES.iter().map(|s| format!("{}{s}", self.name)).collect()
        } else {
            Vec::new()
        }
    }
}

/// A parsed .vdb file: header, metadata, grid list.  Trees are read on demand.
pub struct VdbFile {
    pub file_version: u32,
    pub library_version: (u32, u32),
    pub uuid: String,
    pub has_grid_offsets: bool,
    pub metadata: MetaMap,
    pub grids: Vec<GridInfo>,
    data: Bytes,
}

/// The file's bytes: owned, or a read-only memory map of the file.
enum Bytes {
    Owned(Vec<u8>),
    Mapped(memmap2::Mmap),
}

impl std::ops::Deref for Bytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Bytes::Owned(v) => v,
            Bytes::Mapped(m) => m,
        }
    }
}

/// Reads and parses a file (header, descriptors, grid metadata).
///
/// The file is memory-mapped (read-only), which spares a copy of the whole
/// file; like every mmap-based reader, it assumes the file is not truncated
/// by another process while it is being read.
pub fn open(path: &Path) -> Result<VdbFile, Error> {
    let file = std::fs::File::open(path)?;
    let len = file.metadata()?.len();
    if len == 0 {
        return VdbFile::parse(Vec::new());
    }
    // SAFETY: the map is read-only and private to this reader; see above.
    match unsafe { memmap2::Mmap::map(&file) } {
        Ok(map) => VdbFile::from_bytes(Bytes::Mapped(map)),
        Err(_) => VdbFile::parse(std::fs::read(path)?),
    }
}

fn parse_tree_type(tree_type: &str) -> (ValueType, Option<Unsupported>) {
    let Some(rest) = tree_type.strip_prefix("Tree_") else {
        return (ValueType::Other(tree_type.to_string()), Some(Unsupported::TreeLayout(tree_type.to_string())));
    };
    let (vt, layout) = match rest.strip_suffix("_5_4_3") {
        Some(vt) => (vt, true),
        None => (rest.split('_').next().unwrap_or(rest), false),
    };
    let value = match vt {
        "float" => ValueType::Scalar(ScalarType::Float),
        "double" => ValueType::Scalar(ScalarType::Double),
        "half" => ValueType::Scalar(ScalarType::Half),
        "vec3s" => ValueType::Vec3(ScalarType::Float),
        "vec3d" => ValueType::Vec3(ScalarType::Double),
        other => ValueType::Other(other.to_string()),
    };
    let unsupported = if !layout {
        Some(Unsupported::TreeLayout(tree_type.to_string()))
    } else {
        match &value {
            ValueType::Other(t) => Some(Unsupported::ValueType(t.clone())),
            ValueType::Vec3(_) => Some(Unsupported::Vector(value.name().to_string())),
            ValueType::Scalar(_) => None,
        }
    };
    (value, unsupported)
}

impl VdbFile {
    /// Parses everything but the trees.
    pub fn parse(data: Vec<u8>) -> Result<VdbFile, Error> {
        VdbFile::from_bytes(Bytes::Owned(data))
    }

    fn from_bytes(data: Bytes) -> Result<VdbFile, Error> {
        let mut cur = Cursor::new(&data);
        let magic = cur.array::<8>("header").map_err(|_| Error::NotVdb(0)).and_then(|m| {
            let v = u64::from_le_bytes(m);
            if v == MAGIC {
                Ok(v)
            } else {
                Err(Error::NotVdb(v))
            }
        })?;
        debug_assert_eq!(magic, MAGIC);
        let file_version = cur.u32("header")?;
        if file_version < MIN_FILE_VERSION {
            return Err(Error::Version(file_version));
        }
        let library_version = (cur.u32("header")?, cur.u32("header")?);
        let has_grid_offsets = cur.u8("header")? != 0;
        let mut file_compression = if file_version < VERSION_BLOSC_COMPRESSION { COMPRESS_ZIP | COMPRESS_ACTIVE_MASK } else { COMPRESS_BLOSC | COMPRESS_ACTIVE_MASK };
        if file_version < values::VERSION_NODE_MASK_COMPRESSION {
            file_compression = if cur.u8("header")? != 0 { COMPRESS_ZIP } else { 0 };
        }
        let uuid = String::from_utf8_lossy(cur.take(36, "header uuid")?).into_owned();
        let metadata = meta::read_meta_map(&mut cur)?;
        let grid_count = cur.i32("grid count")?;
        if grid_count < 0 {
            return Err(Error::invalid("grid count", cur.pos() - 4, format!("{grid_count} is negative")));
        }
        // A descriptor holds three strings and three offsets: at least 36 bytes.
        cur.check_count("grid count", grid_count as u64, 36)?;
        let mut file = VdbFile { file_version, library_version, uuid, has_grid_offsets, metadata, grids: Vec::new(), data: Bytes::Owned(Vec::new()) };
        for _ in 0..grid_count {
            let info = file.parse_grid(&mut cur, file_compression)?;
            file.grids.push(info);
        }
        file.data = data;
        Ok(file)
    }

    fn parse_grid(&self, cur: &mut Cursor<'_>, file_compression: u32) -> Result<GridInfo, Error> {
        let unique_name = cur.string("grid name")?;
        let name = unique_name.split(UNIQUE_SEP).next().unwrap_or("").to_string();
        let label = if name.is_empty() { "(unnamed)".to_string() } else { name.clone() };
        let ctx_err = |e: Error| e.in_grid(&label);
        let mut tree_type = cur.string("grid type").map_err(ctx_err)?;
        let half_float = tree_type.ends_with(HALF_SUFFIX);
        if half_float {
            tree_type.truncate(tree_type.len() - HALF_SUFFIX.len());
        }
        let parent = cur.string("instance parent").map_err(ctx_err)?;
        let at = cur.pos();
        let grid_pos = cur.i64("grid offset").map_err(ctx_err)?;
        let _block_pos = cur.i64("grid offset").map_err(ctx_err)?;
        let end_pos = cur.i64("grid offset").map_err(ctx_err)?;
        let len = cur.pos() + cur.remaining();
        let (value_type, mut unsupported) = parse_tree_type(&tree_type);

        let mut g = if self.has_grid_offsets {
            let ok = |p: i64| p >= 0 && (p as u64) <= len as u64;
            if grid_pos >= 0 && end_pos >= grid_pos && ok(grid_pos) && !ok(end_pos) {
                return Err(ctx_err(Error::Truncated { what: "grid data", offset: grid_pos as u64, need: (end_pos - grid_pos) as u64, have: (len as u64).saturating_sub(grid_pos as u64) }));
            }
            // A grid's data lies between its descriptor and the next one, so
            // grids cannot share (or re-read) each other's bytes: reading a
            // file is linear in its size.
            if grid_pos < cur.pos() as i64 {
                return Err(ctx_err(Error::invalid("grid descriptor", at, format!("grid data at offset {grid_pos} starts before its descriptor ends ({})", cur.pos()))));
            }
            if !ok(grid_pos) || !ok(end_pos) || end_pos < grid_pos {
                return Err(ctx_err(Error::invalid("grid descriptor", at, format!("grid offsets {grid_pos}..{end_pos} do not fit in the file ({len} bytes)"))));
            }
            Cursor::at(cur.data(), grid_pos as usize).map_err(ctx_err)?
        } else {
            Cursor::at(cur.data(), cur.pos()).map_err(ctx_err)?
        };
        let mut compression = file_compression;
        if self.file_version >= values::VERSION_NODE_MASK_COMPRESSION {
            compression = g.u32("grid compression").map_err(ctx_err)?;
        }
        let metadata = meta::read_meta_map(&mut g).map_err(ctx_err)?;
        let class = GridClass::from_vdb_name(metadata.get("class").and_then(MetaValue::as_str).unwrap_or(""));
        let transform = match map::read_transform(&mut g) {
            Ok(t) => Some(t),
            Err(map::MapError::NonLinear(m)) => {
                unsupported = Some(Unsupported::NonLinearMap(m));
                None
            }
            Err(map::MapError::Read(e)) => return Err(ctx_err(e)),
        };
        let instance_parent = if parent.is_empty() { None } else { Some(parent) };
        let info = GridInfo { name, unique_name, tree_type, value_type, half_float, instance_parent, compression, class, metadata, transform, unsupported, tree_pos: g.pos() };
        // Move to the next descriptor.
        if self.has_grid_offsets {
            *cur = Cursor::at(cur.data(), end_pos as usize).map_err(ctx_err)?;
        } else if info.instance_parent.is_some() {
            *cur = g;
        } else if !info.is_readable() {
            return Err(ctx_err(Error::Unsupported {
                grid: info.display_name(),
                reason: format!("{} (and the file has no grid offsets to skip it)", info.unsupported.as_ref().map(|u| u.to_string()).unwrap_or_default()),
            }));
        } else {
            tree::scan(&mut g, self.ctx(&info)).map_err(ctx_err)?;
            *cur = g;
        }
        Ok(info)
    }

    fn ctx(&self, g: &GridInfo) -> Ctx {
        let (value, components) = match g.value_type {
            ValueType::Scalar(s) => (s, 1),
            ValueType::Vec3(s) => (s, 3),
            ValueType::Other(_) => (ScalarType::Float, 1),
        };
        Ctx { version: self.file_version, compression: g.compression, value, components, from_half: g.half_float && value != ScalarType::Half, background: [0.0; MAX_COMPONENTS] }
    }

    /// The whole file's bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data
    }

    /// Names of all grids, for error messages.
    pub fn grid_names(&self) -> String {
        let names: Vec<String> = self.grids.iter().map(|g| format!("{} ({})", g.display_name(), g.value_type.name())).collect();
        if names.is_empty() {
            "no grids".into()
        } else {
            names.join(", ")
        }
    }

    /// Picks a grid: by name, or else `density`, or else the first readable scalar grid.
    pub fn select(&self, name: Option<&str>) -> Result<usize, Error> {
        match name {
            Some(n) => self.grids.iter().position(|g| g.name == n || g.unique_name == n).ok_or_else(|| Error::NoSuchGrid { name: n.to_string(), available: self.grid_names() }),
            None => self
                .grids
                .iter()
                .position(|g| g.name == "density" && g.is_readable_scalar())
                .or_else(|| self.grids.iter().position(GridInfo::is_readable_scalar))
                .ok_or_else(|| Error::NoScalarGrid { available: self.grid_names() }),
        }
    }

    /// Reads scalar grid `index`'s tree (its instance parent's, for an
    /// instance).  A vec3 grid is refused: see [`VdbFile::read_vec3`].
    pub fn read_grid(&self, index: usize) -> Result<Grid, Error> {
        let [grid] = self.read_tree::<1>(index, false)?;
        Ok(grid)
    }

    /// Reads vec3 grid `index` as three scalar grids, its x, y and z
    /// components, named `NAME.x`, `NAME.y` and `NAME.z`: the same leaves,
    /// active masks and tiles, each with its component of the background and
    /// of every value, and the grid's class and transform.  A scalar grid is refused.
    pub fn read_vec3(&self, index: usize) -> Result<[Grid; 3], Error> {
        self.read_tree::<3>(index, true)
    }

    /// Reads grid `index` as scalar channels: one grid for a float, double or
    /// half grid, three ([`VdbFile::read_vec3`]) for a vec3 grid; names as
    /// [`GridInfo::channel_names`].
    pub fn read_channels(&self, index: usize) -> Result<Vec<Grid>, Error> {
        match self.grids.get(index) {
            Some(info) if info.is_readable_vec3() => Ok(self.read_vec3(index)?.into()),
            _ => Ok(vec![self.read_grid(index)?]),
        }
    }

    /// Reads grid `index`'s tree as `N` component grids (`vec3`: whether a vec3 grid is expected).
    fn read_tree<const N: usize>(&self, index: usize, vec3: bool) -> Result<[Grid; N], Error> {
        let Some(info) = self.grids.get(index) else {
            return Err(Error::NoSuchGrid { name: format!("#{index}"), available: self.grid_names() });
        };
        let gname = info.display_name();
        let readable = |g: &GridInfo| if vec3 { g.is_readable_vec3() } else { g.is_readable_scalar() };
        if !readable(info) {
            let reason = match &info.unsupported {
                Some(u @ Unsupported::Vector(_)) => format!("{u}: read it with read_vec3 or read_channels"),
                Some(u) => u.to_string(),
                None => format!("value type {} is not a vector", info.value_type.name()),
            };
            return Err(Error::Unsupported { grid: gname, reason });
        }
        let source = match &info.instance_parent {
            None => info,
            Some(p) => {
                let parent = self
                    .grids
                    .iter()
                    .find(|g| &g.unique_name == p && g.instance_parent.is_none())
                    .ok_or_else(|| Error::invalid("grid descriptor", 0, format!("instance parent \"{}\" is missing", p.escape_debug())).in_grid(&gname))?;
                if !readable(parent) {
                    let why = parent.unsupported.as_ref().map(|u| u.to_string()).unwrap_or_else(|| format!("value type {} is not a vector", parent.value_type.name()));
                    return Err(Error::Unsupported { grid: gname, reason: format!("its instance parent: {why}") });
                }
                parent
            }
        };
        let read = || -> Result<[Grid; N], Error> {
            let mut cur = Cursor::at(&self.data, source.tree_pos)?;
            let layout = tree::scan(&mut cur, self.ctx(source))?;
            let comps = layout.decode::<N>()?;
            let transform = info.transform.unwrap_or_else(Transform::identity);
            let mut c = 0;
            Ok(comps.map(|comp| {
                let name = if vec3 { format!("{}{}", info.name, VEC3_SUFFIXES.get(c).unwrap_or(&"")) } else { info.name.clone() };
                c += 1;
                Grid { name, class: info.class, background: comp.background, transform, leaves: comp.leaves, tiles: comp.tiles }
            }))
        };
        read().map_err(|e| e.in_grid(&gname))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tree_types_name_vec3_grids() {
        let (v, u) = parse_tree_type("Tree_vec3s_5_4_3");
        assert_eq!((v.name(), v.components()), ("vec3s", 3));
        assert_eq!(u, Some(Unsupported::Vector("vec3s".into())));
        let (v, _) = parse_tree_type("Tree_vec3d_5_4_3");
        assert_eq!(v, ValueType::Vec3(ScalarType::Double));
        assert_eq!(parse_tree_type("Tree_float_5_4_3"), (ValueType::Scalar(ScalarType::Float), None));
        assert_eq!(parse_tree_type("Tree_vec3i_5_4_3").1, Some(Unsupported::ValueType("vec3i".into())));
        assert_eq!(parse_tree_type("Tree_vec3s_4_3_3").1, Some(Unsupported::TreeLayout("Tree_vec3s_4_3_3".into())));
        assert!(Unsupported::Vector("vec3s".into()).to_string().contains("vec3s"));
    }
}
