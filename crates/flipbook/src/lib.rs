//! The flip-book tree: one L1 node per frame over shared L2/L3 nodes and one
//! shared pool of 8³ bricks.
//!
//! Frames stream in through [`Builder::push`], which keeps only what the
//! output needs: every distinct brick once ([`BrickPool`], exact
//! deduplication by content hash then byte compare), every distinct L3 node
//! (active mask + brick) once, and per frame the list of its leaves and tiles.
//! [`Built::nodes`] then lays out the node arrays ([`Nodes`]), once the union
//! bounding box of all frames is known, after the caller has remapped bricks
//! (clustering, encoded-brick deduplication).
//!
//! # Node layout (all `u32`, little-endian; also the GPU layout)
//!
//! Index space is translated by [`Nodes::offset`] (a multiple of 128) so
//! that every frame fits one L1 node: 4096³ voxels.
//!
//! ```text
//! L1 node  (32³ slots of 128³ voxels)  L1_WORDS = 1024 + 512 + 1
//!   [0, 1024)     occupancy mask: bit s of word s/32 set when slot s holds a child or a tile
//!   [1024, 1536)  prefix counts: u16 pairs, count k = set bits in mask words [0, k)
//!                 (word 1024 + k/2, bits 16·(k%2)..)
//!   1536          first entry: index into l1_entries of slot rank 0
//! L2 node  (16³ slots of 8³ voxels)    L2_WORDS = 128 + 64 + 1, same shape, entries in l2_entries
//! entry    bit 31 clear: child index (L2 node for L1 entries, L3 node for L2 entries)
//!          bit 31 set:   tile index (low 31 bits) into `tiles`
//! L3 array word 0: the number n of L3 nodes; node k is words [1 + 3k, 4 + 3k):
//!   0  brick index
//!   1  states: 2 bits per 4³ sub-block b = (x/4)·4 + (y/4)·2 + z/4 (bits 2b..2b+1):
//!      0 no voxel active, 1 all 64 active, 2 some (a sub-mask is stored)
//!   2  word index (in this array) of the node's first sub-mask
//!   after the n nodes: the sub-masks, 2 words each, of every node's partly active
//!   sub-blocks in sub-block order; bit j = (x%4)·16 + (y%4)·4 + z%4
//! tile     2 words: value (f32 bits), flags (bit 0: active)
//! ```
//! Voxels are x·64 + y·8 + z in a leaf.  A leaf's 512-bit mask would take 64
//! bytes; smoke is mostly made of sub-blocks wholly inside or outside it, which
//! cost 2 bits here (0.37–0.76× of the L3 bytes on the real samples).
//! A slot's entry is `entries[first + prefix(word) + popcount(mask[word] & below(bit))]`:
//! O(1) on the GPU, and only occupied slots cost memory.  Identical L3, L2
//! and L1 nodes are stored once (hash-consing, bottom-up), so the parts of an
//! animation that do not change cost nothing per frame.

use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};
use vdbcook_grid::{Bbox, Coord, Grid, LEAF_VOXELS};

pub const L1_LOG2: u32 = 5;
pub const L2_LOG2: u32 = 4;
pub const L1_SLOTS: usize = 1 << (3 * L1_LOG2);
pub const L2_SLOTS: usize = 1 << (3 * L2_LOG2);
pub const L1_MASK_WORDS: usize = L1_SLOTS / 32;
pub const L2_MASK_WORDS: usize = L2_SLOTS / 32;
pub const L1_WORDS: usize = L1_MASK_WORDS + L1_MASK_WORDS / 2 + 1;
pub const L2_WORDS: usize = L2_MASK_WORDS + L2_MASK_WORDS / 2 + 1;
/// Words of one L3 node record (brick, sub-block states, first sub-mask).
pub const L3_WORDS: usize = 3;
/// Sub-block state: no voxel active.
pub const SUB_EMPTY: u32 = 0;
/// Sub-block state: every voxel active.
pub const SUB_FULL: u32 = 1;
/// Sub-block state: a sub-mask says which voxels are active.
pub const SUB_PARTIAL: u32 = 2;
pub const TILE_FLAG: u32 = 1 << 31;
/// Edge of the index space one L1 node covers.
pub const L1_DIM: i64 = 4096;
/// Voxel edge of an L1 slot (an L2 node or a tile).
pub const L1_CHILD_DIM: i32 = 128;

/// A brick: the 512 values of one leaf.  Inactive voxels hold fill values
/// (see [`brick_of_leaf`]): readers take their value from the background.
pub type Brick = [f32; LEAF_VOXELS];

