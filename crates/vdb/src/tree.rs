//! The 5-4-3 tree: topology (root, internal nodes with their tiles, leaf
//! masks) and then the leaf value buffers.
//!
//! ```text
//! topology:
//!   i32 buffer count (1)
//!   root:  value background, u32 tile count, u32 child count,
//!          tiles  × (i32 x, y, z, value, u8 active),
//!          children × (i32 x, y, z, internal32)
//!   internal32 (32³ slots of 128³ voxels): child mask (4096 B), value mask (4096 B),
//!          value buffer of 32768 tile values, then each child internal16 in mask order
//!   internal16 (16³ slots of 8³ voxels): child mask (512 B), value mask (512 B),
//!          value buffer of 4096 tile values, then each child leaf mask (64 B) in mask order
//! buffers, for every leaf (root children in coordinate order, then mask order):
//!   leaf mask (64 B), [v < 222: i32 x, y, z origin, i8 buffer count], value buffer of 512 values
//! ```
//! A `value` is one scalar, or for vec3 trees three consecutive scalars
//! (x, y, z); value buffers hold `count × components` scalars.
//!
//! Everything is read sequentially by [`scan`], which records each leaf's
//! value buffer; [`TreeLayout::decode`] then inflates the leaves in parallel
//! and splits vectors into one scalar tree per component (same leaves, masks
//! and tiles; each its component of every value).

use crate::cursor::Cursor;
use crate::values::{self, Ctx, Value, ValueBlock, COMPRESS_ZIP, MAX_COMPONENTS, VERSION_NODE_MASK_COMPRESSION};
use crate::Error;
use rayon::prelude::*;
use std::sync::Mutex;
use vdbcook_grid::{set_bits, Coord, Leaf, LeafMask, Tile, LEAF_VOXELS};

struct LeafTopo<'a> {
    origin: Coord,
    mask: LeafMask,
    values: Option<ValueBlock<'a>>,
}

/// A tile whose value has every component.
#[derive(Clone, Copy, Debug)]
struct VecTile {
    origin: Coord,
    dim: u32,
    value: Value,
    active: bool,
}

/// A scanned tree: tiles decoded, leaf buffers located.
pub(crate) struct TreeLayout<'a> {
    tiles: Vec<VecTile>,
    leaves: Vec<LeafTopo<'a>>,
    ctx: Ctx,
}

/// One component of a decoded tree, as a scalar tree.
#[derive(Debug)]
pub(crate) struct Component {
    pub background: f32,
    pub tiles: Vec<Tile>,
    /// Sorted by origin.
    pub leaves: Vec<Leaf>,
}

/// Bytes one node of each kind occupies in the topology at the very least,
/// used to refuse counts the file cannot hold before allocating for them.
const MIN_LEAF_BYTES: u64 = 64;
const MIN_INTERNAL16_BYTES: u64 = 1024 + 1;
const MIN_INTERNAL32_BYTES: u64 = 8192 + 1;

fn bit(words: &[u64], i: usize) -> bool {
    words.get(i >> 6).is_some_and(|w| (w >> (i & 63)) & 1 == 1)
}

fn ones(words: &[u64]) -> u64 {
    words.iter().map(|w| u64::from(w.count_ones())).sum()
}

/// Origin of slot `i` in an internal node with `2^log2dim` slots per axis of `child_dim` voxels.
fn slot_origin(origin: Coord, i: usize, log2dim: u32, child_dim: i32) -> Coord {
    let m = (1usize << log2dim) - 1;
    let x = ((i >> (2 * log2dim)) & m) as i32;
    let y = ((i >> log2dim) & m) as i32;
    let z = (i & m) as i32;
    origin.offset(x * child_dim, y * child_dim, z * child_dim)
}

/// An internal node's shape and masks, for [`Scanner::node_tiles`].
struct Node<'m> {
    origin: Coord,
    log2dim: u32,
    child_dim: i32,
    /// Values stored only for slots without a child (before version 222).
    packed: bool,
    child_mask: &'m [u64],
    value_mask: &'m [u64],
}

