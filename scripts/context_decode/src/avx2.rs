//! The decoder of `simd.rs` for CPUs without AVX-512: G vectors of 8 lanes (N = 8·G),
//! AVX2 and FMA-era instructions only (gathers, variable shifts). What AVX-512 does in one
//! instruction is done here by tables: the words of the lanes that renormalise are moved
//! into place by a byte shuffle chosen by the lanes' mask, and the context's bucket is the
//! exponent of a float (no leading-zero count).

use crate::{pidx, Coded, Texel, NPOS, RANS_L, T};
use std::arch::x86_64::*;

// Renormalisation is "the state's upper half is zero".
const _: () = assert!(RANS_L == 1 << 16);

#[repr(C, align(32))]
#[derive(Clone, Copy)]
struct I32x8([i32; 8]);

#[repr(C, align(8))]
#[derive(Clone, Copy)]
struct U8x8([u8; 8]);

struct Work {
    f: Vec<I32x8>,
    ra: Vec<U8x8>,
}

/// Per 8-bit lane mask: the byte shuffle that puts the t-th next 16-bit word of the stream
/// into the 16-bit slot of the t-th lane set (the others zero).
fn expand_table() -> Vec<[u8; 16]> {
    (0..256u32)
        .map(|m| {
            let mut c = [0x80u8; 16];
            let mut t = 0;
            for l in 0..8 {
                if m >> l & 1 == 1 {
                    c[2 * l] = 2 * t;
                    c[2 * l + 1] = 2 * t + 1;
                    t += 1;
                }
            }
            c
        })
        .collect()
}

#[inline(always)]
unsafe fn ld(v: &I32x8) -> __m256i {
    unsafe { _mm256_load_si256(v.0.as_ptr() as *const __m256i) }
}

#[inline(always)]
unsafe fn ld8(v: &U8x8) -> __m256i {
    unsafe { _mm256_cvtepu8_epi32(_mm_loadl_epi64(v.0.as_ptr() as *const __m128i)) }
}

#[inline(always)]
unsafe fn floor_div3(t: __m256i) -> __m256i {
    unsafe {
        // A multiply instead of the divider, then one step of correction either way
        // (a comparison's all-ones lanes are −1).
        let q = _mm256_cvttps_epi32(_mm256_floor_ps(_mm256_mul_ps(_mm256_cvtepi32_ps(t), _mm256_set1_ps(1.0 / 3.0))));
        let r = _mm256_sub_epi32(t, _mm256_add_epi32(_mm256_add_epi32(q, q), q));
        let q = _mm256_sub_epi32(q, _mm256_cmpgt_epi32(r, _mm256_set1_epi32(2)));
        _mm256_add_epi32(q, _mm256_cmpgt_epi32(_mm256_setzero_si256(), r))
    }
}