/// Fill passes before the remaining inactive voxels take the active mean.
const FILL_PASSES: usize = 4;

/// The brick of a leaf.  Active voxels keep their values; inactive voxels,
/// which every reader replaces by the background (the L3 mask says which),
/// are filled smoothly from their active neighbours (a few passes of
/// 6-neighbour averaging, then the mean of the active values), so that
/// quantised and block-compressed encodings spend no precision on a jump to
/// the background at the edge of the active region.
pub fn brick_of_leaf(leaf: &vdbcook_grid::Leaf) -> Brick {
    let n = leaf.mask.count_on();
    if n as usize == LEAF_VOXELS {
        return leaf.values;
    }
    let mut b = [0.0f32; LEAF_VOXELS];
    let mut sum = 0.0f64;
    for i in leaf.mask.iter_on() {
        b[i] = leaf.values[i];
        sum += f64::from(leaf.values[i]);
    }
    let mean = if n > 0 { (sum / f64::from(n)) as f32 } else { 0.0 };
    // Word x of a mask holds the 64 voxels (y, z) of slab x, bit y·8 + z.
    const NOT_Z0: u64 = 0xfefe_fefe_fefe_fefe;
    const NOT_Z7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    let mut known = leaf.mask.0;
    for _ in 0..FILL_PASSES {
        // The unknown voxels next to a known one: each takes the mean of its
        // known neighbours (in the order -x, +x, -y, +y, -z, +z), which this
        // pass does not change.
        let mut front = [0u64; 8];
        for x in 0..8 {
            let k = known[x];
            let near = (if x > 0 { known[x - 1] } else { 0 }) | (if x < 7 { known[x + 1] } else { 0 }) | k << 8 | k >> 8 | (k << 1 & NOT_Z0) | (k >> 1 & NOT_Z7);
            front[x] = near & !k;
        }
        if front == [0; 8] {
            break;
        }
        for i in vdbcook_grid::set_bits(&front) {
            let (x, y, z) = (i >> 6, (i >> 3) & 7, i & 7);
            let (mut acc, mut cnt) = (0.0f32, 0u32);
            let mut visit = |j: usize| {
                if known[j >> 6] >> (j & 63) & 1 == 1 {
                    acc += b[j];
                    cnt += 1;
                }
            };
            if x > 0 {
                visit(i - 64);
            }
            if x < 7 {
                visit(i + 64);
            }
            if y > 0 {
                visit(i - 8);
            }
            if y < 7 {
                visit(i + 8);
            }
            if z > 0 {
                visit(i - 1);
            }
            if z < 7 {
                visit(i + 1);
            }
            b[i] = acc / cnt as f32;
        }
        for (k, f) in known.iter_mut().zip(front) {
            *k |= f;
        }
    }
    for i in vdbcook_grid::set_bits(&known.map(|k| !k)) {
        b[i] = mean;
    }
    b
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("the frames span {extent} voxels along {axis} (index {min} to {max}); one L1 node holds 4096 voxels starting at a multiple of 128")]
    TooWide { axis: char, extent: i64, min: i64, max: i64 },
    #[error("frame {frame} has background {found}, earlier frames {expected}")]
    Background { frame: usize, found: f32, expected: f32 },
    #[error("more than 2^31 {what}")]
    Overflow { what: &'static str },
}

/// Content hash of a brick: the exact bits of every value (so -0.0 and 0.0,
/// or two NaN payloads, stay distinct).
pub fn brick_hash(b: &Brick) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytemuck::cast_slice(b))
}

fn same_bits(a: &Brick, b: &Brick) -> bool {
    bytemuck::cast_slice::<f32, u32>(a) == bytemuck::cast_slice::<f32, u32>(b)
}

/// Hash maps keyed by data that needs no DoS protection: XXH3, deterministic.
type Map<K, V> = HashMap<K, V, xxhash_rust::xxh3::Xxh3DefaultBuilder>;

/// Ids of items by content hash, for deduplication: equal hashes are told
/// apart by comparing the items themselves.
#[derive(Default)]
pub struct HashIndex {
    /// Hash -> the first item with it.
    first: Map<u64, u32>,
    /// Further items whose hash equals an earlier, different item's.
    more: Map<u64, Vec<u32>>,
}

impl HashIndex {
    pub fn reserve(&mut self, n: usize) {
        self.first.reserve(n);
    }

