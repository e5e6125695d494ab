//! In-memory types for one frame of a sparse scalar volume.
//!
//! A [`Grid`] mirrors the shape of an OpenVDB 5-4-3 tree without its
//! pointers: a flat list of 8³ [`Leaf`] nodes (each with its active mask and
//! all 512 values) plus the constant [`Tile`]s that the upper tree levels
//! hold.  Values are `f32` whatever the file stored (half, float or double):
//! every later stage of the cooker works in `f32`.
//!
//! Index space is integer voxel coordinates; [`Transform`] maps it to world
//! space.

mod bricks;
mod coord;
pub mod lod;
pub mod mem;
pub mod spill;
mod transform;

use rayon::prelude::*;

pub use bricks::{range_of, Brick, Bricks, CONSTANT};
pub use coord::{Bbox, Coord};
pub use transform::{MapType, Transform};

/// Edge length of a leaf node (a brick) in voxels.
pub const LEAF_DIM: i32 = 8;
/// Voxels in a leaf node.
pub const LEAF_VOXELS: usize = 512;

/// Index of a voxel inside its leaf, the OpenVDB order: `x * 64 + y * 8 + z`.
#[inline]
pub fn leaf_offset(x: i32, y: i32, z: i32) -> usize {
    (((x & 7) << 6) | ((y & 7) << 3) | (z & 7)) as usize
}

/// Local (x, y, z) of a voxel offset inside its leaf.
#[inline]
pub fn leaf_local(offset: usize) -> (i32, i32, i32) {
    let o = offset as i32;
    ((o >> 6) & 7, (o >> 3) & 7, o & 7)
}

/// The class a grid declares in its metadata.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridClass {
    FogVolume,
    LevelSet,
    Staggered,
    Unknown,
}

impl GridClass {
    /// Parses OpenVDB's `class` metadata string; anything else is `Unknown`.
    pub fn from_vdb_name(s: &str) -> GridClass {
        match s {
            "fog volume" => GridClass::FogVolume,
            "level set" => GridClass::LevelSet,
            "staggered" => GridClass::Staggered,
            _ => GridClass::Unknown,
        }
    }

    /// The string OpenVDB uses for this class.
    pub fn vdb_name(self) -> &'static str {
        match self {
            GridClass::FogVolume => "fog volume",
            GridClass::LevelSet => "level set",
            GridClass::Staggered => "staggered",
            GridClass::Unknown => "unknown",
        }
    }
}

/// Offsets of the set bits of a mask stored as 64-bit words (bit `i` is bit
/// `i % 64` of word `i / 64`), in increasing order.
pub fn set_bits(words: &[u64]) -> impl Iterator<Item = usize> + '_ {
    words.iter().enumerate().flat_map(|(wi, &w)| {
        let mut bits = w;
        std::iter::from_fn(move || {
            if bits == 0 {
                return None;
            }
            let b = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            Some(wi * 64 + b)
        })
    })
}

