use super::*;

/// `tiles` tiles of `width`-byte elements as the `tiles unpredicted` filter
/// lays them out (divisors, then quotients; shuffled by byte): smooth
/// fields with noise, edges, empty tiles and a few large jumps.
fn section(tiles: usize, width: usize, seed: u32) -> Vec<u8> {
    let max = (1u32 << (8 * width)) - 1;
    let mut next = xorshift(seed.wrapping_mul(2_654_435_761));
    let m = tiles * (TILE + 1);
    let mut e = vec![0u32; m];
    for t in 0..tiles {
        e[t] = next() % 7;
        let kind = next() % 4;
        let scale = if width == 1 { 30 } else { 3000 };
        for v in 0..TILE {
            let (x, y, z) = ((v & 7) as u32, ((v >> 3) & 7) as u32, (v >> 6) as u32);
            let q = match kind {
                0 => 0,
                1 => (x * 3 + y * 2 + z) * scale / 20 + next() % 3,
                2 if next().is_multiple_of(97) => next() % (max + 1),
                2 => (x * y + z * 5) * scale / 40,
                _ => u32::from(x + y + z > 9) * scale + next() % 5,
            };
            e[tiles + t * TILE + v] = q.min(max);
        }
    }
    laid_out(&e, width)
}

/// A section's elements (divisors, then quotients) as the `tiles` filters
/// store them: byte-shuffled, the low bytes first.
fn laid_out(e: &[u32], width: usize) -> Vec<u8> {
    let m = e.len();
    let mut out = vec![0u8; m * width];
    for (i, &v) in e.iter().enumerate() {
        out[i] = v as u8;
        if width == 2 {
            out[m + i] = (v >> 8) as u8;
        }
    }
    out
}

/// `stored` decoded by `decoder` into `len` bytes.
fn decoded(stored: &[u8], width: usize, len: usize, decoder: Decoder) -> Result<Vec<u8>, String> {
    decoded_shown(stored, width, len, decoder, None)
}

/// [`decoded`] as scheme 4 with `shown`, or as scheme 2.
fn decoded_shown(stored: &[u8], width: usize, len: usize, decoder: Decoder, shown: Option<&[TileMask]>) -> Result<Vec<u8>, String> {
    let mut out = vec![0u8; len];
    let tiles = len / width / (TILE + 1);
    let s = parse(stored, width, tiles, &mut out, shown)?;
    decoder.run(&s, width, &mut out)?;
    Ok(out)
}

/// A xorshift generator started at `seed` (1 for 0).
pub(crate) fn xorshift(seed: u32) -> impl FnMut() -> u32 {
    let mut rng = seed.max(1);
    move || {
        rng ^= rng << 13;
        rng ^= rng >> 17;
        rng ^= rng << 5;
        rng
    }
}

/// `stored` (a damaged stream, `what`) decoded into `len` bytes by every
/// decoder this CPU runs: refused by each exactly when the scalar decoder
/// refuses it, and the same bytes where it is taken.
fn decoded_alike(stored: &[u8], width: usize, len: usize, what: &str) {
    decoded_alike_shown(stored, width, len, what, None)
}

/// [`decoded_alike`] as scheme 4 with `shown`, or as scheme 2.
fn decoded_alike_shown(stored: &[u8], width: usize, len: usize, what: &str, shown: Option<&[TileMask]>) {
    let s = decoded_shown(stored, width, len, Decoder::Scalar, shown);
    for d in decoders() {
        let v = decoded_shown(stored, width, len, d, shown);
        assert_eq!(s.is_ok(), v.is_ok(), "{what}, {d:?}: scalar {s:?}");
        if let (Ok(s), Ok(v)) = (&s, v) {
            assert_eq!(*s, v, "{what}, {d:?}");
        }
    }
}

/// The decoders this CPU runs on vdbcook's streams (the scalar one last).
fn decoders() -> Vec<Decoder> {
    Decoder::ALL.into_iter().filter(|d| d.usable(LANES)).collect()
}