    /// The id of an item with hash `h` for which `same(id)` holds, if any.
    pub fn find(&self, h: u64, same: impl Fn(u32) -> bool) -> Option<u32> {
        let first = *self.first.get(&h)?;
        if same(first) {
            return Some(first);
        }
        self.more.get(&h).and_then(|ids| ids.iter().copied().find(|&id| same(id)))
    }

    /// Records item `id`, with hash `h`, as new.
    pub fn add(&mut self, h: u64, id: u32) {
        match self.first.entry(h) {
            std::collections::hash_map::Entry::Occupied(_) => self.more.entry(h).or_default().push(id),
            std::collections::hash_map::Entry::Vacant(e) => {
                e.insert(id);
            }
        }
    }
}

/// Distinct bricks, each stored once.
#[derive(Default)]
pub struct BrickPool {
    bricks: Vec<Brick>,
    index: HashIndex,
}

impl BrickPool {
    /// Returns the id of `brick`, adding it if it is new.
    pub fn insert(&mut self, brick: &Brick) -> Result<u32, Error> {
        let h = brick_hash(brick);
        let id = self.bricks.len();
        self.bricks.push(*brick);
        let mut next = id;
        let found = self.settle(id, &mut next, h);
        self.bricks.truncate(next);
        found
    }

    /// Pools the brick at `from`, which was appended past the pool's first
    /// `next` bricks (all distinct): returns the id of an equal brick among
    /// them, or moves it to `next`, takes that as its id and advances `next`.
    fn settle(&mut self, from: usize, next: &mut usize, h: u64) -> Result<u32, Error> {
        let Some(brick) = self.bricks.get(from) else { return Err(Error::Overflow { what: "bricks" }) };
        if let Some(id) = self.index.find(h, |id| self.bricks.get(id as usize).is_some_and(|b| same_bits(b, brick))) {
            return Ok(id);
        }
        let id = u32::try_from(*next).ok().filter(|&i| i < TILE_FLAG).ok_or(Error::Overflow { what: "bricks" })?;
        if from != *next {
            self.bricks.copy_within(from..from + 1, *next);
        }
        self.index.add(h, id);
        *next += 1;
        Ok(id)
    }

    pub fn len(&self) -> usize {
        self.bricks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.bricks.is_empty()
    }

    pub fn bricks(&self) -> &[Brick] {
        &self.bricks
    }

    pub fn into_bricks(self) -> Vec<Brick> {
        self.bricks
    }
}

/// Hash-consing table: ids in first-seen order (node keys are variable-length
/// `u32` words; L3 nodes are their own keys).
struct Interner<K = Vec<u32>> {
    ids: Map<K, u32>,
    count: u32,
}

impl<K> Default for Interner<K> {
    fn default() -> Self {
        Interner { ids: Map::default(), count: 0 }
    }
}

impl<K: std::hash::Hash + Eq> Interner<K> {
    fn reserve(&mut self, n: usize) {
        self.ids.reserve(n);
    }

    /// Returns `(id, new)`.
    fn intern(&mut self, key: K) -> (u32, bool) {
        let next = self.count;
        let id = *self.ids.entry(key).or_insert(next);
        if id == next {
            self.count += 1;
            (id, true)
        } else {
            (id, false)
        }
    }
}

/// A distinct L3 node: active mask and brick id.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct L3 {
    pub mask: [u64; 8],
    pub brick: u32,
}

/// What one frame holds, in source index space.
#[derive(Clone, Debug, Default)]
pub struct FrameLeaves {
    /// (leaf origin, L3 id), sorted by origin.
    pub leaves: Vec<(Coord, u32)>,
    /// Active tiles: origin, edge (8, 128 or 4096), value.
    pub tiles: Vec<(Coord, u32, f32)>,
    pub active_voxels: u64,
}

/// Per-frame figures reported by [`Builder::push`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    pub leaves: usize,
    pub tiles: usize,
    pub active_voxels: u64,
    pub new_bricks: usize,
    /// Minimum and maximum active value (tiles included); `None` when nothing is active.
    pub range: Option<[f32; 2]>,
}

/// Streams frames into a brick pool and per-frame leaf lists.
#[derive(Default)]
pub struct Builder {
    background: Option<f32>,
    pool: BrickPool,
    l3: Vec<L3>,
    l3_index: Interner<L3>,
    frames: Vec<FrameLeaves>,
    bbox: Option<Bbox>,
    leaves_in: u64,
}

impl Builder {
    pub fn new() -> Builder {
        Builder::default()
    }

