//! A view of bricks of several channels (brick `b`'s channel `c`), stored
//! densely, or sparsely with every constant brick held once.

use crate::LEAF_VOXELS;

/// The 512 values of one leaf, in OpenVDB's order.
pub type Brick = [f32; LEAF_VOXELS];

/// A sparse slot with this bit set names `constants[slot & !CONSTANT]`.
pub const CONSTANT: u32 = 1 << 31;

/// Brick `b`'s channel `c`, for `b < len`, `c < channels`.
#[derive(Clone, Copy)]
pub struct Bricks<'a> {
    channels: usize,
    len: usize,
    /// Per brick per channel, an index into `stored`, or [`CONSTANT`] and an
    /// index into `constants`; `None`: brick `b`'s channel `c` is `stored[b · channels + c]`.
    slots: Option<&'a [u32]>,
    stored: &'a [Brick],
    constants: &'a [Brick],
    /// Per stored brick, its [`range_of`] (empty: taken when asked for).
    ranges: &'a [[f32; 2]],
}

impl<'a> Bricks<'a> {
    /// Bricks of `channels` consecutive [`Brick`]s each.
    pub fn dense(stored: &'a [Brick], channels: usize) -> Bricks<'a> {
        let channels = channels.max(1);
        Bricks { channels, len: stored.len() / channels, slots: None, stored, constants: &[], ranges: &[] }
    }

    /// Bricks whose channels are named by `slots` (`channels` per brick).
    pub fn sparse(slots: &'a [u32], stored: &'a [Brick], constants: &'a [Brick], channels: usize) -> Bricks<'a> {
        let channels = channels.max(1);
        Bricks { channels, len: slots.len() / channels, slots: Some(slots), stored, constants, ranges: &[] }
    }

    /// The view with `ranges[i]`, the [`range_of`] of stored brick `i`,
    /// taken when the bricks were made (then in cache, where a later pass
    /// reads every brick from memory again); ignored unless one per stored brick.
    pub fn with_ranges(self, ranges: &'a [[f32; 2]]) -> Bricks<'a> {
        Bricks { ranges: if ranges.len() == self.stored.len() { ranges } else { &[] }, ..self }
    }

    /// The [`range_of`] brick `b`'s channel `c`: as recorded, or taken now.
    /// Panics past the end, as [`Bricks::get`].
    pub fn range(&self, b: usize, c: usize) -> [f32; 2] {
        let i = b * self.channels + c;
        let at = match self.slots {
            None => Some(i),
            Some(s) => s.get(i).filter(|&&k| k & CONSTANT == 0).map(|&k| k as usize),
        };
        match at.and_then(|k| self.ranges.get(k)) {
            Some(&r) if c < self.channels && b < self.len => r,
            _ => range_of(self.get(b, c)),
        }
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The bricks as one slice (`channels` per brick), when they are dense.
    pub fn as_dense(&self) -> Option<&'a [Brick]> {
        self.slots.is_none().then_some(self.stored)
    }

    /// Brick `b`'s channel `c`; `None` past the end.
    #[inline]
    pub fn try_get(&self, b: usize, c: usize) -> Option<&'a Brick> {
        if c >= self.channels || b >= self.len {
            return None;
        }
        let i = b * self.channels + c;
        match self.slots {
            None => self.stored.get(i),
            Some(s) => match *s.get(i)? {
                k if k & CONSTANT != 0 => self.constants.get((k & !CONSTANT) as usize),
                k => self.stored.get(k as usize),
            },
        }
    }

    /// The constant bricks a sparse view holds once (see [`Bricks::constant_of`]).
    pub fn constants(&self) -> &'a [Brick] {
        self.constants
    }

    /// Which of [`Bricks::constants`] brick `b`'s channel `c` is, if one.
    #[inline]
    pub fn constant_of(&self, b: usize, c: usize) -> Option<usize> {
        let s = *self.slots?.get(b.checked_mul(self.channels)? + c)?;
        (c < self.channels && s & CONSTANT != 0).then_some((s & !CONSTANT) as usize)
    }

    /// Brick `b`'s channel `c`.  Panics past the end: callers index the
    /// bricks they were given.
    #[inline]
    pub fn get(&self, b: usize, c: usize) -> &'a Brick {
        match self.try_get(b, c) {
            Some(brick) => brick,
            None => panic!("brick {b} channel {c} of {} bricks of {} channels", self.len, self.channels),
        }
    }

