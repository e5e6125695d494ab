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
}

impl<'a> Bricks<'a> {
    /// Bricks of `channels` consecutive [`Brick`]s each.
    pub fn dense(stored: &'a [Brick], channels: usize) -> Bricks<'a> {
        let channels = channels.max(1);
        Bricks { channels, len: stored.len() / channels, slots: None, stored, constants: &[] }
    }

    /// Bricks whose channels are named by `slots` (`channels` per brick).
    pub fn sparse(slots: &'a [u32], stored: &'a [Brick], constants: &'a [Brick], channels: usize) -> Bricks<'a> {
        let channels = channels.max(1);
        Bricks { channels, len: slots.len() / channels, slots: Some(slots), stored, constants }
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