    /// Adds one frame.  Only active values are kept: inactive voxels take the
    /// background, inactive tiles are dropped, leaves with no active voxel vanish.
    pub fn push(&mut self, grid: &Grid) -> Result<FrameStats, Error> {
        let frame = self.frames.len();
        match self.background {
            None => self.background = Some(grid.background),
            Some(bg) if bg.to_bits() != grid.background.to_bits() => {
                return Err(Error::Background { frame, found: grid.background, expected: bg });
            }
            Some(_) => {}
        }
        let before = self.pool.len();
        let mut fl = FrameLeaves::default();
        // A bounded batch at a time (in leaf order): the batch's bricks are
        // built straight into the pool and hashed in parallel, then pooled in
        // order, duplicates squeezed out.
        let live: Vec<usize> = (0..grid.leaves.len()).filter(|&i| !grid.leaves[i].mask.is_empty()).collect();
        // Room for every leaf being new, so the pool never moves while it grows
        // (untouched capacity costs no memory).
        self.pool.bricks.reserve(live.len());
        self.pool.index.reserve(live.len());
        vdbcook_grid::mem::advise_huge_pages(&self.pool.bricks);
        self.l3.reserve(live.len());
        self.l3_index.reserve(live.len());
        fl.leaves.reserve(live.len());
        let mut range = [f32::INFINITY, f32::NEG_INFINITY];
        for batch in live.chunks(4096) {
            let start = self.pool.bricks.len();
            self.pool.bricks.par_extend(batch.par_iter().map(|&i| brick_of_leaf(&grid.leaves[i])));
            let hashes: Vec<(u64, f32, f32)> = batch
                .par_iter()
                .zip(self.pool.bricks.get(start..).unwrap_or(&[]).par_iter())
                .map(|(&i, b)| {
                    let s = vdbcook_grid::LeafSummary::of(&grid.leaves[i]);
                    (brick_hash(b), s.min, s.max)
                })
                .collect();
            let mut next = start;
            for (k, (&i, &(h, lo, hi))) in batch.iter().zip(&hashes).enumerate() {
                let leaf = &grid.leaves[i];
                range = [range[0].min(lo), range[1].max(hi)];
                let brick = self.pool.settle(start + k, &mut next, h)?;
                let key = L3 { mask: leaf.mask.0, brick };
                if u32::try_from(self.l3.len()).is_err() {
                    return Err(Error::Overflow { what: "L3 nodes" });
                }
                let (id, new) = self.l3_index.intern(key);
                if new {
                    self.l3.push(key);
                }
                fl.leaves.push((leaf.origin, id));
                fl.active_voxels += u64::from(leaf.mask.count_on());
                self.grow(Bbox::new(leaf.origin, leaf.origin.offset(7, 7, 7)));
            }
            self.pool.bricks.truncate(next);
        }
        for t in grid.tiles.iter().filter(|t| t.active) {
            fl.tiles.push((t.origin, t.dim, t.value));
            fl.active_voxels += t.voxel_count();
            range = [range[0].min(t.value), range[1].max(t.value)];
            self.grow(t.bbox());
        }
        fl.leaves.sort_by_key(|l| l.0);
        self.leaves_in += fl.leaves.len() as u64;
        let range = (fl.active_voxels > 0).then_some(range);
        let stats = FrameStats { leaves: fl.leaves.len(), tiles: fl.tiles.len(), active_voxels: fl.active_voxels, new_bricks: self.pool.len() - before, range };
        self.frames.push(fl);
        Ok(stats)
    }

    /// Adds a frame with nothing in it (a missing grid with `--allow-missing`).
    pub fn push_empty(&mut self) {
        self.frames.push(FrameLeaves::default());
    }

    fn grow(&mut self, b: Bbox) {
        self.bbox = Some(match self.bbox {
            None => b,
            Some(a) => a.union(b),
        });
    }

    pub fn frame_count(&self) -> usize {
        self.frames.len()
    }

    pub fn pool(&self) -> &BrickPool {
        &self.pool
    }

