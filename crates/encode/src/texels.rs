//! A brick's values as texels: the brick range, the levels of the ranged
//! formats, and the texel order of the uncompressed ones (which lane and
//! byte is which is `vdbcook_vpak::layout`'s to say).

use crate::{Brick, Format, Plane, BRICK_VOXELS};
use half::slice::{HalfBitsSliceExt, HalfFloatSliceExt};
pub use vdbcook_grid::range_of;

/// A brick whose NaN and ±∞ voxels are replaced as the ranged formats store
/// them: like inactive voxels, each takes the mean of its finite 6-neighbours
/// (in the order −x, +x, −y, +y, −z, +z), front by front outwards from the
/// finite voxels, so it lies within their range and a block encoder fits
/// nothing through it.  `None` when every voxel is finite (the common case)
/// or none is.
pub fn fill_non_finite(values: &Brick) -> Option<Brick> {
    if values.iter().fold(true, |all, v| all & v.is_finite()) {
        return None;
    }
    let mut known = [0u64; 8];
    for (i, v) in values.iter().enumerate() {
        known[i >> 6] |= u64::from(v.is_finite()) << (i & 63);
    }
    if known == [0; 8] {
        return None;
    }
    let mut out = *values;
    // Fronts reach every voxel of a brick (at most 21 steps apart).
    vdbcook_grid::fill_from_neighbours(&mut out, known, BRICK_VOXELS);
    Some(out)
}

/// A brick's values as levels in [0, top] over its own range (not rounded);
/// non-finite voxels as [`fill_non_finite`] replaces them.
pub(crate) fn levels(values: &Brick, [lo, hi]: [f32; 2], top: f32) -> Brick {
    let filled = fill_non_finite(values);
    let values = filled.as_ref().unwrap_or(values);
    let span = hi - lo;
    let mut out = [0.0f32; BRICK_VOXELS];
    if span > 0.0 && span.is_finite() {
        let scale = top / span;
        for (o, &v) in out.iter_mut().zip(values) {
            *o = ((v - lo) * scale).clamp(0.0, top);
        }
    }
    out
}

/// 8-bit levels of a brick over its own range.
pub(crate) fn quantise(values: &Brick, range: [f32; 2]) -> [u8; BRICK_VOXELS] {
    levels(values, range, 255.0).map(|l| round_level(l) as u8)
}

/// 16-bit levels of a brick over its own range.
pub(crate) fn quantise16(values: &Brick, range: [f32; 2]) -> [u16; BRICK_VOXELS] {
    levels(values, range, 65535.0).map(|l| round_level(l) as u16)
}

/// `l.round()` for a level (0 ≤ l < 2²³, as [`levels`] gives): the whole
/// part plus one from a half up, which is exact there and vectorises where
/// `round` is a call to the C library (x86-64 before SSE4.1).
#[inline(always)]
fn round_level(l: f32) -> u32 {
    let whole = l as u32;
    whole + u32::from(l - whole as f32 >= 0.5)
}

/// BC7 texels of bricks (per brick, its channels' 8-bit levels in slot
/// order): lane `l` of texel (x, y, t) holds slot `l / zpt` at
/// z = `t · zpt + l % zpt` (`vdbcook_vpak::Plane::locate`); empty slots are 0.
pub(crate) fn bc7_texels(bricks: &[Vec<[u8; BRICK_VOXELS]>], zpt: usize) -> Vec<[u8; 4]> {
    let slices = 8 / zpt;
    let mut out = vec![[0u8; 4]; bricks.len() * slices * 64];
    for (k, slots) in bricks.iter().enumerate() {
        for t in 0..slices {
            for y in 0..8 {
                for x in 0..8 {
                    let px = &mut out[(k * slices + t) * 64 + y * 8 + x];
                    for (l, v) in px.iter_mut().enumerate() {
                        if let Some(lv) = slots.get(l / zpt) {
                            *v = lv[x * 64 + y * 8 + t * zpt + l % zpt];
                        }
                    }
                }
            }
        }
    }
    out
}

/// Swaps the x and z axes of a brick: leaf order (`x·64 + y·8 + z`) to texel
/// order (`z·64 + y·8 + x`) and back.
pub(crate) fn swap_xz<T: Copy>(a: &[T; BRICK_VOXELS]) -> [T; BRICK_VOXELS] {
    // Loops of constant bounds: no index checked at run time (1.5-3x faster
    // than one loop over the brick with a computed index, u16 to f32). The
    // swap is its own inverse.
    let mut out = *a;
    for x in 0..8 {
        for y in 0..8 {
            for z in 0..8 {
                out[x * 64 + y * 8 + z] = a[z * 64 + y * 8 + x];
            }
        }
    }
    out
}

