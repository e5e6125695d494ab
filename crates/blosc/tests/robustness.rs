//! Hostile input: truncations, bit flips and overwritten bytes of real
//! c-blosc buffers must give `Err` (or, for harmless changes, `Ok` with
//! exactly the expected length), and never panic.

mod common;

use common::{Rng, Vector, Vectors};
use std::panic::{catch_unwind, AssertUnwindSafe};
use vdbcook_blosc::{decompress, header, Error};

/// Vectors to mutate: for every codec and shuffle, a multi-block split buffer
/// (typesize 4, leftover block) and an unsplit one, plus the odd ones.
fn targets(set: &Vectors) -> Vec<&Vector> {
    let mut out: Vec<&Vector> = set
        .vectors
        .iter()
        .filter(|v| {
            v.c_decodes
                && ((v.dataset == "multi" && v.typesize == 4)
                    || (v.dataset == "smoke" && v.typesize == 8)
                    || v.dataset == "far"
                    || v.dataset == "leaf"
                    || v.dataset == "tiny"
                    || (v.dataset == "mixed" && v.typesize == 2)
                    || (v.dataset == "multi" && v.typesize == 3))
        })
        .collect();
    out.sort_by(|a, b| a.name.cmp(&b.name));
    assert!(out.len() >= 40, "only {} targets", out.len());
    out
}

/// Decodes `src` expecting `len` bytes and, when the header names another
/// small size, that size too. Records panics and wrongly sized results, and
/// returns the first result.
fn probe(v: &Vector, what: &str, src: &[u8], len: usize, failures: &mut Vec<String>) -> Option<Result<Vec<u8>, Error>> {
    let mut first = None;
    let mut sizes = vec![len];
    if let Ok(h) = header(src) {
        if h.nbytes as usize != len && h.nbytes <= 1 << 20 {
            sizes.push(h.nbytes as usize);
        }
    }
    for size in sizes {
        match catch_unwind(AssertUnwindSafe(|| decompress(src, size))) {
            Err(_) => failures.push(format!("{}: panic after {what} (expected len {size})", v.name)),
            Ok(Ok(out)) if out.len() != size => failures.push(format!("{}: {} bytes after {what}, expected {size}", v.name, out.len())),
            Ok(r) => {
                if first.is_none() {
                    first = Some(r);
                }
            }
        }
    }
    first
}

