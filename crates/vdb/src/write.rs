//! Writes float and vec3s grids, one or several per file, as a .vdb file
//! that OpenVDB reads (the format is described in lib.rs and tree.rs).
//!
//! Every node stores all of its values (per-node metadata 6, "no mask, all
//! values"), zlib-compressed or raw, so inactive leaf values survive the round
//! trip.  A vec3s value is three consecutive floats (x, y, z), written from
//! three component grids that share one topology.  File version 224 is the
//! default; 221 (per-file compression, packed internal-node values, leaf
//! origins in the buffers) exists so the reader's legacy path can be checked
//! against OpenVDB.

use crate::values::{COMPRESS_ZIP, VERSION_NODE_MASK_COMPRESSION};
use std::collections::BTreeMap;
use std::io::Write;
use vdbcook_grid::{Coord, Grid, GridClass, Leaf, MapType, Transform, LEAF_VOXELS};

/// Output choices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WriteOptions {
    /// File format version: 224 (current) or 221 (legacy).
    pub version: u32,
    /// zlib-compress value buffers.
    pub zip: bool,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions { version: 224, zip: true }
    }
}

/// One grid to write.
#[derive(Clone, Copy, Debug)]
pub enum WriteGrid<'a> {
    /// A float grid (`Tree_float_5_4_3`): its name, class, transform,
    /// background, leaves and tiles.
    Float(&'a Grid),
    /// A vec3s grid (`Tree_vec3s_5_4_3`) given as its x, y and z component
    /// grids, which must share one topology (leaf origins and active masks,
    /// tile origins, sizes and active states) and one transform; the
    /// background and values are each component's.  The component grids'
    /// own names and classes are ignored.
    Vec3 { name: &'a str, class: GridClass, components: [&'a Grid; 3] },
}

fn invalid(msg: String) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidInput, msg)
}

/// Most components per value (vec3).
const MAX_COMPONENTS: usize = 3;
type Value = [f32; MAX_COMPONENTS];

/// A grid ready to serialise: its component grids (1 or 3) and their shared tree.
struct Source<'a> {
    name: &'a str,
    class: GridClass,
    transform: Transform,
    tree_type: &'static str,
    comps: Vec<&'a Grid>,
    background: Value,
}

