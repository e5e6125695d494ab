//! Version 7: an asset cut into segments, runs of consecutive frames each
//! stored as a complete version-6 body (its own metadata, nodes, brick pool,
//! ranges, tables and atlases, contiguous in the file), behind a segment
//! table. A reader draws any frame of a segment from that segment's bytes
//! alone. [`Writer`] writes segments one after the other as a cook finishes
//! them (or copies them from part files, [`Writer::copy_body`]); [`merged`] is the
//! whole sequence's metadata.

use crate::{body_head, checksum, file_len, header_checksum, write_sections, Error, Metadata, Section, ALIGN, HEADER_LEN, MAGIC};
use std::io::{Seek, SeekFrom, Write};

/// Version of a file with a segment table whose bodies may hold
/// supercompressed sections ([`crate::coding`], context-coded ones and L3
/// arrays through the `l3 nodes` filter included), record their frames' time
/// ([`crate::Time`]) and their channels' voxel sizes ([`crate::Resolution`]),
/// small bodies wrapped whole in one zstd frame ([`crate::wrap`]), L3
/// arrays whose sub-masks are mask-coded ([`crate::masks`]), and atlases
/// context-coded over the voxels their nodes show ([`crate::shown`]).
pub const VERSION: u32 = 15;
/// Version of a file whose atlases are never coded over their shown voxels (still read).
pub const VERSION_14: u32 = 14;

/// Whether `v` is the version of a file of segments this crate reads (7 to [`VERSION`]).
pub fn is_container_version(v: u32) -> bool {
    (VERSION_7..=VERSION).contains(&v)
}
/// Version of a file whose L3 arrays are never mask-coded (still read).
pub const VERSION_13: u32 = 13;
/// Version of a file whose bodies are never wrapped (still read).
pub const VERSION_12: u32 = 12;
/// Version of a file whose L3 arrays are not filtered as nodes (still read).
pub const VERSION_11: u32 = 11;
/// Version of a file whose sections are zstd-compressed only (still read).
pub const VERSION_10: u32 = 10;
/// Version of a file whose channels all have the asset's voxels (still read).
pub const VERSION_9: u32 = 9;
/// Version of a file with a segment table and supercompression, without time (still read).
pub const VERSION_8: u32 = 8;
/// Version of a file with a segment table and no supercompression (still read).
pub const VERSION_7: u32 = 7;
/// Version of a segment's body (and of a file that is one body, as version 6 files are).
pub const BODY_VERSION: u32 = 6;
pub const SEGMENT_ENTRY_LEN: usize = 32;
/// Refuse segment tables larger than this (a sanity bound, not a format limit).
pub const MAX_SEGMENTS: u32 = 1 << 20;

/// The first bytes of a part file (`cook --part I/N`): one of N contiguous
/// groups of an asset's segments, cooked apart and joined by `vdbcook join`.
pub const PART_MAGIC: [u8; 8] = *b"VPAKPART";
/// A part file is its header, then (from here) a version-7 file of its segments.
pub const PART_HEADER_LEN: usize = 256;

/// What a part file says of itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PartInfo {
    /// 0 for the first part.
    pub index: u32,
    pub count: u32,
    /// Segments of the whole asset.
    pub segments: u32,
    /// This part's first segment and first frame in the whole asset.
    pub first_segment: u32,
    pub first_frame: u32,
    /// Of the cook as a whole (settings, tool, inputs): parts join only when it is the same.
    pub fingerprint: u64,
}

impl PartInfo {
    fn bytes(&self) -> [u8; PART_HEADER_LEN] {
        let mut h = [0u8; PART_HEADER_LEN];
        h[..8].copy_from_slice(&PART_MAGIC);
        h[8..12].copy_from_slice(&VERSION.to_le_bytes());
        for (i, v) in [self.index, self.count, self.segments, self.first_segment, self.first_frame].iter().enumerate() {
            h[12 + 4 * i..16 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        h[32..40].copy_from_slice(&self.fingerprint.to_le_bytes());
        let sum = checksum(&h[..40]);
        h[40..48].copy_from_slice(&sum.to_le_bytes());
        h
    }

    pub(crate) fn parse(b: &[u8]) -> Result<PartInfo, Error> {
        if b.len() < PART_HEADER_LEN || b[..8] != PART_MAGIC {
            return Err(Error::NotPart);
        }
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap_or([0; 4]));
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap_or([0; 8]));
        if u64_at(40) != checksum(&b[..40]) || b[48..PART_HEADER_LEN].iter().any(|&x| x != 0) {
            return Err(Error::PartChecksum);
        }
        if u32_at(8) != VERSION {
            return Err(Error::Version(u32_at(8)));
        }
        Ok(PartInfo { index: u32_at(12), count: u32_at(16), segments: u32_at(20), first_segment: u32_at(24), first_frame: u32_at(28), fingerprint: u64_at(32) })
    }
}

/// Writes the part header, then gives a writer of the part's segments (`count` of them) after it.
pub fn part_writer<W: Write + Seek>(mut out: W, info: &PartInfo, count: u32) -> Result<Writer<W>, Error> {
    out.seek(SeekFrom::Start(0))?;
    out.write_all(&info.bytes())?;
    // Its body wrapped as one process would wrap it: when the asset is one segment.
    Ok(Writer { wrap: info.segments == 1, ..Writer::at(out, PART_HEADER_LEN as u64, count)? })
}

