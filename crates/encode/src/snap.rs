//! Texels for the disk (`cook --max-error E --supercompress`): once a
//! brick's format is chosen, its texels are moved to the coarsest grid of
//! values that still keeps every shown voxel within E (levels of the ranged
//! formats on a step of about 2E, their range's `min` moved down to a float
//! of few mantissa bits and its `max` up to make it a whole number of levels;
//! floats with their lowest mantissa bits rounded off), so that a supercompressed file spends bits on what the bound asks
//! and no more. With `--optimize disk` the levels are chosen for the
//! context coder instead: each the one nearest its prediction within the
//! bound ([`Coder::Context`]). The format and the bound are unchanged.

use crate::choose::{decode_one, single_plane, within};
use crate::texels::{levels, swap_xz, to_half};
use crate::{Brick, Format};

/// The coder a ranged format's levels are chosen for.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(crate) enum Coder {
    /// zstd: each shown voxel at its nearest level, the hidden ones (those
    /// no L3 node shows, which no bound holds) at level 0, whose runs cost
    /// zstd next to nothing.
    Zstd,
    /// The context coder (`--optimize disk`, which offers it the atlases of
    /// levels): each voxel, in the coder's order, at the level nearest its
    /// prediction that keeps it within the bound (any level for a hidden
    /// one), on a step of 2E or of E, whichever the coder is estimated to
    /// take fewer bytes for.
    Context,
}

/// The brick's texels in `format` and their range, on the coarsest grid
/// whose decoded voxels of `mask` stay within `max_error` of `values`;
/// `None` when no grid coarser than the format's own over `range` does (or
/// the format has no texels to move).
pub(crate) fn coarsest(format: Format, values: &Brick, range: [f32; 2], mask: &[u64; 8], max_error: f32, coder: Coder) -> Option<(Vec<u8>, [f32; 2])> {
    // Non-finite voxels must decode to themselves: leave such bricks as they are.
    if !values.iter().all(|v| v.is_finite()) {
        return None;
    }
    let passes = |bytes: &[u8], range: [f32; 2]| within(values, &decode_one(format, bytes, range), mask, max_error);
    let floats = |bits: u32, to_bytes: &dyn Fn(u32) -> Vec<u8>| {
        largest_bits(bits, |bits| {
            let out = to_bytes(bits);
            passes(&out, range).then_some(out)
        })
        .map(|b| (b, range))
    };
    let levels_for = |top: u32, push: fn(&mut Vec<u8>, u32)| for_coder(format, coder, |fraction| stepped(values, range, mask, top, max_error, coder, fraction, push, &passes));
    match format {
        Format::Unorm8 => levels_for(255, |out, q| out.push(q as u8)),
        Format::Unorm16 => levels_for(65535, |out, q| out.extend_from_slice(&(q as u16).to_le_bytes())),
        Format::F16 => {
            // Converted once (the brick-at-once conversion), rounded off per try.
            let halves = to_half(values);
            floats(10, &|bits| swap_xz(&halves.map(|h| round_bits(u32::from(h), bits, 0x8000) as u16)).iter().flat_map(|h| h.to_le_bytes()).collect())
        }
        Format::F32 => floats(23, &|bits| swap_xz(&values.map(|v| round_bits(v.to_bits(), bits, 0x8000_0000))).iter().flat_map(|f| f.to_le_bytes()).collect()),
        Format::Bc4 | Format::Bc7 | Format::Constant => None,
    }
    .filter(|(b, _)| b.len() == single_plane(format).brick_bytes())
}

/// A ranged format's levels ([`stepped`] on a step of `fraction` · 2E): on a
/// step of 2E, and for the context coder also on a step of E, where each
/// voxel has two or three levels within the bound to choose from
/// ([`Coder::Context`]), whichever the coder is estimated to take fewer
/// bytes for. A smooth field (a level set) follows the coder's prediction
/// with residuals of 0 on the finer step, where rounding to a step of 2E
/// leaves it ±1 half the time; a noisy one does not, and keeps the coarser.
fn for_coder(format: Format, coder: Coder, on_step: impl Fn(f64) -> Option<(Vec<u8>, [f32; 2])>) -> Option<(Vec<u8>, [f32; 2])> {
    let coarse = on_step(1.0);
    if coder == Coder::Zstd {
        return coarse;
    }
    let fine = on_step(0.5);
    let plane = single_plane(format);
    let cost = |c: &Option<(Vec<u8>, [f32; 2])>| c.as_ref().and_then(|(b, _)| vdbcook_vpak::coding::coder_bits(&plane, b)).unwrap_or(f64::INFINITY);
    if cost(&fine) < cost(&coarse) {
        fine
    } else {
        coarse
    }
}