    /// Ends the stream.  Fails when the frames do not fit one L1 node.
    pub fn finish(self) -> Result<Built, Error> {
        let offset = match self.bbox {
            None => Coord::new(0, 0, 0),
            Some(b) => {
                let floor = |v: i32| v & !(L1_CHILD_DIM - 1);
                let offset = Coord::new(floor(b.min.x), floor(b.min.y), floor(b.min.z));
                for (axis, min, lo, hi) in [('x', b.min.x, offset.x, b.max.x), ('y', b.min.y, offset.y, b.max.y), ('z', b.min.z, offset.z, b.max.z)] {
                    if i64::from(hi) - i64::from(lo) + 1 > L1_DIM {
                        return Err(Error::TooWide { axis, extent: i64::from(hi) - i64::from(min) + 1, min: i64::from(min), max: i64::from(hi) });
                    }
                }
                offset
            }
        };
        Ok(Built { background: self.background.unwrap_or(0.0), pool: self.pool, l3: self.l3, frames: self.frames, bbox: self.bbox, offset, leaves_in: self.leaves_in })
    }
}

/// Everything the builder kept, ready to be laid out.
pub struct Built {
    pub background: f32,
    pub pool: BrickPool,
    pub l3: Vec<L3>,
    pub frames: Vec<FrameLeaves>,
    /// Union of every frame's active bbox (leaf- and tile-granular), in source index space.
    pub bbox: Option<Bbox>,
    /// Source index of the L1 node's origin.
    pub offset: Coord,
    /// Leaves pushed over all frames (before deduplication).
    pub leaves_in: u64,
}

/// The node arrays of a flip-book.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Nodes {
    /// Source index-space position of the L1 nodes' origin.
    pub offset: Coord,
    /// L1 node of each frame.
    pub frames: Vec<u32>,
    pub l1: Vec<u32>,
    pub l1_entries: Vec<u32>,
    pub l2: Vec<u32>,
    pub l2_entries: Vec<u32>,
    pub l3: Vec<u32>,
    /// Pairs of (value bits, flags).
    pub tiles: Vec<u32>,
}

/// Slot of the (translated) coordinate `p` in a node of `2^log2` slots per axis of `2^child_log2` voxels.
fn slot(p: Coord, log2: u32, child_log2: u32) -> usize {
    let m = (1i32 << log2) - 1;
    let (x, y, z) = (((p.x >> child_log2) & m) as usize, ((p.y >> child_log2) & m) as usize, ((p.z >> child_log2) & m) as usize);
    (x << (2 * log2)) | (y << log2) | z
}

/// Occupancy mask, prefix counts and first entry of a node with `slots` slots.
fn node_words(occupied: &[usize], slots: usize, first: u32) -> Vec<u32> {
    let mw = slots / 32;
    let mut words = vec![0u32; mw + mw / 2 + 1];
    for &s in occupied {
        words[s / 32] |= 1 << (s % 32);
    }
    let mut count = 0u32;
    for k in 0..mw {
        words[mw + k / 2] |= (count & 0xffff) << (16 * (k % 2));
        count += words[k].count_ones();
    }
    words[mw + mw / 2] = first;
    words
}

/// The node count word 0 of an L3 array gives, when the array holds that many
/// node records (`None` for an empty or too short array).
pub fn l3_node_count(words: &[u32]) -> Option<usize> {
    let n = *words.first()? as usize;
    (n.saturating_mul(L3_WORDS).saturating_add(1) <= words.len()).then_some(n)
}

/// The L3 array of the given nodes (layout in the module documentation).
fn l3_words(nodes: &[L3]) -> Result<Vec<u32>, Error> {
    let overflow = || Error::Overflow { what: "L3 nodes" };
    let count = u32::try_from(nodes.len()).map_err(|_| overflow())?;
    let mut head = Vec::with_capacity(1 + nodes.len() * L3_WORDS);
    head.push(count);
    let mut masks = Vec::new();
    let start = 1 + nodes.len() * L3_WORDS;
    for l in nodes {
        let (states, partial) = encode_l3_mask(&l.mask);
        let first = u32::try_from(start + masks.len()).map_err(|_| overflow())?;
        head.extend([l.brick, states, first]);
        masks.extend(partial.iter().flat_map(|m| [*m as u32, (*m >> 32) as u32]));
    }
    u32::try_from(start + masks.len()).map_err(|_| overflow())?;
    head.extend(masks);
    Ok(head)
}

/// Interns a node given its occupied slots (ascending) and their entries.
fn intern_node(table: &mut Interner, nodes: &mut Vec<u32>, entries: &mut Vec<u32>, slots: usize, occupied: &[(usize, u32)]) -> Result<u32, Error> {
    // The key is the node's shape and content; `first` is assigned only when new.
    let mut key: Vec<u32> = Vec::with_capacity(occupied.len() * 2);
    for &(s, e) in occupied {
        key.push(s as u32);
        key.push(e);
    }
    let (id, new) = table.intern(key);
    if new {
        let first = u32::try_from(entries.len()).map_err(|_| Error::Overflow { what: "node entries" })?;
        entries.extend(occupied.iter().map(|&(_, e)| e));
        let slots_on: Vec<usize> = occupied.iter().map(|&(s, _)| s).collect();
        nodes.extend(node_words(&slots_on, slots, first));
    }
    if id >= TILE_FLAG {
        return Err(Error::Overflow { what: "nodes" });
    }
    Ok(id)
}

