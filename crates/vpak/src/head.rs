//! The header and tables of a file or of a body, checked from their bytes
//! alone (no section's bytes but the coding section's): what [`crate::Asset`]
//! runs over a mapping and the runtime reader over small positioned reads.

use crate::segments::{self, SegmentEntry};
use crate::{header_checksum, Error, SectionEntry, ALIGN, HEADER_LEN, MAGIC};
use std::borrow::Cow;

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b.get(o..o + 4).and_then(|s| s.try_into().ok()).unwrap_or([0; 4]))
}

fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b.get(o..o + 8).and_then(|s| s.try_into().ok()).unwrap_or([0; 8]))
}

/// The version field of a header (`header`: at least its first
/// [`HEADER_LEN`] bytes) of a file or body of `len` bytes, after the magic
/// and the size field are checked.
pub(crate) fn version(header: &[u8], len: u64) -> Result<u32, Error> {
    if header.len() < HEADER_LEN || header[..8] != MAGIC {
        return Err(Error::Magic);
    }
    let size = u64_at(header, 24);
    if size != len {
        return Err(Error::Size { expected: size, actual: len });
    }
    Ok(u32_at(header, 8))
}

/// Bytes of the table after `header` (entries of `entry_len` bytes, as many
/// as its count field says): refused with `count_error` past `max` entries
/// or past the `len` bytes of the file or body.
pub(crate) fn table_len(header: &[u8], entry_len: usize, max: u32, count_error: fn(u32) -> Error, len: u64) -> Result<usize, Error> {
    let n = u32_at(header, 16);
    (n as usize).checked_mul(entry_len).filter(|&t| n <= max && (HEADER_LEN as u64).saturating_add(t as u64) <= len).ok_or(count_error(n))
}

/// Checks the header checksum over the header's first 32 bytes and the table.
pub(crate) fn check_checksum(header: &[u8], table: &[u8]) -> Result<(), Error> {
    let computed = header_checksum(header.get(..32).unwrap_or_default(), table);
    let stored = u64_at(header, 32);
    if stored != computed {
        return Err(Error::HeaderChecksum { stored, computed });
    }
    Ok(())
}

