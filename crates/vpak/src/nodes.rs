//! The node arrays: their encoding (used by the builder in `vdbcook-flipbook`)
//! and their decoding (used by every reader).  Specified in `docs/format.md`.
//!
//! ```text
//! L1 node  (n³ slots of 128³ voxels, n = 2^L, L = 2 to 5: the smallest that holds
//!           the tree; M = n³/32 mask words)  l1_node_len(L) = 1 + M + M/2 + 1 words
//!   0             L
//!   [1, 1 + M)    occupancy mask: bit s of word s/32 set when slot s holds a child or a tile
//!   [1 + M, ..)   prefix counts: u16 pairs, count k = set bits in mask words [0, k)
//!                 (word 1 + M + k/2, bits 16·(k%2)..)
//!   1 + M + M/2   first entry: index into l1_entries of slot rank 0
//!   The frames array holds each tree's L1 node as the word it starts at.
//! L2 node  (16³ slots of 8³ voxels)    L2_WORDS = 128 + 64 + 1, the same after L, entries in l2_entries
//! entry    bit 31 clear: child index (L2 node for L1 entries, L3 node for L2 entries)
//!          bit 31 set:   tile index (low 31 bits) into `tiles`
//! L3 array word 0: the number n of L3 nodes; node k is words [1 + 3k, 4 + 3k):
//!   0  brick index
//!   1  states: 2 bits per 4³ sub-block b = (x/4)·4 + (y/4)·2 + z/4 (bits 2b..2b+1):
//!      0 no voxel active, 1 all 64 active, 2 some (a sub-mask is stored)
//!   2  word index (in this array) of the node's first sub-mask
//!   after the n nodes: the sub-masks, 2 words each, of every node's partly active
//!   sub-blocks in sub-block order; bit j = (x%4)·16 + (y%4)·4 + z%4
//! tile     one f32 per channel
//! ```
//! Voxels are x·64 + y·8 + z in a leaf.

/// Slots per axis of the largest L1 node (32: 4096 voxels), and of the
/// smallest (4: 512 voxels; two mask words, so the prefix layout is L2's).
pub const L1_LOG2: u32 = 5;
pub const L1_MIN_LOG2: u32 = 2;
pub const L2_LOG2: u32 = 4;
pub const L1_SLOTS: usize = 1 << (3 * L1_LOG2);
pub const L2_SLOTS: usize = 1 << (3 * L2_LOG2);
pub const L2_MASK_WORDS: usize = L2_SLOTS / 32;
pub const L2_WORDS: usize = L2_MASK_WORDS + L2_MASK_WORDS / 2 + 1;

/// Mask words of an L1 node of 2^`log2` slots per axis.
pub fn l1_mask_words(log2: u32) -> usize {
    (1usize << (3 * log2)) / 32
}

/// Words of an L1 node of 2^`log2` slots per axis: L, mask, prefix counts, first entry.
pub fn l1_node_len(log2: u32) -> usize {
    let m = l1_mask_words(log2);
    1 + m + m / 2 + 1
}

/// The smallest L1 node's log2 whose slots reach slot coordinate `max` on every axis.
pub fn l1_log2_for(max: u32) -> u32 {
    (u32::BITS - max.leading_zeros()).clamp(L1_MIN_LOG2, L1_LOG2)
}

/// An L1 node of 2^`log2` slots per axis whose `occupied` slots (numbered in
/// that node: `(x << 2·log2) | (y << log2) | z`) have entries from `first`.
pub fn l1_node_words(log2: u32, occupied: &[usize], first: u32) -> Vec<u32> {
    let mut w = Vec::with_capacity(l1_node_len(log2));
    w.push(log2);
    w.extend(node_words(occupied, 1 << (3 * log2), first));
    w
}

/// The L1 node of an L1 array that starts at word `at`: its L and its words
/// after L (`None` when L is out of range or the node is not whole).
fn l1_node_at(words: &[u32], at: usize) -> Option<(u32, &[u32])> {
    let log2 = *words.get(at)?;
    if !(L1_MIN_LOG2..=L1_LOG2).contains(&log2) {
        return None;
    }
    Some((log2, words.get(at + 1..at + l1_node_len(log2))?))
}

