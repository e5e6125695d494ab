//! The brick pool: distinct bricks of several channels, each stored once,
//! found by content hash then compared; with several channels, a channel's
//! constant brick is held once for every brick that has it.

use crate::{Brick, Error, HashIndex, Map};
use rayon::prelude::*;
use vdbcook_grid::spill::{SpillPolicy, Store};
use vdbcook_grid::{range_of, Bricks, CONSTANT, LEAF_VOXELS};
use vdbcook_vpak::nodes::TILE_FLAG;

/// Distinct bricks, each stored once, `channels` [`Brick`]s each.  With
/// several channels, a channel's brick whose 512 values are all one value
/// (a channel stored at another level, where it is its background
/// everywhere) is held once for every brick, so that a channel costs
/// memory, and the stages after the build time, only where it has content.
pub struct BrickPool {
    channels: usize,
    /// Per brick per channel: an index into `stored`, or [`CONSTANT`] and an index into `constants`.
    slots: Vec<u32>,
    /// The non-constant channel bricks; past the pool's own, those being pooled.
    pub(crate) stored: Store<Brick>,
    /// Per stored brick, its `range_of`, taken as it was made (see
    /// [`Bricks::with_ranges`]); in step with `stored`, under the same spill
    /// policy (a store, and a spill file, of its own).
    pub(crate) ranges: Store<[f32; 2]>,
    constants: Vec<Brick>,
    /// A constant's value bits -> its index in `constants`.
    constant_ids: Map<u32, u32>,
    pub(crate) index: HashIndex,
}

/// One channel of a brick being pooled.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Channel {
    /// All 512 values have these bits (with several channels).
    Constant(u32),
    /// The brick at this index of `stored`, past the pool's own.
    At(usize),
}

/// The bits of the one value of a brick whose values are all bitwise equal.
fn constant_bits(b: &Brick) -> Option<u32> {
    let first = b[0].to_bits();
    b.iter().all(|v| v.to_bits() == first).then_some(first)
}

/// A constant channel's hash: by its one value, so that equal content
/// hashes alike however the brick was made.
fn constant_hash(bits: u32) -> u64 {
    twox_hash::XxHash3_64::oneshot_with_seed(0xc5, &bits.to_le_bytes())
}

/// What pooling needs of a channel brick, taken when it is made (while its
/// values are in cache): its content hash (the exact bits of every value,
/// so -0.0 and 0.0, or two NaN payloads, stay distinct), its value's
/// bits when all 512 are one and the pool shares constants, and else its range.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Made {
    pub(crate) hash: u64,
    constant: Option<u32>,
    pub(crate) range: [f32; 2],
}

impl Made {
    pub(crate) fn of(b: &Brick, shares_constants: bool) -> Made {
        match shares_constants.then(|| constant_bits(b)).flatten() {
            Some(bits) => Made { hash: constant_hash(bits), constant: Some(bits), range: [0.0; 2] },
            None => Made { hash: twox_hash::XxHash3_64::oneshot(bytemuck::cast_slice(b)), constant: None, range: range_of(b) },
        }
    }

    /// The channel of the brick made at `stored[a]`.
    pub(crate) fn channel(&self, a: usize) -> Channel {
        self.constant.map_or(Channel::At(a), Channel::Constant)
    }
}

impl Default for BrickPool {
    fn default() -> Self {
        BrickPool::new(1)
    }
}

impl BrickPool {
    pub fn new(channels: usize) -> BrickPool {
        BrickPool { channels: channels.max(1), slots: Vec::new(), stored: Store::default(), ranges: Store::default(), constants: Vec::new(), constant_ids: Map::default(), index: HashIndex::default() }
    }

    /// Returns the id of `brick` (its `channels` bricks), adding it if it is new.
    pub fn insert(&mut self, brick: &[Brick]) -> Result<u32, Error> {
        if brick.len() != self.channels {
            return Err(Error::Channels { found: brick.len(), expected: self.channels });
        }
        let from = self.stored.len();
        let made: Vec<Made> = brick.iter().map(|b| Made::of(b, self.shares_constants())).collect();
        self.stage(brick, &made)?;
        let channels: Vec<Channel> = made.iter().enumerate().map(|(k, m)| m.channel(from + k)).collect();
        let mut next = from;
        let h = BrickPool::hash(&channels, |a| made[a - from].hash);
        let found = self.settle(&channels, &mut next, h);
        self.truncate_stored(next);
        found
    }

    /// Stores channel bricks to be pooled, `made` taken of each.
    pub(crate) fn stage(&mut self, bricks: &[Brick], made: &[Made]) -> Result<(), Error> {
        self.stored.extend_from_slice(bricks, "the brick pool")?;
        self.staged(made.par_iter().map(|m| m.range))
    }

    /// Records the ranges ([`Made::range`]) of the channel bricks just
    /// stored (straight into `stored`) past the ones recorded, in order.
    pub(crate) fn staged(&mut self, ranges: impl IndexedParallelIterator<Item = [f32; 2]>) -> Result<(), Error> {
        self.ranges.par_extend(ranges, "the bricks' ranges")?;
        debug_assert_eq!(self.ranges.len(), self.stored.len(), "a stored brick without its range");
        Ok(())
    }

    /// Gives back the room its slots grew into: no brick comes now, and the
    /// stages after the build hold them to the segment's end.
    pub(crate) fn settled(&mut self) {
        self.slots.shrink_to_fit();
    }

    /// About the bytes of its hash index and brick slots (what it holds
    /// beside its stores).
    pub(crate) fn index_bytes(&self) -> u64 {
        self.index.heap_bytes() + (self.slots.capacity() * std::mem::size_of::<u32>()) as u64
    }