/// The 64 bits of 4³ sub-block `b` of a leaf mask (bit `j` = (x%4)·16 + (y%4)·4 + z%4).
pub fn sub_mask(mask: &[u64; 8], b: usize) -> u64 {
    let (x0, y0, z0) = ((b >> 2) * 4, ((b >> 1) & 1) * 4, (b & 1) * 4);
    let mut out = 0u64;
    for dx in 0..4 {
        let plane = mask[(x0 + dx) & 7];
        for dy in 0..4 {
            out |= ((plane >> ((y0 + dy) * 8 + z0)) & 0xf) << (dx * 16 + dy * 4);
        }
    }
    out
}

/// Sets sub-block `b` of a leaf mask to `bits` (the inverse of [`sub_mask`]).
fn put_sub_mask(mask: &mut [u64; 8], b: usize, bits: u64) {
    let (x0, y0, z0) = ((b >> 2) * 4, ((b >> 1) & 1) * 4, (b & 1) * 4);
    for dx in 0..4 {
        for dy in 0..4 {
            mask[(x0 + dx) & 7] |= ((bits >> (dx * 16 + dy * 4)) & 0xf) << ((y0 + dy) * 8 + z0);
        }
    }
}

/// The states word of a leaf mask, and its partly active sub-blocks' masks in order.
pub fn encode_l3_mask(mask: &[u64; 8]) -> (u32, Vec<u64>) {
    let mut states = 0u32;
    let mut partial = Vec::new();
    for b in 0..8 {
        let m = sub_mask(mask, b);
        let state = match m {
            0 => SUB_EMPTY,
            u64::MAX => SUB_FULL,
            _ => {
                partial.push(m);
                SUB_PARTIAL
            }
        };
        states |= state << (2 * b);
    }
    (states, partial)
}

/// A leaf mask back from its states word and the words of its sub-masks
/// (`None` for a state of 3, bits past the eight states, or too few words).
pub fn decode_l3_mask(states: u32, words: &[u32]) -> Option<[u64; 8]> {
    if states >> 16 != 0 {
        return None; // only eight 2-bit states
    }
    let mut mask = [0u64; 8];
    let mut k = 0;
    for b in 0..8 {
        let bits = match (states >> (2 * b)) & 3 {
            SUB_EMPTY => 0,
            SUB_FULL => u64::MAX,
            SUB_PARTIAL => {
                let w = words.get(2 * k..2 * k + 2)?;
                k += 1;
                u64::from(w[0]) | (u64::from(w[1]) << 32)
            }
            _ => return None,
        };
        put_sub_mask(&mut mask, b, bits);
    }
    Some(mask)
}

