//! The scheme-2 decoder with its lanes in AVX-512 vectors: G vectors of 16
//! tiles (a stream of 16·G lanes), every lane at the same element, so a
//! neighbour is one vector load, the contexts of all 16·G lanes two byte
//! permutes of a bucket table, the table lookup one gather, the renormalising
//! lanes' words one expand-load from the shared stream, and each row of 8
//! elements leaves the lanes through a byte permute and a scatter. Escape
//! bits are read for all lanes at once, each lane's position a prefix sum of
//! the lanes' bit counts (16-bit levels and sharp bricks escape often). On
//! AMD's cores, which split a 512-bit operation in two, the decoder's speed
//! is its count of operations, which is why they are few. Same
//! output as `decode_scalar`, which the tests hold it to, damaged streams
//! included.

use super::{bucket, finish, padded, Escapes, Stream, ESCAPE, LAST_SYMBOL, RANS_LOW, SKIPPED, TILE};
use std::arch::x86_64::*;

#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct I32x16([i32; 16]);

#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct U8x16([u8; 16]);

/// Per lane vector and padded element: the decoded quotients and the
/// residual magnitudes (saturated at 255: the context sums three of them
/// and saturates there too).
struct Work {
    f: Vec<I32x16>,
    mag: Vec<U8x16>,
}

/// Whether this CPU runs the vector decoder on a stream of `lanes` lanes.
pub(super) fn usable(lanes: usize) -> bool {
    matches!(lanes, 16 | 32 | 64)
        && is_x86_feature_detected!("avx512f")
        && is_x86_feature_detected!("avx512vl")
        && is_x86_feature_detected!("avx512bw")
        && is_x86_feature_detected!("avx512cd")
        && is_x86_feature_detected!("avx512vbmi")
        && is_x86_feature_detected!("avx512vbmi2")
}

#[inline(always)]
unsafe fn ld(v: &I32x16) -> __m512i {
    unsafe { _mm512_load_si512(v.0.as_ptr() as *const __m512i) }
}

