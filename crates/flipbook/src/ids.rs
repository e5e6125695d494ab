//! Hash-consing by id: a table of ids whose items live in a vector of the
//! caller's, so that an item is held once (a map keyed by the item would
//! hold it again as its key: 72 bytes per L3 node, more than the node).

use hashbrown::hash_table::{Entry, HashTable};
use vdbcook_grid::mem::{fallible, OutOfMemory};

#[derive(Default)]
pub(crate) struct IdTable(HashTable<u32>);

impl IdTable {
    /// Room for `n` more ids; `hash_of(id)` is an id's item's hash (the
    /// table rehashes what it holds when it grows).
    pub(crate) fn reserve(&mut self, n: usize, what: &'static str, hash_of: impl Fn(u32) -> u64) -> Result<(), OutOfMemory> {
        let bytes = (self.0.len().saturating_add(n) as u64).saturating_mul(2 * std::mem::size_of::<u32>() as u64 + 2);
        fallible(|| self.0.try_reserve(n, |&id| hash_of(id))).map_err(|_| OutOfMemory { what, bytes })
    }

    /// About the bytes of its table: a bucket per 7/8 of an id's room, each
    /// an id and a control byte.
    pub(crate) fn heap_bytes(&self) -> u64 {
        (self.0.capacity() as u64).saturating_mul(8) / 7 * (std::mem::size_of::<u32>() as u64 + 1)
    }

    /// An id with hash `h` for which `same(id)` holds.
    pub(crate) fn find(&self, h: u64, same: impl Fn(u32) -> bool) -> Option<u32> {
        self.0.find(h, |&id| same(id)).copied()
    }

    /// Records `id`, with hash `h`, beside any others.
    pub(crate) fn insert(&mut self, h: u64, id: u32, hash_of: impl Fn(u32) -> u64) {
        self.0.insert_unique(h, id, |&id| hash_of(id));
    }

    /// The id of the item with hash `h` for which `same(id)` holds, or else
    /// `new`, recorded for it; and whether it was new.
    pub(crate) fn intern(&mut self, h: u64, new: u32, same: impl Fn(u32) -> bool, hash_of: impl Fn(u32) -> u64) -> (u32, bool) {
        match self.0.entry(h, |&id| same(id), |&id| hash_of(id)) {
            Entry::Occupied(e) => (*e.get(), false),
            Entry::Vacant(e) => {
                e.insert(new);
                (new, true)
            }
        }
    }
}
