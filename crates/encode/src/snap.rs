//! Texels for the disk (`cook --max-error E --supercompress`): once a
//! brick's format is chosen, its texels are moved to the coarsest grid of
//! values that still keeps every shown voxel within E (levels of the ranged
//! formats in steps of k; floats with their lowest mantissa bits rounded
//! off), so that a supercompressed file spends bits on what the bound asks
//! and no more. The format, the range and the bound are unchanged.

use crate::choose::{decode_one, single_plane, within};
use crate::texels::{levels, swap_xz};
use crate::{Brick, Format};

/// The brick's texels in `format` over `range` on the coarsest grid whose
/// decoded voxels of `mask` stay within `max_error`; `None` when no grid
/// coarser than the format's own does (or the format has no texels to move).
pub(crate) fn coarsest(format: Format, values: &Brick, range: [f32; 2], mask: &[u64; 8], max_error: f32) -> Option<Vec<u8>> {
    // Non-finite voxels must decode to themselves: leave such bricks as they are.
    if !values.iter().all(|v| v.is_finite()) {
        return None;
    }
    let passes = |bytes: &[u8]| within(values, &decode_one(format, bytes, range), mask, max_error);
    // Levels of a ranged format over [0, top] in steps of k (the largest the bound allows first).
    let stepped = |top: u32, k0_of: fn(u32) -> u32, push: fn(&mut Vec<u8>, u32)| {
        let l = levels(values, range, top as f32);
        let span = f64::from(range[1]) - f64::from(range[0]);
        // Snapping to multiples of k moves a level by at most k/2: k up to 2E/(span/top).
        let k0 = (2.0 * f64::from(max_error) * f64::from(top) / span).floor().min(f64::from(top)) as u32;
        largest_step(k0_of(k0), |k| {
            let mut out = Vec::with_capacity(2 * l.len());
            swap_xz(&l.map(|x| step_level(x, k, top))).into_iter().for_each(|q| push(&mut out, q));
            passes(&out).then_some(out)
        })
    };
    match format {
        Format::Unorm8 => stepped(255, |k0| k0, |out, q| out.push(q as u8)),
        // Steps of a power of two: the low byte of every level (and of its difference
        // from its neighbour) then takes few values, which a byte-wise coder sees.
        Format::Unorm16 => stepped(65535, |k0| k0.checked_ilog2().map_or(0, |b| 1 << b), |out, q| out.extend_from_slice(&(q as u16).to_le_bytes())),
        Format::F16 => largest_bits(10, |bits| {
            let h = values.map(|v| round_bits(u32::from(half::f16::from_f32(v).to_bits()), bits, 0x8000) as u16);
            let out: Vec<u8> = swap_xz(&h).iter().flat_map(|h| h.to_le_bytes()).collect();
            passes(&out).then_some(out)
        }),
        Format::F32 => largest_bits(23, |bits| {
            let f = values.map(|v| round_bits(v.to_bits(), bits, 0x8000_0000));
            let out: Vec<u8> = swap_xz(&f).iter().flat_map(|f| f.to_le_bytes()).collect();
            passes(&out).then_some(out)
        }),
        Format::Bc4 | Format::Bc7 | Format::Constant => None,
    }
    .filter(|b| b.len() == single_plane(format).brick_bytes())
}

/// Level `x` (in [0, top]) moved to the nearest multiple of `k`, or to `top`
/// when that is nearer (so a brick's largest voxel keeps its value).
fn step_level(x: f32, k: u32, top: u32) -> u32 {
    let kf = k as f32;
    let below = ((x / kf).floor() * kf) as u32;
    let above = below + k;
    [below, above.min(top), top].into_iter().filter(|&c| c <= top).min_by(|&a, &b| (a as f32 - x).abs().total_cmp(&(b as f32 - x).abs())).unwrap_or(0)
}