/// One uncompressed brick of a plane: its channels' values lane by lane, in
/// texel order, little-endian.
pub(crate) fn encode_texels(plane: &Plane, slots: &[(&Brick, [f32; 2])], out: &mut [u8]) {
    let lanes = plane.lanes as usize;
    for (l, (values, range)) in slots.iter().enumerate().take(lanes) {
        match plane.format {
            Format::F32 => put_lane(out, lanes, l, swap_xz(values).iter().map(|v| v.to_le_bytes())),
            Format::F16 => {
                // Converted in leaf order, then swapped: half the bytes to move.
                put_lane(out, lanes, l, swap_xz(&to_half(values)).iter().map(|v| v.to_le_bytes()));
            }
            Format::Unorm16 => put_lane(out, lanes, l, swap_xz(&quantise16(values, *range)).iter().map(|q| q.to_le_bytes())),
            Format::Unorm8 => put_lane(out, lanes, l, swap_xz(&quantise(values, *range)).iter().map(|&q| [q])),
            // No texels; block formats are encoded elsewhere.
            Format::Constant | Format::Bc4 | Format::Bc7 => {}
        }
    }
}

/// What a reader decodes of `values` stored in the uncompressed `format`
/// over `range` ([`encode_texels`], then `Plane::decode_brick` and
/// `Plane::channel_values`), value by value without the bytes, into `out`;
/// false (and `out` untouched) for the block formats and constant.
pub(crate) fn round_trip(format: Format, values: &Brick, range: [f32; 2], out: &mut Brick) -> bool {
    let ranged = |t: f32| vdbcook_vpak::layout::from_unit(t, range);
    match format {
        Format::F32 => *out = *values,
        Format::F16 => from_half(&to_half(values), out),
        Format::Unorm16 => out.iter_mut().zip(quantise16(values, range)).for_each(|(o, q)| *o = ranged(f32::from(q) / 65535.0)),
        Format::Unorm8 => out.iter_mut().zip(quantise(values, range)).for_each(|(o, q)| *o = ranged(f32::from(q) / 255.0)),
        Format::Constant | Format::Bc4 | Format::Bc7 => return false,
    }
    true
}

/// A brick's values as IEEE half bits, rounded to nearest even as `half`
/// rounds them: with the F16C instructions over the whole brick in one call
/// where the CPU has them (`half` calls out per eight values).
pub(crate) fn to_half(values: &Brick) -> [u16; BRICK_VOXELS] {
    let mut out = [0u16; BRICK_VOXELS];
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("f16c") {
        // SAFETY: the CPU has F16C (checked just above).
        unsafe { f16c::to_half(values, &mut out) };
        return out;
    }
    out.reinterpret_cast_mut::<half::f16>().convert_from_f32_slice(values);
    out
}

/// Half bits back to values ([`to_half`]'s way).
pub(crate) fn from_half(h: &[u16; BRICK_VOXELS], out: &mut Brick) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("f16c") {
        // SAFETY: the CPU has F16C (checked just above).
        unsafe { f16c::from_half(h, out) };
        return;
    }
    h.reinterpret_cast::<half::f16>().convert_to_f32_slice(out);
}

#[cfg(target_arch = "x86_64")]
mod f16c {
    use super::{Brick, BRICK_VOXELS};
    use std::arch::x86_64::{__m128i, _mm256_cvtph_ps, _mm256_cvtps_ph, _mm256_loadu_ps, _mm256_storeu_ps, _mm_loadu_si128, _mm_storeu_si128, _MM_FROUND_TO_NEAREST_INT};

    /// # Safety
    /// The CPU must have F16C.
    #[target_feature(enable = "f16c")]
    pub(super) unsafe fn to_half(src: &Brick, dst: &mut [u16; BRICK_VOXELS]) {
        for (s, d) in src.chunks_exact(8).zip(dst.chunks_exact_mut(8)) {
            // SAFETY: eight f32 read, eight u16 written, inside the chunks.
            unsafe { _mm_storeu_si128(d.as_mut_ptr().cast::<__m128i>(), _mm256_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(_mm256_loadu_ps(s.as_ptr()))) };
        }
    }

    /// # Safety
    /// The CPU must have F16C.
    #[target_feature(enable = "f16c")]
    pub(super) unsafe fn from_half(src: &[u16; BRICK_VOXELS], dst: &mut Brick) {
        for (s, d) in src.chunks_exact(8).zip(dst.chunks_exact_mut(8)) {
            // SAFETY: eight u16 read, eight f32 written, inside the chunks.
            unsafe { _mm256_storeu_ps(d.as_mut_ptr(), _mm256_cvtph_ps(_mm_loadu_si128(s.as_ptr().cast::<__m128i>()))) };
        }
    }
}

/// Writes lane `lane` of every texel (`lanes` lanes of `N` bytes each). The
/// lane size is a constant, so each write is a store, not a call to memcpy.
fn put_lane<const N: usize>(out: &mut [u8], lanes: usize, lane: usize, texels: impl Iterator<Item = [u8; N]>) {
    if lanes == 1 {
        for (dst, b) in out.chunks_exact_mut(N).zip(texels) {
            dst.copy_from_slice(&b);
        }
    } else {
        for (dst, b) in out.chunks_exact_mut(N * lanes).zip(texels) {
            dst[lane * N..lane * N + N].copy_from_slice(&b);
        }
    }
}
