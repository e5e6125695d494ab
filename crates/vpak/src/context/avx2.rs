//! The scheme-2 decoder for CPUs with AVX2 (and FMA) but not AVX-512: G
//! vectors of 8 tiles (a stream of 8·G lanes), as [`super::avx512`] does
//! with 16. What AVX-512 does in one instruction is done here by tables and
//! arithmetic: the words of the renormalising lanes are moved into place by
//! a byte shuffle chosen by the lanes' mask, the context's bucket is the
//! exponent of a float, a row of 8 elements of 8 lanes leaves by packs and
//! an 8×8 byte transpose, and the escape bits come by prefix sum and one
//! shared load (gathers when they spread further). Same output as
//! `decode_scalar`, which the tests hold it to, damaged streams included.

use super::{finish, padded, Escapes, Stream, ESCAPE, LAST_SYMBOL, RANS_LOW, SKIPPED, TILE};
use std::arch::x86_64::*;

// Renormalisation is "the state's upper half is zero".
const _: () = assert!(RANS_LOW == 1 << 16);

#[repr(C, align(32))]
#[derive(Clone, Copy)]
struct I32x8([i32; 8]);

#[repr(C, align(8))]
#[derive(Clone, Copy)]
struct U8x8([u8; 8]);

/// Per lane vector and padded element: the decoded quotients and the
/// residual magnitudes (saturated at 255, as the context's sum is).
struct Work {
    f: Vec<I32x8>,
    mag: Vec<U8x8>,
}

/// Whether this CPU runs the AVX2 decoder on a stream of `lanes` lanes.
pub(super) fn usable(lanes: usize) -> bool {
    matches!(lanes, 8 | 16 | 32 | 64) && is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
}

/// Per 8-bit lane mask: the byte shuffle that puts the t-th next 16-bit word
/// of the stream into the 16-bit slot of the t-th lane set (the others zero).
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