impl<'a> Source<'a> {
    fn new(g: &WriteGrid<'a>) -> std::io::Result<Source<'a>> {
        match *g {
            WriteGrid::Float(grid) => {
                Ok(Source { name: &grid.name, class: grid.class, transform: grid.transform, tree_type: "Tree_float_5_4_3", comps: vec![grid], background: [grid.background, 0.0, 0.0] })
            }
            WriteGrid::Vec3 { name, class, components } => {
                let [x, y, z] = components;
                for (c, g) in [y, z].into_iter().enumerate() {
                    let axis = ["y", "z"][c];
                    if g.transform != x.transform {
                        return Err(invalid(format!("vec3 grid \"{name}\": the {axis} component's transform differs from the x component's")));
                    }
                    if g.leaves.len() != x.leaves.len() || g.leaves.iter().zip(&x.leaves).any(|(a, b)| a.origin != b.origin || a.mask != b.mask) {
                        return Err(invalid(format!("vec3 grid \"{name}\": the {axis} component's leaves or active masks differ from the x component's")));
                    }
                }
                Ok(Source { name, class, transform: x.transform, tree_type: "Tree_vec3s_5_4_3", comps: components.to_vec(), background: [x.background, y.background, z.background] })
            }
        }
    }

    /// Tiles of every component merged by (size, origin): each its component
    /// values (the component's background where a component lacks an inactive tile).
    fn tiles(&self) -> std::io::Result<BTreeMap<(u32, Coord), (Value, bool)>> {
        let mut tiles: BTreeMap<(u32, Coord), (Value, bool, usize)> = BTreeMap::new();
        for (c, g) in self.comps.iter().enumerate() {
            for t in &g.tiles {
                if !matches!(t.dim, 8 | 128 | 4096) || !t.origin.is_aligned(t.dim as i32) {
                    return Err(invalid(format!("grid \"{}\": tile of size {} at {:?} is not an aligned 8, 128 or 4096 tile", self.name, t.dim, t.origin.to_array())));
                }
                let e = tiles.entry((t.dim, t.origin)).or_insert((self.background, t.active, 0));
                if e.1 != t.active {
                    return Err(invalid(format!("vec3 grid \"{}\": the tile at {:?} is active in some components only", self.name, t.origin.to_array())));
                }
                e.0[c] = t.value;
                e.2 += 1;
            }
        }
        if let Some(((_, o), _)) = tiles.iter().find(|(_, t)| t.1 && t.2 != self.comps.len()) {
            return Err(invalid(format!("vec3 grid \"{}\": the active tile at {:?} is missing from some components", self.name, o.to_array())));
        }
        Ok(tiles.into_iter().map(|(k, (v, on, _))| (k, (v, on))).collect())
    }
}

#[derive(Default)]
struct Node16 {
    /// Slot to index in the components' leaf lists.
    leaves: BTreeMap<usize, usize>,
    tiles: BTreeMap<usize, (Value, bool)>,
}

#[derive(Default)]
struct Node32 {
    children: BTreeMap<usize, Node16>,
    tiles: BTreeMap<usize, (Value, bool)>,
}

/// Slot of `c` inside the node of `2^log2dim` slots per axis of `child_log2` voxels each.
fn slot(c: Coord, log2dim: u32, child_log2: u32) -> usize {
    let m = (1i32 << log2dim) - 1;
    let x = ((c.x >> child_log2) & m) as usize;
    let y = ((c.y >> child_log2) & m) as usize;
    let z = ((c.z >> child_log2) & m) as usize;
    (x << (2 * log2dim)) | (y << log2dim) | z
}

fn origin32(c: Coord) -> Coord {
    Coord::new(c.x & !4095, c.y & !4095, c.z & !4095)
}

struct Out {
    buf: Vec<u8>,
    opts: WriteOptions,
}

impl Out {
    fn bytes(&mut self, b: &[u8]) {
        self.buf.extend_from_slice(b);
    }
    fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.bytes(&v.to_le_bytes());
    }
    fn i64(&mut self, v: i64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.bytes(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.bytes(&v.to_le_bytes());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.bytes(s.as_bytes());
    }
    fn coord(&mut self, c: Coord) {
        for v in c.to_array() {
            self.i32(v);
        }
    }
    fn mask(&mut self, bits: &[bool]) {
        for word in bits.chunks(64) {
            let w = word.iter().enumerate().fold(0u64, |w, (i, &b)| w | (u64::from(b) << i));
            self.bytes(&w.to_le_bytes());
        }
    }
    fn meta_string(&mut self, name: &str, value: &str) {
        self.string(name);
        self.string("string");
        self.string(value);
    }

    /// A value buffer: [metadata 6] then the values, zlib-compressed or raw.
    fn values(&mut self, vals: &[f32]) -> std::io::Result<()> {
        if self.opts.version >= VERSION_NODE_MASK_COMPRESSION {
            self.u8(6);
        }
        let raw: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
        if self.opts.zip {
            let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::new(6));
            z.write_all(&raw)?;
            let packed = z.finish()?;
            self.i64(packed.len() as i64);
            self.bytes(&packed);
        } else {
            self.bytes(&raw);
        }
        Ok(())
    }

    /// One value's `n` components.
    fn value(&mut self, v: &Value, n: usize) {
        for x in &v[..n] {
            self.f32(*x);
        }
    }

    /// An internal node's topology: masks and the tile values (all slots, or
    /// only the slots without a child before version 222), `n` components each.
    fn internal(&mut self, slots: usize, children: &[bool], tiles: &BTreeMap<usize, (Value, bool)>, background: &Value, n: usize) -> std::io::Result<()> {
        let mut active = vec![false; slots];
        let mut vals: Vec<f32> = (0..slots).flat_map(|_| background[..n].iter().copied()).collect();
        for (&i, &(v, on)) in tiles {
            if !children[i] {
                vals[i * n..i * n + n].copy_from_slice(&v[..n]);
                active[i] = on;
            }
        }
        self.mask(children);
        self.mask(&active);
        if self.opts.version < VERSION_NODE_MASK_COMPRESSION {
            let packed: Vec<f32> = (0..slots).filter(|&i| !children[i]).flat_map(|i| vals[i * n..i * n + n].iter().copied()).collect();
            self.values(&packed)
        } else {
            self.values(&vals)
        }
    }
}