#[test]
fn streams_restore_what_was_coded() {
    for width in [1usize, 2] {
        for tiles in [1usize, 15, 64, 65, 200] {
            let raw = section(tiles, width, (tiles * 10 + width) as u32);
            let stored = encode(&raw, width as u32, 3, None).unwrap().unwrap();
            assert!(stored.len() < raw.len(), "{tiles} tiles of {width}: {} bytes coded from {}", stored.len(), raw.len());
            for d in decoders() {
                assert_eq!(decoded(&stored, width, raw.len(), d).unwrap(), raw, "{tiles} tiles of {width} bytes, {d:?}");
            }
            let mut out = vec![0u8; raw.len()];
            decode(&stored, width as u32, &mut out, None).unwrap();
            assert_eq!(out, raw);
        }
    }
}

/// [`section`]'s tiles with the voxels some node shows (every fourth tile
/// all, the next none, then random bits, then half), the others at their
/// prediction within the tile's levels, as the cooker leaves them; but one
/// element of tile 2 that no node shows is off its prediction, so that
/// tile must code all its elements.
fn shown_section(tiles: usize, width: usize, seed: u32) -> (Vec<u8>, Vec<TileMask>) {
    let raw = section(tiles, width, seed);
    let m = tiles * (TILE + 1);
    let mut e: Vec<u32> = (0..m).map(|i| u32::from(raw[i]) | if width == 2 { u32::from(raw[m + i]) << 8 } else { 0 }).collect();
    let mut next = xorshift(seed ^ 0x5bd1_e995);
    let mut shown = Vec::with_capacity(tiles);
    for t in 0..tiles {
        let mask: TileMask = match t % 4 {
            0 => [u64::MAX; 8],
            1 => [0; 8],
            2 => std::array::from_fn(|_| u64::from(next()) << 32 | u64::from(next())),
            _ => [0x0f0f_0f0f_0f0f_0f0f; 8],
        };
        let bounds = Bounds::levels(e[t] as u16, width);
        let mut f = [0i32; 729];
        for v in 0..TILE {
            let p = padded(v);
            let q = &mut e[tiles + t * TILE + v];
            if !bit(&mask, v) {
                *q = predict(position(v), &f, p).clamp(bounds.lo, bounds.hi) as u32;
                if t == 2 && v == 100 && !bit(&mask, v) {
                    *q = (*q + 1) % (bounds.hi as u32 + 1);
                }
            }
            f[p] = *q as i32;
        }
        shown.push(mask);
    }
    (laid_out(&e, width), shown)
}

#[test]
fn streams_over_shown_voxels_restore_what_was_coded_in_fewer_bytes() {
    for width in [1usize, 2] {
        for tiles in [1usize, 7, 65, 130] {
            let (raw, shown) = shown_section(tiles, width, (tiles * 7 + width) as u32);
            let plain = encode(&raw, width as u32, 3, None).unwrap().unwrap();
            let stored = encode(&raw, width as u32, 3, Some(&shown)).unwrap().unwrap();
            if tiles > 1 {
                assert!(stored.len() < plain.len(), "{tiles} tiles of {width}: {} bytes over the shown voxels, {} over all", stored.len(), plain.len());
            }
            for d in decoders() {
                assert_eq!(decoded_shown(&stored, width, raw.len(), d, Some(&shown)).unwrap(), raw, "{tiles} tiles of {width} bytes, {d:?}");
            }
            for lanes in [3usize, 8, 12, 16, 32] {
                let stored = encode_lanes(&raw, width as u32, 3, lanes, Some(&shown)).unwrap().unwrap();
                for d in Decoder::ALL.into_iter().filter(|d| d.usable(lanes)) {
                    assert_eq!(decoded_shown(&stored, width, raw.len(), d, Some(&shown)).unwrap(), raw, "{lanes} lanes, {tiles} tiles of {width} bytes, {d:?}");
                }
            }
            // Masks of another count than the tiles': not coded, and refused.
            assert!(encode(&raw, width as u32, 3, Some(&shown[1..])).unwrap().is_none());
            assert!(decoded_shown(&stored, width, raw.len(), Decoder::Scalar, Some(&shown[1..])).is_err());
        }
    }
}