/// ⌊(t + 1) / 3⌋, the rounded mean of the three 2D predictions, for the
/// t that decoded elements give (−3·65535 ≤ t ≤ 6·65535; a row with any
/// other is refused whatever this gives): t + 1 moved up by 3·2^16 is an
/// exact float from 0 to below 2^20, and one fused multiply-add of 1/3 and
/// 1/6 lands within 1/6 of its quotient's fraction, so truncation is exact
/// (from t = −3·2^16 − 1 to 6,094,848; the tests check the range above).
/// Five operations where the integer division took a dozen.
#[inline(always)]
pub(super) unsafe fn mean3(t: __m512i) -> __m512i {
    unsafe {
        let u = _mm512_cvtepi32_ps(_mm512_add_epi32(t, _mm512_set1_epi32((3 << 16) + 1)));
        let q = _mm512_cvttps_epi32(_mm512_fmadd_ps(u, _mm512_set1_ps(1.0 / 3.0), _mm512_set1_ps(1.0 / 6.0)));
        _mm512_sub_epi32(q, _mm512_set1_epi32(1 << 16))
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
                mean3(_mm512_sub_epi32(_mm512_slli_epi32::<1>(s), _mm512_add_epi32(_mm512_add_epi32(at(p - 90), at(p - 82)), at(p - 10))))
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

/// Where the shared streams stand, and what went wrong so far.
struct Reader<'a> {
    words: *const u16,
    escapes: Escapes<'a>,
    /// The largest symbol and element (unsigned) decoded in a present lane
    /// so far: past `LAST_SYMBOL` (an empty context) or the element's
    /// largest value, the stream is refused at the end of the row.
    sym_max: __m512i,
    q_max: __m512i,
    /// An escape ran past the end of the bits.
    overrun: bool,
}

/// The escape bits of the lanes `esc` (lowest lane first, the stream's
/// order), `kk` of them each (at most 47, as [`Escapes::read`] takes), all
/// at once: each lane's position is the bits before it (an exclusive
/// prefix sum over the lanes), its bits a shift of the 64 bits from the
/// position's byte when they all lie there, else one 64-bit gather each;
/// `None`, before anything is read, when the lanes' bits together run past the end.
#[inline(always)]
unsafe fn escape_bits(e: &mut Escapes, kk: __m512i, esc: __mmask16) -> Option<__m512i> {
    unsafe {
        let zero = _mm512_setzero_si512();
        let cnt = _mm512_maskz_min_epi32(esc, kk, _mm512_set1_epi32(47));
        // Inclusive prefix sum: each lane plus the lanes 1, 2, 4 and 8 below it.
        let mut incl = cnt;
        incl = _mm512_add_epi32(incl, _mm512_alignr_epi32::<15>(incl, zero));
        incl = _mm512_add_epi32(incl, _mm512_alignr_epi32::<14>(incl, zero));
        incl = _mm512_add_epi32(incl, _mm512_alignr_epi32::<12>(incl, zero));
        incl = _mm512_add_epi32(incl, _mm512_alignr_epi32::<8>(incl, zero));
        let start = _mm512_add_epi32(_mm512_sub_epi32(incl, cnt), _mm512_set1_epi32((e.at & 7) as i32));
        // Every lane starts at most `total` bits on: past the bits' end, the stream is refused
        // (a read the scalar decoder would still start there leaves its position past the end,
        // which it refuses once the stream is decoded).
        let total = _mm_extract_epi32::<3>(_mm512_extracti32x4_epi32::<3>(incl)) as usize;
        if e.past_end(total) {
            return None;
        }
        let base = e.bits.as_ptr().add(e.at >> 3) as *const i64;
        // Usually every lane's bits lie in the 64 from the byte the position is in: one load for
        // all of them, and each lane's 32 bits from its start a funnel shift of that window's
        // halves; else a 64-bit gather from each lane's byte.
        let raw = if total + (e.at & 7) <= 64 {
            let window = base.read_unaligned() as u64;
            let (low, high) = (_mm512_set1_epi32(window as i32), _mm512_set1_epi32((window >> 32) as i32));
            let in_low = _mm512_cmplt_epu32_mask(start, _mm512_set1_epi32(32));
            let bits = _mm512_shrdv_epi32(_mm512_mask_blend_epi32(in_low, high, low), _mm512_maskz_mov_epi32(in_low, high), start);
            // A count of 32 or more (a damaged stream's) shifts 1 out: the mask is then every bit.
            _mm512_and_si512(bits, _mm512_sub_epi32(_mm512_sllv_epi32(_mm512_set1_epi32(1), cnt), _mm512_set1_epi32(1)))
        } else {
            let take = |words: __m512i, shift: __m256i, n: __m256i| {
                let v = _mm512_srlv_epi64(words, _mm512_cvtepu32_epi64(shift));
                let mask = _mm512_sub_epi64(_mm512_sllv_epi64(_mm512_set1_epi64(1), _mm512_cvtepu32_epi64(n)), _mm512_set1_epi64(1));
                _mm512_cvtepi64_epi32(_mm512_and_si512(v, mask))
            };
            let bytes = _mm512_srli_epi32::<3>(start);
            let (lo, hi) = (_mm512_castsi512_si256(bytes), _mm512_extracti64x4_epi64::<1>(bytes));
            let words_lo = _mm512_mask_i32gather_epi64::<1>(zero, esc as u8, lo, base);
            let words_hi = _mm512_mask_i32gather_epi64::<1>(zero, (esc >> 8) as u8, hi, base);
            let shift = _mm512_and_si512(start, _mm512_set1_epi32(7));
            let raw_lo = take(words_lo, _mm512_castsi512_si256(shift), _mm512_castsi512_si256(cnt));
            let raw_hi = take(words_hi, _mm512_extracti64x4_epi64::<1>(shift), _mm512_extracti64x4_epi64::<1>(cnt));
            _mm512_inserti64x4::<1>(_mm512_castsi256_si512(raw_lo), raw_hi)
        };
        e.at += total;
        Some(raw)
    }
}

/// Each byte's context row base `8·bucket(e)` for the saturated sum `e` of
/// three residual magnitudes, as four 64-byte tables (`e` 0–63, …, 192–255).
struct Buckets([__m512i; 4]);

impl Buckets {
    #[target_feature(enable = "avx512f")]
    fn new() -> Buckets {
        let table: [u8; 256] = std::array::from_fn(|e| (bucket(e as u32) << 3) as u8);
        // SAFETY: each load reads 64 of the table's 256 bytes.
        Buckets(std::array::from_fn(|k| unsafe { _mm512_loadu_si512(table[64 * k..].as_ptr() as *const __m512i) }))
    }
}

/// Lanes 16·k to 16·k + 15 of 64 bytes.
#[inline(always)]
unsafe fn quarter(v: __m512i, k: usize) -> __m128i {
    unsafe {
        match k {
            0 => _mm512_castsi512_si128(v),
            1 => _mm512_extracti32x4_epi32::<1>(v),
            2 => _mm512_extracti32x4_epi32::<2>(v),
            _ => _mm512_extracti32x4_epi32::<3>(v),
        }
    }
}

/// `v` with lanes 16·k to 16·k + 15 of its bytes replaced by `x`.
#[inline(always)]
unsafe fn with_quarter(v: __m512i, k: usize, x: __m128i) -> __m512i {
    unsafe {
        match k {
            0 => _mm512_inserti32x4::<0>(v, x),
            1 => _mm512_inserti32x4::<1>(v, x),
            2 => _mm512_inserti32x4::<2>(v, x),
            _ => _mm512_inserti32x4::<3>(v, x),
        }
    }
}

/// One element of every lane: context, table entry, state update, escape
/// bits, prediction undone (held within each lane's `bounds`). The contexts
/// of all G vectors come at once from their magnitudes' bytes (saturating
/// adds and two table permutes; the lanes of `skip`, elements a scheme-4
/// stream leaves out, in the [`SKIPPED`] context); the
/// magnitudes of the element before along x, `left`, come in a register
/// (the element's own go out in one, and to memory in one store), so the
/// step does not wait on the store it just made.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn step<const POS: usize, const G: usize, const P: u32>(
    w: &mut Work,
    st: &mut [__m512i; G],
    act: &[__mmask16; G],
    p: usize,
    r: &mut Reader,
    table: *const u32,
    buckets: &Buckets,
    left: __m512i,
    skip: __mmask64,
    bounds: &[(__m512i, __m512i); G],
) -> __m512i {
    unsafe {
        let bytes = match G {
            4 => u64::MAX,
            _ => (1u64 << (16 * G)) - 1,
        };
        let mag = |q: usize| _mm512_maskz_loadu_epi8(bytes, w.mag.as_ptr().add(q * G) as *const i8);
        let e = _mm512_adds_epu8(_mm512_adds_epu8(mag(p - 81), mag(p - 9)), left);
        let mut mags = _mm512_setzero_si512();
        let low = _mm512_permutex2var_epi8(buckets.0[0], e, buckets.0[1]);
        let high = _mm512_permutex2var_epi8(buckets.0[2], e, buckets.0[3]);
        let ctxs = _mm512_add_epi8(_mm512_mask_blend_epi8(_mm512_movepi8_mask(e), low, high), _mm512_set1_epi8(POS as i8));
        let ctxs = _mm512_mask_blend_epi8(skip, ctxs, _mm512_set1_epi8(SKIPPED as u8 as i8));
        for gi in 0..G {
            let act = act[gi];
            let ctx = _mm512_cvtepu8_epi32(quarter(ctxs, gi));
            let x = st[gi];
            let slot = _mm512_and_si512(x, _mm512_set1_epi32((1 << P) - 1));
            let ent = _mm512_i32gather_epi32::<4>(_mm512_or_si512(_mm512_slli_epi32::<P>(ctx), slot), table as *const i32);
            let sym = _mm512_and_si512(ent, _mm512_set1_epi32(63));
            r.sym_max = _mm512_mask_max_epu32(r.sym_max, act, r.sym_max, sym);
            let fr = _mm512_and_si512(_mm512_srli_epi32::<6>(ent), _mm512_set1_epi32(0x1fff));
            // Only the lanes with a tile move on (an absent lane's state is never used).
            let xs = _mm512_mask_sub_epi32(x, act, _mm512_add_epi32(_mm512_mullo_epi32(fr, _mm512_srli_epi32::<P>(x)), slot), _mm512_srli_epi32::<19>(ent));
            let need = _mm512_mask_cmplt_epu32_mask(act, xs, _mm512_set1_epi32(RANS_LOW as i32));
            let words = _mm512_cvtepu16_epi32(_mm256_maskz_expandloadu_epi16(need, r.words as *const i16));
            r.words = r.words.add(need.count_ones() as usize);
            st[gi] = _mm512_mask_or_epi32(xs, need, _mm512_slli_epi32::<16>(xs), words);
            // z: the symbol, or for an escape symbol 16 + k its base 15 + 2^k plus k raw bits.
            let esc = _mm512_mask_cmpge_epu32_mask(act, sym, _mm512_set1_epi32(ESCAPE as i32));
            let mut z = sym;
            if esc != 0 {
                let kk = _mm512_sub_epi32(sym, _mm512_set1_epi32(ESCAPE as i32));
                z = _mm512_mask_add_epi32(z, esc, _mm512_set1_epi32(ESCAPE as i32 - 1), _mm512_sllv_epi32(_mm512_set1_epi32(1), kk));
                match escape_bits(&mut r.escapes, kk, esc) {
                    Some(raw) => z = _mm512_mask_add_epi32(z, esc, z, raw),
                    None => r.overrun = true,
                }
            }
            let res = _mm512_xor_si512(_mm512_srli_epi32::<1>(z), _mm512_sub_epi32(_mm512_setzero_si512(), _mm512_and_si512(z, _mm512_set1_epi32(1))));
            let mag = _mm512_srli_epi32::<1>(_mm512_add_epi32(z, _mm512_set1_epi32(1)));
            mags = with_quarter(mags, gi, _mm512_cvtusepi32_epi8(mag));
            let (lo, hi) = bounds[gi];
            let q = _mm512_add_epi32(_mm512_min_epi32(_mm512_max_epi32(predict::<POS, G>(w, p, gi), lo), hi), res);
            r.q_max = _mm512_mask_max_epu32(r.q_max, act, r.q_max, q);
            _mm512_store_si512(w.f.get_unchecked_mut(p * G + gi).0.as_mut_ptr() as *mut __m512i, q);
        }
        _mm512_mask_storeu_epi8(w.mag.as_mut_ptr().add(p * G) as *mut i8, bytes, mags);
        mags
    }
}

