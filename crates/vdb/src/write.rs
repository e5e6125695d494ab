//! Writes one float grid as a .vdb file that OpenVDB reads (the format is
//! described in lib.rs and tree.rs).
//!
//! Every node stores all of its values (per-node metadata 6, "no mask, all
//! values"), zlib-compressed or raw, so inactive leaf values survive the round
//! trip.  File version 224 is the default; 221 (per-file compression, packed
//! internal-node values, leaf origins in the buffers) exists so the reader's
//! legacy path can be checked against OpenVDB.

use crate::values::{COMPRESS_ZIP, VERSION_NODE_MASK_COMPRESSION};
use std::collections::BTreeMap;
use std::io::Write;
use vdbcook_grid::{Coord, Grid, Leaf, MapType, LEAF_VOXELS};

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

#[derive(Default)]
struct Node16<'a> {
    leaves: BTreeMap<usize, &'a Leaf>,
    tiles: BTreeMap<usize, (f32, bool)>,
}

#[derive(Default)]
struct Node32<'a> {
    children: BTreeMap<usize, Node16<'a>>,
    tiles: BTreeMap<usize, (f32, bool)>,
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

    /// An internal node's topology: masks and the tile values (all slots, or
    /// only the slots without a child before version 222).
    fn internal(&mut self, slots: usize, children: &[bool], tiles: &BTreeMap<usize, (f32, bool)>, background: f32) -> std::io::Result<()> {
        let mut active = vec![false; slots];
        let mut vals = vec![background; slots];
        for (&i, &(v, on)) in tiles {
            if !children[i] {
                vals[i] = v;
                active[i] = on;
            }
        }
        self.mask(children);
        self.mask(&active);
        if self.opts.version < VERSION_NODE_MASK_COMPRESSION {
            let packed: Vec<f32> = (0..slots).filter(|&i| !children[i]).map(|i| vals[i]).collect();
            self.values(&packed)
        } else {
            self.values(&vals)
        }
    }
}

fn map_record(out: &mut Out, grid: &Grid) {
    let t = &grid.transform;
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

/// Serialises `grid` as a complete .vdb file.
pub fn write_vdb(grid: &Grid, opts: WriteOptions) -> std::io::Result<Vec<u8>> {
    if opts.version != 224 && opts.version != 221 {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("cannot write file version {} (224 or 221)", opts.version)));
    }
    // Gather the tree: 32³ nodes keyed by origin, root tiles apart.
    let mut roots: BTreeMap<Coord, Node32<'_>> = BTreeMap::new();
    let mut root_tiles: Vec<(Coord, f32, bool)> = Vec::new();
    for leaf in &grid.leaves {
        let n32 = roots.entry(origin32(leaf.origin)).or_default();
        let n16 = n32.children.entry(slot(leaf.origin, 5, 7)).or_default();
        n16.leaves.insert(slot(leaf.origin, 4, 3), leaf);
    }
    for t in &grid.tiles {
        match t.dim {
            4096 => root_tiles.push((t.origin, t.value, t.active)),
            128 => {
                roots.entry(origin32(t.origin)).or_default().tiles.insert(slot(t.origin, 5, 7), (t.value, t.active));
            }
            _ => {
                let n32 = roots.entry(origin32(t.origin)).or_default();
                n32.children.entry(slot(t.origin, 5, 7)).or_default().tiles.insert(slot(t.origin, 4, 3), (t.value, t.active));
            }
        }
    }
    root_tiles.sort_by_key(|t| t.0);

    let mut out = Out { buf: Vec::new(), opts };
    out.i64(0x5644_4220);
    out.u32(opts.version);
    out.u32(10);
    out.u32(0);
    out.u8(1); // has grid offsets
    if opts.version < VERSION_NODE_MASK_COMPRESSION {
        out.u8(u8::from(opts.zip));
    }
    // A deterministic UUID derived from the grid's name and shape.
    let seed = grid.leaves.len() as u64 ^ (grid.tiles.len() as u64) << 32 ^ grid.name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3));
    let hex = format!("{seed:016x}{:016x}", seed.rotate_left(17) ^ 0x9e37_79b9_7f4a_7c15);
    out.bytes(format!("{}-{}-{}-{}-{}", &hex[0..8], &hex[8..12], &hex[12..16], &hex[16..20], &hex[20..32]).as_bytes());
    // File metadata.
    out.u32(1);
    out.meta_string("creator", concat!("vdbcook ", env!("CARGO_PKG_VERSION")));
    out.i32(1); // grid count
    out.string(&grid.name);
    out.string("Tree_float_5_4_3");
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
    out.meta_string("class", grid.class.vdb_name());
    out.meta_string("name", &grid.name);
    map_record(&mut out, grid);

    // Topology.
    let bg = grid.background;
    out.i32(1);
    out.f32(bg);
    out.u32(root_tiles.len() as u32);
    out.u32(roots.len() as u32);
    for (o, v, on) in &root_tiles {
        out.coord(*o);
        out.f32(*v);
        out.u8(u8::from(*on));
    }
    for (o32, n32) in &roots {
        out.coord(*o32);
        let mut kids = vec![false; 32768];
        for &i in n32.children.keys() {
            kids[i] = true;
        }
        out.internal(32768, &kids, &n32.tiles, bg)?;
        for n16 in n32.children.values() {
            let mut kids = vec![false; 4096];
            for &i in n16.leaves.keys() {
                kids[i] = true;
            }
            out.internal(4096, &kids, &n16.tiles, bg)?;
            for leaf in n16.leaves.values() {
                out.bytes(&leaf_mask_bytes(leaf));
            }
        }
    }
    let block_pos = out.buf.len();
    // Buffers, in the same order.
    for n32 in roots.values() {
        for n16 in n32.children.values() {
            for leaf in n16.leaves.values() {
                out.bytes(&leaf_mask_bytes(leaf));
                if opts.version < VERSION_NODE_MASK_COMPRESSION {
                    out.coord(leaf.origin);
                    out.u8(1);
                }
                out.values(&leaf.values[..LEAF_VOXELS])?;
            }
        }
    }
    let end_pos = out.buf.len();
    for (k, v) in [grid_pos, block_pos, end_pos].into_iter().enumerate() {
        let at = offsets_at + 8 * k;
        out.buf[at..at + 8].copy_from_slice(&(v as i64).to_le_bytes());
    }
    Ok(out.buf)
}

fn leaf_mask_bytes(leaf: &Leaf) -> [u8; 64] {
    let mut b = [0u8; 64];
    for (chunk, w) in b.chunks_exact_mut(8).zip(leaf.mask.0) {
        chunk.copy_from_slice(&w.to_le_bytes());
    }
    b
}