#[test]
fn damaged_streams_over_shown_voxels_are_refused_alike() {
    for width in [1usize, 2] {
        let (raw, shown) = shown_section(70, width, 9);
        let stored = encode(&raw, width as u32, 3, Some(&shown)).unwrap().unwrap();
        for cut in (0..stored.len()).step_by(stored.len() / 61 + 1) {
            for d in decoders() {
                assert!(decoded_shown(&stored[..cut], width, raw.len(), d, Some(&shown)).is_err(), "cut at {cut}, {d:?}");
            }
        }
        for i in (0..stored.len()).step_by(stored.len() / 201 + 1) {
            for bit in [0, 5] {
                let mut bad = stored.clone();
                bad[i] ^= 1 << bit;
                decoded_alike_shown(&bad, width, raw.len(), &format!("byte {i} bit {bit}"), Some(&shown));
            }
        }
    }
    // A flag set past the last tile (the side frame's flag byte of 3 tiles, all set).
    let (raw, shown) = shown_section(3, 1, 4);
    let stored = encode(&raw, 1, 3, Some(&shown)).unwrap().unwrap();
    let a = u32::from_le_bytes(stored[12..16].try_into().unwrap()) as usize;
    let mut side = zstd::bulk::decompress(&stored[HEAD..HEAD + a], 1 << 16).unwrap();
    side[3] |= 0x80;
    let side = zstd::bulk::compress(&side, 3).unwrap();
    let mut bad = stored[..HEAD].to_vec();
    bad[12..16].copy_from_slice(&(side.len() as u32).to_le_bytes());
    bad.extend_from_slice(&side);
    bad.extend_from_slice(&stored[HEAD + a..]);
    let err = decoded_shown(&bad, 1, raw.len(), Decoder::Scalar, Some(&shown)).unwrap_err();
    assert!(err.contains("past its last tile"), "{err}");
    // A lane's first state below 2^16 (its high word 0; scheme 2 takes such a state, scheme 4 does not).
    let words_at = stored.len() - 2 * u32::from_le_bytes(stored[20..24].try_into().unwrap()) as usize;
    let mut low = stored.clone();
    low[words_at..words_at + 2].copy_from_slice(&[0, 0]);
    let err = decoded_shown(&low, 1, raw.len(), Decoder::Scalar, Some(&shown)).unwrap_err();
    assert!(err.contains("first state below 2^16"), "{err}");
}

#[test]
fn what_is_not_whole_tiles_is_not_coded() {
    assert!(encode(&[0u8; 513 * 2 + 1], 1, 3, None).unwrap().is_none());
    assert!(encode(&[0u8; 513 * 3], 2, 3, None).unwrap().is_none());
    assert!(encode(&[], 1, 3, None).unwrap().is_none());
    let stored = encode(&section(3, 1, 1), 1, 3, None).unwrap().unwrap();
    assert!(decode(&stored, 1, &mut vec![0u8; 513 * 3 + 1], None).is_err());
    assert!(decode(&stored, 3, &mut vec![0u8; 513 * 3 * 3], None).is_err());
}

/// Every truncation and many bit flips: an error or (rarely) other bytes,
/// never a panic or a read outside the stream; the vector decoders say what
/// the scalar one does.
#[test]
fn damaged_streams_are_refused_alike() {
    for width in [1usize, 2] {
        let raw = section(70, width, 7);
        let stored = encode(&raw, width as u32, 3, None).unwrap().unwrap();
        for cut in (0..stored.len()).step_by(stored.len() / 97 + 1) {
            for d in decoders() {
                assert!(decoded(&stored[..cut], width, raw.len(), d).is_err(), "cut at {cut}, {d:?}");
            }
        }
        let mut flips = 0;
        for i in (0..stored.len()).step_by(stored.len() / 301 + 1) {
            for bit in [0, 3, 7] {
                let mut bad = stored.clone();
                bad[i] ^= 1 << bit;
                decoded_alike(&bad, width, raw.len(), &format!("byte {i} bit {bit}"));
                flips += 1;
            }
        }
        assert!(flips > 300);
    }
}

/// Streams of 8, 16 and 32 lanes (another writer's choice; vdbcook writes
/// 64): every decoder that takes the count restores what was coded, the
/// last group of tiles short of its lanes.
#[test]
fn every_lane_count_a_decoder_takes_restores_alike() {
    for width in [1usize, 2] {
        let raw = section(75, width, 11);
        for lanes in [8usize, 16, 32] {
            let stored = encode_lanes(&raw, width as u32, 3, lanes, None).unwrap().unwrap();
            let takers: Vec<Decoder> = Decoder::ALL.into_iter().filter(|d| d.usable(lanes)).collect();
            assert!(takers.contains(&Decoder::Scalar));
            for d in takers {
                assert_eq!(decoded(&stored, width, raw.len(), d).unwrap(), raw, "{lanes} lanes of {width}-byte tiles, {d:?}");
            }
        }
    }
}