/// Byte `SHIFT / 8` of row (z, y)'s eight elements of the first `lanes`
/// lanes of vector `gi`, to `out + l·512` for lane l (tiles are 512 bytes
/// apart in each byte plane).
#[inline(always)]
unsafe fn put_row<const G: usize, const SHIFT: u32>(w: &Work, row: usize, gi: usize, lanes: usize, out: *mut u8) {
    unsafe {
        let r = |x: usize| _mm512_cvtepi32_epi8(_mm512_srli_epi32::<SHIFT>(ld(w.f.get_unchecked(padded(row * 8 + x) * G + gi))));
        // Elements x = 0..3 in a, 4..7 in b (16 lanes' bytes each); byte 8l + x of the result is lane l's element x.
        let a = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(_mm256_set_m128i(r(1), r(0))), _mm256_set_m128i(r(3), r(2)));
        let b = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(_mm256_set_m128i(r(5), r(4))), _mm256_set_m128i(r(7), r(6)));
        let keep = (1u32 << lanes) - 1;
        for half in 0..2 {
            let mut idx = [0u8; 64];
            for (t, v) in idx.iter_mut().enumerate() {
                let (l, x) = (half * 8 + t / 8, t % 8);
                *v = if x < 4 { (16 * x + l) as u8 } else { (64 + 16 * (x - 4) + l) as u8 };
            }
            let c = _mm512_permutex2var_epi8(a, _mm512_loadu_si512(idx.as_ptr() as *const __m512i), b);
            let offs = _mm512_setr_epi64(0, 512, 1024, 1536, 2048, 2560, 3072, 3584);
            let m = ((keep >> (half * 8)) & 0xff) as __mmask8;
            if m == 0 {
                // No lane there: its tiles lie past the output's end.
                break;
            }
            _mm512_mask_i64scatter_epi64::<1>(out.add(half * 8 * 512) as *mut i64, m, offs, c);
        }
    }
}