/// Fills the unknown voxels of a leaf-ordered brick from the known ones
/// (`known`: a mask in [`LeafMask`]'s layout), front by front outwards: each
/// unknown voxel next to a known one takes the mean of its known
/// 6-neighbours (in the order −x, +x, −y, +y, −z, +z), which that pass does
/// not change.  Stops after `passes` fronts or when no unknown voxel touches
/// a known one; returns the mask of the voxels known then.
pub fn fill_from_neighbours(values: &mut [f32; LEAF_VOXELS], mut known: [u64; 8], passes: usize) -> [u64; 8] {
    // Word x of a mask holds the 64 voxels (y, z) of slab x, bit y·8 + z.
    const NOT_Z0: u64 = 0xfefe_fefe_fefe_fefe;
    const NOT_Z7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    for _ in 0..passes {
        let mut front = [0u64; 8];
        for x in 0..8 {
            let k = known[x];
            let near = (if x > 0 { known[x - 1] } else { 0 }) | (if x < 7 { known[x + 1] } else { 0 }) | k << 8 | k >> 8 | (k << 1 & NOT_Z0) | (k >> 1 & NOT_Z7);
            front[x] = near & !k;
        }
        if front == [0; 8] {
            break;
        }
        for i in set_bits(&front) {
            let (x, y, z) = (i >> 6, (i >> 3) & 7, i & 7);
            let (mut acc, mut cnt) = (0.0f32, 0u32);
            let mut visit = |j: usize| {
                if known[j >> 6] >> (j & 63) & 1 == 1 {
                    acc += values[j];
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
            values[i] = acc / cnt as f32;
        }
        for (k, f) in known.iter_mut().zip(front) {
            *k |= f;
        }
    }
    known
}

/// A 512-bit voxel mask in OpenVDB's layout: bit `i` is bit `i % 64` of word `i / 64`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct LeafMask(pub [u64; 8]);

impl LeafMask {
    #[inline]
    pub fn is_on(&self, i: usize) -> bool {
        (self.0[(i >> 6) & 7] >> (i & 63)) & 1 == 1
    }
    #[inline]
    pub fn set(&mut self, i: usize, on: bool) {
        let w = &mut self.0[(i >> 6) & 7];
        if on {
            *w |= 1 << (i & 63);
        } else {
            *w &= !(1 << (i & 63));
        }
    }
    pub fn count_on(&self) -> u32 {
        self.0.iter().map(|w| w.count_ones()).sum()
    }
    pub fn is_empty(&self) -> bool {
        self.0.iter().all(|&w| w == 0)
    }
    /// Offsets of the set bits, in increasing order.
    pub fn iter_on(&self) -> impl Iterator<Item = usize> + '_ {
        set_bits(&self.0)
    }
}

/// One 8³ leaf node: origin (a multiple of 8), active mask and all 512 values.
#[derive(Clone, Debug, PartialEq)]
pub struct Leaf {
    pub origin: Coord,
    pub mask: LeafMask,
    pub values: [f32; LEAF_VOXELS],
}

impl Leaf {
    /// Inclusive index-space bbox of the active voxels, `None` if none is active.
    pub fn active_bbox(&self) -> Option<Bbox> {
        let mut bbox: Option<Bbox> = None;
        for i in self.mask.iter_on() {
            let (x, y, z) = leaf_local(i);
            let c = self.origin.offset(x, y, z);
            bbox = Some(match bbox {
                None => Bbox::point(c),
                Some(b) => b.expanded(c),
            });
        }
        bbox
    }
}

/// A constant region held by an upper tree level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tile {
    /// Minimum corner, a multiple of `dim`.
    pub origin: Coord,
    /// Edge length in voxels: 8 (in a 16³ node), 128 (in a 32³ node) or 4096 (at the root).
    pub dim: u32,
    pub value: f32,
    pub active: bool,
}

impl Tile {
    pub fn voxel_count(&self) -> u64 {
        u64::from(self.dim).pow(3)
    }
    pub fn bbox(&self) -> Bbox {
        let d = self.dim as i32 - 1;
        Bbox::new(self.origin, self.origin.offset(d, d, d))
    }
}

/// Summary figures over a grid's active values (tile voxels included).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stats {
    pub active_voxels: u64,
    pub leaf_count: u64,
    pub active_tiles: u64,
    pub bbox: Option<Bbox>,
    /// Minimum, maximum and sum of the active values; `None` for an empty
    /// grid.  NaN values have no order: min and max are over the others
    /// (NaN when every active value is NaN); the sum is plain arithmetic (NaN
    /// when a value is NaN, or when both infinities are active).
    pub min: Option<f64>,
    pub max: Option<f64>,
    pub sum: f64,
    /// Active values (a tile's once per voxel it covers) that are NaN or ±∞.
    pub non_finite: u64,
}

/// Active-value figures of one leaf (min and max are infinite when it has none).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeafSummary {
    pub count: u64,
    pub min: f32,
    pub max: f32,
    pub sum: f64,
    pub bbox: Option<Bbox>,
    /// Active values that are NaN or ±∞ (min and max leave NaN out).
    pub non_finite: u64,
}

impl LeafSummary {
    pub fn of(leaf: &Leaf) -> LeafSummary {
        let mut s = LeafSummary { count: 0, min: f32::INFINITY, max: f32::NEG_INFINITY, sum: 0.0, bbox: None, non_finite: 0 };
        let n = leaf.mask.count_on();
        if n == 0 {
            return s;
        }
        s.count = u64::from(n);
        if n as usize == LEAF_VOXELS {
            // Dense leaf: eight independent lanes the compiler vectorises
            // (a fixed order, so still deterministic).
            let mut lo = [f32::INFINITY; 8];
            let mut hi = [f32::NEG_INFINITY; 8];
            let mut sum = [0.0f64; 8];
            let mut odd = [0u64; 8];
            for chunk in leaf.values.chunks_exact(8) {
                for k in 0..8 {
                    lo[k] = lo[k].min(chunk[k]);
                    hi[k] = hi[k].max(chunk[k]);
                    sum[k] += f64::from(chunk[k]);
                    odd[k] += u64::from(!chunk[k].is_finite());
                }
            }
            s.min = lo.iter().copied().fold(f32::INFINITY, f32::min);
            s.max = hi.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            s.sum = sum.iter().sum();
            s.non_finite = odd.iter().sum();
            let d = LEAF_DIM - 1;
            s.bbox = Some(Bbox::new(leaf.origin, leaf.origin.offset(d, d, d)));
        } else {
            for i in leaf.mask.iter_on() {
                let v = leaf.values[i];
                s.min = s.min.min(v);
                s.max = s.max.max(v);
                s.sum += f64::from(v);
                s.non_finite += u64::from(!v.is_finite());
            }
            s.bbox = leaf.active_bbox();
        }
        s
    }
}