/// Joins parts (in order: each part's header and its segments as an asset)
/// into one asset written to `out`, copying each segment's bytes once they
/// are checked. `names` name the parts in errors.
pub fn join(parts: &[(PartInfo, crate::Asset)], names: &[String], out: std::fs::File) -> Result<std::fs::File, Error> {
    let Some((first, _)) = parts.first() else { return Err(Error::Join("no parts to join".into())) };
    let bad = |i: usize, why: String| Error::Join(format!("{}: {why}", names.get(i).map_or("a part", |n| n.as_str())));
    if parts.len() as u32 != first.count {
        let have: Vec<String> = parts.iter().map(|(p, _)| format!("{}", p.index + 1)).collect();
        return Err(Error::Join(format!("the asset was cooked in {} parts; {} given (parts {})", first.count, parts.len(), have.join(", "))));
    }
    // Which BC7 kernels wrote each part (a setting every segment records).
    let kernels = |a: &crate::Asset| -> Result<String, Error> {
        let m = a.stored_segment(0)?.metadata()?;
        Ok(m.settings.iter().find(|(k, _)| k == "bc7_kernels").map_or_else(String::new, |(_, v)| v.clone()))
    };
    let first_kernels = kernels(&parts[0].1)?;
    let (mut segment, mut frame) = (0u32, 0u32);
    for (i, (p, asset)) in parts.iter().enumerate() {
        let k = kernels(asset)?;
        if k != first_kernels {
            return Err(bad(i, format!("its BC7 blocks come from {k} kernels, the first part's from {first_kernels}, which write other blocks: cook every part on machines of one kind")));
        }
        if p.fingerprint != first.fingerprint || p.count != first.count || p.segments != first.segments {
            return Err(bad(i, "is a part of another cook (other settings, inputs or vdbcook version) than the first part's".into()));
        }
        if p.index as usize != i {
            return Err(bad(i, format!("is part {} of {}, but part {} belongs here (give the parts in order, each once)", p.index + 1, p.count, i + 1)));
        }
        if (p.first_segment, p.first_frame) != (segment, frame) {
            return Err(bad(i, format!("starts at segment {} (frame {}), but the parts before end at segment {segment} (frame {frame})", p.first_segment, p.first_frame)));
        }
        let table = asset.segments()?;
        segment += table.len() as u32;
        frame += table.last().map_or(0, |e| e.first_frame + e.frame_count);
    }
    if segment != first.segments {
        return Err(Error::Join(format!("the parts hold {segment} segments, the asset has {}", first.segments)));
    }
    let mut w = Writer::new(crate::DirectWriter::new(out)?, segment)?;
    let mut order = Vec::new();
    for (i, (_, asset)) in parts.iter().enumerate() {
        order.extend(asset.segments()?.into_iter().enumerate().map(|(s, e)| (i, s, e)));
    }
    // A thread checks the next segment (read in and checked) while this one
    // copies a checked one from its mapping to the output, whose whole
    // blocks go to disk past the page cache (`DirectWriter`).
    let (to_copy, checked) = std::sync::mpsc::sync_channel::<Result<crate::Asset, Error>>(0);
    std::thread::scope(|scope| {
        let order = &order;
        scope.spawn(move || {
            for &(i, s, _) in order {
                let asset = &parts[i].1;
                let check = asset.stored_segment(s).map_err(|err| bad(i, err.to_string())).and_then(|seg| {
                    seg.populate();
                    seg.verify().map_err(|err| bad(i, Error::InSegment(s, Box::new(err)).to_string()))?;
                    Ok(seg)
                });
                let failed = check.is_err();
                if to_copy.send(check).is_err() || failed {
                    return;
                }
            }
        });
        // Owned here, so that an early return lets the checker go: its next send fails.
        let checked = checked;
        for &(i, s, e) in order {
            let seg = checked.recv().map_err(|_| Error::Join("the segment check stopped".into()))??;
            // As the part stores it: a wrapped body's frame, not the body inside
            // (which only an asset of one segment holds).
            let asset = &parts[i].1;
            if asset.is_wrapped(s) && first.segments > 1 {
                return Err(bad(i, crate::wrap::among_segments(first.segments as usize).to_string()));
            }
            w.copy_body(&e, asset.stored_bytes(s)?, seg.is_coded() || asset.is_wrapped(s))?;
            seg.release();
        }
        Ok::<(), Error>(())
    })?;
    Ok(w.finish()?.into_file()?)
}

/// One entry of the segment table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SegmentEntry {
    /// The segment's first frame, counted over the whole asset.
    pub first_frame: u32,
    pub frame_count: u32,
    /// Where the body lies in the file.
    pub offset: u64,
    pub size: u64,
    /// XXH3-64 of the body's header and section table (which hold every section's checksum).
    pub head_checksum: u64,
}

impl SegmentEntry {
    pub fn frames(&self) -> std::ops::Range<usize> {
        self.first_frame as usize..self.first_frame as usize + self.frame_count as usize
    }

    pub(crate) fn parse(b: &[u8]) -> SegmentEntry {
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap_or([0; 4]));
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap_or([0; 8]));
        SegmentEntry { first_frame: u32_at(0), frame_count: u32_at(4), offset: u64_at(8), size: u64_at(16), head_checksum: u64_at(24) }
    }

    fn bytes(&self) -> [u8; SEGMENT_ENTRY_LEN] {
        let mut e = [0u8; SEGMENT_ENTRY_LEN];
        e[0..4].copy_from_slice(&self.first_frame.to_le_bytes());
        e[4..8].copy_from_slice(&self.frame_count.to_le_bytes());
        e[8..16].copy_from_slice(&self.offset.to_le_bytes());
        e[16..24].copy_from_slice(&self.size.to_le_bytes());
        e[24..32].copy_from_slice(&self.head_checksum.to_le_bytes());
        e
    }
}

/// Length of a body's header and section table.
pub(crate) fn head_len(sections: usize) -> usize {
    HEADER_LEN + crate::ENTRY_LEN * sections
}

fn align(n: u64, to: u64) -> u64 {
    n.div_ceil(to) * to
}

/// The multiple of which a body starts in a file of version `version`: 256
/// before version 12; from 12, 8 (and 256 for a body without a coding
/// section, whose sections a reader may use as they lie in the file).
pub(crate) fn body_align(version: u32) -> u64 {
    match version >= VERSION_12 {
        true => crate::CODED_ALIGN as u64,
        false => ALIGN as u64,
    }
}

/// Where the first segment of a file of `count` segments starts at the
/// latest (a supercompressed body may start sooner).
pub fn first_offset(count: u32) -> u64 {
    align((HEADER_LEN + SEGMENT_ENTRY_LEN * count as usize) as u64, ALIGN as u64)
}

/// Writes a version-7 file of a known number of segments to `out`, segment
/// after segment, then its header and table ([`Writer::finish`]). Nothing
/// but the segment being written is held in memory.
pub struct Writer<W: Write + Seek> {
    out: W,
    /// Where the file starts in `out` (after a part header).
    base: u64,
    count: u32,
    entries: Vec<SegmentEntry>,
    /// Where the next segment starts (unpadded end of the last one).
    end: u64,
    /// Whether a small supercompressed body is stored wrapped ([`crate::wrap`]):
    /// only the body of a file of one segment, so that a reader streaming a
    /// sequence never reads a whole body to open the file.
    wrap: bool,
}