#[inline(always)]
unsafe fn predict<const POS: usize, const G: usize>(w: &Work, p: usize, gi: usize) -> __m256i {
    unsafe {
        let at = |q: usize| ld(w.f.get_unchecked(q * G + gi));
        let (a, b, c) = (at(p - 81), at(p - 9), at(p - 1));
        match POS {
            7 => {
                let s = _mm256_add_epi32(_mm256_add_epi32(a, b), c);
                let t = _mm256_sub_epi32(_mm256_slli_epi32::<1>(s), _mm256_add_epi32(_mm256_add_epi32(at(p - 90), at(p - 82)), at(p - 10)));
                floor_div3(_mm256_add_epi32(t, _mm256_set1_epi32(1)))
            }
            3 => _mm256_sub_epi32(_mm256_add_epi32(b, c), at(p - 10)),
            5 => _mm256_sub_epi32(_mm256_add_epi32(a, c), at(p - 82)),
            6 => _mm256_sub_epi32(_mm256_add_epi32(a, b), at(p - 90)),
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
unsafe fn step<const POS: usize, const G: usize, const P: u32>(w: &mut Work, st: &mut [__m256i; G], mb: &[__m256i; G], k: u32, p: usize, s: &mut Streams<G>, lut: *const u32, expand: &[[u8; 16]]) {
    unsafe {
        let one = _mm256_set1_epi32(1);
        for gi in 0..G {
            let act = _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_srl_epi32(mb[gi], _mm_cvtsi32_si128(k as i32)), one), one);
            let e = _mm256_add_epi32(_mm256_add_epi32(ld8(w.ra.get_unchecked((p - 81) * G + gi)), ld8(w.ra.get_unchecked((p - 9) * G + gi))), ld8(w.ra.get_unchecked((p - 1) * G + gi)));
            let e = _mm256_min_epu32(e, _mm256_set1_epi32(255));
            // ilog2(e²) from the float's exponent (e² ≤ 65025 is exact); e below 4 is its own bucket.
            let lg = _mm256_sub_epi32(_mm256_srli_epi32::<23>(_mm256_castps_si256(_mm256_cvtepi32_ps(_mm256_mullo_epi32(e, e)))), _mm256_set1_epi32(127));
            let small = _mm256_cmpgt_epi32(_mm256_set1_epi32(4), e);
            let bucket = _mm256_blendv_epi8(_mm256_min_epi32(lg, _mm256_set1_epi32(15)), e, small);
            let ctx = _mm256_add_epi32(_mm256_slli_epi32::<3>(bucket), _mm256_set1_epi32(POS as i32));
            let x = st[gi];
            let slot = _mm256_and_si256(x, _mm256_set1_epi32((1 << P) - 1));
            let idx = _mm256_or_si256(_mm256_sll_epi32(ctx, _mm_cvtsi32_si128(P as i32)), slot);
            let ent = _mm256_i32gather_epi32::<4>(lut as *const i32, idx);
            let sym = _mm256_and_si256(ent, _mm256_set1_epi32(63));
            let fr = _mm256_and_si256(_mm256_srli_epi32::<6>(ent), _mm256_set1_epi32(0x1fff));
            let cu = _mm256_srli_epi32::<19>(ent);
            let xn = _mm256_sub_epi32(_mm256_add_epi32(_mm256_mullo_epi32(fr, _mm256_srl_epi32(x, _mm_cvtsi32_si128(P as i32))), slot), cu);
            let xs = _mm256_blendv_epi8(x, xn, act);
            let need = _mm256_cmpeq_epi32(_mm256_srli_epi32::<16>(xs), _mm256_setzero_si256());
            let m = _mm256_movemask_ps(_mm256_castsi256_ps(need)) as usize;
            let wi = if s.shared { 0 } else { gi };
            let raw = _mm_loadu_si128(s.wp[wi] as *const __m128i);
            let words = _mm256_cvtepu16_epi32(_mm_shuffle_epi8(raw, _mm_loadu_si128(expand.get_unchecked(m).as_ptr() as *const __m128i)));
            s.wp[wi] = s.wp[wi].add(m.count_ones() as usize);
            st[gi] = _mm256_blendv_epi8(xs, _mm256_or_si256(_mm256_slli_epi32::<16>(xs), words), need);
            let kk = _mm256_sub_epi32(sym, _mm256_set1_epi32(T as i32));
            let esc = _mm256_and_si256(act, _mm256_cmpgt_epi32(sym, _mm256_set1_epi32(T as i32 - 1)));
            let mut z = _mm256_blendv_epi8(sym, _mm256_add_epi32(_mm256_set1_epi32(T as i32 - 1), _mm256_sllv_epi32(one, kk)), esc);
            let em = _mm256_movemask_ps(_mm256_castsi256_ps(esc));
            if em != 0 {
                let mut zs = I32x8([0; 8]);
                let mut ks = I32x8([0; 8]);
                _mm256_store_si256(zs.0.as_mut_ptr() as *mut __m256i, z);
                _mm256_store_si256(ks.0.as_mut_ptr() as *mut __m256i, kk);
                let mut mm = em as u32;
                while mm != 0 {
                    let l = mm.trailing_zeros() as usize;
                    mm &= mm - 1;
                    let nb = ks.0[l] as u32;
                    let peek = std::ptr::read_unaligned(s.bits.add(s.bp >> 3) as *const u64) >> (s.bp & 7);
                    zs.0[l] += (peek & ((1u64 << nb) - 1)) as i32;
                    s.bp += nb as usize;
                }
                z = _mm256_load_si256(zs.0.as_ptr() as *const __m256i);
            }
            let z = _mm256_and_si256(act, z);
            let r = _mm256_xor_si256(_mm256_srli_epi32::<1>(z), _mm256_sub_epi32(_mm256_setzero_si256(), _mm256_and_si256(z, one)));
            let mag = _mm256_min_epu32(_mm256_srli_epi32::<1>(_mm256_add_epi32(z, one)), _mm256_set1_epi32(255));
            // The low byte of each lane, lanes in order, into 8 bytes.
            let b = _mm256_shuffle_epi8(mag, _mm256_setr_epi8(0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1));
            let b8 = _mm_unpacklo_epi32(_mm256_castsi256_si128(b), _mm256_extracti128_si256::<1>(b));
            _mm_storel_epi64(w.ra.get_unchecked_mut(p * G + gi).0.as_mut_ptr() as *mut __m128i, b8);
            let q = _mm256_add_epi32(predict::<POS, G>(w, p, gi), r);
            _mm256_store_si256(w.f.get_unchecked_mut(p * G + gi).0.as_mut_ptr() as *mut __m256i, q);
        }
    }
}

/// Lane l's eight levels of row (i, j) to `out + l·512`, for the first `lanes` lanes of
/// lane vector `gi`: for bytes an 8×8 transpose in registers, else lane by lane.
#[inline(always)]
unsafe fn put_row<O: Texel, const G: usize>(w: &Work, i: usize, j: usize, gi: usize, lanes: usize, out: *mut O) {
    unsafe {
        let row = |k: usize| _mm256_max_epi32(ld(w.f.get_unchecked(pidx(i, j, k) * G + gi)), _mm256_setzero_si256());
        if std::mem::size_of::<O>() == 1 {
            // Rows k as 8 bytes each (lanes 0..7), clamped: packs work within 128-bit halves,
            // so a (k, k+1) pair packs to [k lanes 0-3, k+1 lanes 0-3 | k lanes 4-7, k+1 lanes 4-7].
            let p01 = _mm256_packus_epi32(row(0), row(1));
            let p23 = _mm256_packus_epi32(row(2), row(3));
            let p45 = _mm256_packus_epi32(row(4), row(5));
            let p67 = _mm256_packus_epi32(row(6), row(7));
            // u16 → u8: [0(0-3) 1(0-3) 2(0-3) 3(0-3) | 0(4-7) 1(4-7) 2(4-7) 3(4-7)] and the same for 4..7.
            let a = _mm256_packus_epi16(p01, p23);
            let b = _mm256_packus_epi16(p45, p67);
            // Per 128-bit half of a: byte 4k + l holds row k, lane l (l in 0..4, + 4 in the upper half).
            // Transpose 4×4 blocks of bytes: lane-major 4 bytes of rows 0..3 per lane.
            let t = _mm256_setr_epi8(0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15, 0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15);
            let a = _mm256_shuffle_epi8(a, t); // half h: lane 4h+l's rows 0..3 at bytes 4l..4l+4
            let b = _mm256_shuffle_epi8(b, t); // the same for rows 4..7
            let lo = _mm256_unpacklo_epi32(a, b); // half h: lanes 4h, 4h+1: rows 0-3, 4-7
            let hi = _mm256_unpackhi_epi32(a, b); // half h: lanes 4h+2, 4h+3
            let mut q = [0u64; 8];
            _mm_storeu_si128(q.as_mut_ptr() as *mut __m128i, _mm256_castsi256_si128(lo));
            _mm_storeu_si128(q.as_mut_ptr().add(2) as *mut __m128i, _mm256_castsi256_si128(hi));
            _mm_storeu_si128(q.as_mut_ptr().add(4) as *mut __m128i, _mm256_extracti128_si256::<1>(lo));
            _mm_storeu_si128(q.as_mut_ptr().add(6) as *mut __m128i, _mm256_extracti128_si256::<1>(hi));
            for (l, v) in q.iter().take(lanes).enumerate() {
                std::ptr::write_unaligned(out.add(l * 512) as *mut u64, *v);
            }
        } else {
            let rows: [I32x8; 8] = std::array::from_fn(|k| *w.f.get_unchecked(pidx(i, j, k) * G + gi));
            for l in 0..lanes {
                let o = out.add(l * 512);
                for (k, r) in rows.iter().enumerate() {
                    *o.add(k) = O::from_level(r.0[l]);
                }
            }
        }
    }
}

/// Decodes the n bricks into `out`; the same result as `decode_voxels` with N = 8·G lanes.
///
/// # Safety
/// The CPU must have AVX2.
#[target_feature(enable = "avx2")]
pub unsafe fn decode<O: Texel, const G: usize, const P: u32>(cd: &Coded, n: usize, masks: &[u8], lut: &[u32], out: &mut [O]) {
    let nl = 8 * G;
    let groups = n.div_ceil(nl);
    assert!(out.len() >= n * 512 && masks.len() >= groups * nl * 64 && lut.len() >= (NPOS * 16) << P && cd.words.len() >= 2 * nl);
    let expand = expand_table();
    let mut w = Work { f: vec![I32x8([0; 8]); 729 * G], ra: vec![U8x8([0; 8]); 729 * G] };
    // One stream per vector (its lanes' states first), or one shared stream (every lane's state first).
    let shared = cd.starts.len() == 1;
    assert!(shared || cd.starts.len() == G);
    let mut st = [_mm256_setzero_si256(); G];
    let mut wp = [std::ptr::null::<u16>(); G];
    for (gi, s) in st.iter_mut().enumerate() {
        let (from, first) = if shared { (0, gi * 8) } else { (cd.starts[gi], 0) };
        let mut v = I32x8([0; 8]);
        for (l, x) in v.0.iter_mut().enumerate() {
            let lane = first + l;
            *x = ((cd.words[from + 2 * lane] as u32) << 16 | cd.words[from + 2 * lane + 1] as u32) as i32;
        }
        *s = unsafe { ld(&v) };
        wp[gi] = unsafe { cd.words.as_ptr().add(from + if shared { 2 * nl } else { 2 * 8 }) };
    }
    let mut s = Streams { wp, shared, bits: cd.bits.as_ptr(), bp: 0 };
    let lanes64 = _mm256_setr_epi32(0, 64, 128, 192, 256, 320, 384, 448);
    for g in 0..groups {
        for i in 0..8 {
            for j in 0..8 {
                let mb: [__m256i; G] = std::array::from_fn(|gi| unsafe {
                    let base = masks.as_ptr().add((g * nl + gi * 8) * 64 + i * 8 + j) as *const i32;
                    _mm256_and_si256(_mm256_i32gather_epi32::<1>(base, lanes64), _mm256_set1_epi32(0xff))
                });
                macro_rules! run {
                    ($first:expr, $rest:expr) => {
                        unsafe {
                            step::<{ $first }, G, P>(&mut w, &mut st, &mb, 0, pidx(i, j, 0), &mut s, lut.as_ptr(), &expand);
                            for k in 1..8 {
                                step::<{ $rest }, G, P>(&mut w, &mut st, &mb, k as u32, pidx(i, j, k), &mut s, lut.as_ptr(), &expand);
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
                let valid = nl.min(n - g * nl);
                for gi in 0..G.min(valid.div_ceil(8)) {
                    let lanes = (valid - gi * 8).min(8);
                    unsafe { put_row::<O, G>(&w, i, j, gi, lanes, out.as_mut_ptr().add((g * nl + gi * 8) * 512 + i * 64 + j * 8)) };
                }
            }
        }
    }
}