    /// Keeps the first `n` stored bricks (those being pooled past them go).
    pub(crate) fn truncate_stored(&mut self, n: usize) {
        self.stored.truncate(n);
        self.ranges.truncate(n);
    }

    /// True when the pool holds constant channel bricks once (several
    /// channels; one channel's pool keeps every brick, one dense slice).
    pub(crate) fn shares_constants(&self) -> bool {
        self.channels > 1
    }

    /// The content hash of a brick being pooled, from its channels' hashes
    /// (`made(a)`: that of `stored[a]`, see [`Made`]): a one-channel brick's
    /// is its channel's, several are chained.
    pub(crate) fn hash(channels: &[Channel], made: impl Fn(usize) -> u64) -> u64 {
        let one = |ch: &Channel| match *ch {
            Channel::Constant(bits) => constant_hash(bits),
            Channel::At(a) => made(a),
        };
        match channels {
            [ch] => one(ch),
            _ => channels.iter().fold(0, |acc, ch| twox_hash::XxHash3_64::oneshot_with_seed(acc, &one(ch).to_le_bytes())),
        }
    }

    /// True when pooled brick `id`'s channel `k` is `ch`.
    fn same_channel(&self, id: usize, k: usize, ch: Channel) -> bool {
        let Some(&slot) = self.slots.get(id * self.channels + k) else { return false };
        match ch {
            Channel::Constant(bits) => slot & CONSTANT != 0 && self.constants.get((slot & !CONSTANT) as usize).is_some_and(|b| b[0].to_bits() == bits),
            Channel::At(a) => {
                slot & CONSTANT == 0 && matches!((self.stored.get(slot as usize), self.stored.get(a)), (Some(x), Some(y)) if crate::same_bits(std::slice::from_ref(x), std::slice::from_ref(y)))
            }
        }
    }

    /// Pools a brick whose channels are `channels` (hash `h`; those `At`
    /// past the pool's first `next` stored bricks): returns the id of an
    /// equal brick, or adds it, moving its stored channels to `next` onwards.
    pub(crate) fn settle(&mut self, channels: &[Channel], next: &mut usize, h: u64) -> Result<u32, Error> {
        let c = self.channels;
        if channels.len() != c {
            return Err(Error::Channels { found: channels.len(), expected: c });
        }
        if let Some(id) = self.index.find(h, |id| channels.iter().enumerate().all(|(k, &ch)| self.same_channel(id as usize, k, ch))) {
            return Ok(id);
        }
        let id = u32::try_from(self.len()).ok().filter(|&i| i < TILE_FLAG).ok_or(Error::Overflow { what: "bricks" })?;
        for &ch in channels {
            let slot = match ch {
                Channel::Constant(bits) => {
                    let fresh = u32::try_from(self.constants.len()).ok().filter(|&i| i < CONSTANT).ok_or(Error::Overflow { what: "constant bricks" })?;
                    let at = *self.constant_ids.entry(bits).or_insert(fresh);
                    if at == fresh {
                        self.constants.push([f32::from_bits(bits); LEAF_VOXELS]);
                    }
                    at | CONSTANT
                }
                Channel::At(a) => {
                    let to = u32::try_from(*next).ok().filter(|&i| i < CONSTANT && a < self.stored.len()).ok_or(Error::Overflow { what: "stored bricks" })?;
                    if a != *next {
                        self.stored.copy_within(a..a + 1, *next);
                        self.ranges.copy_within(a..a + 1, *next);
                    }
                    *next += 1;
                    to
                }
            };
            self.slots.push(slot);
        }
        self.index.add(h, id);
        Ok(id)
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    pub fn len(&self) -> usize {
        self.slots.len() / self.channels
    }

    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Reserves room for `n` more bricks, `made` of their channel bricks
    /// made in place (the others constant).
    pub(crate) fn reserve(&mut self, n: usize, made: usize) -> Result<(), Error> {
        // No huge-page advice: the pool grows frame by frame, where huge
        // pages cost more page clearing than they save (docs/benchmarks.md).
        self.stored.try_reserve(made, "the brick pool")?;
        self.ranges.try_reserve(made, "the bricks' ranges")?;
        vdbcook_grid::mem::try_reserve(&mut self.slots, n * self.channels, "the brick pool")?;
        self.index.try_reserve(n, "the brick index")?;
        Ok(())
    }

    /// Every brick's channels (one channel's pool is dense: `Bricks::as_dense`).
    pub fn bricks(&self) -> Bricks<'_> {
        let view = match self.channels {
            1 => Bricks::dense(&self.stored, 1),
            c => Bricks::sparse(&self.slots, &self.stored, &self.constants, c),
        };
        view.with_ranges(&self.ranges)
    }

    /// The memory of the stored bricks, emptied, for another pool to fill
    /// ([`crate::Builder::reuse`]); this pool is left empty.
    pub fn take_storage(&mut self) -> Store<Brick> {
        let mut v = std::mem::take(&mut self.stored);
        v.clear();
        self.ranges.clear();
        v
    }

    /// Stores the bricks (and their ranges) under `policy` (see `Builder::spill_to`).
    pub(crate) fn set_policy(&mut self, policy: Option<SpillPolicy>) {
        self.ranges.set_policy(policy.clone());
        self.stored.set_policy(policy);
    }

    /// Channel bricks held in memory: the stored ones and the constants.
    pub fn held(&self) -> usize {
        self.stored.len() + self.constants.len()
    }

    /// Brick `i`'s channels.
    pub fn brick(&self, i: usize) -> Option<Vec<Brick>> {
        let view = self.bricks();
        (0..self.channels).map(|c| view.try_get(i, c).copied()).collect()
    }
}
