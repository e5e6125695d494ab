//! BC4 and BC7 bricks.
//!
//! A brick is 8×8 texels in x and y. BC4 keeps one voxel per texel and takes
//! 8 slices (z = slice); BC7 packs four consecutive z-slices into a texel's
//! RGBA (z = 4·slice + channel) and takes 2 slices. Each slice of a brick is
//! 2×2 blocks of 4×4 texels; an encoded brick is its blocks in the order
//! (slice, block row, block column): 32 × 8 bytes (BC4, 4 bits per voxel) or
//! 8 × 16 bytes (BC7, 2 bits per voxel). Voxels are first mapped to 8-bit
//! levels over the brick's own [min, max].
//!
//! BC7 blocks come from intel_tex_2 (ISPC). BC4 blocks come from our own
//! encoder ([`bc4_block`]), which leaves 13–28 % less RMSE on the real samples
//! than intel_tex_2's BC4 (see docs/benchmarks.md).

#[cfg(test)]
use crate::Format;
use crate::{Quality, BRICK_VOXELS};

pub const BC4_BRICK_BYTES: usize = 8 * 4 * 8;

/// Which of intel_tex_2's BC7 kernels this machine runs, as a class whose
/// members write the same blocks: its x86-64 kernels with fused multiply-add
/// (AVX2, AVX-512) and those without (SSE2, SSE4, AVX) differ on a few blocks
/// in ten thousand (`bc7_isa`'s test), so BC7 assets are byte-identical only
/// between machines of one class.
pub fn bc7_kernels() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        let fma = (is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")) || is_x86_feature_detected!("avx512f");
        if fma {
            "x86-64 fma"
        } else {
            "x86-64 no-fma"
        }
    }
    #[cfg(target_arch = "aarch64")]
    {
        "aarch64 neon"
    }
    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
    {
        std::env::consts::ARCH
    }
}

pub(crate) fn bc7_settings(q: Quality) -> intel_tex_2::bc7::EncodeSettings {
    use intel_tex_2::bc7;
    match q {
        Quality::UltraFast => bc7::alpha_ultra_fast_settings(),
        Quality::VeryFast => bc7::alpha_very_fast_settings(),
        Quality::Fast => bc7::alpha_fast_settings(),
        Quality::Basic => bc7::alpha_basic_settings(),
        Quality::Slow => bc7::alpha_slow_settings(),
    }
}

/// Encodes bricks of levels in [0, 255] (index `x·64 + y·8 + z`, not
/// rounded: the BC4 palette has steps between whole levels) as BC4 into `out`
/// (`BC4_BRICK_BYTES` per brick).  Only the voxels of each brick's `masks`
/// entry (512 bits, all when `None`) count: readers take the others from the
/// background.
pub fn encode_bc4(quality: Quality, levels: &[[f32; BRICK_VOXELS]], masks: Option<&[[u64; 8]]>, out: &mut [u8]) {
    for (k, (lv, brick)) in levels.iter().zip(out.chunks_exact_mut(BC4_BRICK_BYTES)).enumerate() {
        let mask = masks.and_then(|m| m.get(k)).copied().unwrap_or([u64::MAX; 8]);
        for (j, dst) in brick.chunks_exact_mut(8).enumerate() {
            // Block j is (slice z, block row, block column).
            let (z, br, bc) = (j / 4, (j / 2) % 2, j % 2);
            let (mut v, mut w) = ([0f32; 16], [0f32; 16]);
            for t in 0..16 {
                let i = (bc * 4 + t % 4) * 64 + (br * 4 + t / 4) * 8 + z;
                v[t] = lv[i];
                w[t] = if mask[i >> 6] >> (i & 63) & 1 == 1 { 1.0 } else { 0.0 };
            }
            dst.copy_from_slice(&bc4_block(&v, &w, bc4_radius(quality)));
        }
    }
}

/// A BC7 block whose voxels no reader uses (no L3 node shows them): mode 6
/// with every endpoint and index 0 (it decodes to 0 in every lane).
pub const HIDDEN_BC7: [u8; 16] = [0x40, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0];

