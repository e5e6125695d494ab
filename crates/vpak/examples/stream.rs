//! Streams an asset through the runtime reader as an engine's player would
//! (docs/runtime.md walks through it): open, find each frame's segment,
//! size and fill the segment's buffers on a worker thread one segment
//! ahead, and "draw" every frame from the buffers of its segment.
//!
//!     stream ASSET.vpak
//!
//! Prints per segment its frames, GPU bytes and how long playback waited
//! for it, then per section its kind, index, size and FNV-1a-64 hash (as
//! examples/c/vpak_dump.c does); per frame its segment and tree; at the end
//! the bytes read from disk.

use std::sync::Arc;
use vdbcook_vpak::runtime::{Prefetcher, Reader, SectionBuffers};
use vdbcook_vpak::{kind, Error};

/// FNV-1a, 64-bit: a hash anyone can recompute.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: stream ASSET.vpak")?;
    // Reads the header, the segment table and each segment's tables and metadata: not the sections.
    let reader = Arc::new(Reader::open(path.as_ref())?);
    let meta = reader.metadata();
    let channels: Vec<&str> = meta.channels.iter().map(|c| c.name.as_str()).collect();
    println!("{} frames in {} segments; channels {}", reader.frame_count(), reader.segment_count(), channels.join(", "));

    // The worker reads, restores and validates a segment into buffers of
    // the sizes the reader gives; an engine would upload them here too.
    let fill = |r: &Reader, s: usize| -> Result<SectionBuffers, Error> {
        let mut buffers = SectionBuffers::default();
        r.fill_buffers(s, &mut buffers)?;
        Ok(buffers)
    };
    let mut ahead = Prefetcher::new(reader.clone(), fill);
    let mut resident: Option<(usize, SectionBuffers)> = None;
    for frame in 0..reader.frame_count() {
        let (s, local) = reader.locate(frame).ok_or("a frame outside every segment")?;
        if resident.as_ref().is_none_or(|(now, _)| *now != s) {
            // Drop the old segment first: at most this one and the next are held.
            drop(resident.take());
            let got = ahead.take(s)?;
            if s + 1 < reader.segment_count() {
                ahead.request(s + 1);
            }
            let info = reader.segment(s)?;
            println!("segment {s}: frames {:?}, {} GPU bytes, waited {:?}", info.frames(), info.gpu_bytes(), got.waited);
            for (i, section) in info.sections.iter().enumerate() {
                println!("  section {} {} {} {:016x}  {}", section.kind, section.index, section.size, fnv1a(got.value.section(i)), section.label());
            }
            resident = Some((s, got.value));
        }
        // Draw frame `local` of segment `s` from the resident buffers: its
        // tree at the finest stored level starts at the L1 word that frame
        // table entry `local` holds (docs/format.md, "Sections").
        let info = reader.segment(s)?;
        let table = resident.as_ref().map(|(_, b)| b.section(info.section(kind::FRAMES, 0).unwrap_or(usize::MAX))).unwrap_or_default();
        let root = table.get(4 * local..4 * local + 4).ok_or("no frame table entry")?;
        println!("frame {frame}: segment {s}, frame {local}, l1 node at word {}", u32::from_le_bytes([root[0], root[1], root[2], root[3]]));
    }
    println!("read {} bytes", reader.bytes_read());
    Ok(())
}
