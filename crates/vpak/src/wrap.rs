//! Version 13: a small supercompressed body stored whole as one zstd frame
//! (a *wrapped* body). A body's fixed bytes (header, section table,
//! metadata, coding records, a zstd frame per small section) are most of a
//! small asset; in one frame they are compressed together.

use crate::coding::{self, Coding, SCHEME_ZSTD};
use crate::{kind, Error, Section, HEADER_LEN};

/// The first bytes of a zstd frame (RFC 8878); a body starts with [`crate::MAGIC`].
pub const ZSTD_MAGIC: [u8; 4] = [0x28, 0xB5, 0x2F, 0xFD];
/// A body stored in at most this many bytes is tried wrapped.
pub const WRAP_LIMIT: u64 = 64 << 10;
/// The most bytes a wrapped body's frame may take, and that it may restore
/// to (format.md); more is refused before anything is allocated for it.
pub const MAX_WRAPPED: usize = 1 << 20;
/// Inside a wrapped body, a zstd-coded section of at most this many restored
/// bytes is stored as it is (the frame compresses it with the rest); larger
/// ones, and context-coded ones, keep their coding.
const PLAIN_LIMIT: u64 = 4 << 10;
/// The frame's level: a wrapped body is small, so this costs milliseconds.
const LEVEL: i32 = 19;

/// Whether a segment's stored bytes are a wrapped body.
pub fn is_wrapped(stored: &[u8]) -> bool {
    stored.starts_with(&ZSTD_MAGIC)
}

/// The body of `sections` (supercompressed: with a coding section, and
/// stored in at most [`WRAP_LIMIT`] bytes; or `was_wrapped`, the inside of a
/// wrapped body, whose small sections are plain) as one zstd frame, when that
/// is smaller than the body as it is; `None` for a body stored plainly or
/// too large.
pub(crate) fn wrap(sections: &[Section], was_wrapped: bool) -> Result<Option<Vec<u8>>, Error> {
    let stored = crate::file_len(sections);
    let coding_section = sections.iter().find(|s| s.kind == kind::CODING);
    if !was_wrapped && (stored > WRAP_LIMIT || coding_section.is_none()) {
        return Ok(None);
    }
    let records = coding_section.map_or(Ok(Vec::new()), |c| Coding::parse_all(&c.data))?;
    let mut kept = Vec::new();
    let mut inner = Vec::with_capacity(sections.len());
    for s in sections.iter().filter(|s| s.kind != kind::CODING) {
        let data = match records.iter().find(|c| (c.kind, c.index) == (s.kind, s.index)) {
            Some(c) if c.scheme == SCHEME_ZSTD && c.raw_size <= PLAIN_LIMIT => coding::restore(c, &s.data)?,
            Some(c) => {
                kept.extend_from_slice(&c.bytes());
                s.data.to_vec()
            }
            None => s.data.to_vec(),
        };
        inner.push(Section { kind: s.kind, index: s.index, data: data.into() });
    }
    if !kept.is_empty() {
        inner.push(Section { kind: kind::CODING, index: 0, data: kept.into() });
    }
    let body = crate::assemble(&inner);
    if body.len() > MAX_WRAPPED {
        return Ok(None);
    }
    // The frame states its content size (zstd's default), which readers check before they decompress.
    let frame = zstd::bulk::compress(&body, LEVEL)?;
    Ok(Some(frame).filter(|f| (f.len() as u64) < stored && (HEADER_LEN..=MAX_WRAPPED).contains(&f.len())))
}

/// Refuses a wrapped body's frame of `len` bytes before it is read: over [`MAX_WRAPPED`].
pub(crate) fn check_frame_len(len: u64) -> Result<(), Error> {
    match len <= MAX_WRAPPED as u64 {
        true => Ok(()),
        false => Err(Error::Invalid(format!("its body is wrapped in a zstd frame of {len} bytes (at most {MAX_WRAPPED})"))),
    }
}

/// The error for a wrapped body in a file of `segments` segments (only a
/// file of one segment may wrap its body: a streaming reader opens a
/// sequence on each body's head alone).
pub(crate) fn among_segments(segments: usize) -> Error {
    Error::Invalid(format!("its body is wrapped in a zstd frame in a file of {segments} segments (only a file of one segment wraps its body)"))
}

