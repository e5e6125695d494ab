//! Which texels of a 1-lane atlas some L3 node shows (coding scheme 4,
//! version 15). A texel no node shows is never read as a voxel, so the
//! cooker sets it to whatever costs least (its coder's prediction), and a
//! context-coded stream that knows which texels those are need not code
//! them: the decoder puts the prediction there itself. The masks come from
//! the body's own node arrays and tables, restored before the atlases.
//! `docs/format.md`, "Shown voxels", is the specification.

use crate::{kind, Metadata, CHOICE_SHIFT, PLANE_BRICK_MASK};

/// A tile's 512 elements, bit `v % 64` of word `v / 64` for element
/// `v = x + 8y + 64z` (x fastest, as the tiles filters number them).
pub(crate) type TileMask = [u64; 8];

fn word(b: &[u8], i: usize) -> Option<u32> {
    let at = i.checked_mul(4)?;
    b.get(at..at.checked_add(4)?).map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
}

/// Node `k`'s active voxels in tile order, from the L3 array `l3`; `None`
/// when its record or a sub-mask it names lies outside the array. A
/// sub-block of state 3 (invalid; the validator refuses it) shows nothing.
fn node_mask(l3: &[u8], k: usize) -> Option<TileMask> {
    let record = k.checked_mul(3)?.checked_add(1)?;
    let (states, first) = (word(l3, record + 1)?, word(l3, record.checked_add(2)?)? as usize);
    let mut out = [0u64; 8];
    let mut r = 0;
    for b in 0..8 {
        // Sub-block b = 4·(x / 4) + 2·(y / 4) + z / 4; its bit j = 16·(x % 4) + 4·(y % 4) + z % 4.
        let (x0, y0, z0) = (4 * (b >> 2), 4 * ((b >> 1) & 1), 4 * (b & 1));
        let m: u64 = match (states >> (2 * b)) & 3 {
            1 => {
                // All 64: four rows of four x bits in each of its four z.
                out[z0..z0 + 4].iter_mut().for_each(|w| *w |= 0x0f0f_0f0f << (8 * y0 + x0));
                continue;
            }
            2 => {
                let at = first.checked_add(2 * r)?;
                r += 1;
                u64::from(word(l3, at)?) | u64::from(word(l3, at.checked_add(1)?)?) << 32
            }
            _ => 0,
        };
        if m == 0 {
            continue;
        }
        // Bit 16·dx + 4·dy + dz moved to 16·dz + 4·dy + dx (dx and dz swapped, bit by bit):
        // nibble 4·dz + dy is then row (dy, dz)'s four x bits, which go to byte 4·dz + dy.
        let m = swap_bits(swap_bits(m, 0x0000_aaaa_0000_aaaa, 15), 0x0000_0000_cccc_cccc, 30);
        for (half, dz) in [(m & 0xffff_ffff, 0), (m >> 32, 2)] {
            let x = nibbles_to_bytes(half);
            out[z0 + dz] |= (x & 0xffff_ffff) << (8 * y0 + x0);
            out[z0 + dz + 1] |= (x >> 32) << (8 * y0 + x0);
        }
    }
    Some(out)
}

/// Nibble i of the low 32 bits of `x` to byte i.
#[inline(always)]
fn nibbles_to_bytes(x: u64) -> u64 {
    let x = (x | x << 16) & 0x0000_ffff_0000_ffff;
    let x = (x | x << 8) & 0x00ff_00ff_00ff_00ff;
    (x | x << 4) & 0x0f0f_0f0f_0f0f_0f0f
}

/// `x` with each bit of `mask` swapped with the bit `shift` above it.
fn swap_bits(x: u64, mask: u64, shift: u32) -> u64 {
    let t = ((x >> shift) ^ x) & mask;
    x ^ t ^ (t << shift)
}

/// One atlas section whose tiles' shown voxels are wanted.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Wanted {
    /// Its index among the atlases ([`Metadata::atlas_section`]).
    pub section: u32,
    /// Its tiles (the texture's bricks, empty places included).
    pub tiles: usize,
}