/// Whether block `j` of a BC7 brick (in the order (slice, block row, block
/// column), `zpt` z-slices per texel) holds a voxel of `mask` (index
/// `x·64 + y·8 + z`: word x, bit `y·8 + z`).
fn block_shown(mask: &[u64; 8], zpt: usize, j: usize) -> bool {
    let (s, br, bc) = (j / 4, (j / 2) % 2, j % 2);
    let zs = ((1u64 << zpt) - 1) << (s * zpt);
    let yz = (4 * br..4 * br + 4).fold(0u64, |acc, y| acc | zs << (8 * y));
    mask[4 * bc..4 * bc + 4].iter().any(|&w| w & yz != 0)
}

/// Encodes bricks of RGBA texels of 8-bit levels (per brick `64 · slices`
/// texels in the order (slice, y, x), `zpt` z-slices per texel, slices =
/// 8 / zpt) as BC7 with intel_tex_2 into `out` (`slices · 4 · 16` bytes per
/// brick, blocks in the order (slice, block row, block column)): the blocks
/// that hold a voxel of their brick's `masks` entry (every block without
/// masks, or past them), side by side in one row of blocks, since the
/// kernels work across a row's blocks. The others, whose voxels no reader
/// uses (a reader takes a voxel no L3 node shows from the background), are
/// [`HIDDEN_BC7`], not encoded: a sparse fire's bricks have many.
pub fn encode_bc7_shown(quality: Quality, zpt: usize, texels: &[[u8; 4]], masks: Option<&[[u64; 8]]>, out: &mut [u8]) {
    let zpt = zpt.clamp(1, 8);
    let slices = 8 / zpt;
    const BB: usize = 16;
    let per_brick = slices * 4;
    let n = texels.len() / (64 * slices);
    let shown: Vec<(usize, usize)> = (0..n).flat_map(|k| (0..per_brick).map(move |j| (k, j))).filter(|&(k, j)| masks.and_then(|m| m.get(k)).is_none_or(|m| block_shown(m, zpt, j))).collect();
    let w = 4 * shown.len();
    let mut surface = vec![0u8; w * 4 * 4];
    for (v, &(k, j)) in shown.iter().enumerate() {
        let (s, br, bc) = (j / 4, (j / 2) % 2, j % 2);
        for r in 0..4 {
            let src = (k * slices + s) * 64 + (4 * br + r) * 8 + 4 * bc;
            for c in 0..4 {
                let px = (r * w + 4 * v + c) * 4;
                surface[px..px + 4].copy_from_slice(&texels[src + c]);
            }
        }
    }
    let blocks = match shown.len() {
        0 => Vec::new(),
        _ => intel_tex_2::bc7::compress_blocks(&bc7_settings(quality), &intel_tex_2::RgbaSurface { data: &surface, width: w as u32, height: 4, stride: (w * 4) as u32 }),
    };
    for block in out.chunks_exact_mut(BB).take(n * per_brick) {
        block.copy_from_slice(&HIDDEN_BC7);
    }
    for (v, &(k, j)) in shown.iter().enumerate() {
        if let (Some(dst), Some(src)) = (out.get_mut((k * per_brick + j) * BB..(k * per_brick + j + 1) * BB), blocks.get(v * BB..(v + 1) * BB)) {
            dst.copy_from_slice(src);
        }
    }
}

/// How far around its least-squares endpoints [`bc4_block`] looks.
fn bc4_radius(q: Quality) -> i32 {
    match q {
        Quality::UltraFast => 0,
        Quality::VeryFast => 1,
        Quality::Fast => 2,
        Quality::Basic => 3,
        Quality::Slow => 4,
    }
}