struct Scanner<'c, 'a> {
    cur: &'c mut Cursor<'a>,
    ctx: Ctx,
    tiles: Vec<VecTile>,
}

impl<'a> Scanner<'_, 'a> {
    /// Keeps a tile that is active or differs from the background (in any
    /// component, so that every component has the same tiles).
    fn tile(&mut self, origin: Coord, dim: u32, value: Value, active: bool) {
        if active || value != self.ctx.background {
            self.tiles.push(VecTile { origin, dim, value, active });
        }
    }

    /// Reads an internal node's masks and tile values; returns the child mask.
    fn internal(&mut self, origin: Coord, log2dim: u32, child_dim: i32) -> Result<Vec<u64>, Error> {
        let slots = 1usize << (3 * log2dim);
        let child_mask = self.cur.mask(slots / 64, "internal node child mask")?;
        let value_mask = self.cur.mask(slots / 64, "internal node value mask")?;
        // Before version 222 only the slots without a child store a value.
        let packed = self.ctx.version < VERSION_NODE_MASK_COMPRESSION;
        let count = if packed { slots - ones(&child_mask) as usize } else { slots };
        let blk = values::scan(self.cur, &self.ctx, count, &value_mask)?;
        let n = self.ctx.components;
        let mut vals = vec![0.0f32; count * n];
        blk.decode(&self.ctx, &value_mask, &mut vals)?;
        let node = Node { origin, log2dim, child_dim, packed, child_mask: &child_mask, value_mask: &value_mask };
        match n {
            1 => self.node_tiles::<1>(&node, &vals),
            _ => self.node_tiles::<MAX_COMPONENTS>(&node, &vals),
        }
        Ok(child_mask)
    }

    /// Keeps the tiles among an internal node's slots (values of `N` components each).
    fn node_tiles<const N: usize>(&mut self, node: &Node<'_>, vals: &[f32]) {
        let background = self.ctx.background;
        let bg = &background[..N];
        let mut next = 0;
        for i in 0..1usize << (3 * node.log2dim) {
            if bit(node.child_mask, i) {
                continue;
            }
            let at = if node.packed { next } else { i };
            next += 1;
            let Some(src) = vals.get(at * N..at * N + N) else { continue };
            let active = bit(node.value_mask, i);
            // Most slots are inactive background: skip them before building a tile.
            if !active && src == bg {
                continue;
            }
            let mut v = [0.0; MAX_COMPONENTS];
            v[..N].copy_from_slice(src);
            self.tile(slot_origin(node.origin, i, node.log2dim, node.child_dim), node.child_dim as u32, v, active);
        }
    }

    fn internal32(&mut self, origin: Coord, leaves: &mut Vec<LeafTopo<'a>>) -> Result<(), Error> {
        let child_mask = self.internal(origin, 5, 128)?;
        self.cur.check_count("internal node count", ones(&child_mask), MIN_INTERNAL16_BYTES)?;
        for i in set_bits(&child_mask) {
            let o16 = slot_origin(origin, i, 5, 128);
            let leaf_mask = self.internal(o16, 4, 8)?;
            self.cur.check_count("leaf count", ones(&leaf_mask), MIN_LEAF_BYTES)?;
            for j in set_bits(&leaf_mask) {
                let words = self.cur.mask(8, "leaf mask")?;
                let mut mask = LeafMask::default();
                mask.0.copy_from_slice(&words);
                leaves.push(LeafTopo { origin: slot_origin(o16, j, 4, 8), mask, values: None });
            }
        }
        Ok(())
    }
}

/// The leaves of the root children `roots` (each its origin and its leaves'
/// range of `leaves`, in file order) in the root's coordinate order, the
/// order OpenVDB writes (and reads) leaf buffers in. Files list root
/// children in that order too: then nothing moves.
fn in_root_order<'a>(leaves: Vec<LeafTopo<'a>>, mut roots: Vec<(Coord, std::ops::Range<usize>)>) -> Vec<LeafTopo<'a>> {
    if roots.is_sorted_by_key(|(o, _)| *o) {
        return leaves;
    }
    roots.sort_by_key(|(o, _)| *o);
    let n = leaves.len();
    let mut topo: Vec<Option<LeafTopo<'a>>> = leaves.into_iter().map(Some).collect();
    let sorted: Vec<LeafTopo<'a>> = roots.into_iter().flat_map(|(_, r)| r).filter_map(|i| topo.get_mut(i).and_then(Option::take)).collect();
    // The ranges cut the leaves into the children's, each leaf in one.
    debug_assert_eq!(sorted.len(), n);
    sorted
}