/// For each wanted atlas section, each tile's voxels that some L3 node
/// shows: the union over the nodes of the body's L3 array whose brick's
/// plane brick (through the channel table or the plane's brick table, for
/// each channel stored in the atlas's plane) is the tile's. `section`
/// gives a restored section's bytes by kind and index. Entries that point
/// nowhere add nothing (the validator refuses such a body after restoring).
pub(crate) fn shown_tiles<'a>(meta: &Metadata, wanted: &[Wanted], section: &dyn Fn(u32, u32) -> Option<&'a [u8]>) -> Vec<Vec<TileMask>> {
    let mut out: Vec<Vec<TileMask>> = wanted.iter().map(|w| vec![[0u64; 8]; w.tiles]).collect();
    // Per wanted atlas: its plane, first plane brick and brick count.
    let places: Vec<Option<(usize, u32, u32)>> = wanted
        .iter()
        .map(|w| {
            let (p, a) = meta.section_atlas(w.section)?;
            let atlas = meta.planes[p].atlases[a];
            Some((p, atlas.first_brick, atlas.count))
        })
        .collect();
    let Some(l3) = section(kind::L3_NODES, 0) else { return out };
    // A body the validator would refuse for them (after restoring): nothing shown, rather
    // than work by what a file claims.
    if meta.channels.len() > crate::check::MAX_CHANNELS || meta.planes.len() > crate::check::MAX_CHANNELS {
        return out;
    }
    let nodes = word(l3, 0).unwrap_or(0) as usize;
    // Per channel of a wanted plane: how a brick reaches its plane brick there.
    enum Route<'b> {
        Table(&'b [u8], u32),
        Bricks(&'b [u8]),
        Same,
    }
    // Each wanted plane once; per route, the wanted atlases of its plane.
    let mut planes: Vec<usize> = places.iter().flatten().map(|&(p, _, _)| p).collect();
    planes.sort_unstable();
    planes.dedup();
    let mut routes: Vec<(Route, Vec<usize>)> = Vec::new();
    for &p in &planes {
        let atlases: Vec<usize> = (0..wanted.len()).filter(|&w| places[w].is_some_and(|(q, _, _)| q == p)).collect();
        // The channels of a plane without alternates reach it alike: one route for them all.
        let mut shared = false;
        for (c, ch) in meta.channels.iter().enumerate() {
            let Some(choice) = meta.channel_planes(c).iter().position(|&q| q as usize == p) else { continue };
            let route = match (ch.alternates.is_empty(), meta.plane_has_table(p)) {
                (false, _) => section(kind::CHANNEL_TABLE, c as u32).map(|t| Route::Table(t, choice as u32)),
                (true, _) if shared => None,
                (true, true) => section(kind::BRICK_TABLE, p as u32).map(Route::Bricks),
                (true, false) => Some(Route::Same),
            };
            shared |= ch.alternates.is_empty();
            if let Some(r) = route {
                routes.push((r, atlases.clone()));
            }
        }
    }
    for k in 0..nodes {
        let Some(brick) = k.checked_mul(3).and_then(|r| word(l3, r + 1)) else { break };
        let mut mask = None;
        for (route, atlases) in &routes {
            let pb = match route {
                Route::Table(t, choice) => word(t, brick as usize).filter(|e| e >> CHOICE_SHIFT == *choice).map(|e| e & PLANE_BRICK_MASK),
                Route::Bricks(t) => word(t, brick as usize),
                Route::Same => Some(brick),
            };
            let Some(pb) = pb else { continue };
            for &w in atlases {
                let Some((_, first, count)) = places[w] else { continue };
                if pb < first || pb - first >= count || (pb - first) as usize >= wanted[w].tiles {
                    continue;
                }
                let Some(m) = *mask.get_or_insert_with(|| node_mask(l3, k)) else { continue };
                let tile = &mut out[w][(pb - first) as usize];
                tile.iter_mut().zip(m).for_each(|(t, m)| *t |= m);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Node voxel (x, y, z) active by the layout docs/format.md gives, bit by bit.
    fn by_the_book(states: u32, masks: &[u64], x: usize, y: usize, z: usize) -> bool {
        let b = (x / 4) * 4 + (y / 4) * 2 + z / 4;
        let j = (x % 4) * 16 + (y % 4) * 4 + z % 4;
        let r = (0..b).filter(|&s| (states >> (2 * s)) & 3 == 2).count();
        match (states >> (2 * b)) & 3 {
            1 => true,
            2 => masks[r] >> j & 1 == 1,
            _ => false,
        }
    }

    #[test]
    fn a_node_mask_in_tile_order_is_the_node_layout_moved() {
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            seed
        };
        for _ in 0..200 {
            let states = (0..8).fold(0u32, |s, b| s | ((next() >> 33) as u32 % 3) << (2 * b));
            let subs = ((states >> 1) & 0x5555).count_ones() as usize;
            let masks: Vec<u64> = (0..subs).map(|_| next()).collect();
            // Word 0 the count, one record, then the sub-masks.
            let mut l3 = vec![1u32, 9, states, 4];
            masks.iter().for_each(|m| l3.extend([*m as u32, (m >> 32) as u32]));
            let bytes: Vec<u8> = l3.iter().flat_map(|w| w.to_le_bytes()).collect();
            let got = node_mask(&bytes, 0).expect("a whole node");
            for v in 0..512 {
                let (x, y, z) = (v & 7, (v >> 3) & 7, v >> 6);
                assert_eq!(got[v / 64] >> (v % 64) & 1 == 1, by_the_book(states, &masks, x, y, z), "voxel {x} {y} {z} of states {states:#x}");
            }
        }
        // A sub-mask past the array's end: no mask.
        let bytes: Vec<u8> = [1u32, 0, 2, 4].iter().flat_map(|w| w.to_le_bytes()).collect();
        assert_eq!(node_mask(&bytes, 0), None);
    }
}
