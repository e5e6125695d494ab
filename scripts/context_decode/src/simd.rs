//! The decoder of `decode_voxels_fast` with its lanes in AVX-512 vectors: G vectors of 16
//! bricks each (N = 16·G lanes), every lane at the same voxel, so a neighbour's value is
//! one vector load and a table lookup one gather. Same streams as the scalar decoders
//! (words and escape bits in lane order), so the same encoder serves both.

use crate::{pidx, Coded, Texel, NPOS, RANS_L, T};
use std::arch::x86_64::*;

#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct I32x16([i32; 16]);

#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct U8x16([u8; 16]);

/// Per lane vector: the decoded levels (unclamped, padded 9³ with zeros on the low sides)
/// and the clamped |residual| magnitudes the contexts read.
struct Work {
    f: Vec<I32x16>,
    ra: Vec<U8x16>,
}

#[inline(always)]
unsafe fn ld(v: &I32x16) -> __m512i {
    unsafe { _mm512_load_si512(v.0.as_ptr() as *const __m512i) }
}

#[inline(always)]
unsafe fn ld8(v: &U8x16) -> __m512i {
    unsafe { _mm512_cvtepu8_epi32(_mm_load_si128(v.0.as_ptr() as *const __m128i)) }
}

/// Floor division by 3, exact for |t| < 2^22 (a correctly rounded quotient of two exact
/// floats is never on the wrong side of an integer that close to it).
#[inline(always)]
unsafe fn floor_div3(t: __m512i) -> __m512i {
    unsafe {
        // A multiply instead of the divider, then one step of correction either way.
        let q = _mm512_cvttps_epi32(_mm512_roundscale_ps::<0x09>(_mm512_mul_ps(_mm512_cvtepi32_ps(t), _mm512_set1_ps(1.0 / 3.0))));
        let r = _mm512_sub_epi32(t, _mm512_add_epi32(_mm512_add_epi32(q, q), q));
        let q = _mm512_mask_add_epi32(q, _mm512_cmpge_epi32_mask(r, _mm512_set1_epi32(3)), q, _mm512_set1_epi32(1));
        _mm512_mask_sub_epi32(q, _mm512_cmplt_epi32_mask(r, _mm512_setzero_si512()), q, _mm512_set1_epi32(1))
    }
}

#[inline(always)]
unsafe fn predict<const POS: usize, const G: usize>(w: &Work, p: usize, gi: usize) -> __m512i {
    unsafe {
        let at = |q: usize| ld(w.f.get_unchecked(q * G + gi));
        let (a, b, c) = (at(p - 81), at(p - 9), at(p - 1));
        match POS {
            7 => {
                let s = _mm512_add_epi32(_mm512_add_epi32(a, b), c);
                let t = _mm512_sub_epi32(_mm512_slli_epi32::<1>(s), _mm512_add_epi32(_mm512_add_epi32(at(p - 90), at(p - 82)), at(p - 10)));
                floor_div3(_mm512_add_epi32(t, _mm512_set1_epi32(1)))
            }
            3 => _mm512_sub_epi32(_mm512_add_epi32(b, c), at(p - 10)),
            5 => _mm512_sub_epi32(_mm512_add_epi32(a, c), at(p - 82)),
            6 => _mm512_sub_epi32(_mm512_add_epi32(a, b), at(p - 90)),
            1 => c,
            2 => b,
            _ => a,
        }
    }
}