/// The `min` and `max` of [`LeafSummary::of`], taken in the same order (so
/// the same value of ±0), without its sums and box.
pub fn active_range(leaf: &Leaf) -> [f32; 2] {
    active_range_of(&leaf.mask, &leaf.values)
}

/// [`active_range`] of the voxels of `mask` in `values`.
pub fn active_range_of(mask: &LeafMask, values: &[f32; LEAF_VOXELS]) -> [f32; 2] {
    if mask.count_on() as usize == LEAF_VOXELS {
        let mut lo = [f32::INFINITY; 8];
        let mut hi = [f32::NEG_INFINITY; 8];
        for chunk in values.chunks_exact(8) {
            for k in 0..8 {
                lo[k] = lo[k].min(chunk[k]);
                hi[k] = hi[k].max(chunk[k]);
            }
        }
        return [lo.iter().copied().fold(f32::INFINITY, f32::min), hi.iter().copied().fold(f32::NEG_INFINITY, f32::max)];
    }
    mask.iter_on().map(|i| values[i]).fold([f32::INFINITY, f32::NEG_INFINITY], |[lo, hi], v| [lo.min(v), hi.max(v)])
}

/// One frame of a sparse scalar volume.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    pub name: String,
    pub class: GridClass,
    pub background: f32,
    pub transform: Transform,
    /// Leaves sorted by origin (x, then y, then z).
    pub leaves: Vec<Leaf>,
    /// Tiles that are active or whose value differs from the background.
    pub tiles: Vec<Tile>,
}

impl Grid {
    /// Computes the summary figures.  Leaves are summarised in parallel and
    /// combined in leaf order, so the result does not depend on the thread count.
    pub fn stats(&self) -> Stats {
        let parts: Vec<LeafSummary> = self.leaves.par_iter().map(LeafSummary::of).collect();
        let mut st = Stats { active_voxels: 0, leaf_count: self.leaves.len() as u64, active_tiles: 0, bbox: None, min: None, max: None, sum: 0.0, non_finite: 0 };
        let mut lo = f32::INFINITY;
        let mut hi = f32::NEG_INFINITY;
        let grow = |b: Bbox, bbox: &mut Option<Bbox>| {
            *bbox = Some(match *bbox {
                None => b,
                Some(a) => a.union(b),
            })
        };
        for p in parts.iter().filter(|p| p.count > 0) {
            st.active_voxels += p.count;
            lo = lo.min(p.min);
            hi = hi.max(p.max);
            st.sum += p.sum;
            st.non_finite += p.non_finite;
            if let Some(b) = p.bbox {
                grow(b, &mut st.bbox);
            }
        }
        for t in self.tiles.iter().filter(|t| t.active) {
            st.active_tiles += 1;
            st.active_voxels += t.voxel_count();
            grow(t.bbox(), &mut st.bbox);
            lo = lo.min(t.value);
            hi = hi.max(t.value);
            st.sum += f64::from(t.value) * t.voxel_count() as f64;
            if !t.value.is_finite() {
                st.non_finite += t.voxel_count();
            }
        }
        if st.active_voxels > 0 {
            // lo > hi: every active value is NaN.
            let (lo, hi) = if lo <= hi { (lo, hi) } else { (f32::NAN, f32::NAN) };
            st.min = Some(f64::from(lo));
            st.max = Some(f64::from(hi));
        }
        st
    }

