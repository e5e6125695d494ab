//! Error figures: what is stored, decoded as readers decode it, against the
//! source (each coarser level against the level filtered from the source).

use rayon::prelude::*;
use vdbcook_encode::{Brick, ErrorStats, NonFinite};
use vdbcook_flipbook::Built;
use vdbcook_grid::spill::{Store, StoreError};

/// A stored brick decoder: pool brick and the channels wanted (`want[c]`;
/// empty: all) -> per channel its [`Brick`] (`None` for one not wanted).
pub(crate) type Decode<'a> = dyn Fn(u32, &[bool]) -> Option<Vec<Option<Brick>>> + Sync + 'a;

/// Told how many more of [`work`]'s leaves a pass has measured.
pub(crate) type Advance<'a> = dyn Fn(usize) + Sync + 'a;

/// The leaves one pass of the error figures measures: each L3 node once
/// with one channel, each frame's leaves with several.
pub(crate) fn work(built: &Built) -> usize {
    match built.channels {
        1 => built.l3.len(),
        _ => built.frames.iter().map(|f| f.leaves.len()).sum(),
    }
}

/// The error of an asset's stored levels, per channel.
pub(crate) struct Measured {
    /// Per frame of the first stored level.
    pub(crate) frames: Vec<Vec<ErrorStats>>,
    /// Per coarser stored level, finest first, over every frame.
    pub(crate) levels: Vec<Vec<ErrorStats>>,
    /// The first stored level over every frame.
    pub(crate) totals: Vec<ErrorStats>,
}

/// Measures every tree of `built` (levels `first` … `levels` − 1); `own`:
/// each channel's first stored level, where its per-frame figures are taken.
pub(crate) fn measure(built: &Built, first: u32, levels: u32, own: &[u32], decoded: &Decode, advance: &Advance) -> Result<Measured, StoreError> {
    let channels = own.len();
    let tree_err = voxel_errors(built, decoded, advance)?;
    let tree_level: Vec<u32> = built.frames.iter().map(|f| f.level).collect();
    // A coarser level's figure holds the channels for which it is coarser
    // than their first level (a coarse channel's own level is in `frames`).
    let level_err: Vec<Vec<ErrorStats>> = (first + 1..levels)
        .map(|k| {
            let mut t = vec![ErrorStats::default(); channels];
            for (e, _) in tree_err.iter().zip(&tree_level).filter(|(_, &l)| l == k) {
                t.iter_mut().zip(e).zip(own).filter(|(_, &o)| o < k).for_each(|((t, e), _)| t.merge(e));
            }
            t
        })
        .collect();
    let frames = by_frame(tree_err, &tree_level, first, own);
    let totals = (0..channels)
        .map(|c| {
            let mut t = ErrorStats::default();
            for f in &frames {
                t.merge(&f[c]);
            }
            t
        })
        .collect();
    Ok(Measured { frames, levels: level_err, totals })
}

/// Per frame, each channel's error at its first stored level (`own`); a
/// frame's trees are pushed together, its level-`first` tree first.
fn by_frame(tree_err: Vec<Vec<ErrorStats>>, tree_level: &[u32], first: u32, own: &[u32]) -> Vec<Vec<ErrorStats>> {
    let mut frames: Vec<Vec<ErrorStats>> = Vec::new();
    for (e, &l) in tree_err.into_iter().zip(tree_level) {
        if l == first {
            frames.push(vec![ErrorStats::default(); own.len()]);
        }
        if let Some(f) = frames.last_mut() {
            for ((acc, e), _) in f.iter_mut().zip(e).zip(own).filter(|(_, &o)| o == l) {
                *acc = e;
            }
        }
    }
    frames
}

/// Per frame of level `first` (the first stored), its error per channel at
/// the channel's first stored level (`own`).
pub(crate) fn frame_errors(built: &Built, first: u32, own: &[u32], decoded: &Decode, advance: &Advance) -> Result<Vec<Vec<ErrorStats>>, StoreError> {
    let tree_level: Vec<u32> = built.frames.iter().map(|f| f.level).collect();
    Ok(by_frame(voxel_errors(built, decoded, advance)?, &tree_level, first, own))
}

/// One leaf's [`ErrorStats`] in half the bytes (its counts are at most
/// 512), for a table over every L3 node of a segment.
#[derive(Clone, Copy)]
#[repr(C)]
struct LeafError {
    sum_sq: f64,
    max_abs: f64,
    /// Measured voxels, then NaN, +∞ and −∞ references.
    counts: [u16; 4],
}

// SAFETY: `repr(C)` of two f64 and four u16, no implicit padding (24 bytes).
unsafe impl bytemuck::Zeroable for LeafError {}
// SAFETY: as above; every bit pattern is a valid `LeafError`.
unsafe impl bytemuck::Pod for LeafError {}

impl From<ErrorStats> for LeafError {
    fn from(e: ErrorStats) -> LeafError {
        let n = |v: u64| u16::try_from(v).unwrap_or(u16::MAX);
        LeafError { sum_sq: e.sum_sq, max_abs: e.max_abs, counts: [n(e.count), n(e.non_finite.nan), n(e.non_finite.pos_inf), n(e.non_finite.neg_inf)] }
    }
}

impl LeafError {
    fn stats(&self) -> ErrorStats {
        let [count, nan, pos_inf, neg_inf] = self.counts.map(u64::from);
        ErrorStats { count, sum_sq: self.sum_sq, max_abs: self.max_abs, non_finite: NonFinite { nan, pos_inf, neg_inf } }
    }
}