/// The word each L1 node of an L1 array starts at, in order; `None` when
/// the array is not a sequence of whole nodes with L from 2 to 5.
pub fn l1_records(words: &[u32]) -> Option<Vec<u32>> {
    let mut starts = Vec::new();
    let mut at = 0usize;
    while at < words.len() {
        let (log2, _) = l1_node_at(words, at)?;
        starts.push(u32::try_from(at).ok()?);
        at += l1_node_len(log2);
    }
    Some(starts)
}
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

/// Slot of the asset-space coordinate `p` in a node of `2^log2` slots per axis of `2^child_log2` voxels.
pub fn slot(p: [i32; 3], log2: u32, child_log2: u32) -> usize {
    let m = (1i32 << log2) - 1;
    slot_at(p.map(|c| ((c >> child_log2) & m) as usize), log2)
}

/// Slot `(x << 2·log2) | (y << log2) | z` of slot coordinates (each below 2^`log2`).
pub fn slot_at([x, y, z]: [usize; 3], log2: u32) -> usize {
    (x << (2 * log2)) | (y << log2) | z
}

/// The slot coordinates of slot `s` of a node of 2^`log2` slots per axis ([`slot_at`]'s inverse).
pub fn slot_coords(s: usize, log2: u32) -> [usize; 3] {
    let m = (1 << log2) - 1;
    [(s >> (2 * log2)) & m, (s >> log2) & m, s & m]
}

/// Occupancy mask, prefix counts and first entry of a node with `slots` slots.
pub fn node_words(occupied: &[usize], slots: usize, first: u32) -> Vec<u32> {
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

/// The L3 array of the first `count` of `nodes` (leaf mask, brick), or
/// `None` when `nodes` has fewer or the array would need more than 2^32 words.
/// Made in its exact size (a long segment's array is tens of MB): the node
/// records first, counting the partly active sub-blocks, then their masks
/// from a second pass over `nodes`.
pub fn l3_words<I>(count: usize, nodes: I) -> Option<Vec<u32>>
where
    I: IntoIterator<Item = ([u64; 8], u32)>,
    I::IntoIter: Clone,
{
    let nodes = nodes.into_iter().take(count);
    let start = 1 + count * L3_WORDS;
    let mut head = Vec::with_capacity(start);
    head.push(u32::try_from(count).ok()?);
    let mut partial = 0usize;
    for (mask, brick) in nodes.clone() {
        let states = l3_states(&mask);
        let first = u32::try_from(start + 2 * partial).ok()?;
        head.extend([brick, states, first]);
        partial += partial_sub_blocks(states).count();
    }
    (head.len() == start).then_some(())?;
    u32::try_from(start + 2 * partial).ok()?;
    let mut words = head;
    words.reserve_exact(2 * partial);
    for (i, (mask, _)) in nodes.enumerate() {
        let states = words[2 + L3_WORDS * i];
        for b in partial_sub_blocks(states) {
            let m = sub_mask(&mask, b);
            words.extend([m as u32, (m >> 32) as u32]);
        }
    }
    Some(words)
}

/// The sub-blocks a states word calls partly active, in order.
fn partial_sub_blocks(states: u32) -> impl Iterator<Item = usize> {
    (0..8).filter(move |b| states >> (2 * b) & 3 == SUB_PARTIAL)
}

/// The states word of a leaf mask ([`encode_l3_mask`]'s first).
fn l3_states(mask: &[u64; 8]) -> u32 {
    (0..8).fold(0, |states, b| {
        let state = match sub_mask(mask, b) {
            0 => SUB_EMPTY,
            u64::MAX => SUB_FULL,
            _ => SUB_PARTIAL,
        };
        states | state << (2 * b)
    })
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
    let states = l3_states(mask);
    (states, partial_sub_blocks(states).map(|b| sub_mask(mask, b)).collect())
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

/// What a slot of a node holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Slot {
    Empty,
    Child(u32),
    /// Index of a tile (its values are `channels` floats from word `index · channels` of the tiles array).
    Tile(u32),
}

/// The node arrays of a flip-book (the sections of the same names).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Nodes {
    /// Source index-space position of the L1 nodes' origin.
    pub offset: [i32; 3],
    /// Values per tile (the asset's channel count).
    pub channels: usize,
    /// L1 node of each tree (frame and level): the word of `l1` it starts at.
    pub frames: Vec<u32>,
    pub l1: Vec<u32>,
    pub l1_entries: Vec<u32>,
    pub l2: Vec<u32>,
    pub l2_entries: Vec<u32>,
    pub l3: Vec<u32>,
    /// `channels` f32 bit patterns per tile.
    pub tiles: Vec<u32>,
}