/// Levels of a ranged format on a step of value s (`fraction` · 2E, or a
/// little less where rounding asks): the range's `min` is the float of
/// fewest mantissa bits at most s below the brick's smallest value, and its
/// `max` is moved so that every level is a multiple
/// of an integer k ≥ 2 (k = top / the number of steps the brick spans).
/// Each brick's texels are then k times a small integer, which the `tiles`
/// filter divides out, so every brick's residuals are in steps of about s.
/// For [`Coder::Context`] each voxel, in the coder's order, takes the level
/// of those within the bound nearest its prediction (any level for a voxel
/// no L3 node shows).
#[allow(clippy::too_many_arguments)]
fn stepped(
    values: &Brick,
    range: [f32; 2],
    mask: &[u64; 8],
    top: u32,
    max_error: f32,
    coder: Coder,
    fraction: f64,
    push: fn(&mut Vec<u8>, u32),
    passes: &dyn Fn(&[u8], [f32; 2]) -> bool,
) -> Option<(Vec<u8>, [f32; 2])> {
    // For the context coder: whether texel t's voxel is hidden (texel order).
    let hidden: Option<[bool; 512]> = (coder == Coder::Context).then(|| swap_xz(&std::array::from_fn(|i| mask[i >> 6] >> (i & 63) & 1 == 0)));
    for shrink in [1.0, 0.99, 0.95, 0.85, 0.7, 0.5] {
        let s = 2.0 * f64::from(max_error) * shrink * fraction;
        // The range's min moved down by at most a step, to the float of fewest
        // mantissa bits there: a level is as cheap to code from any min, a
        // brick's min of 24 random bits is not.
        let steps = |low: f32| (f64::from(top) / ((f64::from(range[1]) - f64::from(low)) / s).ceil().max(1.0)).floor() as u32;
        // Unless the step it may add leaves too few levels for a multiple k ≥ 2.
        let low = Some(fewest_bits((f64::from(range[0]) - s) as f32, range[0])).filter(|&l| steps(l) >= 2).unwrap_or(range[0]);
        let (lo, k) = (f64::from(low), steps(low));
        if k < 2 {
            return None;
        }
        let hi = (lo + s * f64::from(top) / f64::from(k)) as f32;
        if !hi.is_finite() || hi <= low {
            return None;
        }
        let moved = [low, hi];
        let mut l = levels(values, moved, top as f32);
        (0..l.len()).filter(|&i| mask[i >> 6] >> (i & 63) & 1 == 0).for_each(|i| l[i] = 0.0);
        // Multiples of k, as their quotients in texel order: the nearest.
        let mut q = swap_xz(&l.map(|x| ((x / k as f32).round() as u32).min(top / k) as u16));
        if let Some(hidden) = hidden.filter(|h| fraction < 1.0 || h.contains(&true)) {
            let (max, nearest, l) = ((top / k) as u16, q, swap_xz(&l));
            // A shown voxel's quotients within the bound: l/k ± E in quotients, a hair
            // inside (its nearest always); on a step of 2E that is the nearest alone.
            let reach = f64::from(max_error) * f64::from(top) / (f64::from(hi) - lo) / f64::from(k) * (1.0 - 1e-4);
            let within_reach = |t: usize| {
                let c = f64::from(l[t]) / f64::from(k);
                // Floors and ceilings of non-negative values by truncation (no libm call).
                let (below, above) = ((c - reach).max(0.0), (c + reach).min(f64::from(max)));
                let a = below as u16 + u16::from(below > f64::from(below as u16));
                (a.min(nearest[t]), (above as u16).max(nearest[t]))
            };
            vdbcook_vpak::coding::nearest_predicted(&mut q, |t| match (hidden[t], fraction < 1.0) {
                (true, _) => (0, max),
                (false, true) => within_reach(t),
                (false, false) => (nearest[t], nearest[t]),
            });
        }
        let mut out = Vec::with_capacity(2 * l.len());
        q.into_iter().for_each(|q| push(&mut out, u32::from(q) * k));
        if passes(&out, moved) {
            return Some((out, moved));
        }
    }
    None
}