/// ⌊(t + 1) / 3⌋ by one fused multiply-add, as [`super::avx512::mean3`]
/// (exact for the t that decoded elements give).
#[inline(always)]
pub(super) unsafe fn mean3(t: __m256i) -> __m256i {
    unsafe {
        let u = _mm256_cvtepi32_ps(_mm256_add_epi32(t, _mm256_set1_epi32((3 << 16) + 1)));
        let q = _mm256_cvttps_epi32(_mm256_fmadd_ps(u, _mm256_set1_ps(1.0 / 3.0), _mm256_set1_ps(1.0 / 6.0)));
        _mm256_sub_epi32(q, _mm256_set1_epi32(1 << 16))
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
                mean3(_mm256_sub_epi32(_mm256_slli_epi32::<1>(s), _mm256_add_epi32(_mm256_add_epi32(at(p - 90), at(p - 82)), at(p - 10))))
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

/// Where the shared streams stand, and what went wrong so far.
struct Reader<'a> {
    words: *const u16,
    escapes: Escapes<'a>,
    /// Lanes (all ones) that met an empty context or decoded outside the element.
    bad: __m256i,
    /// An escape ran past the end of the bits.
    overrun: bool,
}

/// One element of every lane: context, table entry, state update, escape
/// bits, prediction undone (held within each lane's `bounds`). Lane l of
/// vector gi leaves element x out (a scheme-4 stream's, in the [`SKIPPED`]
/// context) when bit x of its `skips` is set.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn step<const POS: usize, const G: usize, const P: i32>(
    w: &mut Work,
    st: &mut [__m256i; G],
    act: &[__m256i; G],
    p: usize,
    r: &mut Reader,
    table: *const u32,
    expand: &[[u8; 16]],
    max: __m256i,
    x: i32,
    skips: &[__m256i; G],
    bounds: &[(__m256i, __m256i); G],
) {
    unsafe {
        let one = _mm256_set1_epi32(1);
        for gi in 0..G {
            let act = act[gi];
            let e = _mm256_add_epi32(_mm256_add_epi32(ld8(w.mag.get_unchecked((p - 81) * G + gi)), ld8(w.mag.get_unchecked((p - 9) * G + gi))), ld8(w.mag.get_unchecked((p - 1) * G + gi)));
            let e = _mm256_min_epu32(e, _mm256_set1_epi32(255));
            // ilog2(e²) from the float's exponent (e² ≤ 65025 is exact); e below 4 is its own bucket.
            let lg = _mm256_sub_epi32(_mm256_srli_epi32::<23>(_mm256_castps_si256(_mm256_cvtepi32_ps(_mm256_mullo_epi32(e, e)))), _mm256_set1_epi32(127));
            let small = _mm256_cmpgt_epi32(_mm256_set1_epi32(4), e);
            let bucket = _mm256_blendv_epi8(_mm256_min_epi32(lg, _mm256_set1_epi32(15)), e, small);
            let ctx = _mm256_add_epi32(_mm256_slli_epi32::<3>(bucket), _mm256_set1_epi32(POS as i32));
            let bit = _mm256_set1_epi32(1 << x);
            let ctx = _mm256_blendv_epi8(ctx, _mm256_set1_epi32(SKIPPED as i32), _mm256_cmpeq_epi32(_mm256_and_si256(skips[gi], bit), bit));
            let x = st[gi];
            let slot = _mm256_and_si256(x, _mm256_set1_epi32((1 << P) - 1));
            let ent = _mm256_i32gather_epi32::<4>(table as *const i32, _mm256_or_si256(_mm256_slli_epi32::<P>(ctx), slot));
            let sym = _mm256_and_si256(ent, _mm256_set1_epi32(63));
            r.bad = _mm256_or_si256(r.bad, _mm256_and_si256(act, _mm256_cmpgt_epi32(sym, _mm256_set1_epi32(LAST_SYMBOL as i32))));
            let fr = _mm256_and_si256(_mm256_srli_epi32::<6>(ent), _mm256_set1_epi32(0x1fff));
            let xn = _mm256_sub_epi32(_mm256_add_epi32(_mm256_mullo_epi32(fr, _mm256_srli_epi32::<P>(x)), slot), _mm256_srli_epi32::<19>(ent));
            let xs = _mm256_blendv_epi8(x, xn, act);
            // Only the lanes with a tile renormalise (an absent lane's state is never used).
            let need = _mm256_and_si256(act, _mm256_cmpeq_epi32(_mm256_srli_epi32::<16>(xs), _mm256_setzero_si256()));
            let m = _mm256_movemask_ps(_mm256_castsi256_ps(need)) as usize;
            let raw = _mm_loadu_si128(r.words as *const __m128i);
            let words = _mm256_cvtepu16_epi32(_mm_shuffle_epi8(raw, _mm_loadu_si128(expand.get_unchecked(m).as_ptr() as *const __m128i)));
            r.words = r.words.add(m.count_ones() as usize);
            st[gi] = _mm256_blendv_epi8(xs, _mm256_or_si256(_mm256_slli_epi32::<16>(xs), words), need);
            // z: the symbol, or for an escape symbol 16 + k its base 15 + 2^k plus k raw bits.
            let kk = _mm256_sub_epi32(sym, _mm256_set1_epi32(ESCAPE as i32));
            let esc = _mm256_and_si256(act, _mm256_cmpgt_epi32(sym, _mm256_set1_epi32(ESCAPE as i32 - 1)));
            let mut z = _mm256_blendv_epi8(sym, _mm256_add_epi32(_mm256_set1_epi32(ESCAPE as i32 - 1), _mm256_sllv_epi32(one, kk)), esc);
            let em = _mm256_movemask_ps(_mm256_castsi256_ps(esc));
            if em != 0 {
                match escape_bits(&mut r.escapes, kk, esc) {
                    Some(raw) => z = _mm256_add_epi32(z, raw),
                    None => r.overrun = true,
                }
            }
            let z = _mm256_and_si256(act, z);
            let res = _mm256_xor_si256(_mm256_srli_epi32::<1>(z), _mm256_sub_epi32(_mm256_setzero_si256(), _mm256_and_si256(z, one)));
            let mag = _mm256_min_epu32(_mm256_srli_epi32::<1>(_mm256_add_epi32(z, one)), _mm256_set1_epi32(255));
            // The low byte of each lane, lanes in order, into 8 bytes.
            let b = _mm256_shuffle_epi8(mag, _mm256_setr_epi8(0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1));
            let b8 = _mm_unpacklo_epi32(_mm256_castsi256_si128(b), _mm256_extracti128_si256::<1>(b));
            _mm_storel_epi64(w.mag.get_unchecked_mut(p * G + gi).0.as_mut_ptr() as *mut __m128i, b8);
            let (lo, hi) = bounds[gi];
            let q = _mm256_add_epi32(_mm256_min_epi32(_mm256_max_epi32(predict::<POS, G>(w, p, gi), lo), hi), res);
            // Outside [0, max]: below 0 or above max, as signed numbers (|q| < 2^31 here).
            let outside = _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_setzero_si256(), q), _mm256_cmpgt_epi32(q, max));
            r.bad = _mm256_or_si256(r.bad, _mm256_and_si256(act, outside));
            _mm256_store_si256(w.f.get_unchecked_mut(p * G + gi).0.as_mut_ptr() as *mut __m256i, q);
        }
    }
}