#[test]
fn every_truncation_is_an_error() {
    let set = common::load();
    let mut failures = Vec::new();
    let mut checked = 0;
    for v in targets(&set).into_iter().step_by(3) {
        let src = set.compressed(v);
        for cut in 0..src.len() {
            let prefix = &src[..cut];
            // As is: the header's cbytes now exceeds the input.
            match catch_unwind(AssertUnwindSafe(|| decompress(prefix, v.nbytes))) {
                Err(_) => failures.push(format!("{}: panic at cut {cut}", v.name)),
                Ok(Ok(_)) => failures.push(format!("{}: decoded cut {cut}", v.name)),
                Ok(Err(_)) => {}
            }
            // With cbytes patched to the cut, so the decoder walks the
            // blocks and streams and runs out of data inside them.
            if cut >= 16 {
                let mut patched = prefix.to_vec();
                patched[12..16].copy_from_slice(&(cut as u32).to_le_bytes());
                match catch_unwind(AssertUnwindSafe(|| decompress(&patched, v.nbytes))) {
                    Err(_) => failures.push(format!("{}: panic at patched cut {cut}", v.name)),
                    Ok(Ok(_)) => failures.push(format!("{}: decoded patched cut {cut}", v.name)),
                    Ok(Err(_)) => {}
                }
            }
            checked += 1;
        }
    }
    assert!(checked > 10_000, "only {checked} truncations");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn bit_flips_never_panic() {
    let set = common::load();
    let mut failures = Vec::new();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut probes = 0;
    let mut codec_errors = std::collections::BTreeMap::new();
    for v in targets(&set) {
        let src = set.compressed(v);
        let h = header(src).unwrap();
        let nblocks = if h.blocksize == 0 { 0 } else { (h.nbytes as usize).div_ceil(h.blocksize as usize) };
        // Every bit of the header, the block table and the first stream
        // headers; then random bits elsewhere.
        let dense = (16 + 4 * nblocks + 48).min(src.len());
        let mut positions: Vec<usize> = (0..dense * 8).collect();
        let sparse = (src.len() - dense) * 8;
        for _ in 0..sparse.min(600) {
            positions.push(dense * 8 + rng.below(sparse));
        }
        let mut mutated = src.to_vec();
        for bit in positions {
            mutated[bit / 8] ^= 1 << (bit % 8);
            let r = probe(v, &format!("flipping bit {bit}"), &mutated, v.nbytes, &mut failures);
            if let Some(Err(Error::CorruptStream { codec, .. })) = r {
                *codec_errors.entry(codec.to_string()).or_insert(0usize) += 1;
            }
            mutated[bit / 8] ^= 1 << (bit % 8);
            probes += 1;
        }
    }
    assert!(probes > 20_000, "only {probes} probes");
    // The flips must reach every codec decoder, not only the header checks.
    for codec in ["blosclz", "lz4", "snappy", "zlib", "zstd"] {
        let n = codec_errors.get(codec).copied().unwrap_or(0);
        assert!(n >= 50, "only {n} corrupt-{codec} results: {codec_errors:?}");
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn overwritten_bytes_never_panic() {
    let set = common::load();
    let mut failures = Vec::new();
    let mut rng = Rng(0xD1B5_4A32_D192_ED03);
    for v in targets(&set) {
        let src = set.compressed(v);
        for round in 0..150 {
            let mut mutated = src.to_vec();
            // 1 to 4 random bytes anywhere past the version byte, with
            // interesting values more often than chance.
            for _ in 0..1 + rng.below(4) {
                let at = 1 + rng.below(mutated.len() - 1);
                mutated[at] = match rng.below(4) {
                    0 => 0,
                    1 => 0xFF,
                    2 => 0x80,
                    _ => rng.next() as u8,
                };
            }
            probe(v, &format!("overwrite round {round}"), &mutated, v.nbytes, &mut failures);
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Hand-made headers with hostile numbers.
#[test]
fn hostile_headers_are_refused() {
    fn frame(flags: u8, typesize: u8, nbytes: u32, blocksize: u32, cbytes: u32) -> Vec<u8> {
        let mut f = vec![2, 1, flags, typesize];
        f.extend_from_slice(&nbytes.to_le_bytes());
        f.extend_from_slice(&blocksize.to_le_bytes());
        f.extend_from_slice(&cbytes.to_le_bytes());
        f
    }
    let msg = |r: Result<Vec<u8>, Error>| r.unwrap_err().to_string();

    // Too short for a header.
    assert_eq!(msg(decompress(&[2, 1, 0], 0)), "blosc buffer is 3 bytes, expected at least the 16-byte header");
    // Future format version and reserved flag.
    let mut f = frame(0, 1, 0, 0, 16);
    f[0] = 3;
    assert_eq!(msg(decompress(&f, 0)), "blosc format version 3 is not supported, expected 2");
    assert!(matches!(decompress(&frame(0x08, 1, 0, 0, 16), 0), Err(Error::ReservedFlag { flags: 0x08 })));
    // Empty buffer is fine, and so is an empty memcpyed one.
    assert_eq!(decompress(&frame(0, 1, 0, 0, 16), 0).unwrap(), b"");
    assert_eq!(decompress(&frame(0x02, 1, 0, 0, 16), 0).unwrap(), b"");
    // nbytes beyond i32 and beyond the expected size: refused before
    // anything is allocated.
    assert!(matches!(decompress(&frame(0, 1, u32::MAX, 1, 16), 10), Err(Error::TooLarge { .. })));
    assert_eq!(msg(decompress(&frame(0, 4, 1 << 20, 1 << 16, 1000), 2048)), "blosc header says 1048576 uncompressed bytes, expected 2048");
    // cbytes beyond the input, or below the header size.
    assert_eq!(msg(decompress(&frame(0, 4, 64, 64, 1000), 64)), "blosc header says 1000 compressed bytes, but the input holds only 16");
    assert!(matches!(decompress(&frame(0, 4, 64, 64, 8), 64), Err(Error::CompressedSizeTooSmall { cbytes: 8 })));
    // typesize 0, block size 0 or larger than the buffer.
    assert!(matches!(decompress(&frame(0, 0, 64, 64, 16), 64), Err(Error::ZeroTypesize)));
    assert!(matches!(decompress(&frame(0, 1, 64, 0, 16), 64), Err(Error::InvalidBlockSize { blocksize: 0, max: 64 })));
    assert!(matches!(decompress(&frame(0, 1, 64, 65, 16), 64), Err(Error::InvalidBlockSize { blocksize: 65, .. })));
    // Memcpyed with the wrong cbytes.
    let mut f = frame(0x02, 1, 4, 4, 19);
    f.extend_from_slice(&[1, 2, 3]);
    assert!(matches!(decompress(&f, 4), Err(Error::MemcpySizeMismatch { cbytes: 19, expected: 20 })));
    // Unknown codec and codec version.
    assert!(matches!(decompress(&frame(5 << 5, 1, 64, 64, 16), 64), Err(Error::UnsupportedCodec { code: 5 })));
    let mut f = frame(0, 1, 64, 64, 16);
    f[1] = 2;
    assert!(matches!(decompress(&f, 64), Err(Error::UnsupportedCodecVersion { found: 2, .. })));
    // Block table larger than the buffer: 1 MiB in 1-byte blocks.
    assert!(matches!(decompress(&frame(0, 1, 1 << 20, 1, 20), 1 << 20).unwrap_err(), Error::CompressedSizeExceedsInput { .. }));
    let mut f = frame(0, 1, 1 << 20, 1, 20);
    f.extend_from_slice(&[0; 4]);
    assert!(matches!(decompress(&f, 1 << 20), Err(Error::BlockTableTruncated { nblocks: 1_048_576, cbytes: 20 })));
    // Block start pointing outside the buffer, or negative.
    for start in [-1i32, 21, i32::MAX] {
        let mut f = frame(0, 1, 200, 200, 24);
        f.extend_from_slice(&start.to_le_bytes());
        f.extend_from_slice(&[0; 4]);
        assert!(matches!(decompress(&f, 200), Err(Error::BadBlockStart { .. })), "start {start}");
    }
    // Stream sizes that are negative or too large.
    for size in [-1i32, 1000, i32::MIN] {
        let mut f = frame(FLAG_DONT_SPLIT_BIT, 1, 200, 200, 28);
        f.extend_from_slice(&20i32.to_le_bytes());
        f.extend_from_slice(&size.to_le_bytes());
        f.extend_from_slice(&[0; 4]);
        assert!(matches!(decompress(&f, 200), Err(Error::BadStreamSize { .. })), "size {size}");
    }
    // A raw stream (csize == neblock) decodes; one byte short does not.
    let mut f = frame(FLAG_DONT_SPLIT_BIT, 1, 200, 200, 224);
    f.extend_from_slice(&20i32.to_le_bytes());
    f.extend_from_slice(&200i32.to_le_bytes());
    f.extend((0..200).map(|i| i as u8));
    assert_eq!(decompress(&f, 200).unwrap(), (0..200).map(|i| i as u8).collect::<Vec<_>>());
    f[12..16].copy_from_slice(&223u32.to_le_bytes());
    assert!(decompress(&f, 200).is_err());
    // A split block whose length is not a multiple of typesize.
    let mut f = frame(0, 2, 301, 301, 28);
    f.extend_from_slice(&20i32.to_le_bytes());
    f.extend_from_slice(&[0; 8]);
    assert!(matches!(decompress(&f, 301), Err(Error::UnevenSplit { len: 301, typesize: 2, .. })));
}

const FLAG_DONT_SPLIT_BIT: u8 = vdbcook_blosc::FLAG_DONT_SPLIT;