/// Decodes `s` into `out` as `decode_scalar` does.
///
/// # Safety
/// The CPU must have AVX-512 F, VL, BW, CD, VBMI and VBMI2 ([`usable`]).
#[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512vbmi,avx512vbmi2,avx512cd")]
pub(super) unsafe fn decode(s: &Stream, w: usize, out: &mut [u8]) -> Result<(), String> {
    match (s.lanes, s.precision) {
        (16, 9) => unsafe { run::<1, 9>(s, w, out) },
        (32, 9) => unsafe { run::<2, 9>(s, w, out) },
        (64, 9) => unsafe { run::<4, 9>(s, w, out) },
        (16, 10) => unsafe { run::<1, 10>(s, w, out) },
        (32, 10) => unsafe { run::<2, 10>(s, w, out) },
        (64, 10) => unsafe { run::<4, 10>(s, w, out) },
        (16, 11) => unsafe { run::<1, 11>(s, w, out) },
        (32, 11) => unsafe { run::<2, 11>(s, w, out) },
        (64, 11) => unsafe { run::<4, 11>(s, w, out) },
        (16, _) => unsafe { run::<1, 12>(s, w, out) },
        (32, _) => unsafe { run::<2, 12>(s, w, out) },
        _ => unsafe { run::<4, 12>(s, w, out) },
    }
}