/// Tiles of noise whose amplitude differs from tile to tile (2^0 to 2^15):
/// in some steps no lane escapes, in some a few lanes' escape bits fit one
/// 64-bit window, in others they run far past it (the vector decoders read
/// those two ways); every decoder restores them, and refuses their damage alike.
#[test]
fn escape_heavy_streams_restore_alike() {
    for width in [1usize, 2] {
        let max = (1u32 << (8 * width)) - 1;
        let tiles = 130;
        let mut next = xorshift(0x9e37_79b9 + width as u32);
        let mut e = vec![1u32; tiles];
        for _ in 0..tiles {
            let amplitude = 1u32 << (next() % (8 * width as u32));
            e.extend((0..TILE).map(|_| (max / 2 + next() % amplitude).min(max)));
        }
        let raw = laid_out(&e, width);
        let stored = encode(&raw, width as u32, 3, None).unwrap().unwrap();
        for d in decoders() {
            assert_eq!(decoded(&stored, width, raw.len(), d).unwrap(), raw, "{width}-byte noise, {d:?}");
        }
        for i in (0..stored.len()).step_by(stored.len() / 101 + 1) {
            let mut bad = stored.clone();
            bad[i] ^= 0x10;
            decoded_alike(&bad, width, raw.len(), &format!("{width}-byte noise, byte {i}"));
        }
    }
}

/// The vector decoders' rounded mean of three predictions (AVX-512 and
/// AVX2, where the CPU has them) is exact for every t that decoded 8- and
/// 16-bit elements give (−3·65535 to 6·65535), and a little past.
#[cfg(target_arch = "x86_64")]
#[test]
fn vector_mean_of_three_is_exact() {
    use std::arch::x86_64::{__m256i, __m512i};
    #[target_feature(enable = "avx512f")]
    fn wide(t: [i32; 16]) -> [i32; 16] {
        // SAFETY: called only where the CPU has AVX-512 F; `mean3` touches no memory.
        unsafe { std::mem::transmute(avx512::mean3(std::mem::transmute::<[i32; 16], __m512i>(t))) }
    }
    #[target_feature(enable = "avx2,fma")]
    fn narrow(t: [i32; 8]) -> [i32; 8] {
        // SAFETY: called only where the CPU has AVX2 and FMA; `mean3` touches no memory.
        unsafe { std::mem::transmute(avx2::mean3(std::mem::transmute::<[i32; 8], __m256i>(t))) }
    }
    let (low, high) = (-3 * 65536 - 1, 6 * 65535 + 4096);
    let check = |first: i32, got: &[i32]| {
        for (t, &got) in (first..).zip(got) {
            assert_eq!(got, (t + 1).div_euclid(3), "t = {t}");
        }
    };
    if is_x86_feature_detected!("avx512f") {
        for first in (low..=high).step_by(16) {
            // SAFETY: the CPU has AVX-512 F.
            check(first, &unsafe { wide(std::array::from_fn(|i| first + i as i32)) });
        }
    }
    if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
        for first in (low..=high).step_by(8) {
            // SAFETY: the CPU has AVX2 and FMA.
            check(first, &unsafe { narrow(std::array::from_fn(|i| first + i as i32)) });
        }
    }
}

/// A stream from its parts: `lanes` lanes, every used context's row given
/// (frequencies summing to 2^9), `divisors` (width 1), escape bits and words.
fn stream(lanes: usize, rows: &[(usize, Vec<u16>)], divisors: &[u8], bits: &[u8], words: &[u16]) -> Vec<u8> {
    let symbols = rows.iter().map(|r| r.1.len()).max().unwrap_or(1);
    let mut side = divisors.to_vec();
    for ctx in 0..CONTEXTS {
        let row = rows.iter().find(|r| r.0 == ctx).map(|r| r.1.clone()).unwrap_or_default();
        (0..symbols).for_each(|s| side.extend_from_slice(&row.get(s).copied().unwrap_or(0).to_le_bytes()));
    }
    let side = zstd::bulk::compress(&side, 3).unwrap();
    let mut out = Vec::new();
    for v in [lanes, 9, symbols, side.len(), bits.len(), words.len()] {
        out.extend_from_slice(&(v as u32).to_le_bytes());
    }
    out.extend_from_slice(&side);
    out.extend_from_slice(bits);
    words.iter().for_each(|w| out.extend_from_slice(&w.to_le_bytes()));
    out
}

