//! The scheme-3 decoder with its lanes in AVX2 vectors: up to 16 lanes as
//! two vectors of 8, interleaved so that their chains overlap; a row's
//! share of a context (its voxels weighed 1, 3, 9, 27: `T[a & 3] + 9·T[a >>
//! 2]`, T = 0, 1, 3, 4) by two 8-entry permutes, the table entries and each
//! lane's next word (gathered before the row is decoded, out of the chain
//! from one row to the next) by gathers. Same output as [`super::step`]
//! lane by lane, which the tests hold it to, damaged streams included. (An
//! AVX-512 version of 16 lanes in one vector ran no faster here.)

use super::{Lane, RANS_LOW, ROWS};
use std::arch::x86_64::*;

/// Whether this CPU runs the AVX2 decoder.
pub(super) fn usable() -> bool {
    is_x86_feature_detected!("avx2")
}

/// Row `r` of every lane's mask (halves `lo`, `hi`).
#[inline(always)]
unsafe fn row(lo: __m256i, hi: __m256i, r: usize) -> __m256i {
    unsafe {
        let (half, shift) = if r < 8 { (lo, 4 * r) } else { (hi, 4 * (r - 8)) };
        _mm256_and_si256(_mm256_srl_epi32(half, _mm_cvtsi32_si128(shift as i32)), _mm256_set1_epi32(15))
    }
}

/// A row's share of a context with both neighbours inside the node.
#[inline(always)]
unsafe fn weight(a: __m256i) -> __m256i {
    unsafe {
        let t = _mm256_setr_epi32(0, 1, 3, 4, 0, 1, 3, 4);
        let low = _mm256_permutevar8x32_epi32(t, a);
        let high = _mm256_permutevar8x32_epi32(t, _mm256_srli_epi32::<2>(a));
        _mm256_add_epi32(low, _mm256_add_epi32(_mm256_slli_epi32::<3>(high), high))
    }
}

/// Eight lanes' decoding state.
struct Eight {
    active: __m256i,
    x: __m256i,
    at: __m256i,
    end: __m256i,
    last: __m256i,
    along_x: [__m256i; 4],
    along_y: [__m256i; 4],
    lo: __m256i,
    hi: __m256i,
}

impl Eight {
    /// Lanes `g` (at most 8).
    #[inline(always)]
    unsafe fn load(g: &[Lane]) -> Eight {
        let (mut active, mut x, mut at, mut end) = ([0i32; 8], [0i32; 8], [0i32; 8], [1i32; 8]);
        let (mut ax, mut ay) = ([[0i32; 8]; 4], [[0i32; 8]; 4]);
        for (j, l) in g.iter().take(8).enumerate() {
            (active[j], x[j], at[j], end[j]) = (-1, l.x as i32, l.at as i32, l.end as i32);
            for r in 0..4 {
                (ax[r][j], ay[r][j]) = (i32::from(l.along_x[r]), i32::from(l.along_y[r]));
            }
        }
        // SAFETY: 8 i32s each.
        let load = |a: &[i32; 8]| unsafe { _mm256_loadu_si256(a.as_ptr() as *const __m256i) };
        let end = load(&end);
        unsafe {
            Eight {
                active: load(&active),
                x: load(&x),
                at: load(&at),
                end,
                last: _mm256_sub_epi32(end, _mm256_set1_epi32(1)),
                along_x: std::array::from_fn(|r| load(&ax[r])),
                along_y: std::array::from_fn(|r| load(&ay[r])),
                lo: _mm256_setzero_si256(),
                hi: _mm256_setzero_si256(),
            }
        }
    }