#[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512vbmi,avx512vbmi2,avx512cd")]
unsafe fn run<const G: usize, const P: u32>(s: &Stream, w: usize, out: &mut [u8]) -> Result<(), String> {
    let n = 16 * G;
    let m = out.len() / w;
    let first = m / (TILE + 1);
    let mut work = Work { f: vec![I32x16([0; 16]); 729 * G], mag: vec![U8x16([0; 16]); 729 * G] };
    let first_states = s.initial_states();
    let mut st: [__m512i; G] = std::array::from_fn(|gi| unsafe { _mm512_loadu_si512(first_states[gi * 16..].as_ptr() as *const __m512i) });
    let base = s.words.as_ptr();
    let zero = _mm512_setzero_si512();
    let mut r = Reader { words: unsafe { base.add(2 * n) }, escapes: s.escapes(), sym_max: zero, q_max: zero, overrun: false };
    let buckets = Buckets::new();
    let max = _mm512_set1_epi32((1 << (8 * w)) - 1);
    let table = s.table.as_ptr();
    let outp = out.as_mut_ptr();
    let zeros = vec![0u8; 64 * n];
    let lane_bytes = match G {
        4 => u64::MAX,
        _ => (1u64 << (16 * G)) - 1,
    };
    for g in 0..s.tiles.div_ceil(n) {
        let present = n.min(s.tiles - g * n);
        let act: [__mmask16; G] = std::array::from_fn(|gi| ((1u32 << present.saturating_sub(gi * 16).min(16)) - 1) as __mmask16);
        let bounds: [(__m512i, __m512i); G] = std::array::from_fn(|gi| {
            let b: [super::Bounds; 16] = std::array::from_fn(|l| s.bounds_of(g * n + gi * 16 + l));
            (_mm512_loadu_si512(b.map(|b| b.lo).as_ptr() as *const __m512i), _mm512_loadu_si512(b.map(|b| b.hi).as_ptr() as *const __m512i))
        });
        let rows = s.skip_rows(g, &zeros);
        for row in 0..64 {
            // A row takes at most 8 words per lane, which the padding after the stream holds.
            if unsafe { r.words.offset_from(base) } as usize > s.words_len {
                return Err("runs past the end of its words".into());
            }
            let p = padded(row * 8);
            // Byte l: lane l's row of left-out elements, bit x.
            let skips = unsafe { _mm512_maskz_loadu_epi8(lane_bytes, rows.as_ptr().add(row * n) as *const i8) };
            let skip = |x: usize| _mm512_test_epi8_mask(skips, _mm512_set1_epi8((1u8 << x) as i8));
            macro_rules! run {
                ($first:expr, $rest:expr) => {
                    unsafe {
                        // The element before x = 0 is the padding, 0.
                        let mut left = step::<{ $first }, G, P>(&mut work, &mut st, &act, p, &mut r, table, &buckets, _mm512_setzero_si512(), skip(0), &bounds);
                        for x in 1..8 {
                            left = step::<{ $rest }, G, P>(&mut work, &mut st, &act, p + x, &mut r, table, &buckets, left, skip(x), &bounds);
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
            let bad = _mm512_cmpgt_epu32_mask(r.sym_max, _mm512_set1_epi32(LAST_SYMBOL as i32)) | _mm512_cmpgt_epu32_mask(r.q_max, max);
            if bad != 0 || r.overrun {
                return Err(match r.overrun {
                    true => "runs past the end of its escape bits".into(),
                    false => "codes in a context its tables leave empty, or decodes outside the element".into(),
                });
            }
            for gi in 0..present.div_ceil(16) {
                let lanes = (present - gi * 16).min(16);
                let at = first + (g * n + gi * 16) * TILE + row * 8;
                unsafe { put_row::<G, 0>(&work, row, gi, lanes, outp.add(at)) };
                if w == 2 {
                    unsafe { put_row::<G, 8>(&work, row, gi, lanes, outp.add(m + at)) };
                }
            }
        }
    }
    let mut states = vec![0u32; n];
    for (gi, v) in st.iter().enumerate() {
        unsafe { _mm512_storeu_si512(states[gi * 16..].as_mut_ptr() as *mut __m512i, *v) };
    }
    let wp = unsafe { r.words.offset_from(base) } as usize;
    finish(s, &states, wp, &r.escapes)
}