impl<W: Write + Seek> Writer<W> {
    /// Starts a file of `count` segments at the start of `out`.
    pub fn new(out: W, count: u32) -> Result<Writer<W>, Error> {
        Writer::at(out, 0, count)
    }

    /// Starts a file of `count` segments at byte `base` of `out`.
    fn at(mut out: W, base: u64, count: u32) -> Result<Writer<W>, Error> {
        if count == 0 || count > MAX_SEGMENTS {
            return Err(Error::Invalid(format!("{count} segments (need 1 to {MAX_SEGMENTS})")));
        }
        let start = (HEADER_LEN + SEGMENT_ENTRY_LEN * count as usize) as u64;
        out.seek(SeekFrom::Start(base))?;
        write_zeros(&mut out, start)?;
        Ok(Writer { out, base, count, entries: Vec::new(), end: start, wrap: count == 1 })
    }

    /// This writer with every body stored as it is, never wrapped in one
    /// zstd frame (what a version-12 writer wrote).
    pub fn unwrapped(mut self) -> Writer<W> {
        self.wrap = false;
        self
    }

    /// The entry of the next segment (of `size` bytes), the output moved
    /// to where its body starts (a multiple of 256, or of 8 for a body with
    /// a coding section: it is restored before use, so a small
    /// supercompressed asset is not padding); [`Writer::record`] adds it once written.
    fn place(&mut self, frame_count: u32, size: u64, head_checksum: u64, coded: bool) -> Result<SegmentEntry, Error> {
        if self.entries.len() as u32 >= self.count {
            return Err(Error::Invalid(format!("more than the {} segments announced", self.count)));
        }
        let first_frame = self.entries.last().map_or(0, |e| e.first_frame + e.frame_count);
        let offset = align(self.end, if coded { body_align(VERSION) } else { ALIGN as u64 });
        write_zeros(&mut self.out, offset - self.end)?;
        Ok(SegmentEntry { first_frame, frame_count, offset, size, head_checksum })
    }

    /// Adds a written segment's entry to the table.
    fn record(&mut self, e: SegmentEntry) -> SegmentEntry {
        self.entries.push(e);
        self.end = e.offset + e.size;
        e
    }

    /// Writes the next segment, of `frame_count` frames, from its sections (as a version-6 body).
    pub fn add(&mut self, frame_count: u32, sections: &[Section]) -> Result<SegmentEntry, Error> {
        self.add_body(frame_count, sections, false)
    }

    /// [`Writer::add`] of the sections of a body that was stored wrapped
    /// ([`crate::wrap`]): wrapped again where that is smaller, whether or
    /// not a coding section is left inside.
    pub fn add_rewrapped(&mut self, frame_count: u32, sections: &[Section]) -> Result<SegmentEntry, Error> {
        self.add_body(frame_count, sections, true)
    }

    fn add_body(&mut self, frame_count: u32, sections: &[Section], was_wrapped: bool) -> Result<SegmentEntry, Error> {
        if let Some(frame) = self.wrap.then(|| crate::wrap::wrap(sections, was_wrapped)).transpose()?.flatten() {
            let e = self.place(frame_count, frame.len() as u64, checksum(&frame), true)?;
            self.out.write_all(&frame)?;
            self.out.flush()?;
            return Ok(self.record(e));
        }
        let size = file_len(sections);
        let mut e = self.place(frame_count, size, 0, sections.iter().any(|s| s.kind == crate::kind::CODING))?;
        let start = self.base + e.offset;
        // The body's head holds every section's checksum: they are computed on
        // a thread beside the copy of the sections (each a pass over a
        // segment's bytes), and the head is written last, in its place.
        let head = std::thread::scope(|s| -> Result<Vec<u8>, Error> {
            let summing = std::thread::Builder::new().name("checksums".into()).spawn_scoped(s, || body_head(sections));
            write_zeros(&mut self.out, crate::body_head_len(sections) as u64)?;
            write_sections(&mut self.out, sections)?;
            Ok(match summing {
                Ok(t) => t.join().unwrap_or_else(|p| std::panic::resume_unwind(p)),
                Err(_) => body_head(sections),
            })
        })?;
        self.out.seek(SeekFrom::Start(start))?;
        self.out.write_all(&head)?;
        self.out.seek(SeekFrom::Start(start + size))?;
        e.head_checksum = checksum(&head);
        // Written out before the next segment is cooked (a writer's buffers go meanwhile).
        self.out.flush()?;
        Ok(self.record(e))
    }

    /// Writes the next segment as the body `body` of another file's segment
    /// `entry`, as that file stores it (checked by the caller; `coded`:
    /// whether it has a coding section or is wrapped).
    pub fn copy_body(&mut self, entry: &SegmentEntry, body: &[u8], coded: bool) -> Result<SegmentEntry, Error> {
        if body.len() as u64 != entry.size {
            return Err(Error::Invalid(format!("a segment body of {} bytes, its entry says {}", body.len(), entry.size)));
        }
        let e = self.place(entry.frame_count, entry.size, entry.head_checksum, coded)?;
        self.out.write_all(body)?;
        Ok(self.record(e))
    }

    /// Where the file starts in the output (after a part header: not 0).
    pub fn base(&self) -> u64 {
        self.base
    }

    /// The segments written so far.
    pub fn entries(&self) -> &[SegmentEntry] {
        &self.entries
    }

    /// Writes the header and the segment table; returns the output.
    pub fn finish(mut self) -> Result<W, Error> {
        if self.entries.len() as u32 != self.count {
            return Err(Error::Invalid(format!("{} segments written of the {} announced", self.entries.len(), self.count)));
        }
        let head = container_head(&self.entries, self.end);
        self.out.seek(SeekFrom::Start(self.base))?;
        self.out.write_all(&head)?;
        self.out.seek(SeekFrom::Start(self.base + self.end))?;
        self.out.flush()?;
        Ok(self.out)
    }
}