/// The escape bits of the lanes `esc` (all ones where a lane escapes,
/// lowest lane first, the stream's order), `kk` of them
/// each (at most 47, as [`Escapes::read`] takes), all at once, as
/// [`super::avx512`] reads them: each lane's position an exclusive prefix
/// sum of the lanes' counts, its bits a shift of the 64 bits from the
/// position's byte when they all lie there, else one 64-bit gather each; 0 in
/// the other lanes; `None`, before anything is read, when the lanes' bits
/// together run past the end.
#[inline(always)]
unsafe fn escape_bits(e: &mut Escapes, kk: __m256i, esc: __m256i) -> Option<__m256i> {
    unsafe {
        let zero = _mm256_setzero_si256();
        let cnt = _mm256_and_si256(esc, _mm256_min_epi32(kk, _mm256_set1_epi32(47)));
        // Inclusive prefix sum within each 128-bit half, then the low half's total into the high half.
        let mut incl = _mm256_add_epi32(cnt, _mm256_slli_si256::<4>(cnt));
        incl = _mm256_add_epi32(incl, _mm256_slli_si256::<8>(incl));
        let low_total = _mm256_permutevar8x32_epi32(incl, _mm256_set1_epi32(3));
        incl = _mm256_add_epi32(incl, _mm256_blend_epi32::<0x0f>(low_total, zero));
        let start = _mm256_add_epi32(_mm256_sub_epi32(incl, cnt), _mm256_set1_epi32((e.at & 7) as i32));
        // Every lane starts at most `total` bits on: past the bits' end, the stream is refused
        // (a read the scalar decoder would still start there leaves its position past the end,
        // which it refuses once the stream is decoded).
        let total = _mm256_extract_epi32::<7>(incl) as u32 as usize;
        if e.past_end(total) {
            return None;
        }
        let base = e.bits.as_ptr().add(e.at >> 3) as *const i64;
        let keep = |v: __m256i, n: __m128i| {
            let keep = _mm256_sub_epi64(_mm256_sllv_epi64(_mm256_set1_epi64x(1), _mm256_cvtepu32_epi64(n)), _mm256_set1_epi64x(1));
            // The low 32 bits of the four 64-bit lanes, in order.
            _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(_mm256_and_si256(v, keep), _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6)))
        };
        let (cnt_lo, cnt_hi) = (_mm256_castsi256_si128(cnt), _mm256_extracti128_si256::<1>(cnt));
        // Usually every lane's bits lie in the 64 from the position's byte: that one load
        // serves every lane, each shifted by its start; else a 64-bit gather from each lane's byte.
        let (lo, hi) = if total + (e.at & 7) <= 64 {
            let window = _mm256_set1_epi64x(base.read_unaligned());
            let shifted = |shift: __m128i| _mm256_srlv_epi64(window, _mm256_cvtepu32_epi64(shift));
            (keep(shifted(_mm256_castsi256_si128(start)), cnt_lo), keep(shifted(_mm256_extracti128_si256::<1>(start)), cnt_hi))
        } else {
            let bytes = _mm256_srli_epi32::<3>(start);
            let shift = _mm256_and_si256(start, _mm256_set1_epi32(7));
            let half = |bytes: __m128i, shift: __m128i, mask: __m128i| {
                let words = _mm256_mask_i32gather_epi64::<1>(zero, base, bytes, _mm256_cvtepi32_epi64(mask));
                _mm256_srlv_epi64(words, _mm256_cvtepu32_epi64(shift))
            };
            let lo = half(_mm256_castsi256_si128(bytes), _mm256_castsi256_si128(shift), _mm256_castsi256_si128(esc));
            let hi = half(_mm256_extracti128_si256::<1>(bytes), _mm256_extracti128_si256::<1>(shift), _mm256_extracti128_si256::<1>(esc));
            (keep(lo, cnt_lo), keep(hi, cnt_hi))
        };
        e.at += total;
        Some(_mm256_set_m128i(hi, lo))
    }
}