    /// The value at an index-space coordinate and whether it is active.
    /// Outside every leaf and tile this is `(background, false)`.
    pub fn probe(&self, c: Coord) -> (f32, bool) {
        let origin = c.leaf_origin();
        if let Ok(i) = self.leaves.binary_search_by(|l| l.origin.cmp(&origin)) {
            let leaf = &self.leaves[i];
            let o = leaf_offset(c.x, c.y, c.z);
            return (leaf.values[o], leaf.mask.is_on(o));
        }
        for t in &self.tiles {
            if t.bbox().contains(c) {
                return (t.value, t.active);
            }
        }
        (self.background, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leaf_with(origin: Coord, on: &[(i32, i32, i32, f32)]) -> Leaf {
        let mut leaf = Leaf { origin, mask: LeafMask::default(), values: [0.0; 512] };
        for &(x, y, z, v) in on {
            let o = leaf_offset(x, y, z);
            leaf.mask.set(o, true);
            leaf.values[o] = v;
        }
        leaf
    }

    #[test]
    fn offsets_round_trip() {
        for o in 0..512 {
            let (x, y, z) = leaf_local(o);
            assert_eq!(leaf_offset(x, y, z), o);
        }
        assert_eq!(leaf_offset(-1, 0, 0), 7 << 6);
    }

    #[test]
    fn mask_iteration_matches_bits() {
        let mut m = LeafMask::default();
        for i in [0usize, 63, 64, 200, 511] {
            m.set(i, true);
        }
        assert_eq!(m.iter_on().collect::<Vec<_>>(), vec![0, 63, 64, 200, 511]);
        assert_eq!(m.count_on(), 5);
        m.set(63, false);
        assert!(!m.is_on(63));
    }

    #[test]
    fn stats_count_non_finite_values() {
        let mut g = Grid {
            name: "d".into(),
            class: GridClass::FogVolume,
            background: 0.0,
            transform: Transform::identity(),
            leaves: vec![leaf_with(Coord::new(0, 0, 0), &[(1, 1, 1, f32::NAN), (2, 2, 2, 0.5), (3, 3, 3, f32::NEG_INFINITY)])],
            tiles: vec![Tile { origin: Coord::new(8, 0, 0), dim: 8, value: f32::INFINITY, active: true }],
        };
        // A dense leaf takes the vectorised path.
        let mut dense = leaf_with(Coord::new(0, 8, 0), &[]);
        dense.mask = LeafMask([u64::MAX; 8]);
        dense.values = std::array::from_fn(|i| if i == 9 { f32::NAN } else { 1.0 });
        g.leaves.push(dense);
        let s = g.stats();
        assert_eq!(s.non_finite, 2 + 512 + 1);
        assert_eq!((s.min, s.max), (Some(f64::NEG_INFINITY), Some(f64::INFINITY)));
        assert!(s.sum.is_nan());
        // Every active value NaN: min and max are NaN, not the empty fold's ±∞.
        g.leaves.truncate(1);
        g.leaves[0].values = [f32::NAN; 512];
        g.tiles.clear();
        let s = g.stats();
        assert_eq!(s.non_finite, 3);
        assert!(s.min.unwrap().is_nan() && s.max.unwrap().is_nan());
    }

    #[test]
    fn stats_count_tiles_once_per_voxel() {
        let g = Grid {
            name: "d".into(),
            class: GridClass::FogVolume,
            background: 0.0,
            transform: Transform::identity(),
            leaves: vec![leaf_with(Coord::new(-8, 0, 0), &[(7, 1, 2, 0.5), (0, 0, 0, 2.0)])],
            tiles: vec![Tile { origin: Coord::new(8, 8, 8), dim: 8, value: 1.0, active: true }, Tile { origin: Coord::new(128, 0, 0), dim: 128, value: 3.0, active: false }],
        };
        let s = g.stats();
        assert_eq!(s.active_voxels, 2 + 512);
        assert_eq!(s.active_tiles, 1);
        assert_eq!(s.leaf_count, 1);
        assert_eq!(s.bbox, Some(Bbox::new(Coord::new(-8, 0, 0), Coord::new(15, 15, 15))));
        assert_eq!(s.min, Some(0.5));
        assert_eq!(s.max, Some(2.0));
        assert_eq!(s.sum, 2.5 + 512.0);
        assert_eq!(g.probe(Coord::new(-1, 1, 2)), (0.5, true));
        assert_eq!(g.probe(Coord::new(130, 5, 5)), (3.0, false));
        assert_eq!(g.probe(Coord::new(-100, 5, 5)), (0.0, false));
    }

    #[test]
    fn empty_grid_has_no_range() {
        let g = Grid { name: String::new(), class: GridClass::Unknown, background: 0.0, transform: Transform::identity(), leaves: vec![], tiles: vec![] };
        let s = g.stats();
        assert_eq!((s.active_voxels, s.min, s.max, s.bbox), (0, None, None, None));
    }
}
