//! Deduplication of the encoded bricks, and the remapping of pool bricks to
//! the bricks stored.

use crate::cluster::{used_work, Clustered};
use crate::Error;
use rayon::prelude::*;
use vdbcook_encode::{Brick, Encoded};
use vdbcook_flipbook::HashIndex;

/// The bricks an asset stores.
pub(crate) struct Stored {
    /// Per stored brick, the encoded brick it is.
    pub(crate) keep: Vec<u32>,
    /// Per plane: its distinct encoded bricks.
    pub(crate) planes: Vec<Vec<u32>>,
    /// Per family of planes ([`Encoded::families`]): its planes, and per
    /// stored brick `j << CHOICE_SHIFT | b`, its plane brick b in the
    /// family's j-th plane (`u32::MAX`: none), as a channel table holds
    /// them (a family of one plane: b, as its brick table does).
    pub(crate) tables: Vec<(Vec<usize>, Vec<u32>)>,
    /// Pool brick -> stored brick.
    pub(crate) remap: Vec<u32>,
}

impl Stored {
    /// Bytes of its tables.
    pub(crate) fn heap_bytes(&self) -> u64 {
        let words = self.keep.capacity() + self.remap.capacity() + self.planes.iter().map(Vec::capacity).sum::<usize>() + self.tables.iter().map(|(_, t)| t.capacity()).sum::<usize>();
        (words * std::mem::size_of::<u32>()) as u64
    }

    /// Pool brick `b` as stored, decoded (one [`Brick`] per channel; the
    /// channels `want` names, or all: `Encoded::decode_wanted`).
    pub(crate) fn decode(&self, encoded: &Encoded, b: u32, want: &[bool]) -> Option<Vec<Option<Brick>>> {
        self.remap.get(b as usize).and_then(|&i| self.keep.get(i as usize)).and_then(|&k| encoded.decode_wanted(k as usize, want))
    }
}

/// Each plane stores its own distinct bricks (a table maps bricks to them),
/// so a channel that repeats where others change (a constant flame, a static
/// shadow) is stored once, as in an asset of its own.  With per-brick
/// formats a plane holds only the bricks that chose it.  A brick is its
/// plane bricks, one per family of planes: the distinct bricks are the
/// distinct combinations.  Tables are per family, not per plane: with
/// per-brick formats a channel's planes share one.
pub(crate) fn store(encoded: &Encoded, clustered: Option<&Clustered>) -> Result<Stored, Error> {
    let used = used_work(clustered, encoded.len());
    let families = encoded.families();
    let mut planes: Vec<Vec<u32>> = vec![Vec::new(); encoded.specs.len()];
    // Per family, per encoded brick: its entry (see `Stored::tables`).
    let mut entries: Vec<Vec<u32>> = Vec::with_capacity(families.len());
    for family in &families {
        let mut all = vec![u32::MAX; encoded.len()];
        for (j, &p) in family.iter().enumerate() {
            let members: Vec<u32> = (0..encoded.len() as u32).filter(|&i| used[i as usize] && encoded.holds(p, i as usize)).collect();
            let (keep, ids) = distinct(members.len(), &|k, buf| plane_brick_bytes(encoded, p, members[k] as usize, buf))?;
            if family.len() > 1 && keep.len() > vdbcook_vpak::PLANE_BRICK_MASK as usize {
                return Err(Error::TooManyPlaneBricks(keep.len() as u32));
            }
            for (&i, id) in members.iter().zip(ids) {
                all[i as usize] = (j as u32) << vdbcook_vpak::CHOICE_SHIFT | id;
            }
            planes[p] = keep.into_iter().map(|k| members[k as usize]).collect();
        }
        entries.push(all);
    }
    // Plane bricks, numbered by first use, are then numbered by first use
    // among the distinct bricks too (a plane without repeats maps brick b to
    // plane brick b).
    let used_bricks: Vec<u32> = (0..encoded.len() as u32).filter(|&i| used[i as usize]).collect();
    let (keep, used_remap) = distinct(used_bricks.len(), &|k, buf| {
        buf.clear();
        buf.extend(entries.iter().flat_map(|e| e[used_bricks[k] as usize].to_le_bytes()));
    })?;
    let keep: Vec<u32> = keep.into_iter().map(|k| used_bricks[k as usize]).collect();
    let mut enc_remap = vec![u32::MAX; encoded.len()];
    for (&i, id) in used_bricks.iter().zip(used_remap) {
        enc_remap[i as usize] = id;
    }
    drop(used_bricks);
    let tables = families.into_iter().zip(entries).map(|(f, e)| (f, keep.iter().map(|&i| e[i as usize]).collect())).collect();
    let remap = match clustered {
        Some(c) => c.remap.iter().map(|&w| enc_remap[w as usize]).collect(),
        None => enc_remap,
    };
    Ok(Stored { keep, planes, tables, remap })
}

/// Brick `i`'s bytes in plane `p`: its encoding, then the range of each of
/// the plane's channels; for a brick from which every channel of the plane
/// is absent, one byte (no brick's bytes are that short): they are all one
/// plane brick, found without encoding them.
fn plane_brick_bytes(encoded: &Encoded, p: usize, i: usize, buf: &mut Vec<u8>) {
    let spec = &encoded.specs[p];
    buf.clear();
    if encoded.plane_absent(p, i) {
        buf.push(0xa5);
        return;
    }
    buf.resize(spec.plane.brick_bytes(), 0);
    encoded.write(p, i, buf);
    for &c in &spec.channels {
        for v in encoded.range(i, c) {
            buf.extend_from_slice(&v.to_bits().to_le_bytes());
        }
    }
}

/// Finds the distinct items `0..n` by their bytes (`bytes_of`; the first of
/// equal ones, in order): returns their indices and, per item, its distinct index.
fn distinct(n: usize, bytes_of: &(dyn Fn(usize, &mut Vec<u8>) + Sync)) -> Result<(Vec<u32>, Vec<u32>), Error> {
    // Hashed a chunk at a time in parallel, then looked up in order: no
    // hash per item held beside the index's own.
    const CHUNK: usize = 1 << 16;
    let mut index = HashIndex::default();
    index.try_reserve(n, "the deduplication's index").map_err(vdbcook_grid::spill::StoreError::from)?;
    let mut keep: Vec<u32> = Vec::new();
    let mut remap = Vec::with_capacity(n);
    for first in (0..n).step_by(CHUNK) {
        let hashes: Vec<u64> = (first..(first + CHUNK).min(n))
            .into_par_iter()
            .map_init(Vec::new, |buf, i| {
                bytes_of(i, buf);
                twox_hash::XxHash3_64::oneshot(buf)
            })
            .collect();
        for (i, &h) in (first..).zip(&hashes) {
            let same = |k: u32| {
                // Equal hashes are rare: make both again to compare.
                let (mut x, mut y) = (Vec::new(), Vec::new());
                bytes_of(keep[k as usize] as usize, &mut x);
                bytes_of(i, &mut y);
                x == y
            };
            let id = match index.find(h, same) {
                Some(k) => k,
                None => {
                    let k = keep.len() as u32;
                    index.add(h, k);
                    keep.push(i as u32);
                    k
                }
            };
            remap.push(id);
        }
    }
    // Held to the segment's end: no room left from growing.
    keep.shrink_to_fit();
    Ok((keep, remap))
}