/// Every decoder refuses what the scalar one and the spec refuse, where a
/// vector decoder could otherwise go its own way.
#[test]
fn what_the_spec_refuses_every_decoder_refuses() {
    let len = TILE + 1;
    // A lane with no tile keeps its first state, which must be the coder's: here it is 1,
    // and a word follows that a lane renormalising it would take (to 2^16).
    let raw = section(1, 1, 5);
    let good = encode(&raw, 1, 3, None).unwrap().unwrap();
    assert_eq!(decoded(&good, 1, raw.len(), Decoder::Scalar).unwrap(), raw);
    let lanes = u32::from_le_bytes(good[0..4].try_into().unwrap()) as usize;
    let words_at = good.len() - 2 * u32::from_le_bytes(good[20..24].try_into().unwrap()) as usize;
    let mut bad = good[..words_at].to_vec();
    let mut words: Vec<u16> = good[words_at..].chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
    (words[2], words[3]) = (0, 1);
    words.insert(2 * lanes, 0);
    bad[20..24].copy_from_slice(&(words.len() as u32).to_le_bytes());
    words.iter().for_each(|w| bad.extend_from_slice(&w.to_le_bytes()));
    for d in decoders() {
        assert!(decoded(&bad, 1, raw.len(), d).is_err(), "{d:?} took words for a lane without a tile");
    }
    // Symbol 47 (31 escape bits, all ones) in the first element's context (class 0, bucket 0):
    // its value is 2^32 + 14, outside every element; 32-bit arithmetic would wrap it into one.
    let mut row = vec![0u16; 48];
    row[47] = 512;
    let states: Vec<u16> = (0..16).flat_map(|_| [1u16, 0]).collect();
    let s = stream(16, &[(0, row)], &[1], &[0xff; 8], &states);
    for d in decoders() {
        let got = decoded(&s, 1, len, d);
        assert!(got.is_err(), "{d:?}: {got:?}");
    }
}

#[test]
fn lying_headers_are_refused() {
    let raw = section(5, 1, 3);
    let stored = encode(&raw, 1, 3, None).unwrap().unwrap();
    for (field, value) in [(0, 0u32), (0, 1000), (1, 8), (1, 13), (2, 0), (2, 49), (3, u32::MAX), (4, 1 << 30), (5, 3)] {
        let mut bad = stored.clone();
        bad[4 * field..4 * field + 4].copy_from_slice(&value.to_le_bytes());
        assert!(decoded(&bad, 1, raw.len(), Decoder::Scalar).is_err(), "field {field} = {value}");
    }
}

#[test]
fn elements_take_the_prediction_within_their_bounds_and_cost_the_coder_less() {
    // A ramp shown in a corner of the tile; the rest hidden, first as 0.
    let ramp: [u16; TILE] = std::array::from_fn(|v| (10 + 3 * (v & 7) + 2 * ((v >> 3) & 7) + (v >> 6)) as u16);
    let hidden = |v: usize| (v & 7) >= 4 || (v >> 6) >= 5;
    let zero: [u16; TILE] = std::array::from_fn(|v| if hidden(v) { 0 } else { ramp[v] });
    let mut filled = zero;
    nearest_predicted(&mut filled, |v| if hidden(v) { (0, 100) } else { (ramp[v], ramp[v]) });
    // Hidden elements cost a residual of 0, and shown ones are as they were.
    let t = tokens(&filled, &[0; 8], UNBOUNDED);
    assert!((0..TILE).filter(|&v| hidden(v)).all(|v| t[v].sym == 0));
    assert!((0..TILE).filter(|&v| !hidden(v)).all(|v| filled[v] == ramp[v]));
    assert!(tile_bits(&filled) < tile_bits(&zero), "{} against {} bits", tile_bits(&filled), tile_bits(&zero));
    // The prediction is clamped to the bounds.
    let mut low = zero;
    nearest_predicted(&mut low, |v| if hidden(v) { (0, 20) } else { (ramp[v], ramp[v]) });
    assert!((0..TILE).filter(|&v| hidden(v)).all(|v| low[v] <= 20));
    assert!((0..TILE).filter(|&v| hidden(v)).any(|v| low[v] == 20), "the ramp passes 20 in the hidden part");
    // A ramp with noise of up to 2, each element free within ±1 of it: less than half the bits.
    let mut seed = 7u32;
    let noisy: [u16; TILE] = std::array::from_fn(|v| {
        seed = seed.wrapping_mul(1_103_515_245).wrapping_add(12_345);
        ramp[v] + ((seed >> 16) % 3) as u16
    });
    let mut free = noisy;
    nearest_predicted(&mut free, |v| (noisy[v] - 1, noisy[v] + 1));
    assert!((0..TILE).all(|v| free[v].abs_diff(noisy[v]) <= 1));
    assert!(tile_bits(&free) < tile_bits(&noisy) / 2.0, "{} against {} bits", tile_bits(&free), tile_bits(&noisy));
}