/// Leaves whose bricks a parallel pass reads between two reports to
/// [`vdbcook_grid::spill::scanned`] (about 16 MiB of source and decoded bricks).
const SCAN_GROUP: usize = 4096;

/// Reports reading `bricks` channel bricks through a spilled pool, each with
/// one more brick made from it (decoded, or copied into another store).
pub(crate) fn scanned_bricks(bricks: usize) {
    vdbcook_grid::spill::scanned(bricks * 2 * std::mem::size_of::<Brick>());
}

/// Error of decoded bricks (`decoded(pool brick)`, one [`Brick`] per
/// channel) against the source, per tree (frames and levels, in push order)
/// and channel, over each channel's own active voxels.
fn voxel_errors(built: &Built, decoded: &Decode, advance: &Advance) -> Result<Vec<Vec<ErrorStats>>, StoreError> {
    let channels = built.channels;
    let pool = built.pool.bricks();
    if channels == 1 {
        // Per L3 node: its error over its own active voxels (the channel's
        // mask), a table as long as the nodes and under their spill policy.
        let mut per_l3 = Store::<LeafError>::with_policy(built.l3.policy().cloned());
        for nodes in built.l3.chunks(SCAN_GROUP) {
            let errors = nodes.par_iter().map(|l| {
                let mut e = ErrorStats::default();
                if let (Some(src), Some(Some(dec))) = (pool.try_get(l.brick as usize, 0), decoded(l.brick, &[]).and_then(|d| d.into_iter().next())) {
                    e.add_masked(src, &dec, &l.mask);
                }
                LeafError::from(e)
            });
            per_l3.par_extend(errors, "the error figures")?;
            scanned_bricks(nodes.len());
            advance(nodes.len());
        }
        return Ok(built
            .frames
            .iter()
            .map(|f| {
                let mut e = ErrorStats::default();
                for &(_, id) in &f.leaves {
                    e.merge(&per_l3[id as usize].stats());
                }
                vec![e]
            })
            .collect());
    }
    // Several channels: each leaf over each channel's own mask, in groups
    // of leaves whose figures are merged in leaf order.
    let leaf_errors = |f: &vdbcook_flipbook::FrameLeaves, k: usize, id: u32| {
        let mut e = vec![ErrorStats::default(); channels];
        let node = &built.l3[id as usize];
        let brick = node.brick as usize;
        // A channel not active in the leaf (one stored at another level) adds nothing: not decoded.
        let masks: Vec<[u64; 8]> = (0..channels).map_while(|c| f.channel_masks.get(k, c, &node.mask)).collect();
        let want: Vec<bool> = masks.iter().map(|m| m.iter().any(|&w| w != 0)).collect();
        if let (true, Some(dec)) = (want.iter().any(|&w| w), decoded(brick as u32, &want)) {
            for (c, e) in e.iter_mut().enumerate() {
                // An unwanted channel's mask is empty: it adds nothing.
                if let (Some(mask), Some(src), Some(Some(d))) = (masks.get(c), pool.try_get(brick, c), dec.get(c)) {
                    e.add_masked(src, d, mask);
                }
            }
        }
        e
    };
    let group = (SCAN_GROUP / channels).max(1);
    Ok(built
        .frames
        .iter()
        .map(|f| {
            let mut total = vec![ErrorStats::default(); channels];
            for (g, leaves) in f.leaves.chunks(group).enumerate() {
                let per_leaf: Vec<Vec<ErrorStats>> = leaves.par_iter().enumerate().map(|(k, &(_, id))| leaf_errors(f, g * group + k, id)).collect();
                for leaf in &per_leaf {
                    for (t, e) in total.iter_mut().zip(leaf) {
                        t.merge(e);
                    }
                }
                scanned_bricks(leaves.len() * channels);
                advance(leaves.len());
            }
            total
        })
        .collect())
}

/// Each channel's PSNR peak: its value range (`ranges`) over its finite
/// values (an infinite range would make every PSNR infinite); 1 for none.
pub(crate) fn peaks(built: &Built, ranges: &[[f32; 2]]) -> Vec<f64> {
    ranges
        .iter()
        .enumerate()
        .map(|(c, &range)| {
            let [lo, hi] = match range {
                r if r.iter().all(|v| v.is_finite()) => r,
                _ => finite_range(built, c),
            };
            let peak = f64::from(hi - lo);
            if peak > 0.0 && peak.is_finite() {
                peak
            } else {
                1.0
            }
        })
        .collect()
}

/// Channel `c`'s range over the finite values of the pool's bricks (their
/// inactive voxels are filled from the active ones, within their range) and
/// of the frames' tiles; `[0, 0]` when it has none.
fn finite_range(built: &Built, c: usize) -> [f32; 2] {
    let pool = built.pool.bricks();
    let bricks = (0..pool.len()).filter_map(|b| pool.try_get(b, c)).flat_map(|b| b.iter().copied());
    let tiles = built.frames.iter().flat_map(|f| f.tiles.iter().filter_map(|t| t.2.get(c).copied()));
    let [lo, hi] = bricks.chain(tiles).filter(|v| v.is_finite()).fold([f32::INFINITY, f32::NEG_INFINITY], |[lo, hi], v| [lo.min(v), hi.max(v)]);
    if lo <= hi {
        [lo, hi]
    } else {
        [0.0, 0.0]
    }
}