/// The header and segment table of a version-7 file.
fn container_head(entries: &[SegmentEntry], file_size: u64) -> Vec<u8> {
    let mut head = vec![0u8; HEADER_LEN];
    head[..8].copy_from_slice(&MAGIC);
    head[8..12].copy_from_slice(&VERSION.to_le_bytes());
    head[16..20].copy_from_slice(&(entries.len() as u32).to_le_bytes());
    head[24..32].copy_from_slice(&file_size.to_le_bytes());
    for e in entries {
        head.extend_from_slice(&e.bytes());
    }
    let h = header_checksum(&head[..32], &head[HEADER_LEN..]);
    head[32..40].copy_from_slice(&h.to_le_bytes());
    head
}

fn write_zeros<W: Write>(w: &mut W, mut n: u64) -> std::io::Result<()> {
    let zeros = [0u8; 4096];
    while n > 0 {
        let k = n.min(zeros.len() as u64) as usize;
        w.write_all(&zeros[..k])?;
        n -= k as u64;
    }
    Ok(())
}

/// Assembles a version-7 file in memory from segments of (frame count, sections).
pub fn assemble_segments(segments: &[(u32, Vec<Section>)]) -> Result<Vec<u8>, Error> {
    assemble_with(Writer::new(std::io::Cursor::new(Vec::new()), segments.len() as u32)?, segments)
}

/// [`assemble_segments`] with no body wrapped (the layout of version 12).
pub fn assemble_unwrapped(segments: &[(u32, Vec<Section>)]) -> Result<Vec<u8>, Error> {
    assemble_with(Writer::new(std::io::Cursor::new(Vec::new()), segments.len() as u32)?.unwrapped(), segments)
}

fn assemble_with(mut w: Writer<std::io::Cursor<Vec<u8>>>, segments: &[(u32, Vec<Section>)]) -> Result<Vec<u8>, Error> {
    for (frames, sections) in segments {
        w.add(*frames, sections)?;
    }
    Ok(w.finish()?.into_inner())
}

/// Writes `asset` again with every segment's metadata changed by `edit`
/// (its other sections as they are): a version-7 file in memory.
pub fn rewrite_metadata(asset: &crate::Asset, edit: impl FnMut(&mut Metadata)) -> Result<Vec<u8>, Error> {
    let w = Writer::new(std::io::Cursor::new(Vec::new()), asset.segment_count() as u32)?;
    Ok(rewrite_into(asset, w, edit)?.into_inner())
}

/// Writes `asset`'s segments to `w` (a file's or a part's writer of as
/// many segments), every segment's metadata changed by `edit` and its
/// other sections as the file stores them: supercompressed ones stay so,
/// a wrapped body is wrapped again.
pub fn rewrite_into<W: Write + Seek>(asset: &crate::Asset, mut w: Writer<W>, mut edit: impl FnMut(&mut Metadata)) -> Result<W, Error> {
    let table = asset.segments()?;
    for (s, e) in table.iter().enumerate() {
        // Stored sections: supercompressed ones stay as they are.
        let mut sections = asset.stored_segment(s)?.to_sections();
        let meta = sections.iter_mut().find(|x| x.kind == crate::kind::METADATA).ok_or(Error::Missing { kind: crate::kind::METADATA, index: 0 })?;
        let mut m = Metadata::from_bytes(&meta.data)?;
        edit(&mut m);
        meta.data = m.to_bytes()?.into();
        // A wrapped body is wrapped again, with or without coding records inside.
        match asset.is_wrapped(s) {
            true => w.add_rewrapped(e.frame_count, &sections)?,
            false => w.add(e.frame_count, &sections)?,
        };
    }
    w.finish()
}