#[test]
fn frequencies_quantise_to_their_total() {
    let mut counts = vec![[0u64; MAX_SYMBOLS]; 3];
    counts[0][0] = 1_000_000;
    counts[0][5] = 1;
    (0..MAX_SYMBOLS).for_each(|s| counts[1][s] = 1 + s as u64 * 1000);
    let q = quantise(&counts, PRECISION);
    for (row, c) in q.iter().zip(&counts) {
        let sum: u32 = row.iter().sum();
        assert!(sum == 1 << PRECISION || (sum == 0 && c.iter().all(|&c| c == 0)));
        assert!(row.iter().zip(c).all(|(&f, &c)| (f > 0) == (c > 0)));
    }
}

/// Not a check but a measurement: every decoder this CPU runs on the context-coded sections of the
/// asset `VPAK_CONTEXT_BENCH` names, best of 7 passes (each over the sections again until it
/// has decoded 20 MB, so that a small asset is not timed on a millisecond), one thread:
/// `VPAK_CONTEXT_BENCH=A.vpak cargo test --release -p vdbcook-vpak context::tests::decoder_speed -- --ignored --nocapture`.
#[test]
#[ignore]
fn decoder_speed() {
    let Ok(path) = std::env::var("VPAK_CONTEXT_BENCH") else { return };
    let asset = crate::Asset::open(std::path::Path::new(&path)).unwrap();
    let mut streams = Vec::new();
    for s in 0..asset.segment_count() {
        let seg = asset.stored_segment(s).unwrap();
        let Ok(table) = seg.section(crate::kind::CODING, 0) else { continue };
        let restored = seg.restored().unwrap();
        let find = |k: u32, i: u32| restored.section(k, i).ok();
        for c in crate::coding::Coding::parse_all(table).unwrap().into_iter().filter(|c| matches!(c.scheme, crate::coding::SCHEME_CONTEXT | crate::coding::SCHEME_SHOWN)) {
            let stored = seg.section(c.kind, c.index).unwrap().to_vec();
            let w = c.filter.code().1 as usize;
            let n = c.raw_size as usize + c.raw_size as usize / TILE;
            let shown = (c.scheme == crate::coding::SCHEME_SHOWN).then(|| crate::coding::shown_of(&[c], None, &find).unwrap().remove(0));
            streams.push((stored, w, n, shown));
        }
    }
    let bytes: usize = streams.iter().map(|s| s.2).sum();
    for d in decoders() {
        let rate = best_rate(bytes, || {
            for (stored, w, n, shown) in &streams {
                std::hint::black_box(decoded_shown(stored, *w, *n, d, shown.as_deref()).unwrap());
            }
        });
        println!("{d:?} decoder: {} sections, {:.1} MB of filtered elements, {rate:.0} MB/s", streams.len(), bytes as f64 / 1e6);
    }
}

/// For the decoders' measurements: MB/s of `pass` (which handles `bytes`),
/// the best of 7 timings, each of `pass` repeated to about 20 MB so that a
/// small asset is not timed on a millisecond.
pub(crate) fn best_rate(bytes: usize, mut pass: impl FnMut()) -> f64 {
    let repeats = (20_000_000 / bytes.max(1)).max(1);
    let mut best = f64::MAX;
    for _ in 0..7 {
        let t = std::time::Instant::now();
        (0..repeats).for_each(|_| pass());
        best = best.min(t.elapsed().as_secs_f64() / repeats as f64);
    }
    bytes as f64 / 1e6 / best
}