/// The word streams: one per lane vector (`Coded::starts` has G entries), or one that
/// every vector reads in turn (one entry).
struct Streams<const G: usize> {
    wp: [*const u16; G],
    shared: bool,
    bits: *const u8,
    bp: usize,
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn step<const POS: usize, const G: usize, const P: u32>(w: &mut Work, st: &mut [__m512i; G], mb: &[__m512i; G], k: u32, p: usize, s: &mut Streams<G>, lut: *const u32) {
    unsafe {
        for gi in 0..G {
            let act: __mmask16 = _mm512_test_epi32_mask(mb[gi], _mm512_set1_epi32(1 << k));
            let e = _mm512_add_epi32(_mm512_add_epi32(ld8(w.ra.get_unchecked((p - 81) * G + gi)), ld8(w.ra.get_unchecked((p - 9) * G + gi))), ld8(w.ra.get_unchecked((p - 1) * G + gi)));
            let e = _mm512_min_epu32(e, _mm512_set1_epi32(255));
            // bucket_lut without a lookup: e below 4 is its own bucket, else ilog2(e²), at most 15.
            let lg = _mm512_sub_epi32(_mm512_set1_epi32(31), _mm512_lzcnt_epi32(_mm512_mullo_epi32(e, e)));
            let bucket = _mm512_mask_mov_epi32(_mm512_min_epi32(lg, _mm512_set1_epi32(15)), _mm512_cmplt_epu32_mask(e, _mm512_set1_epi32(4)), e);
            let ctx = _mm512_add_epi32(_mm512_slli_epi32::<3>(bucket), _mm512_set1_epi32(POS as i32));
            let x = st[gi];
            let slot = _mm512_and_si512(x, _mm512_set1_epi32((1 << P) - 1));
            let idx = _mm512_or_si512(_mm512_slli_epi32::<P>(ctx), slot);
            let ent = _mm512_i32gather_epi32::<4>(idx, lut as *const i32);
            let sym = _mm512_and_si512(ent, _mm512_set1_epi32(63));
            let fr = _mm512_and_si512(_mm512_srli_epi32::<6>(ent), _mm512_set1_epi32(0x1fff));
            let cu = _mm512_srli_epi32::<19>(ent);
            let xn = _mm512_sub_epi32(_mm512_add_epi32(_mm512_mullo_epi32(fr, _mm512_srli_epi32::<P>(x)), slot), cu);
            let xs = _mm512_mask_blend_epi32(act, x, xn);
            let need = _mm512_cmplt_epu32_mask(xs, _mm512_set1_epi32(RANS_L as i32));
            let wi = if s.shared { 0 } else { gi };
            let words = _mm512_cvtepu16_epi32(_mm256_maskz_expandloadu_epi16(need, s.wp[wi] as *const i16));
            s.wp[wi] = s.wp[wi].add(need.count_ones() as usize);
            st[gi] = _mm512_mask_blend_epi32(need, xs, _mm512_or_si512(_mm512_slli_epi32::<16>(xs), words));
            // z: the symbol, or for an escape symbol 16 + k its base 15 + 2^k plus k raw bits.
            let esc = _mm512_mask_cmpge_epi32_mask(act, sym, _mm512_set1_epi32(T as i32));
            let kk = _mm512_sub_epi32(sym, _mm512_set1_epi32(T as i32));
            let mut z = _mm512_mask_mov_epi32(sym, esc, _mm512_add_epi32(_mm512_set1_epi32(T as i32 - 1), _mm512_sllv_epi32(_mm512_set1_epi32(1), kk)));
            if esc != 0 {
                // Rare: the raw bits, lane by lane in lane order (the streams' order).
                let mut zs = I32x16([0; 16]);
                let mut ks = I32x16([0; 16]);
                _mm512_store_si512(zs.0.as_mut_ptr() as *mut __m512i, z);
                _mm512_store_si512(ks.0.as_mut_ptr() as *mut __m512i, kk);
                let mut m = esc;
                while m != 0 {
                    let l = m.trailing_zeros() as usize;
                    m &= m - 1;
                    let nb = ks.0[l] as u32;
                    let peek = std::ptr::read_unaligned(s.bits.add(s.bp >> 3) as *const u64) >> (s.bp & 7);
                    zs.0[l] += (peek & ((1u64 << nb) - 1)) as i32;
                    s.bp += nb as usize;
                }
                z = _mm512_load_si512(zs.0.as_ptr() as *const __m512i);
            }
            let z = _mm512_maskz_mov_epi32(act, z);
            let r = _mm512_xor_si512(_mm512_srli_epi32::<1>(z), _mm512_sub_epi32(_mm512_setzero_si512(), _mm512_and_si512(z, _mm512_set1_epi32(1))));
            let mag = _mm512_srli_epi32::<1>(_mm512_add_epi32(z, _mm512_set1_epi32(1)));
            _mm_store_si128(w.ra.get_unchecked_mut(p * G + gi).0.as_mut_ptr() as *mut __m128i, _mm512_cvtusepi32_epi8(mag));
            let q = _mm512_add_epi32(predict::<POS, G>(w, p, gi), r);
            _mm512_store_si512(w.f.get_unchecked_mut(p * G + gi).0.as_mut_ptr() as *mut __m512i, q);
        }
    }
}

/// Lane l's eight levels of row (i, j) to `out + l·512` (texels of 1 or 2 bytes), for the
/// first `lanes` lanes of lane vector `gi`.
#[inline(always)]
unsafe fn put_row<O: Texel, const G: usize>(w: &Work, i: usize, j: usize, gi: usize, lanes: usize, out: *mut O) {
    unsafe {
        let row = |k: usize| _mm512_max_epi32(ld(w.f.get_unchecked(pidx(i, j, k) * G + gi)), _mm512_setzero_si512());
        let keep = (1u32 << lanes) - 1;
        if std::mem::size_of::<O>() == 1 {
            // Rows k = 0..3 in a, 4..7 in b (16 lanes' bytes each); byte 8l + k of the result is lane l's level k.
            let r = |k: usize| _mm512_cvtusepi32_epi8(row(k));
            let a = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(_mm256_set_m128i(r(1), r(0))), _mm256_set_m128i(r(3), r(2)));
            let b = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(_mm256_set_m128i(r(5), r(4))), _mm256_set_m128i(r(7), r(6)));
            for half in 0..2 {
                let mut idx = [0u8; 64];
                for (t, x) in idx.iter_mut().enumerate() {
                    let (l, k) = (half * 8 + t / 8, t % 8);
                    *x = if k < 4 { (16 * k + l) as u8 } else { (64 + 16 * (k - 4) + l) as u8 };
                }
                let c = _mm512_permutex2var_epi8(a, _mm512_loadu_si512(idx.as_ptr() as *const __m512i), b);
                let offs = _mm512_setr_epi64(0, 512, 1024, 1536, 2048, 2560, 3072, 3584);
                let m = ((keep >> (half * 8)) & 0xff) as __mmask8;
                _mm512_mask_i64scatter_epi64::<1>(out.add(half * 8 * 512) as *mut i64, m, offs, c);
            }
        } else {
            let mut buf = [[0u16; 16]; 8];
            for (k, b) in buf.iter_mut().enumerate() {
                _mm256_storeu_si256(b.as_mut_ptr() as *mut __m256i, _mm512_cvtusepi32_epi16(row(k)));
            }
            for l in 0..lanes {
                let o = out.add(l * 512) as *mut u16;
                for (k, b) in buf.iter().enumerate() {
                    *o.add(k) = b[l];
                }
            }
        }
    }
}

