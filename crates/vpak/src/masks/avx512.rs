//! The scheme-3 decoder with up to 16 lanes in AVX-512 vectors: each lane's
//! sub-mask as two 32-bit halves, a row's neighbours one shift of a half, a
//! context the sum of one permute per neighbour (a row's voxels weigh 1, 3,
//! 9 and 27, so the count of active neighbours per voxel is a sum), the
//! table entries one gather, and each lane's next word gathered from its
//! own run before the row is decoded, out of the chain from one row to the
//! next. Same output as [`super::step`] lane by lane, which the tests hold
//! it to, damaged streams included.

use super::{Lane, CONTEXT, RANS_LOW, ROWS};
use std::arch::x86_64::*;

/// Whether this CPU runs the vector decoder.
pub(super) fn usable() -> bool {
    is_x86_feature_detected!("avx512f")
}

/// A row's share of a context with both neighbours inside the node: its
/// voxels weighed 1, 3, 9, 27 (the context is the two rows' sum).
const WEIGHT: [i32; 16] = {
    let mut t = [0i32; 16];
    let mut a = 0;
    while a < 16 {
        t[a] = CONTEXT[a * 32] as i32;
        a += 1;
    }
    t
};

/// Row `r` of every lane's mask (halves `lo`, `hi`).
#[inline(always)]
unsafe fn row(lo: __m512i, hi: __m512i, r: usize) -> __m512i {
    unsafe {
        let (half, shift) = if r < 8 { (lo, 4 * r) } else { (hi, 4 * (r - 8)) };
        _mm512_and_si512(_mm512_srl_epi32(half, _mm_cvtsi32_si128(shift as i32)), _mm512_set1_epi32(15))
    }
}

/// Decodes the 16 rows of the sub-masks of `g` (at most 16 lanes) side by
/// side, as [`super::step`] does lane by lane; `words` has one more word
/// than any lane's run reaches (a gather reads 32 bits).
///
/// # Safety
/// The CPU must have AVX-512F ([`usable`]); `table` must hold `128 <<
/// precision` entries, `words` every index below each lane's `end` and one
/// more.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn group(g: &mut [Lane], precision: u32, table: &[u32], words: &[u16], bad: &mut bool) {
    let n = g.len().min(16);
    let k: __mmask16 = ((1u32 << n) - 1) as __mmask16;
    let (mut xs, mut ats, mut ends) = ([0i32; 16], [0i32; 16], [1i32; 16]);
    let (mut ax, mut ay) = ([[0i32; 16]; 4], [[0i32; 16]; 4]);
    for (j, l) in g.iter().take(n).enumerate() {
        (xs[j], ats[j], ends[j]) = (l.x as i32, l.at as i32, l.end as i32);
        for r in 0..4 {
            (ax[r][j], ay[r][j]) = (i32::from(l.along_x[r]), i32::from(l.along_y[r]));
        }
    }
    // SAFETY: 16 i32s each.
    let load = |a: &[i32; 16]| unsafe { _mm512_loadu_si512(a.as_ptr() as *const __m512i) };
    let (mut x, mut at, end) = (load(&xs), load(&ats), load(&ends));
    let last = _mm512_sub_epi32(end, _mm512_set1_epi32(1));
    let along_x: [__m512i; 4] = std::array::from_fn(|r| load(&ax[r]));
    let along_y: [__m512i; 4] = std::array::from_fn(|r| load(&ay[r]));
    let (weight, outside) = (load(&WEIGHT), _mm512_set1_epi32(16));
    let zero = _mm512_setzero_si512();
    let (mut lo, mut hi) = (zero, zero);
    let (low, p) = (_mm512_set1_epi32((1 << precision) - 1), _mm_cvtsi32_si128(precision as i32));
    let mut wrong: __mmask16 = 0;
    for t in 0..ROWS {
        // SAFETY: the gathers read the table below 128 << precision (a context is below 128,
        // a slot below 2^precision) and the words at most at a lane's end − 1, each of its 32
        // bits inside `words`.
        unsafe {
            // The lane's next word, whether it renormalises or not.
            let next = _mm512_mask_i32gather_epi32::<2>(zero, k, _mm512_min_epi32(at, last), words.as_ptr() as *const i32);
            let a = if t >= 4 { row(lo, hi, t - 4) } else { along_x[t & 3] };
            let b = if t & 3 != 0 { row(lo, hi, t - 1) } else { along_y[t >> 2] };
            // Both inside: the sum; b outside: 81 + a; a outside: 97 + b (113 for both).
            let mut ctx = _mm512_add_epi32(_mm512_permutexvar_epi32(a, weight), _mm512_permutexvar_epi32(b, weight));
            if t < 4 || t & 3 == 0 {
                ctx = _mm512_mask_add_epi32(ctx, _mm512_cmpeq_epi32_mask(b, outside), a, _mm512_set1_epi32(81));
                ctx = _mm512_mask_add_epi32(ctx, _mm512_cmpeq_epi32_mask(a, outside), b, _mm512_set1_epi32(97));
            }
            let slot = _mm512_and_si512(x, low);
            let e = _mm512_mask_i32gather_epi32::<4>(zero, k, _mm512_or_si512(_mm512_sll_epi32(ctx, p), slot), table.as_ptr() as *const i32);
            let f = _mm512_and_si512(_mm512_srli_epi32::<4>(e), _mm512_set1_epi32(0x1fff));
            wrong |= _mm512_mask_cmpeq_epi32_mask(k, f, zero);
            x = _mm512_sub_epi32(_mm512_add_epi32(_mm512_mullo_epi32(f, _mm512_srl_epi32(x, p)), slot), _mm512_srli_epi32::<17>(e));
            let renormalise = _mm512_mask_cmplt_epu32_mask(k, x, _mm512_set1_epi32(RANS_LOW as i32));
            wrong |= _mm512_mask_cmpeq_epi32_mask(renormalise, at, end);
            x = _mm512_mask_mov_epi32(x, renormalise, _mm512_or_si512(_mm512_slli_epi32::<16>(x), _mm512_and_si512(next, _mm512_set1_epi32(0xffff))));
            at = _mm512_mask_add_epi32(at, renormalise, at, _mm512_set1_epi32(1));
            let sym = _mm512_and_si512(e, _mm512_set1_epi32(15));
            let (half, shift) = if t < 8 { (&mut lo, 4 * t) } else { (&mut hi, 4 * (t - 8)) };
            *half = _mm512_or_si512(*half, _mm512_sll_epi32(sym, _mm_cvtsi32_si128(shift as i32)));
        }
    }
    let store = |v: __m512i| {
        let mut a = [0i32; 16];
        // SAFETY: 16 i32s.
        unsafe { _mm512_storeu_si512(a.as_mut_ptr() as *mut __m512i, v) };
        a
    };
    let (x, at, lo, hi) = (store(x), store(at), store(lo), store(hi));
    for (j, l) in g.iter_mut().take(n).enumerate() {
        (l.x, l.at, l.m) = (x[j] as u32, at[j] as usize, u64::from(lo[j] as u32) | u64::from(hi[j] as u32) << 32);
    }
    *bad |= wrong != 0;
}