/// Reads topology and locates every leaf buffer, leaving the cursor at the
/// end of the tree.  `ctx.background` is filled in from the root.
pub(crate) fn scan<'a>(cur: &mut Cursor<'a>, mut ctx: Ctx) -> Result<TreeLayout<'a>, Error> {
    let _buffer_count = cur.i32("tree buffer count")?;
    ctx.background = ctx.read_value(cur, "background value")?;
    let num_tiles = cur.u32("root tile count")?;
    let num_children = cur.u32("root child count")?;
    let tile_bytes = 12 + ctx.value_size() as u64 + 1;
    cur.check_count("root tile count", u64::from(num_tiles), tile_bytes)?;
    cur.check_count("root child count", u64::from(num_children), 12 + MIN_INTERNAL32_BYTES)?;

    let mut sc = Scanner { cur, ctx, tiles: Vec::new() };
    // Every root child's leaves in one vector, in file order; per child its origin and its leaves' range.
    let mut leaves: Vec<LeafTopo<'a>> = Vec::new();
    let mut roots: Vec<(Coord, std::ops::Range<usize>)> = Vec::with_capacity(num_children as usize);
    let mut origins = Vec::with_capacity((num_tiles + num_children) as usize);
    for _ in 0..num_tiles {
        let at = sc.cur.pos();
        let origin = sc.cur.coord("root tile")?;
        let value = ctx.read_value(sc.cur, "root tile")?;
        let active = sc.cur.u8("root tile")? != 0;
        if !origin.is_aligned(4096) {
            return Err(Error::invalid("root tile", at, format!("origin {:?} is not a multiple of 4096", origin.to_array())));
        }
        origins.push((origin, at));
        sc.tile(origin, 4096, value, active);
    }
    for _ in 0..num_children {
        let at = sc.cur.pos();
        let origin = sc.cur.coord("root child")?;
        if !origin.is_aligned(4096) {
            return Err(Error::invalid("root child", at, format!("origin {:?} is not a multiple of 4096", origin.to_array())));
        }
        origins.push((origin, at));
        let first = leaves.len();
        sc.internal32(origin, &mut leaves)?;
        roots.push((origin, first..leaves.len()));
    }
    origins.sort();
    if let Some(w) = origins.windows(2).find(|w| w[0].0 == w[1].0) {
        return Err(Error::invalid("root node", w[1].1, format!("two entries at origin {:?}", w[1].0.to_array())));
    }
    let tiles = sc.tiles;

    let mut leaves = in_root_order(leaves, roots);
    for leaf in leaves.iter_mut() {
        cur.take(64, "leaf buffer mask")?;
        let mut num_buffers = 1i8;
        if ctx.version < VERSION_NODE_MASK_COMPRESSION {
            cur.take(12, "leaf buffer origin")?;
            num_buffers = cur.u8("leaf buffer count")? as i8;
        }
        leaf.values = Some(values::scan(cur, &ctx, LEAF_VOXELS, &leaf.mask.0)?);
        // Files from before 222 could hold auxiliary buffers; they are
        // stored whole (never mask-compressed) and are skipped.
        let aux = Ctx { compression: ctx.compression & COMPRESS_ZIP, version: 0, ..ctx };
        for _ in 1..num_buffers.max(1) {
            values::scan(cur, &aux, LEAF_VOXELS, &leaf.mask.0)?;
        }
    }
    Ok(TreeLayout { tiles, leaves, ctx })
}

