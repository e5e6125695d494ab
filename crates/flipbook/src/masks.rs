//! Each leaf's active mask in each channel's own grid, kept per frame with
//! several channels for the error figures (a channel is measured over its
//! own active voxels). A channel's mask at a leaf is mostly the leaf's own
//! (the union over the channels, its L3 node's mask) or empty, so those
//! take a 4-byte code and only the others their 64 bytes: held whole, a
//! five-channel fire kept 320 bytes per leaf of every frame of a segment,
//! more than the leaf's L3 node, for as long as the segment cooked.

use crate::Error;

/// Codes of a channel's mask at a leaf; any other code indexes `other`.
const EMPTY: u32 = u32::MAX;
const UNION: u32 = u32::MAX - 1;

/// One frame's leaves' channel masks, in leaf order (see the module's text).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ChannelMasks {
    channels: usize,
    /// Per leaf per channel: [`EMPTY`], [`UNION`] or an index into `other`.
    codes: Vec<u32>,
    other: Vec<[u64; 8]>,
}

impl ChannelMasks {
    pub(crate) fn new(channels: usize) -> ChannelMasks {
        ChannelMasks { channels, ..ChannelMasks::default() }
    }

    /// Room for `leaves` more leaves' codes.
    pub(crate) fn reserve(&mut self, leaves: usize) {
        self.codes.reserve(leaves.saturating_mul(self.channels));
    }

    /// Adds the next leaf's masks, one per channel; `union` is theirs.
    pub(crate) fn push(&mut self, masks: &[[u64; 8]], union: &[u64; 8]) -> Result<(), Error> {
        for m in masks {
            let code = if m == union {
                UNION
            } else if m.iter().all(|&w| w == 0) {
                EMPTY
            } else {
                let at = u32::try_from(self.other.len()).ok().filter(|&i| i < 1 << 31).ok_or(Error::Overflow { what: "channel masks in a frame" })?;
                self.other.push(*m);
                at
            };
            self.codes.push(code);
        }
        Ok(())
    }

    /// About the bytes it holds.
    pub(crate) fn heap_bytes(&self) -> u64 {
        (self.codes.capacity() * std::mem::size_of::<u32>() + self.other.capacity() * std::mem::size_of::<[u64; 8]>()) as u64
    }

    /// Leaves recorded.
    pub fn leaves(&self) -> usize {
        self.codes.len().checked_div(self.channels).unwrap_or(0)
    }

    /// Channel `c`'s mask at leaf `k`, whose L3 node's mask is `union`
    /// (`None` past the leaves or the channels recorded).
    pub fn get(&self, k: usize, c: usize, union: &[u64; 8]) -> Option<[u64; 8]> {
        if c >= self.channels {
            return None;
        }
        match *self.codes.get(k.checked_mul(self.channels)?.checked_add(c)?)? {
            EMPTY => Some([0; 8]),
            UNION => Some(*union),
            i => self.other.get(i as usize).copied(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masks_read_back_as_pushed_and_only_the_uncommon_ones_are_held_whole() {
        let union = [0xff, 1, 0, 0, 0, 0, 0, 7];
        let part = [0x0f, 1, 0, 0, 0, 0, 0, 0];
        let other = [0xf0, 0, 0, 0, 0, 0, 0, 7];
        let mut m = ChannelMasks::new(3);
        m.push(&[union, [0; 8], part], &union).unwrap();
        m.push(&[part, other, [0; 8]], &union).unwrap();
        assert_eq!(m.leaves(), 2);
        assert_eq!(m.other.len(), 3, "the union and empty masks are codes");
        let pushed = [[union, [0; 8], part], [part, other, [0; 8]]];
        for (k, leaf) in pushed.iter().enumerate() {
            for (c, want) in leaf.iter().enumerate() {
                assert_eq!(m.get(k, c, &union), Some(*want), "leaf {k} channel {c}");
            }
        }
        assert_eq!(m.get(2, 0, &union), None, "past the leaves");
        assert_eq!(m.get(0, 3, &union), None, "past the channels");
        assert_eq!(ChannelMasks::default().leaves(), 0);
    }
}