/// The BC4 palette for endpoints (e0, e1), in units of 1/35 level (35 = 5·7:
/// every entry is whole, so exact in f32): e0 > e1 gives e0, e1 and 6 even
/// steps between; otherwise e0, e1, 4 even steps between, 0 and 255.
/// Returns the number of even steps `n` (7 or 5), the step (signed, from e0
/// towards e1) and the `n` midpoints between steps (padded with values no
/// level passes).
fn bc4_steps(e0: i32, e1: i32) -> (i32, f32, [f32; 7]) {
    let (n, per) = if e0 > e1 { (7, 5) } else { (5, 7) };
    let step = ((e1 - e0) * per) as f32;
    let far = if step < 0.0 { -1e9 } else { 1e9 };
    let mut mid = [far; 7];
    for (k, m) in mid.iter_mut().enumerate().take(n as usize) {
        *m = (e0 * 35) as f32 + (k as f32 + 0.5) * step;
    }
    (n, step, mid)
}

/// Palette index of even step `j` of `n`.
fn bc4_index(j: i32, n: i32) -> u8 {
    match j {
        0 => 0,
        j if j == n => 1,
        j => (j + 1) as u8,
    }
}

/// Squared error of levels `x` (in 1/35 level), weighted by `w`, against the
/// nearest entries of the palette of (e0, e1).  The nearest even step is the number of
/// midpoints x has passed going from e0 towards e1; in the second mode 0 and
/// 255 compete.  Written lane by lane so that it vectorises.
fn bc4_error(x: &[f32; 16], w: &[f32; 16], e0: i32, e1: i32) -> f32 {
    let (n, step, mid) = bc4_steps(e0, e1);
    let mut at = [(e0 * 35) as f32; 16];
    for m in mid {
        for l in 0..16 {
            let passed = if step < 0.0 { x[l] < m } else { x[l] > m };
            at[l] += if passed { step } else { 0.0 };
        }
    }
    let mut sse = 0.0f32;
    for l in 0..16 {
        let mut d = (x[l] - at[l]).abs();
        if n == 5 {
            d = d.min(x[l].abs()).min((255.0 * 35.0 - x[l]).abs());
        }
        sse += w[l] * d * d;
    }
    sse
}

/// Each level's palette index for (e0, e1): the nearest entry, as
/// [`bc4_error`] counts it.
fn bc4_indices(x: &[f32; 16], e0: i32, e1: i32) -> [u8; 16] {
    let (n, step, mid) = bc4_steps(e0, e1);
    let mut idx = [0u8; 16];
    for (i, &x) in idx.iter_mut().zip(x) {
        let j = mid.iter().filter(|&&m| if step < 0.0 { x < m } else { x > m }).count() as i32;
        let d = (x - ((e0 * 35) as f32 + j as f32 * step)).abs();
        let (to0, to255) = (x.abs(), (255.0 * 35.0 - x).abs());
        *i = if n == 5 && to0 < d && to0 <= to255 {
            6
        } else if n == 5 && to255 < d {
            7
        } else {
            bc4_index(j, n)
        };
    }
    idx
}