impl Built {
    /// Lays out the node arrays; `brick_of(l3.brick)` gives each brick's final id.
    pub fn nodes(&self, brick_of: impl Fn(u32) -> u32) -> Result<Nodes, Error> {
        let mut n = Nodes { offset: self.offset, ..Nodes::default() };
        // L3 nodes, re-interned after the brick remap (two L3s may now be equal).
        let mut l3_table = Interner::<L3>::default();
        l3_table.reserve(self.l3.len());
        let mut l3_id = Vec::with_capacity(self.l3.len());
        let mut distinct = Vec::with_capacity(self.l3.len());
        for l in &self.l3 {
            let key = L3 { mask: l.mask, brick: brick_of(l.brick) };
            let (id, new) = l3_table.intern(key);
            if new {
                distinct.push(key);
            }
            l3_id.push(id);
        }
        n.l3 = l3_words(&distinct)?;
        let mut tile_table = Interner::default();
        let mut tile = |value: f32, n: &mut Nodes| -> u32 {
            let key = vec![value.to_bits(), 1];
            let (id, new) = tile_table.intern(key.clone());
            if new {
                n.tiles.extend(key);
            }
            id | TILE_FLAG
        };
        let mut l2_table = Interner::default();
        let mut l1_table = Interner::default();
        let off = self.offset;
        let local = |c: Coord| Coord::new(c.x.wrapping_sub(off.x), c.y.wrapping_sub(off.y), c.z.wrapping_sub(off.z));
        for fl in &self.frames {
            // (l1 slot, l2 slot, entry), or a tile for a whole l1 slot.
            let mut l2s: Vec<(usize, usize, u32)> = Vec::with_capacity(fl.leaves.len());
            let mut l1_tiles: BTreeMap<usize, u32> = BTreeMap::new();
            for &(o, id) in &fl.leaves {
                let p = local(o);
                l2s.push((slot(p, L1_LOG2, 7), slot(p, L2_LOG2, 3), l3_id[id as usize]));
            }
            for &(o, dim, value) in &fl.tiles {
                let t = tile(value, &mut n);
                match dim {
                    8 => {
                        let p = local(o);
                        l2s.push((slot(p, L1_LOG2, 7), slot(p, L2_LOG2, 3), t));
                    }
                    128 => {
                        l1_tiles.insert(slot(local(o), L1_LOG2, 7), t);
                    }
                    _ => {
                        // A root tile: every 128³ slot of the L1 region inside it.
                        let span = i64::from(dim);
                        for s in 0..L1_SLOTS {
                            let (x, y, z) = ((s >> 10) as i64 * 128, ((s >> 5) & 31) as i64 * 128, (s & 31) as i64 * 128);
                            let w = [i64::from(off.x) + x, i64::from(off.y) + y, i64::from(off.z) + z];
                            let o = [i64::from(o.x), i64::from(o.y), i64::from(o.z)];
                            if (0..3).all(|a| w[a] >= o[a] && w[a] < o[a] + span) {
                                l1_tiles.insert(s, t);
                            }
                        }
                    }
                }
            }
            // By slot; of two entries for one slot, the later one counts.
            l2s.sort_by_key(|e| (e.0, e.1));
            let mut l1_occ: Vec<(usize, u32)> = Vec::with_capacity(l1_tiles.len() + 1);
            for node in l2s.chunk_by(|a, b| a.0 == b.0) {
                let mut occ: Vec<(usize, u32)> = Vec::with_capacity(node.len());
                for e in node {
                    match occ.last_mut() {
                        Some(last) if last.0 == e.1 => last.1 = e.2,
                        _ => occ.push((e.1, e.2)),
                    }
                }
                let id = intern_node(&mut l2_table, &mut n.l2, &mut n.l2_entries, L2_SLOTS, &occ)?;
                l1_occ.push((node[0].0, id));
            }
            let with_l2 = l1_occ.len();
            for (&s, &t) in &l1_tiles {
                if l1_occ[..with_l2].binary_search_by_key(&s, |e| e.0).is_err() {
                    l1_occ.push((s, t));
                }
            }
            l1_occ.sort_unstable_by_key(|e| e.0);
            let id = intern_node(&mut l1_table, &mut n.l1, &mut n.l1_entries, L1_SLOTS, &l1_occ)?;
            n.frames.push(id);
        }
        Ok(n)
    }
}

/// What a slot of a node holds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Slot {
    Empty,
    Child(u32),
    Tile { value: f32, active: bool },
}

impl Nodes {
    fn lookup(node: &[u32], entries: &[u32], tiles: &[u32], mask_words: usize, s: usize) -> Slot {
        let (w, b) = (s / 32, s % 32);
        let Some(&word) = node.get(w) else { return Slot::Empty };
        if word >> b & 1 == 0 {
            return Slot::Empty;
        }
        let prefix = node.get(mask_words + w / 2).map_or(0, |p| (p >> (16 * (w % 2))) & 0xffff);
        let first = node.get(mask_words + mask_words / 2).copied().unwrap_or(0);
        let below = (word & ((1u32 << b) - 1)).count_ones();
        // Saturating: a corrupt `first` must give "no entry", not an overflow.
        let e = entries.get(first.saturating_add(prefix).saturating_add(below) as usize).copied().unwrap_or(0);
        if e & TILE_FLAG != 0 {
            let t = ((e & !TILE_FLAG) * 2) as usize;
            Slot::Tile { value: f32::from_bits(tiles.get(t).copied().unwrap_or(0)), active: tiles.get(t + 1).is_some_and(|f| f & 1 == 1) }
        } else {
            Slot::Child(e)
        }
    }

    /// Slot `s` of L1 node `id`.
    pub fn l1_slot(&self, id: u32, s: usize) -> Slot {
        let node = self.l1.get(id as usize * L1_WORDS..(id as usize + 1) * L1_WORDS).unwrap_or(&[]);
        Nodes::lookup(node, &self.l1_entries, &self.tiles, L1_MASK_WORDS, s)
    }