impl TreeLayout<'_> {
    /// Decodes every leaf (in parallel) into `N` scalar trees, one per
    /// component (`N` must be the tree's component count), leaves sorted by origin.
    pub fn decode<const N: usize>(mut self) -> Result<[Component; N], Error> {
        let ctx = self.ctx;
        if ctx.components != N || N > MAX_COMPONENTS {
            return Err(Error::invalid("tree", 0, format!("{} components read as {N}", ctx.components)));
        }
        // Sort the (small) descriptions first so the decoded leaves are
        // written once, in their final order.
        self.leaves.sort_unstable_by_key(|l| l.origin);
        let background = ctx.background;
        let tiles = self.tiles;
        let mut comps: [Component; N] = std::array::from_fn(|c| Component {
            background: background[c],
            tiles: tiles.iter().map(|t| Tile { origin: t.origin, dim: t.dim, value: t.value[c], active: t.active }).collect(),
            leaves: Vec::new(),
        });
        if let [only] = &mut comps[..] {
            only.leaves = decode_scalar_leaves(&self.leaves, &ctx)?;
            return Ok(comps);
        }
        for c in comps.iter_mut() {
            c.leaves.reserve_exact(self.leaves.len());
            vdbcook_grid::mem::advise_huge_pages(&c.leaves);
        }
        // Vectors are decoded in parallel a batch at a time and split into
        // their components, so no buffer ever holds every component of every leaf.
        for batch in self.leaves.chunks(VECTOR_BATCH) {
            let decoded: Vec<Result<[Leaf; N], Error>> = batch
                .par_iter()
                .map(|t| {
                    let mut out: [Leaf; N] = std::array::from_fn(|_| Leaf { origin: t.origin, mask: t.mask, values: [0.0f32; LEAF_VOXELS] });
                    if let Some(blk) = &t.values {
                        let mut vals = [0.0f32; LEAF_VOXELS * MAX_COMPONENTS];
                        let vals = &mut vals[..LEAF_VOXELS * N];
                        blk.decode(&ctx, &t.mask.0, vals)?;
                        for (v, xyz) in vals.chunks_exact(N).enumerate() {
                            for (leaf, &x) in out.iter_mut().zip(xyz) {
                                leaf.values[v] = x;
                            }
                        }
                    }
                    Ok(out)
                })
                .collect();
            // The first failing leaf in leaf order, whatever the thread count.
            for leaves in decoded {
                for (c, leaf) in comps.iter_mut().zip(leaves?) {
                    c.leaves.push(leaf);
                }
            }
        }
        Ok(comps)
    }
}

/// Leaves per parallel batch of vector leaves (64 × 6 KiB for vec3).
const VECTOR_BATCH: usize = 64;

