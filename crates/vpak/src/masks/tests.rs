use super::*;

/// An L3 array of `n` nodes as the writer lays it out (records, then each
/// node's sub-masks in sub-block order), masks from `mask(node, sub-block)`:
/// 0 is an empty sub-block, all ones a full one, anything else partial.
fn l3_array(n: usize, mask: impl Fn(usize, usize) -> u64) -> Vec<u8> {
    let mut words = vec![n as u32];
    let mut subs = Vec::new();
    for k in 0..n {
        let mut states = 0u32;
        let first = 1 + 3 * n + 2 * subs.len() / 2;
        for b in 0..8 {
            let m = mask(k, b);
            let state = match m {
                0 => 0,
                u64::MAX => FULL,
                _ => PARTIAL,
            };
            states |= state << (2 * b);
            if state == PARTIAL {
                subs.push(m as u32);
                subs.push((m >> 32) as u32);
            }
        }
        words.extend_from_slice(&[k as u32, states, first as u32]);
    }
    words.extend_from_slice(&subs);
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

/// A ball's surface band: the voxels of node k (of 8³ nodes, x slowest)
/// whose distance from the centre is within a shell, as a level set's
/// active band is.
fn shell(k: usize, b: usize) -> u64 {
    let mut m = 0u64;
    for j in 0..64 {
        let x = 8 * (k / 64) + 4 * (b >> 2 & 1) + j / 16;
        let y = 8 * (k / 8 % 8) + 4 * (b >> 1 & 1) + j / 4 % 4;
        let z = 8 * (k % 8) + 4 * (b & 1) + j % 4;
        let d = [x, y, z].iter().map(|&c| (c as f64 - 30.5).powi(2)).sum::<f64>().sqrt();
        if (20.0..22.5).contains(&d) {
            m |= 1 << j;
        }
    }
    m
}

/// The nodes of [`shell`] with a voxel of the band.
fn band() -> Vec<usize> {
    (0..512).filter(|&k| (0..8).any(|b| shell(k, b) != 0)).collect()
}

fn round_trip(filtered: &[u8]) -> Vec<u8> {
    let coded = encode(filtered, 3).unwrap().expect("an L3 array");
    let mut out = vec![0u8; filtered.len()];
    decode(&coded, &mut out).unwrap();
    assert_eq!(out, filtered);
    coded
}

#[test]
fn masks_restore_exactly_and_smaller_than_zstd() {
    let raw = l3_array(512, shell);
    let filtered = crate::l3_filter::apply(&raw);
    let coded = round_trip(&filtered);
    let zstd = zstd::bulk::compress(&filtered, 19).unwrap().len();
    assert!(coded.len() < zstd, "{} bytes coded, zstd {zstd}", coded.len());
    // Random masks, full and empty sub-blocks among them, every context reached.
    let mut next = crate::context::tests::xorshift(0x3a5c);
    let mut word = || u64::from(next()) << 32 | u64::from(next());
    let masks: Vec<u64> = (0..400 * 8)
        .map(|i| match i % 7 {
            0 => 0,
            1 => u64::MAX,
            2 => word() & word(),
            _ => word(),
        })
        .collect();
    round_trip(&crate::l3_filter::apply(&l3_array(400, |k, b| masks[8 * k + b])));
}

#[test]
fn every_lane_count_restores_and_other_layouts_are_not_coded() {
    let nodes = band();
    let raw = l3_array(nodes.len(), |k, b| shell(nodes[k], b));
    let filtered = crate::l3_filter::apply(&raw);
    for lanes in [1, 3, 16, 64] {
        let coded = encode_lanes(&filtered, 3, lanes).unwrap().unwrap();
        let mut out = vec![0u8; filtered.len()];
        decode(&coded, &mut out).unwrap();
        assert_eq!(out, filtered, "{lanes} lanes");
    }
    // No node at all; nodes without sub-masks.
    round_trip(&crate::l3_filter::apply(&l3_array(0, shell)));
    round_trip(&crate::l3_filter::apply(&l3_array(4, |_, b| if b % 2 == 0 { u64::MAX } else { 0 })));
    // Sub-masks past those the states name, fewer, or not whole: not this scheme's.
    let mut more = raw.clone();
    more.extend_from_slice(&0x0123_4567_89ab_cdefu64.to_le_bytes());
    let mut odd = raw.clone();
    odd.extend_from_slice(&[0; 4]);
    for other in [more, raw[..raw.len() - 8].to_vec(), odd] {
        assert!(encode(&crate::l3_filter::apply(&other), 3).unwrap().is_none());
    }
}

#[test]
fn damaged_streams_are_refused_or_restore_other_bytes_without_panic() {
    let nodes = band();
    let filtered = crate::l3_filter::apply(&l3_array(6, |k, b| shell(nodes[k], b)));
    let coded = encode(&filtered, 3).unwrap().unwrap();
    let mut out = vec![0u8; filtered.len()];
    for cut in 0..coded.len() {
        assert!(decode(&coded[..cut], &mut out).is_err(), "cut at {cut}");
    }
    let mut longer = coded.clone();
    longer.push(0);
    assert!(decode(&longer, &mut out).is_err());
    // A flipped bit is refused, or restores bytes the record's checksum then refuses (or,
    // in a part of the side frame zstd does not read, the same bytes).
    let mut refused = 0;
    for i in 0..coded.len() {
        for bit in [0, 3, 7] {
            let mut bad = coded.clone();
            bad[i] ^= 1 << bit;
            refused += usize::from(decode(&bad, &mut out).is_err());
        }
    }
    assert!(refused * 2 > 3 * coded.len(), "{refused} of {} refused", 3 * coded.len());
    // The wrong restored size.
    for len in [filtered.len() - 8, filtered.len() + 8, filtered.len() + 4, 0] {
        let mut other = vec![0u8; len];
        assert!(decode(&coded, &mut other).is_err(), "{len} bytes");
    }
}

#[test]
fn contexts_take_each_neighbour_voxel_count() {
    let context = |a: usize, b: usize| CONTEXT[a * 32 + b];
    assert_eq!(context(0, 0), 0);
    assert_eq!(context(15, 15), 80);
    assert_eq!(context(1, 0), 1);
    assert_eq!(context(8, 8), 54);
    assert_eq!(context(5, 16), 86);
    assert_eq!(context(16, 15), 112);
    assert_eq!(context(16, 16), 113);
}

#[test]
fn the_vector_decoder_gives_the_scalar_ones_bytes_and_refusals() {
    let nodes = band();
    let filtered = crate::l3_filter::apply(&l3_array(nodes.len(), |k, b| shell(nodes[k], b)));
    let run = |d: Decoder, stored: &[u8], len: usize| {
        DECODER.set(Some(d));
        let mut out = vec![0u8; len];
        let r = decode(stored, &mut out).map(|()| out);
        DECODER.set(None);
        r
    };
    let vectors: Vec<Decoder> = [Decoder::Avx2].into_iter().filter(|d| d.usable()).collect();
    if vectors.is_empty() {
        eprintln!("no AVX2 here: the scalar decoder alone");
    }
    for lanes in [1, 5, 16, 64] {
        let coded = encode_lanes(&filtered, 3, lanes).unwrap().unwrap();
        let scalar = run(Decoder::Scalar, &coded, filtered.len());
        assert_eq!(scalar.as_deref(), Ok(&filtered[..]), "{lanes} lanes");
        // Every word near the end of the rANS runs damaged in turn: the same bytes or the same refusal.
        let damaged: Vec<Vec<u8>> = (coded.len() - 2 * 40..coded.len())
            .step_by(2)
            .map(|i| {
                let mut bad = coded.clone();
                bad[i] ^= 0x5a;
                bad
            })
            .collect();
        for &d in &vectors {
            assert_eq!(run(d, &coded, filtered.len()), scalar, "{d:?}, {lanes} lanes");
            for (i, bad) in damaged.iter().enumerate() {
                assert_eq!(run(d, bad, filtered.len()), run(Decoder::Scalar, bad, filtered.len()), "{d:?}, {lanes} lanes, damage {i}");
            }
        }
    }
}

#[test]
fn runs_longer_than_their_rows_can_read_are_refused_before_decoding() {
    let nodes = band();
    let filtered = crate::l3_filter::apply(&l3_array(4, |k, b| shell(nodes[k], b)));
    let coded = encode_lanes(&filtered, 3, 2).unwrap().unwrap();
    let field = |i: usize| u32::from_le_bytes(coded[4 * i..4 * i + 4].try_into().unwrap()) as usize;
    let (side_len, words) = (field(2), field(3));
    let mut side = zstd::bulk::decompress(&coded[HEAD..HEAD + side_len], 1 << 20).unwrap();
    // Lane 0 holds nodes 0 and 2: one word more than 2 + 16 per sub-mask they have.
    let subs: usize = [0, 2].iter().map(|&k| (0..8).filter(|&b| ![0, u64::MAX].contains(&shell(nodes[k], b))).count()).sum();
    let runs = side.len() - 8;
    let r0 = u32::from_le_bytes(side[runs..runs + 4].try_into().unwrap()) as usize;
    let extra = 2 + 16 * subs + 1 - r0;
    side[runs..runs + 4].copy_from_slice(&((r0 + extra) as u32).to_le_bytes());
    let frame = zstd::bulk::compress(&side, 3).unwrap();
    let mut bad = Vec::new();
    [2u32, 9, frame.len() as u32, (words + extra) as u32].iter().for_each(|v| bad.extend_from_slice(&v.to_le_bytes()));
    bad.extend_from_slice(&frame);
    let lane0 = HEAD + side_len + 2 * r0;
    bad.extend_from_slice(&coded[HEAD + side_len..lane0]);
    bad.extend(std::iter::repeat_n(0u8, 2 * extra));
    bad.extend_from_slice(&coded[lane0..]);
    let mut out = vec![0u8; filtered.len()];
    let err = decode(&bad, &mut out).unwrap_err();
    assert!(err.contains("at most 16 per sub-mask"), "{err}");
}

/// Not a check but a measurement: the scalar and (where the CPU has it) the vector decoder on
/// the mask-coded sections of the asset `VPAK_MASKS_BENCH` names, best of 7 passes of about
/// 20 MB of restored L3 bytes each, one thread:
/// `VPAK_MASKS_BENCH=A.vpak cargo test --release -p vdbcook-vpak masks::tests::decoder_speed -- --ignored --nocapture`.
#[test]
#[ignore]
fn decoder_speed() {
    let Ok(path) = std::env::var("VPAK_MASKS_BENCH") else { return };
    let asset = crate::Asset::open(std::path::Path::new(&path)).unwrap();
    let mut streams = Vec::new();
    for s in 0..asset.segment_count() {
        let seg = asset.stored_segment(s).unwrap();
        let Ok(table) = seg.section(crate::kind::CODING, 0) else { continue };
        for c in crate::coding::Coding::parse_all(table).unwrap().into_iter().filter(|c| c.scheme == crate::coding::SCHEME_MASKS) {
            streams.push((seg.section(c.kind, c.index).unwrap().to_vec(), c.raw_size as usize));
        }
    }
    let bytes: usize = streams.iter().map(|s| s.1).sum();
    for d in Decoder::ALL.into_iter().filter(|d| d.usable()) {
        DECODER.set(Some(d));
        let rate = crate::context::tests::best_rate(bytes, || {
            for (stored, n) in &streams {
                let mut out = vec![0u8; *n];
                decode(stored, &mut out).unwrap();
                std::hint::black_box(&out);
            }
        });
        println!("{d:?} decoder: {} sections, {:.2} MB of L3 arrays, {rate:.0} MB/s", streams.len(), bytes as f64 / 1e6);
    }
    DECODER.set(None);
}