/// Byte `SHIFT / 8` of row `row`'s eight elements of the first `lanes`
/// lanes of vector `gi`, to `out + l·512` for lane l: packs, then an 8×8
/// byte transpose in registers.
#[inline(always)]
unsafe fn put_row<const G: usize, const SHIFT: i32>(w: &Work, row: usize, gi: usize, lanes: usize, out: *mut u8) {
    unsafe {
        let r = |x: usize| _mm256_and_si256(_mm256_srai_epi32::<SHIFT>(ld(w.f.get_unchecked(padded(row * 8 + x) * G + gi))), _mm256_set1_epi32(0xff));
        // Packs work within 128-bit halves: an (x, x+1) pair packs to [x lanes 0-3, x+1 lanes 0-3 | x lanes 4-7, x+1 lanes 4-7].
        let a = _mm256_packus_epi16(_mm256_packus_epi32(r(0), r(1)), _mm256_packus_epi32(r(2), r(3)));
        let b = _mm256_packus_epi16(_mm256_packus_epi32(r(4), r(5)), _mm256_packus_epi32(r(6), r(7)));
        // Per 128-bit half: byte 4x + l holds element x of lane l (+ 4 in the upper half); lane-major after the shuffle.
        let t = _mm256_setr_epi8(0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15, 0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15);
        let (a, b) = (_mm256_shuffle_epi8(a, t), _mm256_shuffle_epi8(b, t));
        let (lo, hi) = (_mm256_unpacklo_epi32(a, b), _mm256_unpackhi_epi32(a, b));
        let mut q = [0u64; 8];
        _mm_storeu_si128(q.as_mut_ptr() as *mut __m128i, _mm256_castsi256_si128(lo));
        _mm_storeu_si128(q.as_mut_ptr().add(2) as *mut __m128i, _mm256_castsi256_si128(hi));
        _mm_storeu_si128(q.as_mut_ptr().add(4) as *mut __m128i, _mm256_extracti128_si256::<1>(lo));
        _mm_storeu_si128(q.as_mut_ptr().add(6) as *mut __m128i, _mm256_extracti128_si256::<1>(hi));
        for (l, v) in q.iter().take(lanes).enumerate() {
            std::ptr::write_unaligned(out.add(l * 512) as *mut u64, *v);
        }
    }
}

/// Decodes `s` into `out` as `decode_scalar` does.
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`usable`]).
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn decode(s: &Stream, w: usize, out: &mut [u8]) -> Result<(), String> {
    match (s.lanes, s.precision) {
        (8, 9) => unsafe { run::<1, 9>(s, w, out) },
        (16, 9) => unsafe { run::<2, 9>(s, w, out) },
        (32, 9) => unsafe { run::<4, 9>(s, w, out) },
        (64, 9) => unsafe { run::<8, 9>(s, w, out) },
        (8, 10) => unsafe { run::<1, 10>(s, w, out) },
        (16, 10) => unsafe { run::<2, 10>(s, w, out) },
        (32, 10) => unsafe { run::<4, 10>(s, w, out) },
        (64, 10) => unsafe { run::<8, 10>(s, w, out) },
        (8, 11) => unsafe { run::<1, 11>(s, w, out) },
        (16, 11) => unsafe { run::<2, 11>(s, w, out) },
        (32, 11) => unsafe { run::<4, 11>(s, w, out) },
        (64, 11) => unsafe { run::<8, 11>(s, w, out) },
        (8, _) => unsafe { run::<1, 12>(s, w, out) },
        (16, _) => unsafe { run::<2, 12>(s, w, out) },
        (32, _) => unsafe { run::<4, 12>(s, w, out) },
        _ => unsafe { run::<8, 12>(s, w, out) },
    }
}

