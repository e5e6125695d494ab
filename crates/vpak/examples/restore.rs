//! Times restoring an asset's supercompressed segments (decompression and
//! unfiltering, as a reader does before upload), for `scripts/bench_disk.py`:
//!
//!     restore ASSET [FRAMES_OUT]
//!
//! Prints one JSON line: the restored bytes of the compressed sections (of a
//! segment stored wrapped in one zstd frame, version 13: the body the frame
//! holds, with its own compressed sections restored), their stored bytes, and
//! the seconds one restore of every segment (unwrapping included) takes, each
//! segment restored into the memory of the one before as the runtime's
//! reader does (`seconds`) or into fresh memory (`seconds_fresh`): the best
//! of three passes, each restoring the asset again until about 100 MB are
//! restored (as `zstd -d` is timed on the frames repeated to about 100 MB), so
//! that a small asset is not timed on one cold millisecond. With FRAMES_OUT,
//! also writes the compressed sections' zstd frames one after the other (what
//! `zstd -d` is timed on, the same bytes: a wrapped body's frame, then the frames
//! of the sections compressed inside it; a context-coded section as the
//! zstd frame of the same filtered bytes at level 19). Run with `RAYON_NUM_THREADS=1` for one core.

use std::io::Write;
use vdbcook_vpak::coding::{self, Coding};
use vdbcook_vpak::{kind, Asset};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let asset = Asset::open(std::path::Path::new(args.get(1).ok_or("usage: restore ASSET [FRAMES_OUT]")?))?;
    let segments: Vec<Asset> = (0..asset.segment_count()).map(|s| asset.stored_segment(s)).collect::<Result<_, _>>()?;
    let (mut raw, mut stored) = (0u64, 0u64);
    let mut frames = Vec::new();
    for (s, seg) in segments.iter().enumerate() {
        if asset.is_wrapped(s) {
            let frame = asset.stored_bytes(s)?;
            (raw, stored) = (raw + seg.bytes().len() as u64, stored + frame.len() as u64);
            frames.extend_from_slice(frame);
        }
        let Ok(table) = seg.section(kind::CODING, 0) else { continue };
        // The segment restored, for the coded sections' bytes (a scheme-4 atlas takes the others').
        let restored = seg.restored()?;
        for c in Coding::parse_all(table)? {
            let b = seg.section(c.kind, c.index)?;
            // Inside a wrapped body, the frame's bytes are counted already.
            match asset.is_wrapped(s) {
                true => raw += c.raw_size - b.len() as u64,
                false => (raw, stored) = (raw + c.raw_size, stored + b.len() as u64),
            }
            match c.scheme {
                // A context- or mask-coded section as zstd would store it (level 19, the same filter).
                coding::SCHEME_CONTEXT | coding::SCHEME_MASKS | coding::SCHEME_SHOWN => frames.extend_from_slice(&coding::zstd_frame(&c, restored.section(c.kind, c.index)?, 19)?),
                _ => frames.extend_from_slice(b),
            }
        }
    }
    if let Some(out) = args.get(2) {
        std::fs::File::create(out)?.write_all(&frames)?;
    }
    // As the runtime's reader restores a sequence: each segment into the
    // words of the one before (memory already touched); and, for
    // comparison, each into fresh memory. A wrapped segment is unwrapped
    // each time (a plain one is used as it was parsed).
    let stored_segment = |s: usize| match asset.is_wrapped(s) {
        true => asset.stored_segment(s),
        false => Ok(segments[s].clone()),
    };
    let mut buf = Vec::new();
    let (mut best, mut best_fresh) = (f64::MAX, f64::MAX);
    // An asset with nothing supercompressed is timed once (the benchmark says so).
    let repeats = match raw {
        0 => 1,
        _ => (100_000_000 / raw).clamp(1, 100_000),
    };
    for _ in 0..3 {
        let t = std::time::Instant::now();
        for _ in 0..repeats {
            for s in 0..segments.len() {
                let restored = stored_segment(s)?.restored_into(std::mem::take(&mut buf))?;
                buf = std::hint::black_box(restored).into_words().unwrap_or_default();
            }
        }
        best = best.min(t.elapsed().as_secs_f64() / repeats as f64);
        let t = std::time::Instant::now();
        for _ in 0..repeats {
            for s in 0..segments.len() {
                std::hint::black_box(stored_segment(s)?.restored()?);
            }
        }
        best_fresh = best_fresh.min(t.elapsed().as_secs_f64() / repeats as f64);
    }
    println!("{{\"restored_bytes\": {raw}, \"stored_bytes\": {stored}, \"seconds\": {best}, \"seconds_fresh\": {best_fresh}}}");
    Ok(())
}