    /// Every channel of brick `b`, in order.
    pub fn channels_of(&self, b: usize) -> impl Iterator<Item = &'a Brick> + '_ {
        (0..self.channels).filter_map(move |c| self.try_get(b, c))
    }
}

/// The smallest and largest of a brick's finite values (NaN and ±∞ left
/// out, so that the ranged formats keep their precision and decode to finite
/// values); for a brick without any finite value, `[m, m]` with m = `f32::MAX`
/// if it holds +∞, else `-f32::MAX` if it holds −∞, else 0 (all NaN).
pub fn range_of(values: &Brick) -> [f32; 2] {
    // Most bricks hold no ±∞: the plain min and max (which pass NaN over)
    // are then the range, and only a brick whose min or max is not finite
    // takes the slower pass that leaves ±∞ out.
    let plain = lanes_min_max(values, |v| (v, v));
    if plain[0].is_finite() && plain[1].is_finite() {
        return plain;
    }
    let [lo, hi] = lanes_min_max(values, |v| if v.is_finite() { (v, v) } else { (f32::INFINITY, f32::NEG_INFINITY) });
    if lo <= hi {
        return [lo, hi];
    }
    let m = if values.contains(&f32::INFINITY) {
        f32::MAX
    } else if values.contains(&f32::NEG_INFINITY) {
        -f32::MAX
    } else {
        0.0
    };
    [m, m]
}

/// The min and max of `f(v).0` and `f(v).1` over a brick, in eight
/// independent lanes so the compiler can vectorise (NaN never wins).
#[inline(always)]
fn lanes_min_max(values: &Brick, f: impl Fn(f32) -> (f32, f32)) -> [f32; 2] {
    let mut lo = [f32::INFINITY; 8];
    let mut hi = [f32::NEG_INFINITY; 8];
    for c in values.chunks_exact(8) {
        for k in 0..8 {
            let (l, h) = f(c[k]);
            lo[k] = lo[k].min(l);
            hi[k] = hi[k].max(h);
        }
    }
    [lo.iter().copied().fold(f32::INFINITY, f32::min), hi.iter().copied().fold(f32::NEG_INFINITY, f32::max)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_view_gives_recorded_ranges_of_stored_bricks_and_takes_the_others() {
        let stored: Vec<Brick> = vec![[1.0; LEAF_VOXELS], std::array::from_fn(|i| i as f32), [f32::NAN; LEAF_VOXELS]];
        let constants = [[-2.0f32; LEAF_VOXELS]];
        // Recorded ranges that are not the bricks' own, to tell them apart from ranges taken.
        let recorded = [[10.0, 11.0], [20.0, 21.0], [30.0, 31.0]];
        let slots = [1, CONSTANT, 2, 0];
        let sparse = Bricks::sparse(&slots, &stored, &constants, 2).with_ranges(&recorded);
        assert_eq!(sparse.range(0, 0), [20.0, 21.0]);
        assert_eq!(sparse.range(0, 1), [-2.0, -2.0], "a constant's range is taken");
        assert_eq!(sparse.range(1, 0), [30.0, 31.0]);
        assert_eq!(sparse.range(1, 1), [10.0, 11.0]);
        let dense = Bricks::dense(&stored, 1);
        assert_eq!(dense.with_ranges(&recorded).range(2, 0), [30.0, 31.0]);
        // No ranges, or not one per stored brick: taken from the values.
        for view in [dense, dense.with_ranges(&recorded[..2])] {
            assert_eq!(view.range(1, 0), [0.0, 511.0]);
            assert_eq!(view.range(2, 0), [0.0, 0.0], "all NaN");
        }
    }
}