/// A wrapped body's frame decompressed: the body in 8-byte words and its
/// length. Refused before anything is allocated: a frame over
/// [`MAX_WRAPPED`] bytes, anything but one zstd frame, one that does not
/// state its content size or states more than [`MAX_WRAPPED`]; then one that
/// does not decompress to exactly the size it states.
pub(crate) fn unwrap(stored: &[u8]) -> Result<(Vec<u64>, usize), Error> {
    check_frame_len(stored.len() as u64)?;
    let bad = |problem: String| Error::Invalid(format!("its body is wrapped in a zstd frame that {problem}"));
    if zstd::zstd_safe::find_frame_compressed_size(stored) != Ok(stored.len()) {
        return Err(bad("is not one frame with nothing after it".into()));
    }
    let len = match zstd::zstd_safe::get_frame_content_size(stored) {
        Ok(Some(n)) if n <= MAX_WRAPPED as u64 => n as usize,
        Ok(Some(n)) => return Err(bad(format!("states {n} bytes of content (at most {MAX_WRAPPED})"))),
        _ => return Err(bad("does not state its content size".into())),
    };
    let mut words = vec![0u64; len.div_ceil(8)];
    let out = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..len];
    match coding::decompress_into(stored, out) {
        Ok(got) if got == len => Ok((words, len)),
        Ok(got) => Err(bad(format!("decompresses to {got} bytes, not the {len} it states"))),
        Err(e) => Err(bad(format!("does not decompress to the {len} bytes it states ({e})"))),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::segments::tests::{body, meta};
    use crate::segments::{assemble_segments, assemble_unwrapped, SegmentEntry, Writer, VERSION_12};
    use crate::{checksum, Asset};

    /// `n` bytes zstd cannot shrink much.
    fn noise(n: usize) -> Vec<u8> {
        let mut x = 0x9E3779B97F4A7C15u64;
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 56) as u8
            })
            .collect()
    }

    /// A body of two frames with 4 KiB of L2 entries and 2 KiB of L3 words,
    /// supercompressed at level 3.
    pub(crate) fn coded() -> Vec<Section> {
        let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        let mut b = body(&m, 1);
        b.push(Section { kind: kind::L2_ENTRIES, index: 0, data: (0..1024u32).flat_map(|i| (i / 5).to_le_bytes()).collect::<Vec<u8>>().into() });
        b.push(Section { kind: kind::L3_NODES, index: 0, data: (0..512u32).flat_map(|i| (i % 7).to_le_bytes()).collect::<Vec<u8>>().into() });
        crate::coding::supercompress(b, &m, crate::coding::Schemes { level: 3, context: false }).unwrap()
    }

    /// A one-segment file of two frames whose body is the stored bytes `frame`.
    fn file_of(frame: &[u8]) -> Vec<u8> {
        let mut w = Writer::new(std::io::Cursor::new(Vec::new()), 1).unwrap();
        let e = SegmentEntry { first_frame: 0, frame_count: 2, offset: 0, size: frame.len() as u64, head_checksum: checksum(frame) };
        w.copy_body(&e, frame, true).unwrap();
        w.finish().unwrap().into_inner()
    }

    #[test]
    fn a_small_supercompressed_body_is_wrapped_and_restores_the_same_body() {
        let (wrapped, plain) = (assemble_segments(&[(2, coded())]).unwrap(), assemble_unwrapped(&[(2, coded())]).unwrap());
        assert!(wrapped.len() < plain.len(), "{} bytes wrapped, {} not", wrapped.len(), plain.len());
        let (w, p) = (Asset::from_bytes(&wrapped).unwrap(), Asset::from_bytes(&plain).unwrap());
        w.verify().unwrap();
        assert!(w.is_wrapped(0) && !p.is_wrapped(0));
        assert!(w.stored_bytes(0).unwrap().starts_with(&ZSTD_MAGIC));
        assert_eq!(w.metadata().unwrap(), p.metadata().unwrap());
        let (ws, ps) = (w.segment(0).unwrap(), p.segment(0).unwrap());
        assert!(ws.bytes() == ps.bytes(), "the restored bodies differ");
        // Inside, the small sections are stored as they are: the frame compresses them together.
        assert!(!w.stored_segment(0).unwrap().is_coded());
        // A bake's metadata edit keeps the body wrapped, though no coding section is left inside.
        // So does a large one (a bake record's thumbnail): the body inside passes 64 KiB.
        let thumbnail: String = noise(80 << 10).iter().map(|b| char::from(b'a' + b % 26)).collect();
        let edited = crate::segments::rewrite_metadata(&w, |m| m.settings.push(("key".into(), thumbnail.clone()))).unwrap();
        let e = Asset::from_bytes(&edited).unwrap();
        assert!(e.is_wrapped(0) && e.stored_segment(0).unwrap().bytes().len() > WRAP_LIMIT as usize);
        assert_eq!(e.segment(0).unwrap().metadata().unwrap().settings.last(), Some(&("key".to_string(), thumbnail)));
    }

    #[test]
    fn a_plain_or_large_body_is_not_wrapped() {
        let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        assert_eq!(wrap(&body(&m, 1), false).unwrap(), None);
        // 80 KiB of noise beside a section zstd shrinks: supercompressed, but too large.
        let mut b = body(&m, 1);
        b.push(Section { kind: kind::ATLAS, index: 0, data: noise(80 << 10).into() });
        b.push(Section { kind: kind::L2_ENTRIES, index: 0, data: vec![0; 4096].into() });
        let b = crate::coding::supercompress(b, &m, crate::coding::Schemes { level: 3, context: false }).unwrap();
        assert!(b.iter().any(|s| s.kind == kind::CODING) && crate::file_len(&b) > WRAP_LIMIT);
        assert_eq!(wrap(&b, false).unwrap(), None);
        assert!(!Asset::from_bytes(&assemble_segments(&[(2, b)]).unwrap()).unwrap().is_wrapped(0));
    }

    #[test]
    fn a_damaged_wrapped_body_is_refused() {
        let b = assemble_segments(&[(2, coded())]).unwrap();
        let frame = Asset::from_bytes(&b).unwrap().stored_bytes(0).unwrap().to_vec();
        // Every flipped byte but the file header's reserved ones.
        for i in 0..b.len() {
            let mut c = b.clone();
            c[i] ^= 0x10;
            let r = Asset::from_bytes(&c).and_then(|a| a.verify().and_then(|()| a.segment(0)).map(|_| ()));
            assert_eq!(r.is_err(), !(40..HEADER_LEN).contains(&i), "byte {i}");
        }
        let err = |file: Vec<u8>| Asset::from_bytes(&file).unwrap().segment(0).err().unwrap().to_string();
        // Bytes after the frame, a frame cut short (its checksums made good), and one that restores to more than 1 MiB.
        let e = err(file_of(&[frame.as_slice(), &[0; 8]].concat()));
        assert!(e.contains("is not one frame with nothing after it"), "{e}");
        let e = err(file_of(&frame[..frame.len() - 3]));
        assert!(e.contains("wrapped in a zstd frame"), "{e}");
        let mut big = noise(256);
        big.resize(MAX_WRAPPED + 1, 0);
        let e = err(file_of(&zstd::bulk::compress(&big, 3).unwrap()));
        assert!(e.contains(&format!("states {} bytes of content (at most {MAX_WRAPPED})", MAX_WRAPPED + 1)), "{e}");
        // A frame that does not state its size, and one larger than 1 MiB, are refused unread.
        let body = Asset::from_bytes(&b).unwrap().stored_segment(0).unwrap().bytes().to_vec();
        let mut c = zstd::bulk::Compressor::new(3).unwrap();
        c.set_parameter(zstd::zstd_safe::CParameter::ContentSizeFlag(false)).unwrap();
        let e = err(file_of(&c.compress(&body).unwrap()));
        assert!(e.contains("does not state its content size"), "{e}");
        let e = err(file_of(&[frame.as_slice(), &noise(MAX_WRAPPED)].concat()));
        assert!(e.contains(&format!("of {} bytes (at most {MAX_WRAPPED})", frame.len() + MAX_WRAPPED)), "{e}");
        // Only a file of one segment wraps its body.
        let mut w = Writer::new(std::io::Cursor::new(Vec::new()), 2).unwrap();
        for _ in 0..2 {
            let e = SegmentEntry { first_frame: 0, frame_count: 2, offset: 0, size: frame.len() as u64, head_checksum: checksum(&frame) };
            w.copy_body(&e, &frame, true).unwrap();
        }
        let e = err(w.finish().unwrap().into_inner());
        assert!(e.contains("in a file of 2 segments"), "{e}");
        // A version-12 file holds no wrapped body.
        let mut old = b.clone();
        old[8..12].copy_from_slice(&VERSION_12.to_le_bytes());
        let sum = crate::header_checksum(&old[..32], &old[HEADER_LEN..HEADER_LEN + crate::segments::SEGMENT_ENTRY_LEN]);
        old[32..40].copy_from_slice(&sum.to_le_bytes());
        assert!(Asset::from_bytes(&old).unwrap().segment(0).is_err());
    }
}
