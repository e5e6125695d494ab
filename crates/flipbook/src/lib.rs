//! The flip-book tree: one L1 node per frame over shared L2/L3 nodes and one
//! shared pool of 8³ bricks, for one or several channels.
//!
//! Frames stream in through [`Builder::push`], which keeps only what the
//! output needs: every distinct brick once ([`BrickPool`], exact
//! deduplication by content hash then byte compare, over every channel of the
//! brick together), every distinct L3 node (active mask + brick) once, and
//! per frame the list of its leaves and tiles.  With several channels a frame
//! has one tree over the union of the channels' active voxels: a leaf active
//! in any channel is one L3 node whose brick holds every channel (a voxel
//! inactive in a channel holds that channel's background), and a tile holds
//! one value per channel (tiles of one channel over another's leaves are
//! split until they no longer overlap).  [`Built::nodes`] then lays out the
//! node arrays with `vdbcook_vpak::nodes`, which owns their encoding, once
//! the union bounding box of all frames is known and the caller has
//! remapped bricks (clustering, encoded-brick deduplication).

use ids::IdTable;
pub use masks::ChannelMasks;
use merge::{merge_channels, Merged};
pub use pool::BrickPool;
use pool::{Channel, Made};
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};
use vdbcook_grid::spill::{Charge, SpillPolicy, Store};
use vdbcook_grid::{Bbox, Coord, Grid, LEAF_VOXELS};
use vdbcook_vpak::nodes::{self, Nodes, L1_CHILD_DIM, L1_DIM, L1_LOG2, L1_SLOTS, L2_LOG2, L2_SLOTS, TILE_FLAG};