    /// Slot `s` of L2 node `id`.
    pub fn l2_slot(&self, id: u32, s: usize) -> Slot {
        let node = self.l2.get(id as usize * L2_WORDS..(id as usize + 1) * L2_WORDS).unwrap_or(&[]);
        Nodes::lookup(node, &self.l2_entries, &self.tiles, L2_MASK_WORDS, s)
    }

    /// Active mask and brick of L3 node `id` (`None` past the end or when
    /// the node's words are inconsistent).
    pub fn l3_node(&self, id: u32) -> Option<([u64; 8], u32)> {
        if id as usize >= self.l3_count() {
            return None;
        }
        let at = 1 + id as usize * L3_WORDS;
        let w = self.l3.get(at..at + L3_WORDS)?;
        let masks = self.l3.get(w[2] as usize..).unwrap_or(&[]);
        Some((decode_l3_mask(w[1], masks)?, w[0]))
    }

    /// Every leaf (source origin, mask, brick) and active tile (source origin,
    /// edge, value) of a frame; `None` when there are more than `max_leaves`
    /// leaves or `max_tiles` tiles (shared nodes let a small, corrupt asset
    /// claim billions, so callers bound what they will decode).
    #[allow(clippy::type_complexity)]
    pub fn frame_contents(&self, frame: usize, max_leaves: usize, max_tiles: usize) -> Option<(Vec<(Coord, [u64; 8], u32)>, Vec<(Coord, u32, f32)>)> {
        let mut leaves = Vec::new();
        let mut tiles = Vec::new();
        let Some(&l1) = self.frames.get(frame) else { return Some((leaves, tiles)) };
        let node = self.l1.get(l1 as usize * L1_WORDS..(l1 as usize + 1) * L1_WORDS).unwrap_or(&[]);
        let o = self.offset;
        for w in 0..L1_MASK_WORDS {
            let mut bits = node.get(w).copied().unwrap_or(0);
            while bits != 0 {
                let s1 = w * 32 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let c1 = o.offset(((s1 >> 10) & 31) as i32 * 128, ((s1 >> 5) & 31) as i32 * 128, (s1 & 31) as i32 * 128);
                match self.l1_slot(l1, s1) {
                    Slot::Tile { value, active: true } => tiles.push((c1, 128, value)),
                    Slot::Child(l2) => {
                        for s2 in 0..L2_SLOTS {
                            let c2 = c1.offset(((s2 >> 8) & 15) as i32 * 8, ((s2 >> 4) & 15) as i32 * 8, (s2 & 15) as i32 * 8);
                            match self.l2_slot(l2, s2) {
                                Slot::Tile { value, active: true } => tiles.push((c2, 8, value)),
                                Slot::Child(l3) => {
                                    if let Some((mask, brick)) = self.l3_node(l3) {
                                        leaves.push((c2, mask, brick));
                                    }
                                }
                                _ => {}
                            }
                        }
                    }
                    _ => {}
                }
                if leaves.len() > max_leaves || tiles.len() > max_tiles {
                    return None;
                }
            }
        }
        Some((leaves, tiles))
    }

    /// Bytes of each node array, for reports.
    pub fn byte_sizes(&self) -> [(&'static str, usize); 7] {
        [
            ("frames", self.frames.len() * 4),
            ("l1", self.l1.len() * 4),
            ("l1_entries", self.l1_entries.len() * 4),
            ("l2", self.l2.len() * 4),
            ("l2_entries", self.l2_entries.len() * 4),
            ("l3", self.l3.len() * 4),
            ("tiles", self.tiles.len() * 4),
        ]
    }

    pub fn l1_count(&self) -> usize {
        self.l1.len() / L1_WORDS
    }
    pub fn l2_count(&self) -> usize {
        self.l2.len() / L2_WORDS
    }
    /// L3 nodes, as word 0 of the L3 array says (0 when the array cannot
    /// hold that many records).
    pub fn l3_count(&self) -> usize {
        l3_node_count(&self.l3).unwrap_or(0)
    }
}

/// Bytes the thesis's layout would take for the same frames: every L1
/// allocates all 32768 L2 children (4100 B per L1, 516 B per L2), and every
/// leaf of every frame is its own 68-byte L3.
pub fn thesis_tree_bytes(frames: usize, leaves: u64) -> u64 {
    frames as u64 * (4100 + 32768 * 516) + leaves * 68
}

#[cfg(test)]
mod tests;