/// One BC4 block for 16 levels in [0, 255], of which those with weight 0 do
/// not count: the 8-step mode from the (counted) levels' extremes, refined by
/// least squares (three rounds), then every endpoint pair within `radius` of
/// the best (and again around a better one found, up to four times); and the
/// 6-step mode (which has exact 0 and 255, the extremes of
/// every brick) from the extremes of the other levels, likewise.  The
/// smallest weighted squared error wins (the first found on ties):
/// deterministic.
pub fn bc4_block(v: &[f32; 16], w: &[f32; 16], radius: i32) -> [u8; 8] {
    let mut x = [0f32; 16];
    for (x, &v) in x.iter_mut().zip(v) {
        *x = v * 35.0;
    }
    let mut best = (f32::INFINITY, 0i32, 0i32);
    let consider = |e0: i32, e1: i32, best: &mut (f32, i32, i32)| {
        if (0..=255).contains(&e0) && (0..=255).contains(&e1) {
            let sse = bc4_error(&x, w, e0, e1);
            if sse < best.0 {
                *best = (sse, e0, e1);
            }
        }
    };
    let counted = || v.iter().zip(w).filter(|(_, &w)| w > 0.0).map(|(&v, _)| v);
    let lo = counted().fold(f32::INFINITY, f32::min);
    let hi = counted().fold(f32::NEG_INFINITY, f32::max);
    if lo > hi {
        // Nothing counts.
        return [0; 8];
    }
    let (lo, hi) = (lo.round().clamp(0.0, 255.0) as i32, hi.round().clamp(0.0, 255.0) as i32);
    if lo == hi {
        consider(hi, lo, &mut best);
    }
    // 8-step mode (e0 > e1).
    let (mut a, mut b) = (hi, lo);
    for _ in 0..3 {
        if a <= b {
            (a, b) = if b < 255 { (b + 1, b) } else { (255, 254) };
        }
        consider(a, b, &mut best);
        // Least squares for the endpoints with these indices: each level is
        // (1 - t)·e0 + t·e1, t = 0, 1 or j/7.
        let idx = bc4_indices(&x, a, b);
        let (mut s00, mut s01, mut s11, mut r0, mut r1) = (0f32, 0f32, 0f32, 0f32, 0f32);
        for ((&v, &w), &i) in v.iter().zip(w).zip(&idx) {
            let t = match i {
                0 => 0.0,
                1 => 1.0,
                i => f32::from(i - 1) / 7.0,
            };
            let (p, q) = (1.0 - t, t);
            s00 += w * p * p;
            s01 += w * p * q;
            s11 += w * q * q;
            r0 += w * p * v;
            r1 += w * q * v;
        }
        let det = s00 * s11 - s01 * s01;
        if det.abs() < 1e-6 {
            break;
        }
        let na = ((r0 * s11 - r1 * s01) / det).round().clamp(0.0, 255.0) as i32;
        let nb = ((r1 * s00 - r0 * s01) / det).round().clamp(0.0, 255.0) as i32;
        if (na, nb) == (a, b) {
            break;
        }
        (a, b) = (na, nb);
    }
    // Every pair of one mode within `radius` of `center`; again around a
    // better pair of that mode, up to four rounds.
    // (A pair the previous round already tried cannot win again: skipping
    // it changes nothing.)
    let search = |mut center: (i32, i32), six_step: bool, best: &mut (f32, i32, i32)| {
        let in_mode = |e0: i32, e1: i32| (e0 <= e1) == six_step;
        let mut prev: Option<(i32, i32)> = None;
        for _ in 0..4 {
            for da in -radius..=radius {
                for db in -radius..=radius {
                    let (e0, e1) = (center.0 + da, center.1 + db);
                    let tried = prev.is_some_and(|p| (e0 - p.0).abs() <= radius && (e1 - p.1).abs() <= radius);
                    if in_mode(e0, e1) && !tried {
                        consider(e0, e1, best);
                    }
                }
            }
            if !in_mode(best.1, best.2) || (best.1, best.2) == center {
                break;
            }
            prev = Some(center);
            center = (best.1, best.2);
        }
    };
    search((best.1, best.2), false, &mut best);
    // 6-step mode (e0 <= e1), from the extremes of the levels away from 0 and 255.
    let inner = counted().filter(|&x| x > 16.0 && x < 239.0);
    let (l, h) = (inner.clone().fold(f32::INFINITY, f32::min), inner.fold(f32::NEG_INFINITY, f32::max));
    if l <= h {
        search((l.round() as i32, h.round() as i32), true, &mut best);
    }
    let bits = bc4_indices(&x, best.1, best.2).iter().enumerate().fold(0u64, |acc, (k, &i)| acc | u64::from(i) << (3 * k));
    let mut out = [0u8; 8];
    out[0] = best.1 as u8;
    out[1] = best.2 as u8;
    out[2..8].copy_from_slice(&bits.to_le_bytes()[..6]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use vdbcook_vpak::Plane;

    const BC7_BRICK_BYTES: usize = 2 * 4 * 16;

    /// A one-channel brick's levels in [0, 1] (index `x·64 + y·8 + z`).
    fn decode(format: Format, data: &[u8]) -> [f32; BRICK_VOXELS] {
        let plane = if format == Format::Bc7 { Plane { format, lanes: 4, z_per_texel: 4 } } else { Plane { format, lanes: 1, z_per_texel: 1 } };
        plane.channel_values(&plane.decode_brick(data), 0, [0.0, 1.0])
    }

    /// One-channel bricks of levels as BC7 texels (four z-slices in RGBA).
    fn encode_bc7_levels(q: Quality, levels: &[[u8; BRICK_VOXELS]], out: &mut [u8]) {
        let texels = crate::texels::bc7_texels(&levels.iter().map(|l| vec![*l]).collect::<Vec<_>>(), 4);
        encode_bc7_shown(q, 4, &texels, None, out);
    }

    /// The reference for [`encode_bc7_shown`]: every block, the bricks side by
    /// side in one surface (`8·n` texels wide, `8 · slices` tall), as the
    /// encoder did before it took masks.
    fn encode_bc7(quality: Quality, slices: usize, texels: &[[u8; 4]], out: &mut [u8]) {
        let n = texels.len() / (64 * slices).max(1);
        if n == 0 {
            return;
        }
        let (w, h) = (8 * n, 8 * slices);
        let mut surface = vec![0u8; w * h * 4];
        for k in 0..n {
            for s in 0..slices {
                for y in 0..8 {
                    let px = ((s * 8 + y) * w + k * 8) * 4;
                    let src = (k * slices + s) * 64 + y * 8;
                    for x in 0..8 {
                        surface[px + 4 * x..px + 4 * x + 4].copy_from_slice(&texels[src + x]);
                    }
                }
            }
        }
        const BB: usize = 16;
        let surf = intel_tex_2::RgbaSurface { data: &surface, width: w as u32, height: h as u32, stride: (w * 4) as u32 };
        let blocks = intel_tex_2::bc7::compress_blocks(&bc7_settings(quality), &surf);
        // Blocks come out row-major over the surface: row r = 2s + block row, column 2k + block column.
        let cols = w / 4;
        for (k, brick) in out.chunks_exact_mut(slices * 4 * BB).take(n).enumerate() {
            for (j, dst) in brick.chunks_exact_mut(BB).enumerate() {
                let (s, br, bc) = (j / 4, (j / 2) % 2, j % 2);
                let i = ((2 * s + br) * cols + 2 * k + bc) * BB;
                if let Some(src) = blocks.get(i..i + BB) {
                    dst.copy_from_slice(src);
                }
            }
        }
    }

    /// A smooth field with one distinct value per (x, y, z) direction.
    fn ramp() -> [u8; BRICK_VOXELS] {
        std::array::from_fn(|i| {
            let (x, y, z) = (i / 64, (i / 8) % 8, i % 8);
            (x * 24 + y * 6 + z * 2) as u8
        })
    }

    #[test]
    fn bc4_round_trip_keeps_orientation() {
        let lv = ramp();
        let mut enc = [0u8; 2 * BC4_BRICK_BYTES];
        encode_bc4(Quality::Fast, &[lv.map(f32::from), [200.0; BRICK_VOXELS]], None, &mut enc);
        let enc: Vec<&[u8]> = enc.chunks(BC4_BRICK_BYTES).collect();
        let d = decode(Format::Bc4, enc[0]);
        for i in 0..BRICK_VOXELS {
            assert!((d[i] * 255.0 - f32::from(lv[i])).abs() <= 6.0, "voxel {i}: {} vs {}", d[i] * 255.0, lv[i]);
        }
        let flat = decode(Format::Bc4, enc[1]);
        assert!(flat.iter().all(|&v| (v * 255.0 - 200.0).abs() < 0.5));
    }

    #[test]
    fn bc7_round_trip_keeps_orientation_and_channels() {
        let lv = ramp();
        for q in Quality::ALL {
            let mut enc = [0u8; 2 * BC7_BRICK_BYTES];
            encode_bc7_levels(q, &[[7; BRICK_VOXELS], lv], &mut enc);
            let enc: Vec<&[u8]> = enc.chunks(BC7_BRICK_BYTES).collect();
            let d = decode(Format::Bc7, enc[1]);
            let mut worst = 0.0f32;
            for i in 0..BRICK_VOXELS {
                worst = worst.max((d[i] * 255.0 - f32::from(lv[i])).abs());
            }
            assert!(worst <= 12.0, "{q:?}: worst level error {worst}");
            assert!(decode(Format::Bc7, enc[0]).iter().all(|&v| (v * 255.0 - 7.0).abs() < 0.5));
        }
    }

    /// Blocks of levels: smooth ramps, noise, whole levels (every other
    /// block) and ones holding the brick extremes 0 and 255.
    fn test_blocks() -> Vec<[f32; 16]> {
        let mut rng = vdbcook_testkit::Rng::new(0xbc4);
        let mut out = Vec::new();
        for k in 0..3000 {
            let (base, slope, noise) = (rng.below(256) as f32, rng.unit() * 40.0 - 20.0, (k % 5) as f32 * rng.unit() * 30.0);
            let mut b = [0f32; 16];
            for (t, v) in b.iter_mut().enumerate() {
                *v = (base + slope * (t % 4) as f32 + slope * 0.5 * (t / 4) as f32 + noise * (rng.unit() - 0.5)).clamp(0.0, 255.0);
                if k % 2 == 0 {
                    *v = v.round();
                }
            }
            if k % 7 == 0 {
                b[(k / 7) % 16] = 0.0;
                b[(k / 3) % 16] = 255.0;
            }
            out.push(b);
        }
        out
    }

    /// Squared error in levels² of a packed block, decoded by bcdec_rs.
    fn decoded_sse(v: &[f32; 16], block: &[u8]) -> f64 {
        let mut r = [0.0f32; 16];
        bcdec_rs::bc4_float(block, &mut r, 4, false);
        v.iter().zip(r).map(|(&x, y)| (f64::from(y) * 255.0 - f64::from(x)).powi(2)).sum()
    }

    #[test]
    fn bc4_palette_and_indices_match_the_decoder() {
        // For any endpoints, in both modes, the error the encoder counts is
        // what bcdec_rs decodes from the packed indices, and no palette
        // entry is nearer to a level than the one chosen.
        let mut rng = vdbcook_testkit::Rng::new(7);
        for v in test_blocks().iter().take(600) {
            let (e0, e1) = (rng.below(256) as i32, rng.below(256) as i32);
            let x = v.map(|v| v * 35.0);
            let idx = bc4_indices(&x, e0, e1);
            let bits = idx.iter().enumerate().fold(0u64, |acc, (k, &i)| acc | u64::from(i) << (3 * k));
            let mut block = [e0 as u8, e1 as u8, 0, 0, 0, 0, 0, 0];
            block[2..].copy_from_slice(&bits.to_le_bytes()[..6]);
            let counted = f64::from(bc4_error(&x, &[1.0; 16], e0, e1)) / 35.0 / 35.0;
            assert!((decoded_sse(v, &block) - counted).abs() <= 1e-3 * (1.0 + counted), "{v:?} {e0} {e1}");
            // Nearest: try every index for every level.
            for (k, &x) in v.iter().enumerate() {
                let mut b = block;
                let here = {
                    let mut r = [0.0f32; 16];
                    bcdec_rs::bc4_float(&b, &mut r, 4, false);
                    (r[k] * 255.0 - x).abs()
                };
                for i in 0..8u64 {
                    let bits = (bits & !(7 << (3 * k))) | i << (3 * k);
                    b[2..].copy_from_slice(&bits.to_le_bytes()[..6]);
                    let mut r = [0.0f32; 16];
                    bcdec_rs::bc4_float(&b, &mut r, 4, false);
                    assert!((r[k] * 255.0 - x).abs() >= here - 1e-3, "{v:?} {e0} {e1} level {k}: index {i} is nearer");
                }
            }
        }
    }

    #[test]
    fn bc4_encoder_beats_intel_tex_and_improves_with_radius() {
        // Over all blocks, a wider search does better (per block it usually
        // does too, but a search that moves on can end elsewhere).
        // intel_tex_2's BC4 sees the levels rounded (its input is 8-bit);
        // both are measured against the levels themselves.
        let blocks = test_blocks();
        let mut surface = vec![0u8; blocks.len() * 16];
        let w = blocks.len() * 4;
        for (b, v) in blocks.iter().enumerate() {
            for (t, &x) in v.iter().enumerate() {
                surface[(t / 4) * w + b * 4 + t % 4] = x.round() as u8;
            }
        }
        let intel = intel_tex_2::bc4::compress_blocks(&intel_tex_2::RSurface { data: &surface, width: w as u32, height: 4, stride: w as u32 });
        let theirs = |whole: bool| -> f64 { blocks.iter().enumerate().filter(|(b, _)| (b % 2 == 0) == whole).map(|(b, v)| decoded_sse(v, &intel[b * 8..b * 8 + 8])).sum() };
        let ours = |whole: bool, radius: i32| -> f64 { blocks.iter().enumerate().filter(|(b, _)| (b % 2 == 0) == whole).map(|(_, v)| decoded_sse(v, &bc4_block(v, &[1.0; 16], radius))).sum() };
        for whole in [true, false] {
            let mut last = f64::INFINITY;
            for radius in 0..4 {
                let o = ours(whole, radius);
                assert!(o < theirs(whole) * 0.9, "whole levels {whole}, radius {radius}: {o} against intel_tex_2's {}", theirs(whole));
                assert!(o <= last, "radius {radius}: {o} after {last}");
                last = o;
            }
        }
    }

    #[test]
    fn bc4_is_exact_where_the_palette_allows() {
        let blocks: [[f32; 16]; 5] = [[77.0; 16], [0.0; 16], [255.0; 16], std::array::from_fn(|t| if t % 3 == 0 { 10.0 } else { 200.0 }), std::array::from_fn(|t| [0.0, 255.0, 120.0, 121.0][t % 4])];
        for v in blocks {
            assert!(decoded_sse(&v, &bc4_block(&v, &[1.0; 16], 1)) < 1e-6, "{v:?}");
        }
        // Steps between whole levels: 100 + 3/7 is the second step of (100, 101).
        let v: [f32; 16] = std::array::from_fn(|t| [100.0, 101.0, 100.0 + 3.0 / 7.0][t % 3]);
        assert!(decoded_sse(&v, &bc4_block(&v, &[1.0; 16], 1)) < 1e-6, "{v:?}");
    }

    #[test]
    fn bc4_spends_nothing_on_voxels_that_do_not_count() {
        // Half of each brick is a smooth ramp, the other half noise that no
        // reader sees: with the mask, the ramp comes out better.
        let mut rng = vdbcook_testkit::Rng::new(99);
        let mut mask = [0u64; 8];
        let levels: Vec<[f32; BRICK_VOXELS]> = (0..20)
            .map(|k| {
                std::array::from_fn(|i| {
                    let (x, y, z) = (i / 64, (i / 8) % 8, i % 8);
                    if (x + y + z) % 2 == 0 {
                        mask[i >> 6] |= 1 << (i & 63);
                        (x * 9 + y * 7 + z * 11 + k) as f32
                    } else {
                        rng.below(256) as f32
                    }
                })
            })
            .collect();
        let masks = vec![mask; levels.len()];
        let error = |masks: Option<&[[u64; 8]]>| -> f64 {
            let mut out = vec![0u8; levels.len() * BC4_BRICK_BYTES];
            encode_bc4(Quality::VeryFast, &levels, masks, &mut out);
            let mut sse = 0.0;
            for (lv, enc) in levels.iter().zip(out.chunks(BC4_BRICK_BYTES)) {
                let d = decode(Format::Bc4, enc);
                for i in (0..BRICK_VOXELS).filter(|&i| mask[i >> 6] >> (i & 63) & 1 == 1) {
                    sse += (f64::from(d[i]) * 255.0 - f64::from(lv[i])).powi(2);
                }
            }
            sse
        };
        let (with, without) = (error(Some(&masks)), error(None));
        assert!(with < without * 0.5, "{with} against {without}");
        // A block with nothing that counts is still a valid block.
        assert_eq!(bc4_block(&[3.0; 16], &[0.0; 16], 1), [0; 8]);
    }

    #[test]
    fn known_good_blocks_decode() {
        // A BC4 block with endpoints 255 and 0 and every index 0 is all 255;
        // index 1 everywhere is all 0 (the second endpoint).
        let mut b = [0u8; BC4_BRICK_BYTES];
        for blk in b.chunks_exact_mut(8) {
            blk[0] = 255;
            blk[1] = 0;
        }
        assert!(decode(Format::Bc4, &b).iter().all(|&v| v == 1.0));
        for blk in b.chunks_exact_mut(8) {
            // 16 three-bit indices of value 1: bit pattern 001 repeated.
            let bits: u64 = (0..16).fold(0, |acc, i| acc | (1u64 << (3 * i)));
            blk[2..8].copy_from_slice(&bits.to_le_bytes()[..6]);
        }
        assert!(decode(Format::Bc4, &b).iter().all(|&v| v == 0.0));
        // BC7 mode 6 block (bit 6 set) with all-zero endpoints and indices decodes to 0.
        let mut b7 = [0u8; BC7_BRICK_BYTES];
        for blk in b7.chunks_exact_mut(16) {
            blk.copy_from_slice(&HIDDEN_BC7);
        }
        assert_eq!(HIDDEN_BC7[0], 0x40);
        assert!(decode(Format::Bc7, &b7).iter().all(|&v| v == 0.0));
    }

    #[test]
    fn a_voxel_shows_the_one_block_its_texel_is_in() {
        for zpt in [1, 2, 4] {
            let slices = 8 / zpt;
            for i in 0..BRICK_VOXELS {
                let (x, y, z) = (i / 64, (i / 8) % 8, i % 8);
                let mut mask = [0u64; 8];
                mask[i >> 6] |= 1 << (i & 63);
                // Texel (x, y) of slice z / zpt; block (slice, block row, block column).
                let want = (z / zpt) * 4 + (y / 4) * 2 + x / 4;
                let shown: Vec<usize> = (0..slices * 4).filter(|&j| block_shown(&mask, zpt, j)).collect();
                assert_eq!(shown, [want], "zpt {zpt} voxel {i}");
            }
        }
    }

    #[test]
    fn shown_blocks_are_encoded_as_before_and_hidden_ones_are_one_block() {
        let lv = [ramp(), std::array::from_fn(|i| (i * 37 % 251) as u8), [90; BRICK_VOXELS]];
        // One channel in four lanes, two in two, four in one.
        for zpt in [4, 2, 1] {
            let slots: Vec<Vec<[u8; BRICK_VOXELS]>> = (0..3).map(|k| (0..4 / zpt).map(|c| lv[(k + c) % 3]).collect()).collect();
            let texels = crate::texels::bc7_texels(&slots, zpt);
            let (slices, bytes) = (8 / zpt, 3 * (8 / zpt) * 4 * 16);
            let mut all = vec![0u8; bytes];
            encode_bc7(Quality::Fast, slices, &texels, &mut all);
            // Brick 0: one voxel, (x, y, z) = (5, 2, 6); brick 1 every voxel;
            // brick 2 none (past the masks given: every block).
            let mut one = [0u64; 8];
            one[5] = 1 << (2 * 8 + 6);
            let masks = [one, [u64::MAX; 8]];
            let mut out = vec![0xffu8; bytes];
            encode_bc7_shown(Quality::Fast, zpt, &texels, Some(&masks), &mut out);
            let per_brick = slices * 4;
            for (j, (got, want)) in out.chunks_exact(16).zip(all.chunks_exact(16)).enumerate() {
                let shown = j == (6 / zpt) * 4 + 1 || j >= per_brick;
                assert_eq!(got, if shown { want } else { &HIDDEN_BC7[..] }, "zpt {zpt} block {j}");
            }
            let mut none = vec![0u8; bytes];
            encode_bc7_shown(Quality::Fast, zpt, &texels, None, &mut none);
            assert_eq!(none, all);
        }
    }
}