/// Decodes scalar leaves (in parallel) straight into their final vector.
fn decode_scalar_leaves(topo: &[LeafTopo<'_>], ctx: &Ctx) -> Result<Vec<Leaf>, Error> {
    // The first failing leaf (in leaf order, whatever the thread count).
    let failure: Mutex<Option<(usize, Error)>> = Mutex::new(None);
    let mut leaves = Vec::with_capacity(topo.len());
    vdbcook_grid::mem::advise_huge_pages(&leaves);
    topo.par_iter()
        .enumerate()
        .map(|(i, t)| {
            let mut leaf = Leaf { origin: t.origin, mask: t.mask, values: [0.0f32; LEAF_VOXELS] };
            if let Some(Err(e)) = t.values.as_ref().map(|blk| blk.decode(ctx, &t.mask.0, &mut leaf.values)) {
                let mut f = failure.lock().unwrap_or_else(|p| p.into_inner());
                if f.as_ref().is_none_or(|(j, _)| i < *j) {
                    *f = Some((i, e));
                }
            }
            leaf
        })
        .collect_into_vec(&mut leaves);
    match failure.into_inner().unwrap_or_else(|p| p.into_inner()) {
        Some((_, e)) => Err(e),
        None => Ok(leaves),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slot_origins_follow_openvdb_order() {
        let o = Coord::new(-4096, 0, 4096);
        assert_eq!(slot_origin(o, 0, 5, 128), o);
        assert_eq!(slot_origin(o, 1, 5, 128), Coord::new(-4096, 0, 4096 + 128));
        assert_eq!(slot_origin(o, 32, 5, 128), Coord::new(-4096, 128, 4096));
        assert_eq!(slot_origin(o, 1024, 5, 128), Coord::new(-4096 + 128, 0, 4096));
        assert_eq!(slot_origin(Coord::new(0, 0, 0), (3 << 8) | (2 << 4) | 1, 4, 8), Coord::new(24, 16, 8));
    }

    #[test]
    fn leaves_of_root_children_listed_out_of_order_are_put_in_coordinate_order() {
        let topo = |x: i32| LeafTopo { origin: Coord::new(x, 0, 0), mask: LeafMask::default(), values: None };
        let origins = |v: &[LeafTopo]| v.iter().map(|l| l.origin.x).collect::<Vec<_>>();
        // Children at x = 4096 (two leaves), 0 (one) and -4096 (two), in that order.
        let leaves = vec![topo(4096), topo(4104), topo(8), topo(-4096), topo(-4088)];
        let roots = vec![(Coord::new(4096, 0, 0), 0..2), (Coord::new(0, 0, 0), 2..3), (Coord::new(-4096, 0, 0), 3..5)];
        assert_eq!(origins(&in_root_order(leaves, roots)), [-4096, -4088, 8, 4096, 4104]);
        let sorted = vec![topo(-8), topo(16)];
        let in_order = vec![(Coord::new(-4096, 0, 0), 0..1), (Coord::new(0, 0, 0), 1..2)];
        assert_eq!(origins(&in_root_order(sorted, in_order)), [-8, 16]);
    }

    #[test]
    fn mask_iteration() {
        let w = [0b1001u64, 1 << 63];
        assert_eq!(set_bits(&w).collect::<Vec<_>>(), vec![0, 3, 127]);
        assert_eq!(ones(&w), 3);
    }

    #[test]
    fn vec3_trees_split_into_components_with_one_topology() {
        use vdbcook_grid::{Grid, GridClass, Transform};
        let mut leaf = Leaf { origin: Coord::new(-8, 16, 0), mask: LeafMask::default(), values: [0.0; LEAF_VOXELS] };
        leaf.mask.set(3, true);
        let comps: Vec<Grid> = (0..3)
            .map(|c| {
                let mut l = leaf.clone();
                l.values[3] = c as f32 + 0.5;
                let tiles = vec![
                    Tile { origin: Coord::new(128, 0, 0), dim: 128, value: 10.0 + c as f32, active: true },
                    Tile { origin: Coord::new(8, 0, 0), dim: 8, value: if c == 2 { 7.0 } else { c as f32 }, active: false },
                ];
                Grid { name: String::new(), class: GridClass::Staggered, background: c as f32, transform: Transform::identity(), leaves: vec![l], tiles }
            })
            .collect();
        let bytes =
            crate::write_vdb_grids(&[crate::WriteGrid::Vec3 { name: "v", class: GridClass::Staggered, components: [&comps[0], &comps[1], &comps[2]] }], crate::WriteOptions::default()).unwrap();
        let file = crate::VdbFile::parse(bytes).unwrap();
        let info = &file.grids[0];
        let layout = || scan(&mut Cursor::at(file.bytes(), info.tree_pos).unwrap(), file.ctx(info)).unwrap();
        // Read with the wrong component count: an error, not a panic.
        assert!(layout().decode::<1>().is_err());
        let out = layout().decode::<3>().unwrap();
        for (c, comp) in out.iter().enumerate() {
            assert_eq!(comp.background, c as f32);
            assert_eq!(comp.leaves.len(), 1);
            assert_eq!((comp.leaves[0].mask, comp.leaves[0].values[3]), (leaf.mask, c as f32 + 0.5));
            // The inactive tile differs from the background only in z, and is kept in every component.
            let mut tiles = comp.tiles.clone();
            tiles.sort_by_key(|t| t.dim);
            assert_eq!(tiles, comps[c].tiles.iter().rev().copied().collect::<Vec<_>>());
        }
    }
}