/// A brick: the 512 values of one leaf.  Inactive voxels hold fill values
/// (see [`brick_of_leaf`]): readers take their value from the background.
pub use vdbcook_grid::Brick;

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
    let known = vdbcook_grid::fill_from_neighbours(&mut b, leaf.mask.0, FILL_PASSES);
    for i in vdbcook_grid::set_bits(&known.map(|k| !k)) {
        b[i] = mean;
    }
    b
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("the frames span {extent} voxels along {axis} (index {min} to {max}); one L1 node holds 4096 voxels starting at a multiple of 128")]
    TooWide { axis: char, extent: i64, min: i64, max: i64 },
    #[error("channel {channel}: frame {frame} has background {found}, earlier frames {expected}")]
    Background { channel: usize, frame: usize, found: f32, expected: f32 },
    #[error("more than 2^31 {what}")]
    Overflow { what: &'static str },
    #[error("a frame gave {found} channels, the builder was made for {expected}")]
    Channels { found: usize, expected: usize },
    #[error(transparent)]
    OutOfMemory(#[from] vdbcook_grid::mem::OutOfMemory),
    #[error(transparent)]
    Spill(#[from] vdbcook_grid::spill::StoreError),
}

fn same_bits(a: &[Brick], b: &[Brick]) -> bool {
    bytemuck::cast_slice::<Brick, u32>(a) == bytemuck::cast_slice::<Brick, u32>(b)
}

/// Hash maps keyed by data that needs no DoS protection (content hashes,
/// node keys): deterministic, and cheap for their word-sized keys.
pub(crate) type Map<K, V> = HashMap<K, V, std::hash::BuildHasherDefault<WordHasher>>;

/// Folds each 8-byte word in with a rotate, xor and multiply (the FxHash
/// scheme; a streaming XXH3 costs more per key than the lookups it serves),
/// then moves the product's well-mixed high bits down for the table's index.
#[derive(Default, Clone, Copy)]
pub(crate) struct WordHasher(u64);

impl std::hash::Hasher for WordHasher {
    fn write(&mut self, bytes: &[u8]) {
        let mut words = bytes.chunks_exact(8);
        for w in words.by_ref() {
            self.write_u64(u64::from_le_bytes(w.try_into().unwrap_or_default()));
        }
        let rest = words.remainder();
        if !rest.is_empty() {
            let mut w = [0u8; 8];
            w[..rest.len()].copy_from_slice(rest);
            self.write_u64(u64::from_le_bytes(w));
        }
    }
    fn write_u64(&mut self, w: u64) {
        self.0 = (self.0.rotate_left(5) ^ w).wrapping_mul(0xf135_7aea_2e62_a9c5);
    }
    fn write_u32(&mut self, w: u32) {
        self.write_u64(u64::from(w));
    }
    fn write_usize(&mut self, w: usize) {
        self.write_u64(w as u64);
    }
    fn finish(&self) -> u64 {
        self.0.rotate_left(26)
    }
}

/// Ids of items by content hash, for deduplication: equal hashes are told
/// apart by comparing the items themselves.  Each item's hash is held once,
/// beside a table of ids: 8 bytes an item and 5 a table slot, where a map
/// from hash to id took 16 bytes a slot.
#[derive(Default)]
pub struct HashIndex {
    /// Per id, its item's hash.
    hashes: Vec<u64>,
    ids: IdTable,
}

impl HashIndex {
    /// Room for `n` more items, or the error naming `what` when memory runs out.
    pub fn try_reserve(&mut self, n: usize, what: &'static str) -> Result<(), vdbcook_grid::mem::OutOfMemory> {
        vdbcook_grid::mem::try_reserve(&mut self.hashes, n, what)?;
        let hashes = &self.hashes;
        self.ids.reserve(n, what, |id| hashes.get(id as usize).copied().unwrap_or(0))
    }

    /// The id of an item with hash `h` for which `same(id)` holds, if any.
    pub fn find(&self, h: u64, same: impl Fn(u32) -> bool) -> Option<u32> {
        self.ids.find(h, |id| self.hashes.get(id as usize) == Some(&h) && same(id))
    }

    /// About the bytes it holds.
    pub fn heap_bytes(&self) -> u64 {
        (self.hashes.capacity() * std::mem::size_of::<u64>()) as u64 + self.ids.heap_bytes()
    }

    /// Records item `id`, with hash `h`, as new.
    pub fn add(&mut self, h: u64, id: u32) {
        let i = id as usize;
        if i >= self.hashes.len() {
            self.hashes.resize(i + 1, 0);
        }
        self.hashes[i] = h;
        let hashes = &self.hashes;
        self.ids.insert(h, id, |id| hashes.get(id as usize).copied().unwrap_or(0));
    }
}

/// Hash-consing table of L1, L2 and tile nodes: ids in first-seen order
/// (their keys are variable-length `u32` words).
#[derive(Default)]
struct Interner {
    ids: Map<Vec<u32>, u32>,
    count: u32,
}

impl Interner {
    /// Returns `(id, new)`.
    fn intern(&mut self, key: Vec<u32>) -> (u32, bool) {
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

/// A distinct L3 node: active mask (the union over channels) and brick id.
/// Plain bytes (its padding spelled out), so that the nodes of a long
/// segment can spill to a file with the bricks ([`Store`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct L3 {
    pub mask: [u64; 8],
    pub brick: u32,
    pad: u32,
}

// SAFETY: `repr(C)` of integer fields with no implicit padding (64 + 4 + 4 bytes).
unsafe impl bytemuck::Zeroable for L3 {}
// SAFETY: as above; every bit pattern is a valid `L3`.
unsafe impl bytemuck::Pod for L3 {}

impl L3 {
    pub fn new(mask: [u64; 8], brick: u32) -> L3 {
        L3 { mask, brick, pad: 0 }
    }

    /// Its content hash, for hash-consing.
    fn hash(mask: &[u64; 8], brick: u32) -> u64 {
        twox_hash::XxHash3_64::oneshot_with_seed(u64::from(brick), bytemuck::cast_slice(mask))
    }
}

/// What one frame holds, in source index space.
#[derive(Clone, Debug, Default)]
pub struct FrameLeaves {
    /// (leaf origin, L3 id), sorted by origin.
    pub leaves: Vec<(Coord, u32)>,
    /// With several channels, each leaf's active mask in each channel's own
    /// grid (none with one channel, whose mask is the L3 node's).
    pub channel_masks: ChannelMasks,
    /// Active tiles: origin, edge (8, 128 or 4096), one value per channel.
    pub tiles: Vec<(Coord, u32, Vec<f32>)>,
    pub active_voxels: u64,
    /// Level of detail: coordinates are in level `level`'s index space
    /// (source index >> level, see `vdbcook_grid::lod`).
    pub level: u32,
}

impl FrameLeaves {
    /// About the bytes of its lists.
    fn heap_bytes(&self) -> u64 {
        let tiles: usize = self.tiles.iter().map(|t| std::mem::size_of_val(t) + t.2.capacity() * std::mem::size_of::<f32>()).sum();
        (self.leaves.capacity() * std::mem::size_of::<(Coord, u32)>() + tiles) as u64 + self.channel_masks.heap_bytes()
    }
}

/// Per-frame figures reported by [`Builder::push`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameStats {
    pub leaves: usize,
    pub tiles: usize,
    pub active_voxels: u64,
    pub new_bricks: usize,
    /// Per channel, the minimum and maximum stored value of the frame (tiles
    /// included; a channel's background where only other channels are
    /// active); `None` when nothing is active.
    pub ranges: Vec<Option<[f32; 2]>>,
}

/// Streams frames into a brick pool and per-frame leaf lists.
pub struct Builder {
    channels: usize,
    backgrounds: Vec<Option<f32>>,
    pool: BrickPool,
    l3: Store<L3>,
    /// `l3`'s ids by content, with each node's hash beside it: growing the
    /// table rehashes without reading the nodes (spilled, they are a file).
    l3_index: HashIndex,
    frames: Vec<FrameLeaves>,
    bbox: Option<Bbox>,
    leaves_in: u64,
    /// Level of the tree being pushed.
    level: u32,
    /// Its indexes and frames' lists, counted against the spill policy.
    charge: Charge,
    /// Bytes of `frames`' lists.
    frame_bytes: u64,
}

impl Default for Builder {
    fn default() -> Self {
        Builder::new(1)
    }
}

impl Builder {
    pub fn new(channels: usize) -> Builder {
        let channels = channels.max(1);
        Builder {
            channels,
            backgrounds: vec![None; channels],
            pool: BrickPool::new(channels),
            l3: Store::default(),
            l3_index: HashIndex::default(),
            frames: Vec::new(),
            bbox: None,
            leaves_in: 0,
            level: 0,
            charge: Charge::default(),
            frame_bytes: 0,
        }
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    /// A builder for the frames after this one's (the next segment of a
    /// sequence): as many channels, held to the backgrounds seen so far.
    pub fn successor(&self) -> Builder {
        let mut next = Builder { backgrounds: self.backgrounds.clone(), ..Builder::new(self.channels) };
        next.spill_to(self.pool.stored.policy().cloned());
        next
    }

    /// Moves the brick pool and the L3 nodes into temporary files in
    /// `policy.dir` once they would pass `policy.above` bytes
    /// (`vdbcook_grid::spill`): the cook's memory stops growing with the
    /// sequence's distinct bricks.
    pub fn spill_to(&mut self, policy: Option<SpillPolicy>) {
        self.l3.set_policy(policy.clone());
        self.pool.set_policy(policy.clone());
        self.charge = Charge::new(policy);
        self.recharge();
    }

    /// Counts what grows with the segment but cannot spill (the hash
    /// indexes, a few bytes per distinct brick and L3 node, and the frames'
    /// leaf lists, 16 bytes per leaf of every frame) against the spill
    /// policy: its stores then spill sooner, and memory stays near the
    /// budget however long the segment.
    fn recharge(&mut self) {
        self.charge.set(self.pool.index_bytes() + self.l3_index.heap_bytes() + self.frame_bytes);
    }

    /// Fills its pool in `storage` (an emptied pool's memory,
    /// [`BrickPool::take_storage`]) while it has no brick and `storage` has
    /// more room: memory already the process's, where fresh memory costs the
    /// system a page clearing per page (a sequence's next segment reuses the
    /// last one's).
    pub fn reuse(&mut self, mut storage: Store<Brick>) {
        if self.pool.stored.is_empty() && storage.is_empty() && storage.capacity() > self.pool.stored.capacity() {
            storage.set_policy(self.pool.stored.policy().cloned());
            self.pool.stored = storage;
        }
    }

    /// Adds one frame: one grid per channel (`None`: the channel is empty in
    /// this frame).  Only active values are kept: inactive voxels take the
    /// background, inactive tiles are dropped, leaves with no active voxel vanish.
    pub fn push(&mut self, grids: &[Option<&Grid>]) -> Result<FrameStats, Error> {
        self.push_level(0, grids)
    }

    /// Adds a frame's tree at a coarser level (`level` > 0: the grids are the
    /// frame's filtered to that level, in its index space), an ordinary tree
    /// over the same pool.  Push every level of a frame before the next frame;
    /// [`Built::nodes`] lists the trees level by level.
    pub fn push_level(&mut self, level: u32, grids: &[Option<&Grid>]) -> Result<FrameStats, Error> {
        self.level = level;
        if grids.len() != self.channels {
            return Err(Error::Channels { found: grids.len(), expected: self.channels });
        }
        let frame = self.frames.len();
        for (c, g) in grids.iter().enumerate() {
            let Some(g) = g else { continue };
            match self.backgrounds[c] {
                None => self.backgrounds[c] = Some(g.background),
                Some(bg) if bg.to_bits() != g.background.to_bits() => return Err(Error::Background { channel: c, frame, found: g.background, expected: bg }),
                Some(_) => {}
            }
        }
        let backgrounds: Vec<f32> = self.backgrounds.iter().map(|b| b.unwrap_or(0.0)).collect();
        let merged = match grids {
            [Some(g)] => Merged::single(g),
            _ => merge_channels(grids, &backgrounds)?,
        };
        self.push_merged(merged, &backgrounds)
    }

    /// Adds a frame's union tree: its positions' bricks (every channel's, in
    /// channel order) and tiles.
    fn push_merged(&mut self, m: Merged, backgrounds: &[f32]) -> Result<FrameStats, Error> {
        let c = self.channels;
        let before = self.pool.len();
        let n = m.positions.len();
        let mut fl = FrameLeaves { channel_masks: m.channel_masks, level: self.level, ..FrameLeaves::default() };
        let bg = |k: usize| backgrounds.get(k).copied().unwrap_or(0.0);
        // The channel bricks known to be constant (a channel with nothing at
        // a position) are not made; room for all the others being new, so
        // the pool never moves while it grows (untouched capacity costs no memory).
        let shares = self.pool.shares_constants();
        let known: Vec<Option<u32>> = (0..n * c).map(|j| m.parts[j].known_constant(m.positions[j / c].1, bg(j % c)).filter(|_| shares)).collect();
        self.pool.reserve(n, known.iter().filter(|k| k.is_none()).count())?;
        self.l3.try_reserve(n, "the L3 nodes")?;
        self.l3_index.try_reserve(n, "the L3 nodes' index")?;
        fl.leaves.reserve(n);
        let mut ranges = vec![[f32::INFINITY, f32::NEG_INFINITY]; c];
        // A bounded batch at a time (in position order): the batch's bricks
        // are built straight into the pool and hashed in parallel, then
        // pooled in order, duplicates squeezed out.
        for first in (0..n).step_by(4096) {
            let end = (first + 4096).min(n);
            let start = self.pool.stored.len();
            // Each channel brick of the batch: a known constant, or made at
            // the next place past the pool's bricks (straight into the pool).
            let mut at = start;
            let plan: Vec<Channel> = known[first * c..end * c]
                .iter()
                .map(|k| match *k {
                    Some(bits) => Channel::Constant(bits),
                    None => {
                        at += 1;
                        Channel::At(at - 1)
                    }
                })
                .collect();
            let made: Vec<usize> = (first * c..end * c).filter(|&j| matches!(plan[j - first * c], Channel::At(_))).collect();
            // Each brick is hashed as it is made (in cache), beside it, and
            // its value range taken there where it is its leaf's.
            let mut seen = vec![(Made::default(), None); made.len()];
            self.pool.stored.par_extend(
                made.par_iter().zip(seen.par_iter_mut()).map(|(&j, seen)| {
                    let (origin, mask) = m.positions[j / c];
                    let b = m.parts[j].brick(origin, mask, bg(j % c));
                    *seen = (Made::of(&b, shares), m.parts[j].range_of_brick(mask, &b));
                    b
                }),
                "the brick pool",
            )?;
            self.pool.staged(seen.par_iter().map(|s| s.0.range))?;
            // Per position: its channels, its hash, and per channel its value range.
            let hashes: Vec<(u64, Vec<[f32; 2]>, Vec<Channel>)> = (first..end)
                .into_par_iter()
                .map(|i| {
                    let (origin, mask) = m.positions[i];
                    let j = (i - first) * c;
                    let channels: Vec<Channel> = plan[j..j + c]
                        .iter()
                        .map(|&p| match p {
                            Channel::At(a) => seen[a - start].0.channel(a),
                            constant => constant,
                        })
                        .collect();
                    let made_range = |k: usize| match plan[j + k] {
                        Channel::At(a) => seen[a - start].1,
                        Channel::Constant(_) => None,
                    };
                    let r = (0..c).map(|k| made_range(k).unwrap_or_else(|| m.parts[i * c + k].range(origin, mask, bg(k)))).collect();
                    (BrickPool::hash(&channels, |a| seen[a - start].0.hash), r, channels)
                })
                .collect();
            let mut next = start;
            for (&(origin, mask), (h, r, channels)) in m.positions[first..end].iter().zip(&hashes) {
                for (acc, r) in ranges.iter_mut().zip(r) {
                    *acc = [acc[0].min(r[0]), acc[1].max(r[1])];
                }
                let brick = self.pool.settle(channels, &mut next, *h)?;
                let key = L3::new(mask.0, brick);
                let Ok(next_id) = u32::try_from(self.l3.len()) else {
                    return Err(Error::Overflow { what: "L3 nodes" });
                };
                let l3 = &self.l3;
                let h = L3::hash(&key.mask, brick);
                let id = match self.l3_index.find(h, |id| l3.get(id as usize) == Some(&key)) {
                    Some(id) => id,
                    None => {
                        self.l3_index.add(h, next_id);
                        self.l3.push(key, "the L3 nodes")?;
                        next_id
                    }
                };
                fl.leaves.push((origin, id));
                fl.active_voxels += u64::from(mask.count_on());
                if fl.level == 0 {
                    self.grow(Bbox::new(origin, origin.offset(7, 7, 7)));
                }
            }
            self.pool.truncate_stored(next);
        }
        for (origin, dim, values) in m.tiles {
            let t = vdbcook_grid::Tile { origin, dim, value: 0.0, active: true };
            fl.active_voxels += t.voxel_count();
            for (acc, &v) in ranges.iter_mut().zip(&values) {
                *acc = [acc[0].min(v), acc[1].max(v)];
            }
            if fl.level == 0 {
                self.grow(t.bbox());
            }
            fl.tiles.push((origin, dim, values));
        }
        self.leaves_in += fl.leaves.len() as u64;
        let ranges = ranges.into_iter().map(|r| (fl.active_voxels > 0 && r[0] <= r[1]).then_some(r)).collect();
        let stats = FrameStats { leaves: fl.leaves.len(), tiles: fl.tiles.len(), active_voxels: fl.active_voxels, new_bricks: self.pool.len() - before, ranges };
        self.frame_bytes += fl.heap_bytes();
        self.frames.push(fl);
        self.recharge();
        Ok(stats)
    }

    /// Adds a frame with nothing in it (a missing grid with `--allow-missing`).
    pub fn push_empty(&mut self) {
        self.frames.push(FrameLeaves::default());
    }

    /// Adds an empty tree at level `level` (of an empty frame).
    pub fn push_empty_level(&mut self, level: u32) {
        self.frames.push(FrameLeaves { level, ..FrameLeaves::default() });
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
    pub fn finish(mut self) -> Result<Built, Error> {
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
        let backgrounds = self.backgrounds.iter().map(|b| b.unwrap_or(0.0)).collect();
        // Deduplication is over: its indexes (the L3 nodes' goes with `self`) are not kept.
        self.pool.index = HashIndex::default();
        self.pool.settled();
        self.l3_index = HashIndex::default();
        self.recharge();
        Ok(Built { channels: self.channels, backgrounds, pool: self.pool, l3: self.l3, frames: self.frames, bbox: self.bbox, offset, leaves_in: self.leaves_in, _charge: self.charge })
    }
}

/// Everything the builder kept, ready to be laid out.
pub struct Built {
    pub channels: usize,
    /// Per channel, the background of its grids (0 when it never had one).
    pub backgrounds: Vec<f32>,
    /// The distinct bricks (without their hash index: a brick inserted
    /// now is added, not matched against those before).
    pub pool: BrickPool,
    pub l3: Store<L3>,
    pub frames: Vec<FrameLeaves>,
    /// Union of every frame's active bbox (leaf- and tile-granular), in source index space.
    pub bbox: Option<Bbox>,
    /// Source index of the L1 node's origin.
    pub offset: Coord,
    /// Leaves pushed over all frames (before deduplication).
    pub leaves_in: u64,
    /// Its frames' lists and brick slots, still counted against the spill
    /// policy (the stages after the build hold them).
    _charge: Charge,
}

/// Interns a node given its occupied slots (ascending) and their entries
/// (`shape`: what else tells nodes apart, an L1 node's size); `words(slots,
/// first)` encodes a new one. Returns its id and whether it is new.
fn intern_node(table: &mut Interner, nodes: &mut Vec<u32>, entries: &mut Vec<u32>, shape: u32, occupied: &[(usize, u32)], words: impl Fn(&[usize], u32) -> Vec<u32>) -> Result<(u32, bool), Error> {
    // The key is the node's shape and content; `first` is assigned only when new.
    let mut key: Vec<u32> = Vec::with_capacity(occupied.len() * 2 + 1);
    key.push(shape);
    for &(s, e) in occupied {
        key.push(s as u32);
        key.push(e);
    }
    let (id, new) = table.intern(key);
    if new {
        let first = u32::try_from(entries.len()).map_err(|_| Error::Overflow { what: "node entries" })?;
        entries.extend(occupied.iter().map(|&(_, e)| e));
        let slots_on: Vec<usize> = occupied.iter().map(|&(s, _)| s).collect();
        nodes.extend(words(&slots_on, first));
        u32::try_from(nodes.len()).map_err(|_| Error::Overflow { what: "node words" })?;
    }
    if id >= TILE_FLAG {
        return Err(Error::Overflow { what: "nodes" });
    }
    Ok((id, new))
}

impl Built {
    /// The trees of levels `first` and coarser, with only the L3 nodes and
    /// bricks they use (each kept in its order, so ids stay deterministic);
    /// the index space, bounding box and backgrounds are the frames' own.
    pub fn from_level(&self, first: u32) -> Result<Built, Error> {
        let frames: Vec<FrameLeaves> = self.frames.iter().filter(|f| f.level >= first).cloned().collect();
        let mut used = vec![false; self.l3.len()];
        for &(_, id) in frames.iter().flat_map(|f| &f.leaves) {
            if let Some(u) = used.get_mut(id as usize) {
                *u = true;
            }
        }
        // Old id -> new id of the L3 nodes and bricks kept, in their order.
        let mut l3_new = vec![u32::MAX; self.l3.len()];
        let mut brick_new = vec![u32::MAX; self.pool.len()];
        let mut pool = BrickPool::new(self.channels);
        let mut l3 = Store::with_policy(self.l3.policy().cloned());
        for (old, new) in l3_new.iter_mut().enumerate().filter(|&(old, _)| used[old]) {
            let node = self.l3[old];
            let b = node.brick as usize;
            if brick_new[b] == u32::MAX {
                brick_new[b] = pool.insert(&self.pool.brick(b).ok_or(Error::Overflow { what: "bricks" })?)?;
            }
            *new = l3.len() as u32;
            l3.push(L3::new(node.mask, brick_new[b]), "the L3 nodes")?;
        }
        let frames = frames
            .into_iter()
            .map(|mut f| {
                f.leaves.iter_mut().for_each(|(_, id)| *id = l3_new[*id as usize]);
                f
            })
            .collect::<Vec<_>>();
        let leaves_in = frames.iter().map(|f| f.leaves.len() as u64).sum();
        Ok(Built { channels: self.channels, backgrounds: self.backgrounds.clone(), pool, l3, frames, bbox: self.bbox, offset: self.offset, leaves_in, _charge: Charge::default() })
    }

    /// Lays out the node arrays; `brick_of(l3.brick)` gives each brick's final id.
    pub fn nodes(&self, brick_of: impl Fn(u32) -> u32) -> Result<Nodes, Error> {
        let off = self.offset;
        let mut n = Nodes { offset: off.to_array(), channels: self.channels, ..Nodes::default() };
        // L3 nodes, re-interned after the brick remap (two L3s may now be
        // equal): each distinct one by the index of its first in `self.l3`.
        let remapped = |i: u32| self.l3.get(i as usize).map(|l| (l.mask, brick_of(l.brick)));
        let hash_of = |i: u32| remapped(i).map_or(0, |(m, b)| L3::hash(&m, b));
        let mut l3_table = IdTable::default();
        l3_table.reserve(self.l3.len(), "the L3 nodes' index", hash_of)?;
        let mut l3_id = Vec::with_capacity(self.l3.len());
        let mut distinct: Vec<u32> = Vec::new();
        for i in 0..self.l3.len() as u32 {
            let Some(key) = remapped(i) else { break };
            let (first, _) = l3_table.intern(L3::hash(&key.0, key.1), i, |j| remapped(j) == Some(key), hash_of);
            if first == i {
                l3_id.push(distinct.len() as u32);
                distinct.push(i);
            } else {
                l3_id.push(l3_id[first as usize]);
            }
        }
        drop(l3_table);
        n.l3 = nodes::l3_words(distinct.len(), distinct.iter().filter_map(|&i| remapped(i))).ok_or(Error::Overflow { what: "L3 words" })?;
        let mut tile_table = Interner::default();
        let mut tile = |values: &[f32], n: &mut Nodes| -> u32 {
            let key: Vec<u32> = values.iter().map(|v| v.to_bits()).collect();
            let (id, new) = tile_table.intern(key.clone());
            if new {
                n.tiles.extend(key);
            }
            id | TILE_FLAG
        };
        let mut l2_table = Interner::default();
        let mut l1_table = Interner::default();
        // Where each distinct L1 node starts in the L1 array (they differ in size).
        let mut l1_starts: Vec<u32> = Vec::new();
        let mut trees: Vec<(u32, u32)> = Vec::with_capacity(self.frames.len());
        for fl in &self.frames {
            // Level k's index space is the asset's >> k (the offset, a multiple of 128, shifts exactly).
            let lo = Coord::new(off.x >> fl.level, off.y >> fl.level, off.z >> fl.level);
            let local = |c: Coord| [c.x.wrapping_sub(lo.x), c.y.wrapping_sub(lo.y), c.z.wrapping_sub(lo.z)];
            // (l1 slot, l2 slot, entry), or a tile for a whole l1 slot.
            let mut l2s: Vec<(usize, usize, u32)> = Vec::with_capacity(fl.leaves.len());
            let mut l1_tiles: BTreeMap<usize, u32> = BTreeMap::new();
            for &(o, id) in &fl.leaves {
                let p = local(o);
                l2s.push((nodes::slot(p, L1_LOG2, 7), nodes::slot(p, L2_LOG2, 3), l3_id[id as usize]));
            }
            for (o, dim, values) in &fl.tiles {
                let t = tile(values, &mut n);
                match dim {
                    8 => {
                        let p = local(*o);
                        l2s.push((nodes::slot(p, L1_LOG2, 7), nodes::slot(p, L2_LOG2, 3), t));
                    }
                    128 => {
                        l1_tiles.insert(nodes::slot(local(*o), L1_LOG2, 7), t);
                    }
                    _ => {
                        // A root tile: every 128³ slot of the L1 region inside it.
                        let span = i64::from(*dim);
                        for s in 0..L1_SLOTS {
                            let [x, y, z] = nodes::slot_coords(s, L1_LOG2).map(|v| v as i64 * 128);
                            let w = [i64::from(lo.x) + x, i64::from(lo.y) + y, i64::from(lo.z) + z];
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
                let (id, _) = intern_node(&mut l2_table, &mut n.l2, &mut n.l2_entries, 0, &occ, |slots, first| nodes::node_words(slots, L2_SLOTS, first))?;
                l1_occ.push((node[0].0, id));
            }
            let with_l2 = l1_occ.len();
            for (&s, &t) in &l1_tiles {
                if l1_occ[..with_l2].binary_search_by_key(&s, |e| e.0).is_err() {
                    l1_occ.push((s, t));
                }
            }
            l1_occ.sort_unstable_by_key(|e| e.0);
            // The smallest node that holds every occupied slot; renumbering
            // the slots for it keeps their order.
            let log2 = nodes::l1_log2_for(l1_occ.iter().flat_map(|e| nodes::slot_coords(e.0, L1_LOG2)).max().unwrap_or(0) as u32);
            let occ: Vec<(usize, u32)> = l1_occ.iter().map(|&(s, e)| (nodes::slot_at(nodes::slot_coords(s, L1_LOG2), log2), e)).collect();
            let start = n.l1.len() as u32;
            let (id, new) = intern_node(&mut l1_table, &mut n.l1, &mut n.l1_entries, log2, &occ, |slots, first| nodes::l1_node_words(log2, slots, first))?;
            if new {
                l1_starts.push(start);
            }
            trees.push((fl.level, l1_starts[id as usize]));
        }
        // Level by level, frames in order within each (the frames section's order).
        trees.sort_by_key(|t| t.0);
        n.frames = trees.into_iter().map(|t| t.1).collect();
        Ok(n)
    }
}

/// Bytes the thesis's layout would take for the same frames: every L1
/// allocates all 32768 L2 children (4100 B per L1, 516 B per L2), and every
/// leaf of every frame is its own 68-byte L3.
pub fn thesis_tree_bytes(frames: usize, leaves: u64) -> u64 {
    frames as u64 * (4100 + 32768 * 516) + leaves * 68
}

mod ids;
mod masks;
mod merge;
mod pool;
#[cfg(test)]
mod tests;