fn map_record(out: &mut Out, t: &Transform) {
    out.string(t.map_type.vdb_name());
    let m = &t.matrix;
    let scale = [m[0][0], m[1][1], m[2][2]];
    let scale_block = |out: &mut Out| {
        let inv = scale.map(|s| 1.0 / s);
        for v in [scale, scale.map(f64::abs), inv, inv.map(|i| i * i), inv.map(|i| i * 0.5)] {
            for x in v {
                out.f64(x);
            }
        }
    };
    match t.map_type {
        MapType::Scale | MapType::UniformScale => scale_block(out),
        MapType::ScaleTranslate | MapType::UniformScaleTranslate => {
            for x in t.translation() {
                out.f64(x);
            }
            scale_block(out);
        }
        MapType::Translation => {
            for x in t.translation() {
                out.f64(x);
            }
        }
        MapType::Affine | MapType::Unitary => {
            for x in m.iter().flatten() {
                out.f64(*x);
            }
        }
    }
}

/// Serialises `grid` (a float grid) as a complete .vdb file.
pub fn write_vdb(grid: &Grid, opts: WriteOptions) -> std::io::Result<Vec<u8>> {
    write_vdb_grids(&[WriteGrid::Float(grid)], opts)
}

/// A deterministic UUID derived from the grids' names and shapes.
fn uuid(sources: &[Source<'_>]) -> String {
    let mut seed = 0u64;
    for (i, s) in sources.iter().enumerate() {
        let g = s.comps[0];
        let h = g.leaves.len() as u64 ^ (g.tiles.len() as u64) << 32 ^ s.name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3));
        seed = if i == 0 { h } else { seed.rotate_left(5) ^ h };
    }
    let hex = format!("{seed:016x}{:016x}", seed.rotate_left(17) ^ 0x9e37_79b9_7f4a_7c15);
    format!("{}-{}-{}-{}-{}", &hex[0..8], &hex[8..12], &hex[12..16], &hex[16..20], &hex[20..32])
}