#[target_feature(enable = "avx2,fma")]
unsafe fn run<const G: usize, const P: i32>(s: &Stream, w: usize, out: &mut [u8]) -> Result<(), String> {
    let n = 8 * G;
    let m = out.len() / w;
    let first = m / (TILE + 1);
    let expand = expand_table();
    let mut work = Work { f: vec![I32x8([0; 8]); 729 * G], mag: vec![U8x8([0; 8]); 729 * G] };
    let first_states = s.initial_states();
    let mut st: [__m256i; G] = std::array::from_fn(|gi| unsafe { _mm256_loadu_si256(first_states[gi * 8..].as_ptr() as *const __m256i) });
    let base = s.words.as_ptr();
    let mut r = Reader { words: unsafe { base.add(2 * n) }, escapes: s.escapes(), bad: _mm256_setzero_si256(), overrun: false };
    let max = _mm256_set1_epi32((1 << (8 * w)) - 1);
    let table = s.table.as_ptr();
    let outp = out.as_mut_ptr();
    let lane_ids = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let zeros = vec![0u8; 64 * n];
    for g in 0..s.tiles.div_ceil(n) {
        let present = n.min(s.tiles - g * n);
        let act: [__m256i; G] = std::array::from_fn(|gi| _mm256_cmpgt_epi32(_mm256_set1_epi32(present as i32 - (gi * 8) as i32), lane_ids));
        let bounds: [(__m256i, __m256i); G] = std::array::from_fn(|gi| {
            let b: [super::Bounds; 8] = std::array::from_fn(|l| s.bounds_of(g * n + gi * 8 + l));
            (_mm256_loadu_si256(b.map(|b| b.lo).as_ptr() as *const __m256i), _mm256_loadu_si256(b.map(|b| b.hi).as_ptr() as *const __m256i))
        });
        let rows = s.skip_rows(g, &zeros);
        for row in 0..64 {
            // A row takes at most 8 words per lane, which the padding after the stream holds
            // (and a 16-byte load of words at the end reads 8 words: within it too).
            if unsafe { r.words.offset_from(base) } as usize > s.words_len {
                return Err("runs past the end of its words".into());
            }
            let p = padded(row * 8);
            // Per vector, each lane's row of left-out elements (bit x).
            let skips: [__m256i; G] = std::array::from_fn(|gi| unsafe { _mm256_cvtepu8_epi32(_mm_loadl_epi64(rows.as_ptr().add(row * n + gi * 8) as *const __m128i)) });
            macro_rules! run {
                ($first:expr, $rest:expr) => {
                    unsafe {
                        step::<{ $first }, G, P>(&mut work, &mut st, &act, p, &mut r, table, &expand, max, 0, &skips, &bounds);
                        for x in 1..8 {
                            step::<{ $rest }, G, P>(&mut work, &mut st, &act, p + x, &mut r, table, &expand, max, x as i32, &skips, &bounds);
                        }
                    }
                };
            }
            match (row >= 8, row % 8 > 0) {
                (true, true) => run!(6, 7),
                (false, true) => run!(2, 3),
                (true, false) => run!(4, 5),
                (false, false) => run!(0, 1),
            }
            if _mm256_testz_si256(r.bad, r.bad) == 0 || r.overrun {
                return Err(match r.overrun {
                    true => "runs past the end of its escape bits".into(),
                    false => "codes in a context its tables leave empty, or decodes outside the element".into(),
                });
            }
            for gi in 0..present.div_ceil(8) {
                let lanes = (present - gi * 8).min(8);
                let at = first + (g * n + gi * 8) * TILE + row * 8;
                unsafe { put_row::<G, 0>(&work, row, gi, lanes, outp.add(at)) };
                if w == 2 {
                    unsafe { put_row::<G, 8>(&work, row, gi, lanes, outp.add(m + at)) };
                }
            }
        }
    }
    let mut states = vec![0u32; n];
    for (gi, v) in st.iter().enumerate() {
        unsafe { _mm256_storeu_si256(states[gi * 8..].as_mut_ptr() as *mut __m256i, *v) };
    }
    let wp = unsafe { r.words.offset_from(base) } as usize;
    finish(s, &states, wp, &r.escapes)
}