/// A body's section table (`table`, of a body of `len` bytes, of a file of
/// version `version`): each section inside the body after the table, at a
/// multiple of 256 (the coding section and those it names: of 8; in a
/// version-11 body with a coding section, every section: of 8), none listed
/// twice, a coding section only from version 8 and a context-coded one only
/// from version 11, an `l3 nodes` one only from version 12; a body at
/// `at` bytes into its file (0 for a body on its own) off a multiple of 256
/// only when it has a coding section (version 12). `coding` gives a coding
/// section's bytes (which say which sections it names).
pub(crate) fn sections<'a>(table: &[u8], len: u64, version: u32, at: u64, mut coding: impl FnMut(&SectionEntry) -> Result<Cow<'a, [u8]>, Error>) -> Result<Vec<SectionEntry>, Error> {
    let table_end = (HEADER_LEN + table.len()) as u64;
    let mut sections = Vec::with_capacity(table.len() / crate::ENTRY_LEN);
    for e in table.chunks_exact(crate::ENTRY_LEN) {
        let s = SectionEntry { kind: u32_at(e, 0), index: u32_at(e, 4), offset: u64_at(e, 8), size: u64_at(e, 16), checksum: u64_at(e, 24) };
        let end = s.offset.checked_add(s.size);
        if !s.offset.is_multiple_of(crate::CODED_ALIGN as u64) || s.offset < table_end || end.is_none_or(|e| e > len) {
            return Err(Error::SectionBounds { kind: s.kind, index: s.index, offset: s.offset, size: s.size });
        }
        sections.push(s);
    }
    // Every section at a multiple of 256 but the coding section and those it names (at a multiple
    // of 8); in a version-11 body with a coding section, every section at a multiple of 8.
    let mut codings = Vec::new();
    for e in sections.iter().filter(|e| e.kind == crate::kind::CODING) {
        codings.push((e.kind, e.index, coding(e)?));
    }
    // What the file's version allows is said first: a newer body's layout is not a misalignment.
    if version < segments::VERSION_8 && !codings.is_empty() {
        return Err(Error::Invalid(format!("a supercompressed section in a file older than version {}", segments::VERSION_8)));
    }
    if !at.is_multiple_of(ALIGN as u64) && codings.is_empty() {
        return Err(Error::Invalid(format!("a body at byte {at} without a coding section (such a body starts at a multiple of {ALIGN})")));
    }
    // The records, parsed once (a table that does not parse is refused when the body is restored).
    let records: Vec<crate::coding::Coding> = codings.iter().flat_map(|(_, _, b)| crate::coding::Coding::parse_all(b).unwrap_or_default()).collect();
    if let Some(c) = records.iter().find(|c| c.scheme == crate::coding::SCHEME_CONTEXT && version < segments::VERSION_11) {
        return Err(Error::Coding { kind: c.kind, index: c.index, problem: format!("is context-coded in a version-{version} file (context coding is version {})", segments::VERSION_11) });
    }
    if let Some(c) = records.iter().find(|c| c.filter == crate::coding::Filter::L3Nodes && version < segments::VERSION_12) {
        return Err(Error::Coding { kind: c.kind, index: c.index, problem: format!("is filtered as l3 nodes in a version-{version} file (that filter is version {})", segments::VERSION_12) });
    }
    if let Some(c) = records.iter().find(|c| c.scheme == crate::coding::SCHEME_MASKS && version < segments::VERSION_14) {
        return Err(Error::Coding { kind: c.kind, index: c.index, problem: format!("is mask-coded in a version-{version} file (mask coding is version {})", segments::VERSION_14) });
    }
    if let Some(c) = records.iter().find(|c| c.scheme == crate::coding::SCHEME_SHOWN && version < segments::VERSION) {
        return Err(Error::Coding { kind: c.kind, index: c.index, problem: format!("is coded over its shown voxels in a version-{version} file (that coding is version {})", segments::VERSION) });
    }
    // The sections at multiples of 8 in a version-8 to 10 body: the coding section and those it names.
    let coded_set: std::collections::HashSet<(u32, u32)> = codings.iter().map(|(k, i, _)| (*k, *i)).chain(records.iter().map(|c| (c.kind, c.index))).collect();
    let packed = version >= segments::VERSION_11 && !codings.is_empty();
    if let Some(s) = sections.iter().find(|s| !packed && !coded_set.contains(&(s.kind, s.index)) && !s.offset.is_multiple_of(ALIGN as u64)) {
        return Err(Error::SectionBounds { kind: s.kind, index: s.index, offset: s.offset, size: s.size });
    }
    // One section per (kind, index): a reader must not have to pick.
    let mut keys: Vec<(u32, u32)> = sections.iter().map(|s| (s.kind, s.index)).collect();
    keys.sort_unstable();
    if let Some(w) = keys.windows(2).find(|w| w[0] == w[1]) {
        return Err(Error::DuplicateSection { kind: w[0].0, index: w[0].1 });
    }
    Ok(sections)
}

/// A file's segment table (`table`, of a file of `len` bytes and version
/// `version`): at least one segment, each body in order, inside the file
/// after the table at a multiple of 256 (version 12: of 8, [`sections`]
/// checking that such a body has a coding section), frames counted on from
/// 0 without a gap.
pub(crate) fn segments(table: &[u8], len: u64, version: u32) -> Result<Vec<SegmentEntry>, Error> {
    if table.is_empty() {
        return Err(Error::SegmentCount(0));
    }
    let entries: Vec<SegmentEntry> = table.chunks_exact(segments::SEGMENT_ENTRY_LEN).map(SegmentEntry::parse).collect();
    let align = segments::body_align(version);
    let mut at = (HEADER_LEN + table.len()) as u64;
    let mut frame = 0u64;
    for (s, e) in entries.iter().enumerate() {
        let end = e.offset.checked_add(e.size);
        if !e.offset.is_multiple_of(align) || e.offset < at || end.is_none_or(|end| end > len) || e.size < HEADER_LEN as u64 {
            return Err(Error::SegmentBounds { segment: s, offset: e.offset, size: e.size });
        }
        if u64::from(e.first_frame) != frame {
            return Err(Error::Invalid(format!("segment {s} starts at frame {}, the segments before it end at frame {frame}", e.first_frame)));
        }
        frame += u64::from(e.frame_count);
        at = e.offset + e.size;
    }
    if frame > u64::from(u32::MAX) {
        return Err(Error::Invalid("more than 2^32 frames".into()));
    }
    Ok(entries)
}

/// A segment's body header: version 6, or the error a reader gives.
pub(crate) fn body_version(header: &[u8], len: u64) -> Result<(), Error> {
    match version(header, len)? {
        segments::BODY_VERSION => Ok(()),
        v => Err(Error::Invalid(format!("a body of version {v} (segments are version {})", segments::BODY_VERSION))),
    }
}