    /// Decodes row `t` in every active lane; gives the lanes gone wrong (a bit each).
    #[inline(always)]
    unsafe fn step(&mut self, t: usize, precision: u32, table: &[u32], words: &[u16]) -> i32 {
        unsafe {
            let zero = _mm256_setzero_si256();
            let next = _mm256_mask_i32gather_epi32::<2>(zero, words.as_ptr() as *const i32, _mm256_min_epi32(self.at, self.last), self.active);
            let a = if t >= 4 { row(self.lo, self.hi, t - 4) } else { self.along_x[t & 3] };
            let b = if t & 3 != 0 { row(self.lo, self.hi, t - 1) } else { self.along_y[t >> 2] };
            let mut ctx = _mm256_add_epi32(weight(a), weight(b));
            if t < 4 || t & 3 == 0 {
                let outside = _mm256_set1_epi32(16);
                ctx = _mm256_blendv_epi8(ctx, _mm256_add_epi32(a, _mm256_set1_epi32(81)), _mm256_cmpeq_epi32(b, outside));
                ctx = _mm256_blendv_epi8(ctx, _mm256_add_epi32(b, _mm256_set1_epi32(97)), _mm256_cmpeq_epi32(a, outside));
            }
            let p = _mm_cvtsi32_si128(precision as i32);
            let slot = _mm256_and_si256(self.x, _mm256_set1_epi32((1 << precision) - 1));
            let e = _mm256_mask_i32gather_epi32::<4>(zero, table.as_ptr() as *const i32, _mm256_or_si256(_mm256_sll_epi32(ctx, p), slot), self.active);
            let f = _mm256_and_si256(_mm256_srli_epi32::<6>(e), _mm256_set1_epi32(0x1fff));
            let unused = _mm256_and_si256(_mm256_cmpeq_epi32(f, zero), self.active);
            let x = _mm256_sub_epi32(_mm256_add_epi32(_mm256_mullo_epi32(f, _mm256_srl_epi32(self.x, p)), slot), _mm256_srli_epi32::<19>(e));
            let renormalise = _mm256_and_si256(_mm256_cmpeq_epi32(_mm256_srli_epi32::<16>(x), zero), self.active);
            let overrun = _mm256_and_si256(renormalise, _mm256_cmpeq_epi32(self.at, self.end));
            self.x = _mm256_blendv_epi8(x, _mm256_or_si256(_mm256_slli_epi32::<16>(x), _mm256_and_si256(next, _mm256_set1_epi32(0xffff))), renormalise);
            self.at = _mm256_sub_epi32(self.at, renormalise);
            let sym = _mm256_and_si256(e, _mm256_set1_epi32(15));
            let (half, shift) = if t < 8 { (&mut self.lo, 4 * t) } else { (&mut self.hi, 4 * (t - 8)) };
            *half = _mm256_or_si256(*half, _mm256_sll_epi32(sym, _mm_cvtsi32_si128(shift as i32)));
            _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_or_si256(unused, overrun)))
        }
    }

    /// Back into lanes `g`.
    #[inline(always)]
    unsafe fn store(&self, g: &mut [Lane]) {
        let store = |v: __m256i| {
            let mut a = [0i32; 8];
            // SAFETY: 8 i32s.
            unsafe { _mm256_storeu_si256(a.as_mut_ptr() as *mut __m256i, v) };
            a
        };
        let (x, at, lo, hi) = (store(self.x), store(self.at), store(self.lo), store(self.hi));
        for (j, l) in g.iter_mut().take(8).enumerate() {
            (l.x, l.at, l.m) = (x[j] as u32, at[j] as usize, u64::from(lo[j] as u32) | u64::from(hi[j] as u32) << 32);
        }
    }
}

/// Decodes the 16 rows of the sub-masks of `g` (at most 16 lanes) side by
/// side, as [`super::step`] does lane by lane; `words` has one more word
/// than any lane's run reaches (a gather reads 32 bits).
///
/// # Safety
/// The CPU must have AVX2 ([`usable`]); `table` must hold `128 <<
/// precision` entries, `words` every index below each lane's `end` and one
/// more, every `end` below 2³¹.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn group(g: &mut [Lane], precision: u32, table: &[u32], words: &[u16], bad: &mut bool) {
    let (first, second) = g.split_at_mut(g.len().min(8));
    // SAFETY: the caller's promises, for each half.
    unsafe {
        let (mut u, mut v) = (Eight::load(first), Eight::load(second));
        let mut wrong = 0;
        for t in 0..ROWS {
            wrong |= u.step(t, precision, table, words);
            wrong |= v.step(t, precision, table, words);
        }
        u.store(first);
        v.store(second);
        *bad |= wrong != 0;
    }
}

// RANS_LOW is 2^16: a state below it is one whose top 16 bits are 0.
const _: () = assert!(RANS_LOW == 1 << 16);