impl Nodes {
    /// Bytes of its arrays.
    pub fn heap_bytes(&self) -> u64 {
        let words = [&self.frames, &self.l1, &self.l1_entries, &self.l2, &self.l2_entries, &self.l3, &self.tiles].iter().map(|v| v.capacity()).sum::<usize>();
        (words * std::mem::size_of::<u32>()) as u64
    }
}

/// What some trees of a flip-book use ([`Nodes::usage`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Usage {
    pub trees: usize,
    pub l1: usize,
    /// Words of those L1 nodes (they differ in size).
    pub l1_words: usize,
    pub l1_entries: usize,
    pub l2: usize,
    pub l2_entries: usize,
    pub l3: usize,
    /// Sub-masks (2 words each) of the L3 nodes: sub-blocks partly active.
    pub l3_sub_masks: usize,
    pub tiles: usize,
    /// The distinct bricks, ascending.
    pub bricks: Vec<u32>,
}

impl Usage {
    /// Bytes of the node arrays these trees need on their own (frame entries,
    /// L1, L2 and L3 nodes with their entries and sub-masks, tiles of `channels` floats).
    pub fn tree_bytes(&self, channels: usize) -> u64 {
        let words = self.trees + self.l1_words + self.l1_entries + self.l2 * L2_WORDS + self.l2_entries + 1 + self.l3 * L3_WORDS + 2 * self.l3_sub_masks + self.tiles * channels;
        4 * words as u64
    }
}

/// A frame's leaves (source origin, active mask, brick) and active tiles
/// (source origin, edge in voxels, tile index).
pub type FrameContents = (Vec<([i32; 3], [u64; 8], u32)>, Vec<([i32; 3], u32, u32)>);

fn lookup(node: &[u32], entries: &[u32], mask_words: usize, s: usize) -> Slot {
    let (w, b) = (s / 32, s % 32);
    let Some(&word) = node.get(w) else { return Slot::Empty };
    if word >> b & 1 == 0 {
        return Slot::Empty;
    }
    let prefix = node.get(mask_words + w / 2).map_or(0, |p| (p >> (16 * (w % 2))) & 0xffff);
    let first = node.get(mask_words + mask_words / 2).copied().unwrap_or(0);
    let below = (word & ((1u32 << b) - 1)).count_ones();
    // Saturating: a corrupt `first` must give "no entry", not an overflow.
    match entries.get(first.saturating_add(prefix).saturating_add(below) as usize) {
        None => Slot::Empty,
        Some(&e) if e & TILE_FLAG != 0 => Slot::Tile(e & !TILE_FLAG),
        Some(&e) => Slot::Child(e),
    }
}

impl Nodes {
    /// The L1 node starting at word `at`: its log2 and its words after L
    /// (`None` when L is out of range or the node is not whole).
    pub fn l1_node(&self, at: u32) -> Option<(u32, &[u32])> {
        l1_node_at(&self.l1, at as usize)
    }

    /// What the L1 node starting at word `at` holds for the 128³ region at
    /// slot coordinates `c` (asset index >> 7): empty past the node's slots.
    pub fn l1_slot(&self, at: u32, c: [u32; 3]) -> Slot {
        let Some((log2, node)) = self.l1_node(at) else { return Slot::Empty };
        if c.iter().any(|&v| v >> log2 != 0) {
            return Slot::Empty;
        }
        lookup(node, &self.l1_entries, l1_mask_words(log2), slot_at(c.map(|v| v as usize), log2))
    }