/// The whole sequence's metadata from its segments' (in order): the frames,
/// their figures and sources one after the other, each channel's value range
/// over every segment, the union bounding box and the smallest index offset;
/// every setting shared by all segments is checked to be the same.
/// Planes and channel placement are per segment: the merged record keeps
/// the first segment's, with the brick counts of every segment added up.
pub fn merged(metas: &[Metadata]) -> Result<Metadata, Error> {
    let Some(first) = metas.first() else { return Err(Error::Invalid("no segments".into())) };
    let mut m = first.clone();
    // The smallest offset of the segments that have active voxels (a segment without any has none that means anything).
    let placed = metas.iter().filter(|s| s.index_bbox.is_some()).map(|s| s.index_offset);
    m.index_offset = placed.reduce(|a, b| std::array::from_fn(|i| a[i].min(b[i]))).unwrap_or(first.index_offset);
    m.frames.clear();
    m.sources.clear();
    m.frame_count = 0;
    for (s, seg) in metas.iter().enumerate() {
        let differs = |what: &str| Err(Error::Invalid(format!("segment {s}'s {what} differs from segment 0's")));
        if seg.tool != first.tool || seg.settings != first.settings {
            return differs("tool or settings");
        }
        if seg.map_type != first.map_type || seg.transform != first.transform {
            return differs("transform");
        }
        if (seg.levels, seg.first_level, &seg.level_filters) != (first.levels, first.first_level, &first.level_filters) {
            return differs("levels of detail");
        }
        let same_channel = |a: &crate::Channel, b: &crate::Channel| {
            (&a.name, &a.grid, a.component, &a.value_type, &a.class, a.background.to_bits(), a.group) == (&b.name, &b.grid, b.component, &b.value_type, &b.class, b.background.to_bits(), b.group)
        };
        if seg.channels.len() != first.channels.len() || !seg.channels.iter().zip(&first.channels).all(|(a, b)| same_channel(a, b)) {
            return differs("channels");
        }
        if s > 0 {
            for (acc, c) in m.channels.iter_mut().zip(&seg.channels) {
                acc.value_range = [acc.value_range[0].min(c.value_range[0]), acc.value_range[1].max(c.value_range[1])];
            }
            for (acc, p) in m.planes.iter_mut().zip(&seg.planes) {
                if acc.plane == p.plane {
                    acc.bricks = acc.bricks.saturating_add(p.bricks);
                }
            }
            m.brick_count = m.brick_count.saturating_add(seg.brick_count);
            m.index_bbox = match (m.index_bbox, seg.index_bbox) {
                (Some((a0, a1)), Some((b0, b1))) => Some((std::array::from_fn(|i| a0[i].min(b0[i])), std::array::from_fn(|i| a1[i].max(b1[i])))),
                (a, b) => a.or(b),
            };
        }
        if seg.time.as_ref().map(|t| t.fps.to_bits()) != first.time.as_ref().map(|t| t.fps.to_bits()) {
            return differs("frame rate");
        }
        if seg.resolutions != first.resolutions {
            return differs("channel resolutions");
        }
        for f in &seg.frames {
            let mut f = f.clone();
            f.source = match f.source.and_then(|i| seg.sources.get(i as usize)) {
                Some(src) => Some(match m.sources.iter().position(|o| o == src) {
                    Some(i) => i as u32,
                    None => {
                        m.sources.push(src.clone());
                        (m.sources.len() - 1) as u32
                    }
                }),
                None => None,
            };
            m.frames.push(f);
        }
        // Files no frame names (several files per frame): each once too.
        for src in &seg.sources {
            if !m.sources.contains(src) {
                m.sources.push(src.clone());
            }
        }
        m.frame_count = m.frame_count.checked_add(seg.frame_count).ok_or_else(|| Error::Invalid("more than 2^32 frames".into()))?;
    }
    if let Some(t) = &mut m.time {
        t.numbers = metas.iter().flat_map(|seg| seg.time.iter().flat_map(|t| t.numbers.iter().copied())).collect();
        if let Some(p) = t.problem(m.frame_count) {
            return Err(Error::Invalid(format!("the segments' time: {p}")));
        }
    }
    Ok(m)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::{kind, Asset, FrameInfo, SourceFile};

    pub(crate) fn meta(frames: u32, sources: &[&str], range: [f32; 2], offset: i32) -> Metadata {
        let channel = crate::Channel {
            name: "density".into(),
            grid: "density".into(),
            component: None,
            value_type: "float".into(),
            class: "fog volume".into(),
            background: 0.0,
            value_range: range,
            group: 0,
            plane: 0,
            lane: 0,
            alternates: vec![],
        };
        Metadata {
            tool: "t".into(),
            frame_count: frames,
            map_type: "UniformScaleMap".into(),
            transform: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
            index_offset: [offset, 0, 0],
            index_bbox: Some(([offset + 3, 0, 0], [offset + 9, 5, 5])),
            channels: vec![channel],
            planes: vec![],
            brick_count: 2,
            settings: vec![("format".into(), "f32".into())],
            sources: sources.iter().map(|p| SourceFile { path: p.to_string(), bytes: 1, xxh3_128: "0".into() }).collect(),
            frames: (0..frames).map(|f| FrameInfo { source: Some(f.min(sources.len() as u32 - 1)), active_voxels: 10 + u64::from(f), leaves: 1, tiles: 0, coarse: vec![] }).collect(),
            levels: 1,
            level_filters: vec![],
            first_level: 0,
            time: None,
            resolutions: Vec::new(),
        }
    }

    /// `sections` supercompressed at zstd level 3, without context coding.
    fn supercompressed(sections: Vec<Section>, m: &Metadata) -> Vec<Section> {
        crate::coding::supercompress(sections, m, crate::coding::Schemes { level: 3, context: false }).unwrap()
    }

    /// [`body`] with 4 KiB of zero L2 entries, which compress to a few bytes.
    fn body_with_zeros(m: &Metadata) -> Vec<Section> {
        let mut sections = body(m, 1);
        sections.push(Section { kind: kind::L2_ENTRIES, index: 0, data: vec![0; 4096].into() });
        sections
    }

    pub(crate) fn body(m: &Metadata, marker: u32) -> Vec<Section> {
        vec![
            Section { kind: kind::METADATA, index: 0, data: m.to_bytes().unwrap().into() },
            Section { kind: kind::FRAMES, index: 0, data: (0..m.frame_count).flat_map(|f| (f + marker).to_le_bytes()).collect::<Vec<u8>>().into() },
        ]
    }

    fn sample() -> Vec<u8> {
        let a = meta(2, &["a.vdb", "b.vdb"], [0.0, 1.0], 0);
        let b = meta(3, &["b.vdb", "c.vdb", "d.vdb"], [-1.0, 0.5], -128);
        assemble_segments(&[(2, body(&a, 100)), (3, body(&b, 200))]).unwrap()
    }

    #[test]
    fn segments_read_back_as_bodies_and_frames_are_located() {
        let bytes = sample();
        let a = Asset::from_bytes(&bytes).unwrap();
        a.verify().unwrap();
        assert_eq!(a.segment_count(), 2);
        let table = a.segments().unwrap();
        assert_eq!((table[0].frames(), table[1].frames()), (0..2, 2..5));
        assert!(table.iter().all(|e| e.offset % ALIGN as u64 == 0));
        assert_eq!(a.segment(1).unwrap().u32s(kind::FRAMES).unwrap(), &[200, 201, 202]);
        assert_eq!([0, 1, 2, 4].map(|f| a.locate(f)), [Some((0, 0)), Some((0, 1)), Some((1, 0)), Some((1, 2))]);
        assert_eq!(a.locate(5), None);
        assert!(matches!(a.section(kind::FRAMES, 0), Err(Error::Segmented(2))));
        assert!(matches!(a.segment(2), Err(Error::NoSegment { .. })));
        let m = a.metadata().unwrap();
        assert_eq!(m.frame_count, 5);
        assert_eq!(m.channels[0].value_range, [-1.0, 1.0]);
        assert_eq!(m.index_offset, [-128, 0, 0]);
        assert_eq!(m.index_bbox, Some(([-125, 0, 0], [9, 5, 5])));
        // Sources once each, frames pointing at the right ones.
        let names: Vec<&str> = m.frames.iter().map(|f| m.sources[f.source.unwrap() as usize].path.as_str()).collect();
        assert_eq!(names, ["a.vdb", "b.vdb", "b.vdb", "c.vdb", "d.vdb"]);
        assert_eq!(m.sources.len(), 4);
    }

    #[test]
    fn a_body_is_one_segment() {
        let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        let a = Asset::from_bytes(&crate::assemble(&body(&m, 7))).unwrap();
        assert_eq!((a.segment_count(), a.is_segmented()), (1, false));
        assert_eq!(a.segments().unwrap()[0].frames(), 0..2);
        assert_eq!(a.segment(0).unwrap().u32s(kind::FRAMES).unwrap(), &[7, 8]);
        assert_eq!(a.locate(1), Some((0, 1)));
    }

    #[test]
    fn every_flipped_byte_of_a_segmented_file_is_caught() {
        let b = sample();
        for i in 0..b.len() {
            let mut c = b.clone();
            c[i] ^= 0x10;
            let r = Asset::from_bytes(&c).and_then(|a| a.verify().map(|_| a));
            // Only the file header's reserved bytes 40 to 63 are free (the
            // table holds a checksum of each body's whole header).
            assert_eq!(r.is_err(), !(40..HEADER_LEN).contains(&i), "byte {i}");
        }
    }

    #[test]
    fn supercompressed_segments_restore_the_bytes_written() {
        let long = |m: &Metadata, marker: u32| {
            let mut b = body(m, marker);
            b.push(Section { kind: kind::L2_ENTRIES, index: 0, data: (0..5000u32).flat_map(|i| (i / 3 + marker).to_le_bytes()).collect::<Vec<u8>>().into() });
            b
        };
        let (a, b) = (meta(2, &["a.vdb", "b.vdb"], [0.0, 1.0], 0), meta(3, &["c.vdb"], [-1.0, 0.5], -128));
        let plain = [(2, long(&a, 100)), (3, long(&b, 200))];
        let coded = [(2, supercompressed(long(&a, 100), &a)), (3, supercompressed(long(&b, 200), &b))];
        let (plain, coded) = (assemble_unwrapped(&plain).unwrap(), assemble_unwrapped(&coded).unwrap());
        assert!(coded.len() < plain.len(), "{} vs {} bytes", coded.len(), plain.len());
        let (p, c) = (Asset::from_bytes(&plain).unwrap(), Asset::from_bytes(&coded).unwrap());
        c.verify().unwrap();
        assert_eq!(c.metadata().unwrap(), p.metadata().unwrap());
        for s in 0..2 {
            assert!(c.stored_segment(s).unwrap().is_coded());
            assert_eq!(c.segment(s).unwrap().bytes(), p.segment(s).unwrap().bytes(), "segment {s}");
        }
        // A flipped byte of a compressed section fails the stored checksum; a
        // coding record rewritten with its checksums made good fails restoring.
        let seg = c.stored_segment(1).unwrap();
        let e = *seg.sections.iter().find(|e| e.kind == kind::L2_ENTRIES).unwrap();
        let mut bad = coded.clone();
        bad[(c.segments().unwrap()[1].offset + e.offset) as usize + 9] ^= 1;
        assert!(Asset::from_bytes(&bad).unwrap().verify().is_err());
        let mut sections = seg.to_sections();
        let coding = sections.iter_mut().find(|x| x.kind == kind::CODING).unwrap();
        coding.data.to_mut()[24] ^= 4; // the restored size of the first record
        let lied = assemble_unwrapped(&[(3, sections)]).unwrap();
        let a = Asset::from_bytes(&lied).unwrap();
        a.verify().unwrap();
        let err = a.segment(0).err().unwrap().to_string();
        assert!(err.contains("supercompressed section") && err.contains("coding table says"), "{err}");
    }

    /// A one-segment file `b` with its body moved to byte `at`, as an older
    /// writer placed it (at 256) or a newer one may (at 96, after the table).
    fn with_body_at(b: &[u8], at: u64) -> Vec<u8> {
        let e = SegmentEntry::parse(&b[HEADER_LEN..HEADER_LEN + SEGMENT_ENTRY_LEN]);
        let mut out = b[..HEADER_LEN + SEGMENT_ENTRY_LEN].to_vec();
        out.resize(at as usize, 0);
        out.extend_from_slice(&b[e.offset as usize..(e.offset + e.size) as usize]);
        out[HEADER_LEN + 8..HEADER_LEN + 16].copy_from_slice(&at.to_le_bytes());
        let len = out.len() as u64;
        out[24..32].copy_from_slice(&len.to_le_bytes());
        let v = u32::from_le_bytes(out[8..12].try_into().unwrap());
        set_version(&mut out, v);
        out
    }

    /// The error reading segment 0 of the one-segment file `b` gives once its
    /// body sits at byte 256, as an older writer placed it, and the file is
    /// relabelled as version `v`.
    fn older_error(b: &[u8], v: u32) -> String {
        let mut b = with_body_at(b, ALIGN as u64);
        set_version(&mut b, v);
        Asset::from_bytes(&b).unwrap().segment(0).err().unwrap().to_string()
    }

    /// A one-segment file `b` relabelled as version `v`, its header checksum made anew.
    fn set_version(b: &mut [u8], v: u32) {
        b[8..12].copy_from_slice(&v.to_le_bytes());
        let sum = crate::header_checksum(&b[..32], &b[HEADER_LEN..HEADER_LEN + SEGMENT_ENTRY_LEN]);
        b[32..40].copy_from_slice(&sum.to_le_bytes());
    }

    #[test]
    fn a_version_7_file_holds_no_supercompressed_section() {
        let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        let b = assemble_unwrapped(&[(2, supercompressed(body_with_zeros(&m), &m))]).unwrap();
        let err = older_error(&b, VERSION_7);
        assert!(err.contains("older than version 8"), "{err}");
    }

    #[test]
    fn only_a_version_11_body_packs_its_sections() {
        let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        let b = assemble_unwrapped(&[(2, supercompressed(body_with_zeros(&m), &m))]).unwrap();
        // Every section of the supercompressed body at a multiple of 8, some not of 256.
        let a = Asset::from_bytes(&b).unwrap();
        let body = a.stored_segment(0).unwrap();
        let offsets: Vec<u64> = body.sections.iter().map(|e| e.offset).collect();
        assert!(offsets.iter().all(|o| o % 8 == 0) && offsets.iter().any(|o| o % ALIGN as u64 != 0), "{offsets:?}");
        a.segment(0).unwrap();
        // In a version-10 file, the sections no coding record names must be at multiples of 256.
        let err = older_error(&b, VERSION_10);
        assert!(err.contains("misaligned"), "{err}");
    }

    /// A file of one body holding one section of kind `coded`, coded as `scheme` with `filter`
    /// (`stored`, restoring to `raw`): it restores `raw`; relabelled as
    /// version `older`, the error it is refused with.
    fn one_coded_section(coded: u32, scheme: u32, filter: crate::coding::Filter, stored: Vec<u8>, raw: &[u8], older: u32) -> String {
        let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        let mut sections = body(&m, 1);
        let record = crate::coding::Coding { kind: coded, index: 0, scheme, filter, raw_size: raw.len() as u64, raw_checksum: crate::checksum(raw) };
        sections.push(Section { kind: coded, index: 0, data: stored.into() });
        sections.push(Section { kind: kind::CODING, index: 0, data: record.bytes().to_vec().into() });
        let b = assemble_unwrapped(&[(2, sections)]).unwrap();
        let restored = Asset::from_bytes(&b).unwrap().segment(0).unwrap();
        assert_eq!(restored.section(coded, 0).unwrap(), raw);
        older_error(&b, older)
    }

    #[test]
    fn context_coding_is_version_11() {
        use crate::coding::{Filter, Tiles, SCHEME_CONTEXT};
        // Eight tiles of zeros: their divisors and quotients (the tiles filters' output) are zeros too.
        let stored = crate::context::encode(&[0u8; 8 + 4096], 1, 3, None).unwrap().unwrap();
        let tiles = Filter::Tiles(Tiles { width: 1, x: 8, y: 1, predict: false });
        let err = one_coded_section(kind::L2_ENTRIES, SCHEME_CONTEXT, tiles, stored, &[0u8; 4096], VERSION_10);
        assert!(err.contains("context-coded in a version-10 file"), "{err}");
    }

    #[test]
    fn a_supercompressed_body_starts_at_a_multiple_of_8_from_version_12() {
        let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        let plain = assemble_segments(&[(2, body_with_zeros(&m))]).unwrap();
        let mut b = assemble_segments(&[(2, supercompressed(body_with_zeros(&m), &m))]).unwrap();
        // Right after the table (64 + 32 bytes), where a plain body waits for byte 256.
        let first = |b: &[u8]| Asset::from_bytes(b).unwrap().segments().unwrap()[0].offset;
        assert_eq!((first(&b), first(&plain)), (96, ALIGN as u64));
        Asset::from_bytes(&b).unwrap().verify().unwrap();
        // A plain body moved there is refused when it is read, and so is the coded one in a version-11 file.
        let moved = with_body_at(&plain, 96);
        let err = Asset::from_bytes(&moved).unwrap().segment(0).err().unwrap().to_string();
        assert!(err.contains("without a coding section"), "{err}");
        set_version(&mut b, VERSION_11);
        assert!(matches!(Asset::from_bytes(&b), Err(Error::SegmentBounds { .. })));
        let mut b = with_body_at(&b, ALIGN as u64);
        set_version(&mut b, VERSION);
        Asset::from_bytes(&b).unwrap().segment(0).unwrap();
    }

    #[test]
    fn coding_over_shown_voxels_is_version_15() {
        use crate::coding::{Filter, Tiles, SCHEME_SHOWN};
        // Eight tiles of zeros that no node shows (the body has no L3 array): every element left out.
        let stored = crate::context::encode(&[0u8; 8 + 4096], 1, 3, Some(&[[0u64; 8]; 8])).unwrap().unwrap();
        let tiles = Filter::Tiles(Tiles { width: 1, x: 8, y: 1, predict: false });
        let err = one_coded_section(kind::ATLAS, SCHEME_SHOWN, tiles, stored, &[0u8; 4096], VERSION_14);
        assert!(err.contains("coded over its shown voxels in a version-14 file"), "{err}");
    }

    #[test]
    fn mask_coding_is_version_14() {
        use crate::coding::{Filter, SCHEME_MASKS};
        // 40 nodes, each with two sub-masks of a striped pattern.
        let (n, mut words) = (40u32, vec![40u32]);
        for k in 0..n {
            words.extend([k, 0b1010, 1 + 3 * n + 4 * k]);
        }
        words.extend((0..4 * n).map(|i| if i % 2 == 0 { 0x0f0f_0f0f } else { 0x3333_3333 }));
        let raw: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        let stored = crate::masks::encode(&crate::l3_filter::apply(&raw), 3).unwrap().unwrap();
        let err = one_coded_section(kind::L3_NODES, SCHEME_MASKS, Filter::L3Nodes, stored, &raw, VERSION_13);
        assert!(err.contains("mask-coded in a version-13 file"), "{err}");
    }

    #[test]
    fn the_l3_nodes_filter_is_version_12() {
        let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        let mut sections = body(&m, 1);
        // 300 nodes in the writer's order: bricks counting up, every other one with two sub-masks.
        let (n, mut words) = (300u32, vec![300u32]);
        let mut first = 1 + 3 * n;
        for k in 0..n {
            let states = if k % 2 == 0 { 0b1010 } else { 0x5555 };
            words.extend([k, states, first]);
            first += if k % 2 == 0 { 4 } else { 0 };
        }
        words.extend((0..first - words.len() as u32).map(|i| i.wrapping_mul(2654435761)));
        let raw: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        sections.push(Section { kind: kind::L3_NODES, index: 0, data: raw.clone().into() });
        let b = assemble_unwrapped(&[(2, supercompressed(sections, &m))]).unwrap();
        let a = Asset::from_bytes(&b).unwrap();
        let codings = crate::coding::Coding::parse_all(a.stored_segment(0).unwrap().section(kind::CODING, 0).unwrap()).unwrap();
        assert_eq!(codings.iter().find(|c| c.kind == kind::L3_NODES).map(|c| c.filter), Some(crate::coding::Filter::L3Nodes));
        assert_eq!(a.segment(0).unwrap().section(kind::L3_NODES, 0).unwrap(), &raw[..]);
        let err = older_error(&b, VERSION_11);
        assert!(err.contains("filtered as l3 nodes in a version-11 file"), "{err}");
    }

    #[test]
    fn time_is_merged_and_an_older_file_records_none() {
        let timed = |frames: u32, first: i64, fps: f64| Metadata {
            time: Some(crate::Time { fps, numbers: (0..i64::from(frames)).map(|i| first + 3 * i).collect() }),
            resolutions: Vec::new(),
            ..meta(frames, &["a.vdb"], [0.0, 1.0], 0)
        };
        let b = assemble_segments(&[(2, body(&timed(2, 1001, 30.0), 1)), (3, body(&timed(3, 1007, 30.0), 2))]).unwrap();
        let m = Asset::from_bytes(&b).unwrap().metadata().unwrap();
        assert_eq!(m.time, Some(crate::Time { fps: 30.0, numbers: vec![1001, 1004, 1007, 1010, 1013] }));
        assert_eq!((m.frame_of_number(1010), m.frame_number(4)), (Some(3), 1013));
        // Segments that disagree on the rate, or whose numbers go back, are refused.
        let b = assemble_segments(&[(2, body(&timed(2, 1001, 30.0), 1)), (3, body(&timed(3, 1007, 24.0), 2))]).unwrap();
        assert!(Asset::from_bytes(&b).unwrap().metadata().unwrap_err().to_string().contains("frame rate differs"));
        let b = assemble_segments(&[(2, body(&timed(2, 1001, 30.0), 1)), (3, body(&timed(3, 1002, 30.0), 2))]).unwrap();
        assert!(Asset::from_bytes(&b).unwrap().metadata().unwrap_err().to_string().contains("must increase"));
        // A version-8 file (no time): frames numbered from 0 at the default rate.
        let mut b = assemble_segments(&[(2, body(&meta(2, &["a.vdb"], [0.0, 1.0], 0), 1))]).unwrap();
        set_version(&mut b, VERSION_8);
        let a = Asset::from_bytes(&b).unwrap();
        assert_eq!(a.version(), VERSION_8);
        let m = a.metadata().unwrap();
        assert_eq!((m.time.is_none(), m.frame_number(1), m.fps()), (true, 1, crate::DEFAULT_FPS));
    }

    #[test]
    fn channel_resolutions_are_refused_before_version_10() {
        let mut m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        m.time = Some(crate::Time { fps: 24.0, numbers: vec![0, 1] });
        m.resolutions = vec![crate::Resolution { level: 0, half_offset: [1, 0, 0] }; m.channels.len()];
        let mut b = assemble_segments(&[(2, body(&m, 1))]).unwrap();
        assert_eq!(Asset::from_bytes(&b).unwrap().metadata().unwrap().resolutions, m.resolutions);
        set_version(&mut b, VERSION_9);
        let err = Asset::from_bytes(&b).unwrap().metadata().unwrap_err().to_string();
        assert!(err.contains("channel resolutions in a version-9 file"), "{err}");
    }

    #[test]
    fn truncation_is_an_error() {
        let b = sample();
        for n in (0..b.len()).step_by(7) {
            assert!(Asset::from_bytes(&b[..n]).is_err(), "{n} bytes");
        }
    }

    #[test]
    fn segments_that_disagree_are_refused() {
        let a = meta(2, &["a.vdb"], [0.0, 1.0], 0);
        let mut b = meta(1, &["b.vdb"], [0.0, 1.0], 0);
        b.channels[0].background = 1.0;
        let bytes = assemble_segments(&[(2, body(&a, 0)), (1, body(&b, 0))]).unwrap();
        let err = Asset::from_bytes(&bytes).unwrap().metadata().unwrap_err().to_string();
        assert!(err.contains("segment 1's channels differ"), "{err}");
        // The table's frame counts must be the bodies'.
        let bytes = assemble_segments(&[(3, body(&a, 0))]).unwrap();
        let err = Asset::from_bytes(&bytes).unwrap().metadata().unwrap_err().to_string();
        assert!(err.contains("segment 0: the asset is inconsistent: its metadata has 2 frames, the segment table 3"), "{err}");
    }

    #[test]
    fn a_writer_needs_every_segment_it_announced() {
        let m = meta(1, &["a.vdb"], [0.0, 1.0], 0);
        let mut w = Writer::new(std::io::Cursor::new(Vec::new()), 2).unwrap();
        w.add(1, &body(&m, 0)).unwrap();
        assert!(w.finish().is_err());
        assert!(Writer::new(std::io::Cursor::new(Vec::new()), 0).is_err());
    }

    /// A part file in memory of the segments (frames, metadata), numbered `index` of `count`.
    fn part(index: u32, count: u32, first_segment: u32, first_frame: u32, segments: &[(u32, Metadata)]) -> Vec<u8> {
        let info = PartInfo { index, count, segments: 4, first_segment, first_frame, fingerprint: 9 };
        let mut w = part_writer(std::io::Cursor::new(Vec::new()), &info, segments.len() as u32).unwrap();
        for (frames, m) in segments {
            w.add(*frames, &body(m, 0)).unwrap();
        }
        w.finish().unwrap().into_inner()
    }

    #[test]
    fn parts_join_in_order_and_kernels_must_agree() {
        let with = |kernels: &str| {
            let mut m = meta(1, &["a.vdb"], [0.0, 1.0], 0);
            m.settings.push(("bc7_kernels".into(), kernels.into()));
            (1, m)
        };
        let fma = with("x86-64 fma");
        let a = part(0, 2, 0, 0, &[fma.clone(), fma.clone()]);
        let b = part(1, 2, 2, 2, &[fma.clone(), fma.clone()]);
        let dir = std::env::temp_dir().join(format!("vpak-join-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = || std::fs::OpenOptions::new().read(true).write(true).create(true).truncate(true).open(dir.join("out")).unwrap();
        let run = |x: &[u8], y: &[u8]| {
            let parts = [Asset::part_from_bytes(x).unwrap(), Asset::part_from_bytes(y).unwrap()];
            join(&parts, &["a".to_string(), "b".to_string()], out()).map(|_| std::fs::read(dir.join("out")).unwrap())
        };
        let joined = run(&a, &b).unwrap();
        let asset = Asset::from_bytes(&joined).unwrap();
        asset.verify().unwrap();
        assert_eq!((asset.segment_count(), asset.metadata().unwrap().frame_count), (4, 4));
        // The same segments written by one writer: the same bytes.
        let whole = assemble_segments(&(0..4).map(|_| (1, body(&fma.1, 0))).collect::<Vec<_>>()).unwrap();
        assert!(joined == whole);
        let other = part(1, 2, 2, 2, &[with("x86-64 no-fma"), with("x86-64 no-fma")]);
        let err = run(&a, &other).unwrap_err().to_string();
        assert!(err.contains("b: its BC7 blocks come from x86-64 no-fma kernels, the first part's from x86-64 fma"), "{err}");
        let err = run(&b, &a).unwrap_err().to_string();
        assert!(err.contains("a: is part 2 of 2, but part 1 belongs here"), "{err}");
        // A part is not an asset.
        assert!(matches!(Asset::from_bytes(&a), Err(Error::Part)));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