/// The float in [lo, hi] with the fewest mantissa bits (0 where the
/// interval holds it): the end of larger magnitude with its lowest bits
/// cleared, as many as leave it inside.
pub(crate) fn fewest_bits(lo: f32, hi: f32) -> f32 {
    if !lo.is_finite() || !hi.is_finite() || lo > hi {
        return hi;
    }
    if lo <= 0.0 && hi >= 0.0 {
        return 0.0;
    }
    let edge = if lo > 0.0 { hi } else { lo };
    (0..=23u32).rev().map(|bits| f32::from_bits(edge.to_bits() & !((1u32 << bits) - 1))).find(|c| (lo..=hi).contains(c)).unwrap_or(edge)
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
                let Some((snapped, moved)) = coarsest(format, &v, range, &mask, e, Coder::Zstd) else {
                    // Only where the format's own grid is already as coarse as the bound allows.
                    assert!(format == Format::Unorm8 && e < 0.005, "{format:?} at {e}: nothing coarser");
                    continue;
                };
                assert!(within(&v, &decode_one(format, &snapped, moved), &mask, e), "{format:?} at {e}");
                if matches!(format, Format::Unorm8 | Format::Unorm16) {
                    // The range starts at most a step lower, on a float of fewer mantissa bits.
                    assert!(moved[0] <= range[0] && f64::from(range[0] - moved[0]) <= 2.0 * f64::from(e), "{format:?} at {e}: {moved:?} from {range:?}");
                    assert!(moved[0].to_bits().trailing_zeros() > range[0].to_bits().trailing_zeros(), "{format:?} at {e}: {} from {}", moved[0], range[0]);
                    // Every level a multiple of one k ≥ 2, and the step in value no more than 2E.
                    let w = format.lane_bytes();
                    let level = |c: &[u8]| c.iter().rev().fold(0u32, |v, &b| v << 8 | u32::from(b));
                    let k = snapped.chunks(w).map(level).fold(0, gcd);
                    let top = if w == 1 { 255.0 } else { 65535.0 };
                    assert!(k >= 2, "{format:?} at {e}: levels share no step");
                    assert!(f64::from(moved[1] - moved[0]) * f64::from(k) / top <= 2.0 * f64::from(e) * 1.0001, "{format:?} at {e}: step {k}");
                } else {
                    assert_eq!(moved, range);
                }
                let distinct = |b: &[u8]| {
                    let w = format.lane_bytes();
                    b.chunks(w).collect::<std::collections::HashSet<_>>().len()
                };
                assert!(distinct(&snapped) < distinct(&plain), "{format:?} at {e}: {} vs {} values", distinct(&snapped), distinct(&plain));
            }
        }
    }

    /// [`stepped`] for `format` (unorm8 or unorm16) as [`coarsest`] calls it.
    fn levels_on(format: Format, v: &Brick, mask: &[u64; 8], e: f32, coder: Coder, fraction: f64) -> Option<(Vec<u8>, [f32; 2])> {
        let passes = |bytes: &[u8], range: [f32; 2]| within(v, &decode_one(format, bytes, range), mask, e);
        let (top, push): (u32, fn(&mut Vec<u8>, u32)) = match format {
            Format::Unorm8 => (255, |out, q| out.push(q as u8)),
            _ => (65535, |out, q| out.extend_from_slice(&(q as u16).to_le_bytes())),
        };
        stepped(v, crate::range_of(v), mask, top, e, coder, fraction, push, &passes)
    }

    #[test]
    fn hidden_voxels_at_the_prediction_leave_the_shown_ones_as_they_were() {
        let v = cloud();
        // Half the brick shown: x < 4.
        let mask: [u64; 8] = std::array::from_fn(|x| if x < 4 { u64::MAX } else { 0 });
        for format in [Format::Unorm8, Format::Unorm16] {
            let (zero, moved) = levels_on(format, &v, &mask, 0.01, Coder::Zstd, 1.0).expect("a coarser grid");
            let (predicted, moved_too) = levels_on(format, &v, &mask, 0.01, Coder::Context, 1.0).expect("a coarser grid");
            assert_eq!(moved, moved_too, "{format:?}: the same range");
            let w = format.lane_bytes();
            let texel = |b: &[u8], t: usize| b[t * w..(t + 1) * w].to_vec();
            // Texel t (z·64 + y·8 + x) is shown when x < 4.
            for t in 0..512 {
                match t & 7 < 4 {
                    true => assert_eq!(texel(&zero, t), texel(&predicted, t), "{format:?}: shown texel {t}"),
                    false => assert!(texel(&zero, t).iter().all(|&b| b == 0), "{format:?}: hidden texel {t} is level 0"),
                }
            }
            assert!((0..512).filter(|t| t & 7 >= 4).any(|t| texel(&predicted, t).iter().any(|&b| b != 0)), "{format:?}: hidden texels continue the shown ones");
            assert!(within(&v, &decode_one(format, &predicted, moved), &mask, 0.01), "{format:?}");
        }
    }

    #[test]
    fn a_smooth_brick_takes_the_finer_step_for_the_coder_and_a_noisy_one_does_not() {
        let smooth = cloud();
        let mut seed = 99u32;
        let noisy: Brick = std::array::from_fn(|i| {
            seed = seed.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            smooth[i] + 0.05 * ((seed >> 16) % 1000) as f32 / 1000.0
        });
        let mask = [u64::MAX; 8];
        for format in [Format::Unorm8, Format::Unorm16] {
            let chosen = |v: &Brick| coarsest(format, v, crate::range_of(v), &mask, 0.01, Coder::Context).expect("a coarser grid");
            let on = |v: &Brick, fraction| levels_on(format, v, &mask, 0.01, Coder::Context, fraction).expect("a grid");
            let (bytes, range) = chosen(&smooth);
            assert!(within(&smooth, &decode_one(format, &bytes, range), &mask, 0.01), "{format:?}");
            // Steps of E: the range's max moved for twice the levels, each as near its prediction as the bound allows.
            assert_eq!((bytes.clone(), range), on(&smooth, 0.5), "{format:?}: the smooth brick on a step of E");
            assert_ne!(range, on(&smooth, 1.0).1, "{format:?}");
            assert_eq!(chosen(&noisy), on(&noisy, 1.0), "{format:?}: the noisy brick on a step of 2E");
        }
    }

    #[test]
    fn the_float_of_fewest_mantissa_bits_in_an_interval() {
        assert_eq!(fewest_bits(0.30, 0.32), 0.3125); // 1.01 · 2⁻²
        assert_eq!(fewest_bits(0.26, 0.30), 0.28125); // the first bit that fits, from the top
        assert_eq!(fewest_bits(0.2, 0.6), 0.5);
        assert_eq!(fewest_bits(-0.32, -0.30), -0.3125); // by magnitude, the sign kept
        assert_eq!(fewest_bits(-0.01, 0.02), 0.0);
        assert_eq!(fewest_bits(0.7, 0.7), 0.7); // nothing to drop
        for (lo, hi) in [(0.123_f32, 0.125_f32), (1.0e-6, 1.1e-6), (3.0e5, 3.1e5)] {
            let c = fewest_bits(lo, hi);
            assert!((lo..=hi).contains(&c), "{c} outside [{lo}, {hi}]");
            // No float of the interval has more trailing zero bits.
            let best = (lo.to_bits()..=hi.to_bits()).map(|b| b.trailing_zeros()).max();
            assert_eq!(Some(c.to_bits().trailing_zeros()), best, "[{lo}, {hi}]: {c}");
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

    fn gcd(a: u32, b: u32) -> u32 {
        if b == 0 {
            a
        } else {
            gcd(b, a % b)
        }
    }
}