    /// Slot `s` of L2 node `id`.
    pub fn l2_slot(&self, id: u32, s: usize) -> Slot {
        let node = self.l2.get(id as usize * L2_WORDS..(id as usize + 1) * L2_WORDS).unwrap_or(&[]);
        lookup(node, &self.l2_entries, L2_MASK_WORDS, s)
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

    /// The values of tile `index`, one per channel (`None` past the end).
    pub fn tile(&self, index: u32) -> Option<Vec<f32>> {
        let c = self.channels;
        let at = (index as usize).checked_mul(c)?;
        self.tiles.get(at..at.checked_add(c)?).map(|w| w.iter().map(|&b| f32::from_bits(b)).collect())
    }

    /// Every leaf and active tile of a frame; `None` when there are more
    /// than `max_leaves` leaves or `max_tiles` tiles (shared nodes let a
    /// small, corrupt asset claim billions, so callers bound what they decode).
    pub fn frame_contents(&self, frame: usize, max_leaves: usize, max_tiles: usize) -> Option<FrameContents> {
        self.tree_contents(frame, self.offset, max_leaves, max_tiles)
    }

    /// [`Nodes::frame_contents`] of entry `tree` of the frames array (a
    /// frame at a level, see `Metadata::tree_index`), placed at `offset`
    /// (the level's offset, `Metadata::level_offset`).
    pub fn tree_contents(&self, tree: usize, offset: [i32; 3], max_leaves: usize, max_tiles: usize) -> Option<FrameContents> {
        let mut leaves = Vec::new();
        let mut tiles = Vec::new();
        let Some(&l1) = self.frames.get(tree) else { return Some((leaves, tiles)) };
        let Some((log2, node)) = self.l1_node(l1) else { return Some((leaves, tiles)) };
        let mask_words = l1_mask_words(log2);
        let o = offset;
        let at = |base: [i32; 3], d: [i32; 3]| [base[0].wrapping_add(d[0]), base[1].wrapping_add(d[1]), base[2].wrapping_add(d[2])];
        for w in 0..mask_words {
            let mut bits = node.get(w).copied().unwrap_or(0);
            while bits != 0 {
                let s1 = w * 32 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let c1 = at(o, slot_coords(s1, log2).map(|v| v as i32 * 128));
                match lookup(node, &self.l1_entries, mask_words, s1) {
                    Slot::Tile(t) => tiles.push((c1, 128, t)),
                    Slot::Child(l2) => {
                        for s2 in 0..L2_SLOTS {
                            let c2 = at(c1, slot_coords(s2, L2_LOG2).map(|v| v as i32 * 8));
                            match self.l2_slot(l2, s2) {
                                Slot::Tile(t) => tiles.push((c2, 8, t)),
                                Slot::Child(l3) => {
                                    if let Some((mask, brick)) = self.l3_node(l3) {
                                        leaves.push((c2, mask, brick));
                                    }
                                }
                                Slot::Empty => {}
                            }
                        }
                    }
                    Slot::Empty => {}
                }
                if leaves.len() > max_leaves || tiles.len() > max_tiles {
                    return None;
                }
            }
        }
        Some((leaves, tiles))
    }

    /// What the trees rooted at `roots` (L1 node ids) use, each node, tile
    /// and brick counted once however many of them share it.
    pub fn usage(&self, roots: &[u32]) -> Usage {
        use std::collections::BTreeSet;
        let (mut l1s, mut l2s, mut l3s, mut tiles) = (BTreeSet::new(), BTreeSet::new(), BTreeSet::new(), BTreeSet::new());
        let mut u = Usage { trees: roots.len(), ..Usage::default() };
        // A node's occupied slots: children and tiles collected, the count returned.
        fn slots(node: &[u32], entries: &[u32], mask_words: usize, children: &mut BTreeSet<u32>, tiles: &mut BTreeSet<u32>) -> usize {
            let mut n = 0;
            for w in 0..mask_words {
                let mut bits = node.get(w).copied().unwrap_or(0);
                while bits != 0 {
                    let s = w * 32 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    n += 1;
                    match lookup(node, entries, mask_words, s) {
                        Slot::Child(c) => {
                            children.insert(c);
                        }
                        Slot::Tile(t) => {
                            tiles.insert(t);
                        }
                        Slot::Empty => {}
                    }
                }
            }
            n
        }
        for &r in roots {
            if !l1s.insert(r) {
                continue;
            }
            if let Some((log2, node)) = self.l1_node(r) {
                u.l1_words += l1_node_len(log2);
                u.l1_entries += slots(node, &self.l1_entries, l1_mask_words(log2), &mut l2s, &mut tiles);
            }
        }
        for &c in &l2s {
            let node = self.l2.get(c as usize * L2_WORDS..).unwrap_or(&[]);
            u.l2_entries += slots(node, &self.l2_entries, L2_MASK_WORDS, &mut l3s, &mut tiles);
        }
        let mut bricks = BTreeSet::new();
        for &c in &l3s {
            if let Some((mask, brick)) = self.l3_node(c) {
                bricks.insert(brick);
                u.l3_sub_masks += (0..8).filter(|&b| !matches!(sub_mask(&mask, b), 0 | u64::MAX)).count();
            }
        }
        (u.l1, u.l2, u.l3, u.tiles) = (l1s.len(), l2s.len(), l3s.len(), tiles.len());
        u.bricks = bricks.into_iter().collect();
        u
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
        l1_records(&self.l1).map_or(0, |r| r.len())
    }
    pub fn l2_count(&self) -> usize {
        self.l2.len() / L2_WORDS
    }
    /// L3 nodes, as word 0 of the L3 array says (0 when the array cannot
    /// hold that many records).
    pub fn l3_count(&self) -> usize {
        l3_node_count(&self.l3).unwrap_or(0)
    }
    /// Tiles (0 for an asset without channels).
    pub fn tile_count(&self) -> usize {
        self.tiles.len().checked_div(self.channels).unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// L1 nodes of every size: a slot inside reads its entry, one past the
    /// node's slots is empty, and an array of them walks back to its starts.
    #[test]
    fn l1_nodes_are_as_large_as_what_they_hold() {
        assert_eq!([0, 3, 4, 7, 8, 15, 16, 31].map(l1_log2_for), [2, 2, 3, 3, 4, 4, 5, 5]);
        assert_eq!([2, 3, 4, 5].map(l1_node_len), [5, 26, 194, 1538]);
        let mut n = Nodes { channels: 1, ..Nodes::default() };
        for log2 in [5, 2, 3] {
            let far = (1u32 << log2) - 1;
            let slot = |c: [u32; 3]| ((c[0] << (2 * log2)) | (c[1] << log2) | c[2]) as usize;
            let at = n.l1.len() as u32;
            n.l1.extend(l1_node_words(log2, &[slot([0, 0, 1]), slot([far, 1, far])], n.l1_entries.len() as u32));
            n.l1_entries.extend([10 + log2, TILE_FLAG | log2]);
            n.frames.push(at);
            assert_eq!(n.l1_slot(at, [0, 0, 1]), Slot::Child(10 + log2));
            assert_eq!(n.l1_slot(at, [far, 1, far]), Slot::Tile(log2));
            assert_eq!(n.l1_slot(at, [0, 0, 0]), Slot::Empty);
            assert_eq!(n.l1_slot(at, [far + 1, 0, 1]), Slot::Empty, "past the node's slots");
            let tiles = n.tree_contents(n.frames.len() - 1, [0; 3], 0, 10).unwrap().1;
            assert_eq!(tiles, vec![([far as i32 * 128, 128, far as i32 * 128], 128, log2)]);
        }
        assert_eq!(l1_records(&n.l1), Some(n.frames.clone()));
        assert_eq!(n.l1_count(), 3);
        assert_eq!(l1_records(&n.l1[..n.l1.len() - 1]), None, "a node cut short");
        let mut bad = n.l1.clone();
        bad[0] = 6;
        assert_eq!(l1_records(&bad), None, "L past 5");
    }

    #[test]
    fn prefix_counts_make_lookup_match_a_scan() {
        let occupied: Vec<usize> = (0..L2_SLOTS).filter(|s| s % 7 == 0 || s % 11 == 3).collect();
        let node = node_words(&occupied, L2_SLOTS, 5);
        let mut entries = vec![0u32; 5];
        entries.extend((0..occupied.len() as u32).map(|i| i + 100));
        let n = Nodes { channels: 1, l2: node, l2_entries: entries, ..Nodes::default() };
        for s in 0..L2_SLOTS {
            let want = occupied.iter().position(|&o| o == s).map_or(Slot::Empty, |r| Slot::Child(r as u32 + 100));
            assert_eq!(n.l2_slot(0, s), want, "slot {s}");
        }
    }
}