/// Serialises `grids`, in order, as one complete .vdb file.  Grids sharing
/// a name are told apart as OpenVDB does (`name\x1eN` descriptor names).
pub fn write_vdb_grids(grids: &[WriteGrid<'_>], opts: WriteOptions) -> std::io::Result<Vec<u8>> {
    if opts.version != 224 && opts.version != 221 {
        return Err(invalid(format!("cannot write file version {} (224 or 221)", opts.version)));
    }
    let sources = grids.iter().map(Source::new).collect::<std::io::Result<Vec<_>>>()?;
    let mut out = Out { buf: Vec::new(), opts };
    out.i64(0x5644_4220);
    out.u32(opts.version);
    out.u32(10);
    out.u32(0);
    out.u8(1); // has grid offsets
    if opts.version < VERSION_NODE_MASK_COMPRESSION {
        out.u8(u8::from(opts.zip));
    }
    out.bytes(uuid(&sources).as_bytes());
    // File metadata.
    out.u32(1);
    out.meta_string("creator", concat!("vdbcook ", env!("CARGO_PKG_VERSION")));
    out.i32(i32::try_from(sources.len()).map_err(|_| invalid(format!("{} grids are too many for one file", sources.len())))?);
    let mut seen: BTreeMap<&str, usize> = BTreeMap::new();
    for src in &sources {
        let dups = sources.iter().filter(|s| s.name == src.name).count();
        let n = seen.entry(src.name).or_insert(0);
        let unique = if dups > 1 { format!("{}\u{1e}{n}", src.name) } else { src.name.to_string() };
        *n += 1;
        write_grid(&mut out, src, &unique)?;
    }
    Ok(out.buf)
}

/// One grid: descriptor, metadata, transform, topology and buffers.
fn write_grid(out: &mut Out, src: &Source<'_>, unique_name: &str) -> std::io::Result<()> {
    let opts = out.opts;
    let n = src.comps.len();
    let first = src.comps[0];
    // Gather the tree: 32³ nodes keyed by origin, root tiles apart.
    let mut roots: BTreeMap<Coord, Node32> = BTreeMap::new();
    let mut root_tiles: Vec<(Coord, Value, bool)> = Vec::new();
    for (i, leaf) in first.leaves.iter().enumerate() {
        let n32 = roots.entry(origin32(leaf.origin)).or_default();
        let n16 = n32.children.entry(slot(leaf.origin, 5, 7)).or_default();
        n16.leaves.insert(slot(leaf.origin, 4, 3), i);
    }
    for ((dim, origin), (value, active)) in src.tiles()? {
        match dim {
            4096 => root_tiles.push((origin, value, active)),
            128 => {
                roots.entry(origin32(origin)).or_default().tiles.insert(slot(origin, 5, 7), (value, active));
            }
            _ => {
                let n32 = roots.entry(origin32(origin)).or_default();
                n32.children.entry(slot(origin, 5, 7)).or_default().tiles.insert(slot(origin, 4, 3), (value, active));
            }
        }
    }
    root_tiles.sort_by_key(|t| t.0);
    // A tile where a child node or leaf also is would make two entries for one slot.
    let overlap = |o: Coord| invalid(format!("grid \"{}\": the tile at {:?} overlaps a leaf", src.name, o.to_array()));
    if let Some(t) = root_tiles.iter().find(|t| roots.contains_key(&t.0)) {
        return Err(overlap(t.0));
    }
    for n32 in roots.values() {
        if n32.tiles.keys().any(|i| n32.children.contains_key(i)) || n32.children.values().any(|n16| n16.tiles.keys().any(|i| n16.leaves.contains_key(i))) {
            return Err(invalid(format!("grid \"{}\": a tile overlaps a leaf", src.name)));
        }
    }

    out.string(unique_name);
    out.string(src.tree_type);
    out.string(""); // instance parent
    let offsets_at = out.buf.len();
    out.i64(0);
    out.i64(0);
    out.i64(0);
    let grid_pos = out.buf.len();
    if opts.version >= VERSION_NODE_MASK_COMPRESSION {
        out.u32(if opts.zip { COMPRESS_ZIP } else { 0 });
    }
    out.u32(2);
    out.meta_string("class", src.class.vdb_name());
    out.meta_string("name", src.name);
    map_record(out, &src.transform);

    // Topology.
    let bg = src.background;
    out.i32(1);
    out.value(&bg, n);
    out.u32(root_tiles.len() as u32);
    out.u32(roots.len() as u32);
    for (o, v, on) in &root_tiles {
        out.coord(*o);
        out.value(v, n);
        out.u8(u8::from(*on));
    }
    for (o32, n32) in &roots {
        out.coord(*o32);
        let mut kids = vec![false; 32768];
        for &i in n32.children.keys() {
            kids[i] = true;
        }
        out.internal(32768, &kids, &n32.tiles, &bg, n)?;
        for n16 in n32.children.values() {
            let mut kids = vec![false; 4096];
            for &i in n16.leaves.keys() {
                kids[i] = true;
            }
            out.internal(4096, &kids, &n16.tiles, &bg, n)?;
            for &i in n16.leaves.values() {
                out.bytes(&leaf_mask_bytes(&first.leaves[i]));
            }
        }
    }
    let block_pos = out.buf.len();
    // Buffers, in the same order.
    let mut interleaved = vec![0.0f32; LEAF_VOXELS * n];
    for n32 in roots.values() {
        for n16 in n32.children.values() {
            for &i in n16.leaves.values() {
                let leaf = &first.leaves[i];
                out.bytes(&leaf_mask_bytes(leaf));
                if opts.version < VERSION_NODE_MASK_COMPRESSION {
                    out.coord(leaf.origin);
                    out.u8(1);
                }
                if n == 1 {
                    out.values(&leaf.values[..LEAF_VOXELS])?;
                } else {
                    for (c, g) in src.comps.iter().enumerate() {
                        for (v, x) in g.leaves[i].values.iter().enumerate() {
                            interleaved[v * n + c] = *x;
                        }
                    }
                    out.values(&interleaved)?;
                }
            }
        }
    }
    let end_pos = out.buf.len();
    for (k, v) in [grid_pos, block_pos, end_pos].into_iter().enumerate() {
        let at = offsets_at + 8 * k;
        out.buf[at..at + 8].copy_from_slice(&(v as i64).to_le_bytes());
    }
    Ok(())
}

fn leaf_mask_bytes(leaf: &Leaf) -> [u8; 64] {
    let mut b = [0u8; 64];
    for (chunk, w) in b.chunks_exact_mut(8).zip(leaf.mask.0) {
        chunk.copy_from_slice(&w.to_le_bytes());
    }
    b
}