/// The texels of the largest step from `k0` down to 2 that `try_step`
/// accepts: `k0` first (where the bound says it should hold), then smaller
/// steps by a quarter each time (rounding may cost a step or two), or by
/// half when `k0` is a power of two (so they stay powers of two).
fn largest_step(k0: u32, try_step: impl Fn(u32) -> Option<Vec<u8>>) -> Option<Vec<u8>> {
    let mut k = k0;
    while k >= 2 {
        if let Some(b) = try_step(k) {
            return Some(b);
        }
        k = if k.is_power_of_two() { k / 2 } else { (k * 3 / 4).min(k - 1) };
    }
    None
}

/// The texels with the most low mantissa bits (at most `max`) rounded off
/// that `try_bits` accepts: a binary search (the error grows with the bits).
fn largest_bits(max: u32, try_bits: impl Fn(u32) -> Option<Vec<u8>>) -> Option<Vec<u8>> {
    let (mut lo, mut hi, mut best) = (1, max, None);
    while lo <= hi {
        let mid = (lo + hi) / 2;
        match try_bits(mid) {
            Some(b) => {
                best = Some(b);
                lo = mid + 1;
            }
            None => hi = mid - 1,
        }
    }
    best
}

/// A float's bits (sign and magnitude) with the lowest `bits` mantissa bits
/// rounded to nearest; a carry moves into the exponent as it should.
fn round_bits(x: u32, bits: u32, sign_bit: u32) -> u32 {
    let half = 1u32 << (bits - 1);
    let mask = (1u32 << bits) - 1;
    let sign = x & sign_bit;
    let magnitude = x & !sign;
    (magnitude.saturating_add(half) & !mask) | sign
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> Brick {
        std::array::from_fn(|i| {
            let (x, y, z) = ((i / 64) as f32, (i / 8 % 8) as f32, (i % 8) as f32);
            0.2 + 0.05 * x + 0.03 * (y * 1.3).sin() + 0.01 * z * z
        })
    }

    #[test]
    fn coarser_texels_stay_within_the_bound_and_take_fewer_values() {
        let v = cloud();
        let mask = [u64::MAX; 8];
        let range = crate::range_of(&v);
        for format in [Format::Unorm8, Format::Unorm16, Format::F16, Format::F32] {
            for e in [0.002f32, 0.01, 0.05] {
                let plain = crate::choose::encode_one(format, crate::Quality::VeryFast, &v, range, &mask);
                let Some(snapped) = coarsest(format, &v, range, &mask, e) else {
                    // Only where the format's own grid is already as coarse as the bound allows.
                    assert!(format == Format::Unorm8 && e < 0.005, "{format:?} at {e}: nothing coarser");
                    continue;
                };
                assert!(within(&v, &decode_one(format, &snapped, range), &mask, e), "{format:?} at {e}");
                let distinct = |b: &[u8]| {
                    let w = format.lane_bytes();
                    b.chunks(w).collect::<std::collections::HashSet<_>>().len()
                };
                assert!(distinct(&snapped) < distinct(&plain), "{format:?} at {e}: {} vs {} values", distinct(&snapped), distinct(&plain));
            }
        }
    }

    #[test]
    fn bits_round_to_nearest_and_carry() {
        assert_eq!(round_bits(0x3c01, 2, 0x8000), 0x3c00); // f16 just above 1 → 1
        assert_eq!(round_bits(0x3c03, 2, 0x8000), 0x3c04);
        assert_eq!(round_bits(0xbc03, 2, 0x8000), 0xbc04); // the sign stays
        assert_eq!(round_bits(0x3fff_ffff, 23, 0x8000_0000), 0x4000_0000); // carry into the exponent
        assert_eq!(round_bits(0xbf80_0001, 4, 0x8000_0000), 0xbf80_0000);
        assert_eq!(round_bits(0x0000_9001, 4, 0x8000_0000), 0x0000_9000); // a tiny f32 has no sign at bit 15
    }

    #[test]
    fn levels_snap_to_steps_or_the_top() {
        assert_eq!(step_level(254.6, 10, 255), 255);
        assert_eq!(step_level(247.0, 10, 255), 250);
        assert_eq!(step_level(4.9, 10, 255), 0);
        assert_eq!(step_level(5.1, 10, 255), 10);
    }
}