/// Decodes the n bricks into `out` (512 texels each); the same result as `decode_voxels`
/// with N = 16·G lanes.
///
/// # Safety
/// The CPU must have AVX-512 F, VL, BW, CD, VBMI and VBMI2.
#[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512vbmi,avx512vbmi2,avx512cd")]
pub unsafe fn decode<O: Texel, const G: usize, const P: u32>(cd: &Coded, n: usize, masks: &[u8], lut: &[u32], out: &mut [O]) {
    let nl = 16 * G;
    let groups = n.div_ceil(nl);
    assert!(out.len() >= n * 512 && masks.len() >= groups * nl * 64 && lut.len() >= (NPOS * 16) << P && cd.words.len() >= 2 * nl);
    let mut w = Work { f: vec![I32x16([0; 16]); 729 * G], ra: vec![U8x16([0; 16]); 729 * G] };
    // One stream per vector (its lanes' states first), or one shared stream (every lane's state first).
    let shared = cd.starts.len() == 1;
    assert!(shared || cd.starts.len() == G);
    let mut st = [_mm512_setzero_si512(); G];
    let mut wp = [std::ptr::null::<u16>(); G];
    for (gi, s) in st.iter_mut().enumerate() {
        let (from, first) = if shared { (0, gi * 16) } else { (cd.starts[gi], 0) };
        let mut v = I32x16([0; 16]);
        for (l, x) in v.0.iter_mut().enumerate() {
            let lane = first + l;
            *x = ((cd.words[from + 2 * lane] as u32) << 16 | cd.words[from + 2 * lane + 1] as u32) as i32;
        }
        *s = unsafe { ld(&v) };
        wp[gi] = unsafe { cd.words.as_ptr().add(from + if shared { 2 * nl } else { 2 * 16 }) };
    }
    let mut s = Streams { wp, shared, bits: cd.bits.as_ptr(), bp: 0 };
    let lanes64 = _mm512_mullo_epi32(_mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15), _mm512_set1_epi32(64));
    for g in 0..groups {
        for i in 0..8 {
            for j in 0..8 {
                let mb: [__m512i; G] = std::array::from_fn(|gi| unsafe {
                    let base = masks.as_ptr().add((g * nl + gi * 16) * 64 + i * 8 + j) as *const i32;
                    _mm512_and_si512(_mm512_i32gather_epi32::<1>(lanes64, base), _mm512_set1_epi32(0xff))
                });
                macro_rules! run {
                    ($first:expr, $rest:expr) => {
                        unsafe {
                            step::<{ $first }, G, P>(&mut w, &mut st, &mb, 0, pidx(i, j, 0), &mut s, lut.as_ptr());
                            for k in 1..8 {
                                step::<{ $rest }, G, P>(&mut w, &mut st, &mb, k as u32, pidx(i, j, k), &mut s, lut.as_ptr());
                            }
                        }
                    };
                }
                match (i > 0, j > 0) {
                    (true, true) => run!(6, 7),
                    (false, true) => run!(2, 3),
                    (true, false) => run!(4, 5),
                    (false, false) => run!(0, 1),
                }
                // The row's eight levels of every lane out, clamped to the texel, while in cache.
                let valid = nl.min(n - g * nl);
                for gi in 0..G.min(valid.div_ceil(16)) {
                    let lanes = (valid - gi * 16).min(16);
                    let first = g * nl + gi * 16;
                    unsafe { put_row::<O, G>(&w, i, j, gi, lanes, out.as_mut_ptr().add(first * 512 + i * 64 + j * 8)) };
                }
            }
        }
    }
}
