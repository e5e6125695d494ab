//! The runtime reader: what an engine links to play an asset a segment at a
//! time within a memory budget (guide: `docs/runtime.md`; meaning of every
//! byte: `docs/format.md`). Opening reads the header, the segment table and
//! each segment's body header, section table, metadata and coding records
//! (small positioned reads, never the whole file); a segment's GPU-ready
//! sections are then read, restored and checked on demand, into buffers the
//! caller owns ([`Reader::fill_segment`]) or as an [`Asset`] over a buffer the
//! caller reuses ([`Reader::segment_asset`]); [`Prefetcher`] does either (and
//! whatever the caller adds, an upload say) on a worker thread.

mod info;
mod prefetch;
mod source;
#[cfg(test)]
mod tests;

pub use info::{SectionBuffers, SectionInfo, SegmentInfo, TextureInfo};
pub use prefetch::{Fetched, Prefetcher};
pub use source::{FileSource, Source};

use crate::coding::{self, Part};
use crate::segments::{self, SegmentEntry};
use crate::{checksum, head, kind, Asset, Checked, Error, Metadata, SectionEntry, ENTRY_LEN, HEADER_LEN, MAX_SECTIONS};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

/// What opening learnt of a segment beyond its [`SegmentInfo`].
struct Inner {
    /// The segment table's checksum of the body's header and section table.
    head_checksum: u64,
    parts: Vec<Part>,
    /// A wrapped body ([`crate::wrap`]), decompressed when the asset was
    /// opened: its sections are read from here, not from the source.
    wrapped: Option<std::sync::Arc<Vec<u8>>>,
}

/// The source and what has been read of it.
struct Io {
    source: Box<dyn Source>,
    bytes_read: AtomicU64,
}

/// An opened asset, read on demand from its [`Source`]. Shared between
/// threads (`Arc<Reader>`): every method takes `&self`.
pub struct Reader {
    io: Io,
    /// A file of segments (version 7 or later), not a single body (version 6).
    segmented: bool,
    /// The file's format version.
    version: u32,
    segments: Vec<(SegmentInfo, Inner)>,
    metadata: Metadata,
}

impl Reader {
    /// Opens the asset at `path`, memory-mapped.
    pub fn open(path: &Path) -> Result<Reader, Error> {
        let f = std::fs::File::open(path)?;
        // SAFETY: read-only mapping; the asset is assumed not to change while open
        // (a change is caught by the checksums, not a fault, unless the file shrinks).
        let map = unsafe { memmap2::Mmap::map(&f)? };
        Reader::new(map)
    }

    /// Opens the asset in `file`, read with positioned reads (no mapping).
    pub fn from_file(file: std::fs::File) -> Result<Reader, Error> {
        Reader::new(FileSource::new(file)?)
    }

    /// Opens the asset `source` holds: checks the header and the segment
    /// table, and each segment's body header, section table (against the
    /// segment table's head checksum), metadata and coding records, as
    /// docs/format.md asks before a segment is used; merges the metadata.
    pub fn new(source: impl Source + 'static) -> Result<Reader, Error> {
        let io = Io { source: Box::new(source), bytes_read: AtomicU64::new(0) };
        let len = io.source.len();
        if len < HEADER_LEN as u64 {
            return Err(Error::Magic);
        }
        let header = io.read_vec(0, HEADER_LEN as u64)?;
        if header.starts_with(&segments::PART_MAGIC) {
            return Err(Error::Part);
        }
        let version = head::version(&header, len)?;
        let bodies = match version {
            segments::BODY_VERSION => vec![io.body(version, 0, len, None)?],
            v if segments::is_container_version(v) => {
                let n = head::table_len(&header, segments::SEGMENT_ENTRY_LEN, segments::MAX_SEGMENTS, Error::SegmentCount, len)?;
                let table = io.read_vec(HEADER_LEN as u64, n as u64)?;
                head::check_checksum(&header, &table)?;
                let entries = head::segments(&table, len, version)?;
                let read = entries.iter().enumerate().map(|(s, e)| io.segment(version, e, entries.len()).map_err(|err| Error::InSegment(s, Box::new(err))));
                read.collect::<Result<Vec<_>, _>>()?
            }
            v => return Err(Error::Version(v)),
        };
        let segmented = version != segments::BODY_VERSION;
        // A file that is one body: its own metadata; a file of segments: theirs merged.
        let metadata = match &bodies[..] {
            [(one, _)] if !segmented => one.metadata.clone(),
            _ => segments::merged(&bodies.iter().map(|(i, _)| i.metadata.clone()).collect::<Vec<_>>())?,
        };
        Ok(Reader { io, segmented, version, segments: bodies, metadata })
    }

    /// The whole sequence's metadata ([`segments::merged`]: frames, sources
    /// and value ranges of all segments; planes and placement of the first).
    pub fn metadata(&self) -> &Metadata {
        &self.metadata
    }

    /// Frames of the whole asset.
    pub fn frame_count(&self) -> usize {
        self.segments.last().map_or(0, |(i, _)| i.frames().end)
    }

    pub fn segment_count(&self) -> usize {
        self.segments.len()
    }

    /// Whether the file has a segment table (version 7 or later), not one body (version 6).
    pub fn is_segmented(&self) -> bool {
        self.segmented
    }

    /// Segment `s`: its frames, metadata and sections.
    pub fn segment(&self, s: usize) -> Result<&SegmentInfo, Error> {
        self.segments.get(s).map(|(i, _)| i).ok_or(Error::NoSegment { segment: s, count: self.segments.len() })
    }

    /// The segment holding frame `frame` of the asset, and the frame's index within it.
    pub fn locate(&self, frame: usize) -> Option<(usize, usize)> {
        let s = self.segments.partition_point(|(i, _)| i.frames().end <= frame);
        let (info, _) = self.segments.get(s)?;
        info.frames().contains(&frame).then(|| (s, frame - info.first_frame as usize))
    }

    /// Frame `frame`'s number in the source sequence (version 9; an older
    /// asset's frames are numbered from 0).
    pub fn frame_number(&self, frame: usize) -> i64 {
        self.metadata.frame_number(frame)
    }

    /// The frame whose source number is `number`, if there is one.
    pub fn frame_of_number(&self, number: i64) -> Option<usize> {
        self.metadata.frame_of_number(number)
    }

    /// The sequence's frame rate (version 9; [`crate::DEFAULT_FPS`] for an older asset).
    pub fn fps(&self) -> f64 {
        self.metadata.fps()
    }

    /// The file's format version (6 to [`crate::VERSION`]).
    pub fn version(&self) -> u32 {
        self.version
    }

    /// Bytes read from the source so far (opening included).
    pub fn bytes_read(&self) -> u64 {
        self.io.bytes_read.load(Ordering::Relaxed)
    }

    /// An error of segment `s`, named as the segment's where the file has segments.
    fn in_segment(&self, s: usize, e: Error) -> Error {
        match self.segmented {
            true => Error::InSegment(s, Box::new(e)),
            false => e,
        }
    }

    /// Reads section `section` (its position in [`SegmentInfo::sections`])
    /// of segment `s` into `out` (its restored size), restored and its
    /// checksums (stored and restored) checked (an atlas coded over its
    /// shown voxels reads and restores the segment's L3 array and tables
    /// for them first). The sections are not validated against each other:
    /// [`Reader::fill_segment`] does that.
    pub fn read_section_into(&self, s: usize, section: usize, out: &mut [u8]) -> Result<(), Error> {
        let (info, inner) = self.segments.get(s).ok_or(Error::NoSegment { segment: s, count: self.segments.len() })?;
        let part = inner.parts.get(section).ok_or_else(|| Error::Invalid(format!("segment {s} has {} sections, not {}", inner.parts.len(), section + 1)))?;
        if out.len() != part.size {
            return Err(Error::Invalid(format!("a buffer of {} bytes for section {} of {} bytes", out.len(), kind::label(part.stored.kind, part.stored.index), part.size)));
        }
        let shown = match (part.needs_shown(), part.coding) {
            (true, Some(c)) => Some(self.shown_from_source(info, inner, c).map_err(|e| self.in_segment(s, e))?),
            _ => None,
        };
        self.read_part(info, inner, part, out, &mut Vec::new(), &mut Vec::new(), shown.as_deref()).map_err(|e| self.in_segment(s, e))
    }

    /// The shown voxels of scheme-4 atlas `c`, from the segment's L3 array
    /// and tables read (and restored) for it.
    fn shown_from_source(&self, info: &SegmentInfo, inner: &Inner, c: coding::Coding) -> Result<Vec<crate::shown::TileMask>, Error> {
        let mut read = Vec::new();
        for part in inner.parts.iter().filter(|p| matches!(p.stored.kind, kind::L3_NODES | kind::BRICK_TABLE | kind::CHANNEL_TABLE)) {
            let mut buf = Vec::new();
            buf.try_reserve_exact(part.size).map_err(|_| Error::Invalid(format!("no memory for a section of {} bytes", part.size)))?;
            buf.resize(part.size, 0);
            self.read_part(info, inner, part, &mut buf, &mut Vec::new(), &mut Vec::new(), None)?;
            read.push(((part.stored.kind, part.stored.index), buf));
        }
        let find = |k: u32, i: u32| read.iter().find(|(key, _)| *key == (k, i)).map(|(_, b)| &b[..]);
        Ok(coding::shown_of(&[c], Some(&info.metadata), &find)?.pop().unwrap_or_default())
    }

    /// Reads bytes `at` of a segment's body: from the source, or from the
    /// body a wrapped segment was decompressed to.
    fn read_body(&self, info: &SegmentInfo, inner: &Inner, at: u64, buf: &mut [u8]) -> Result<(), Error> {
        match &inner.wrapped {
            Some(body) => Ok(body.read_at(at, buf)?),
            None => self.io.read(info.offset + at, buf),
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn read_part(&self, info: &SegmentInfo, inner: &Inner, part: &Part, out: &mut [u8], stored: &mut Vec<u8>, scratch: &mut Vec<u8>, shown: Option<&[crate::shown::TileMask]>) -> Result<(), Error> {
        let e = &part.stored;
        if part.coding.is_none() {
            self.read_body(info, inner, e.offset, out)?;
            return check_sum(e, out);
        }
        // Bounded by the source: the section lies inside it.
        stored.clear();
        stored.resize(e.size as usize, 0);
        self.read_body(info, inner, e.offset, stored)?;
        check_sum(e, stored)?;
        coding::restore_part(part, stored, out, scratch, shown)
    }

    /// Fills `out`, one buffer per section of segment `s` in
    /// [`SegmentInfo::sections`] order, each exactly the section's `size`
    /// (the metadata's may be empty: it is then skipped), with the segment's
    /// GPU-ready bytes: read, restored, checksums checked, then the sections
    /// validated against each other and the metadata ([`Checked`]), as every
    /// reader does before upload. Buffers of 4-byte items (every section but
    /// the metadata and the atlases) must start at a multiple of 4 bytes.
    /// Sections are read in parallel.
    pub fn fill_segment(&self, s: usize, out: &mut [&mut [u8]]) -> Result<(), Error> {
        let (info, inner) = self.segments.get(s).ok_or(Error::NoSegment { segment: s, count: self.segments.len() })?;
        if out.len() != info.sections.len() {
            return Err(Error::Invalid(format!("{} buffers for the {} sections of segment {s}", out.len(), info.sections.len())));
        }
        for (sec, o) in info.sections.iter().zip(out.iter()) {
            let skipped = sec.kind == kind::METADATA && o.is_empty();
            if o.len() as u64 != sec.size && !skipped {
                return Err(Error::Invalid(format!("a buffer of {} bytes for section {} of {} bytes", o.len(), sec.label(), sec.size)));
            }
            if !matches!(sec.kind, kind::METADATA | kind::ATLAS) && !(o.as_ptr() as usize).is_multiple_of(4) {
                return Err(Error::Invalid(format!("the buffer for section {} does not start at a multiple of 4 bytes", sec.label())));
            }
        }
        let parts: Vec<(&Part, &mut [u8], ())> = inner.parts.iter().zip(out.iter_mut()).map(|(part, o)| (part, &mut **o, ())).collect();
        let filled = coding::restore_parts(
            parts,
            Some(&info.metadata),
            || (Vec::new(), Vec::new()),
            |(stored, scratch), part, o, _, shown| match part.stored.kind == kind::METADATA && o.is_empty() {
                true => Ok(()),
                false => self.read_part(info, inner, part, o, stored, scratch, shown),
            },
        );
        filled.map_err(|e| self.in_segment(s, e))?;
        let find = |k: u32, i: u32| -> Result<&[u8], Error> { info.section(k, i).and_then(|j| out.get(j)).map(|b| &b[..]).ok_or(Error::Missing { kind: k, index: i }) };
        Checked::from_sections(info.metadata.clone(), find).map(|_| ()).map_err(|e| self.in_segment(s, e))
    }

    /// [`Reader::fill_segment`] into `buffers` (owned, 4-byte aligned,
    /// resized to segment `s`'s sections and reused from one segment to
    /// the next), the metadata's included.
    pub fn fill_buffers(&self, s: usize, buffers: &mut SectionBuffers) -> Result<(), Error> {
        let info = self.segment(s)?;
        buffers.sizes = info.sections.iter().map(|x| x.size as usize).collect();
        buffers.words.resize_with(buffers.sizes.len(), Vec::new);
        for (w, &size) in buffers.words.iter_mut().zip(&buffers.sizes) {
            // Fresh memory zeroed lazily: a size that lies costs address space until reading fails.
            *w = coding::reuse_words(std::mem::take(w), size.div_ceil(4)).ok_or_else(|| Error::Invalid(format!("no memory for a section of {size} bytes")))?;
        }
        let mut views: Vec<&mut [u8]> = buffers.words.iter_mut().zip(&buffers.sizes).map(|(w, &n)| &mut bytemuck::cast_slice_mut::<u32, u8>(w)[..n]).collect();
        self.fill_segment(s, &mut views)
    }

    /// Segment `s`'s restored body as an [`Asset`] of its own (its frames
    /// counted from 0), as [`Asset::segment`] gives it, byte for byte: what
    /// `vdbcook_validate`'s renderer uploads. Read into `buf` when it has
    /// room (the words of an earlier one, [`Asset::into_words`]), every
    /// section's stored checksum, the padding and (restored) every restored
    /// checksum checked; the validator ([`Checked::new`]) is the caller's to
    /// run, as every user of an `Asset` does (the renderer's upload does).
    pub fn segment_asset(&self, s: usize, buf: Vec<u64>) -> Result<Asset, Error> {
        let (info, inner) = self.segments.get(s).ok_or(Error::NoSegment { segment: s, count: self.segments.len() })?;
        self.body_asset(info, inner, buf).map_err(|e| self.in_segment(s, e))
    }

    fn body_asset(&self, info: &SegmentInfo, inner: &Inner, buf: Vec<u64>) -> Result<Asset, Error> {
        let size = inner.wrapped.as_ref().map_or(info.stored_size as usize, |b| Vec::len(b));
        let coded = info.supercompressed();
        // A plainly stored body is read straight into the caller's buffer; one to restore, into its own.
        let (stored_buf, out_buf) = if coded { (Vec::new(), buf) } else { (buf, Vec::new()) };
        let no_memory = || Error::Invalid(format!("no memory for the {size} bytes of a segment"));
        let mut words = coding::reuse_words(stored_buf, size.div_ceil(8)).ok_or_else(no_memory)?;
        let bytes = bytemuck::cast_slice_mut::<u64, u8>(&mut words);
        bytes[size..].fill(0);
        self.read_body(info, inner, 0, &mut bytes[..size])?;
        let stored = Asset::stored_body_from_words(words, size, self.version)?;
        let computed = checksum(stored.bytes().get(..segments::head_len(stored.sections.len())).unwrap_or_default());
        if computed != inner.head_checksum {
            return Err(Error::HeaderChecksum { stored: inner.head_checksum, computed });
        }
        stored.verify()?;
        match coded {
            true => stored.restored_into(out_buf),
            false => Ok(stored),
        }
    }

    /// Validates the whole asset a segment at a time, as `Asset::open` and
    /// [`Asset::check`] do: every segment read, restored and validated
    /// ([`Checked`]), and every byte after the segment table that no body
    /// holds zero. Reads the whole file: for an import step, not for playback.
    pub fn check(&self) -> Result<(), Error> {
        let mut buf = Vec::new();
        for s in 0..self.segments.len() {
            let a = self.segment_asset(s, buf)?;
            Checked::new(&a).map_err(|e| self.in_segment(s, e))?;
            buf = a.into_words().unwrap_or_default();
        }
        self.zero_between_segments()
    }

    /// Every byte after the segment table that no body holds is zero.
    fn zero_between_segments(&self) -> Result<(), Error> {
        if !self.segmented {
            return Ok(());
        }
        let mut at = (HEADER_LEN + segments::SEGMENT_ENTRY_LEN * self.segments.len()) as u64;
        let ends = self.segments.iter().map(|(i, _)| (i.offset, i.offset + i.stored_size)).chain([(self.io.source.len(), self.io.source.len())]);
        let mut chunk = Vec::new();
        for (start, end) in ends {
            while at < start {
                let n = (start - at).min(1 << 16);
                chunk.resize(n as usize, 0);
                self.io.read(at, &mut chunk)?;
                if let Some(k) = chunk.iter().position(|&x| x != 0) {
                    return Err(Error::Padding(at + k as u64));
                }
                at += n;
            }
            at = at.max(end);
        }
        Ok(())
    }
}

impl Io {
    /// Segment table entry `e`'s body (of a file of version `version` and
    /// `count` segments), as [`Io::body`] reads it: a wrapped one (the only
    /// segment) read whole, its frame checked against the entry and
    /// decompressed, the body inside read from memory.
    fn segment(&self, version: u32, e: &SegmentEntry, count: usize) -> Result<(SegmentInfo, Inner), Error> {
        // The body's header, which tells a wrapped body by its first bytes.
        let header = self.read_vec(e.offset, HEADER_LEN.min(e.size as usize) as u64)?;
        if version < segments::VERSION_13 || !crate::wrap::is_wrapped(&header) {
            return self.body_with(header, version, e.offset, e.size, Some(e));
        }
        if count > 1 {
            return Err(crate::wrap::among_segments(count));
        }
        crate::wrap::check_frame_len(e.size)?;
        let frame = self.read_vec(e.offset, e.size)?;
        let computed = checksum(&frame);
        if computed != e.head_checksum {
            return Err(Error::HeaderChecksum { stored: e.head_checksum, computed });
        }
        let (words, len) = crate::wrap::unwrap(&frame)?;
        let body = std::sync::Arc::new(bytemuck::cast_slice::<u64, u8>(&words)[..len].to_vec());
        let io = Io { source: Box::new(body.clone()), bytes_read: AtomicU64::new(0) };
        let (mut info, mut inner) = io.body(version, 0, len as u64, None)?;
        if info.frame_count != e.frame_count {
            return Err(Error::Invalid(format!("its metadata has {} frames, the segment table {}", info.frame_count, e.frame_count)));
        }
        (info.first_frame, info.offset, info.stored_size, info.wrapped) = (e.first_frame, e.offset, e.size, true);
        inner.wrapped = Some(body);
        Ok((info, inner))
    }

    /// The body at `offset`, `size` bytes, of a file of version `version`,
    /// named by segment table entry `entry` (none for a file that is one
    /// body): its header and table checked, its metadata and coding records
    /// read, its restored layout planned.
    fn body(&self, version: u32, offset: u64, size: u64, entry: Option<&SegmentEntry>) -> Result<(SegmentInfo, Inner), Error> {
        let header = self.read_vec(offset, HEADER_LEN.min(size as usize) as u64)?;
        self.body_with(header, version, offset, size, entry)
    }

    /// [`Io::body`] of a body whose `header` (its first bytes, up to
    /// [`HEADER_LEN`]) is read already.
    fn body_with(&self, header: Vec<u8>, version: u32, offset: u64, size: u64, entry: Option<&SegmentEntry>) -> Result<(SegmentInfo, Inner), Error> {
        head::body_version(&header, size)?;
        let n = head::table_len(&header, ENTRY_LEN, MAX_SECTIONS, Error::SectionCount, size)?;
        let table = self.read_vec(offset + HEADER_LEN as u64, n as u64)?;
        head::check_checksum(&header, &table)?;
        let head_checksum = checksum(&[header.as_slice(), &table].concat());
        if let Some(e) = entry.filter(|e| e.head_checksum != head_checksum) {
            return Err(Error::HeaderChecksum { stored: e.head_checksum, computed: head_checksum });
        }
        // The coding section is read once: the table's check needs it, and the restore plan.
        let mut coding_bytes = None;
        let stored = head::sections(&table, size, version, offset, |e| {
            let b = self.read_section(offset, e)?;
            if e.index == 0 {
                coding_bytes = Some(b.clone());
            }
            Ok(std::borrow::Cow::Owned(b))
        })?;
        let find = |k: u32| stored.iter().find(|e| (e.kind, e.index) == (k, 0));
        let meta_entry = find(kind::METADATA).ok_or(Error::Missing { kind: kind::METADATA, index: 0 })?;
        let metadata = Metadata::from_bytes_of(&self.read_section(offset, meta_entry)?, version)?;
        if let Some(e) = entry.filter(|e| e.frame_count != metadata.frame_count) {
            return Err(Error::Invalid(format!("its metadata has {} frames, the segment table {}", metadata.frame_count, e.frame_count)));
        }
        let plan = coding::plan(&stored, coding_bytes.as_deref())?;
        // A body stored plainly is used as it is stored; one with supercompressed sections as the plan lays it out.
        let plain = coding_bytes.is_none();
        let sections = plan
            .parts
            .iter()
            .map(|p| SectionInfo {
                kind: p.stored.kind,
                index: p.stored.index,
                size: p.size as u64,
                offset: if plain { p.stored.offset } else { p.offset as u64 },
                checksum: p.checksum(),
                stored_size: p.stored.size,
                compressed: p.coding.is_some(),
                texture: (p.stored.kind == kind::ATLAS).then(|| TextureInfo::of(&metadata, p.stored.index)).flatten(),
            })
            .collect();
        let body_size = if plain { size } else { plan.len as u64 };
        let (first_frame, frame_count) = entry.map_or((0, metadata.frame_count), |e| (e.first_frame, e.frame_count));
        let info = SegmentInfo { first_frame, frame_count, offset, stored_size: size, body_size, wrapped: false, metadata, sections };
        Ok((info, Inner { head_checksum, parts: plan.parts, wrapped: None }))
    }

    /// Reads `len` bytes at `offset` into a new buffer, counted; refused
    /// before anything is allocated when they lie past the source's end.
    fn read_vec(&self, offset: u64, len: u64) -> Result<Vec<u8>, Error> {
        if offset.checked_add(len).is_none_or(|end| end > self.source.len()) {
            return Err(Error::Io(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, format!("{len} bytes at {offset} lie past the end of the {}-byte source", self.source.len()))));
        }
        let mut b = vec![0u8; len as usize];
        self.read(offset, &mut b)?;
        Ok(b)
    }

    fn read(&self, offset: u64, buf: &mut [u8]) -> Result<(), Error> {
        self.source.read_at(offset, buf)?;
        self.bytes_read.fetch_add(buf.len() as u64, Ordering::Relaxed);
        Ok(())
    }

    /// A section's stored bytes (of the body at `body`), their checksum checked.
    fn read_section(&self, body: u64, e: &SectionEntry) -> Result<Vec<u8>, Error> {
        let b = self.read_vec(body + e.offset, e.size)?;
        check_sum(e, &b)?;
        Ok(b)
    }
}

fn check_sum(e: &SectionEntry, b: &[u8]) -> Result<(), Error> {
    let computed = checksum(b);
    match computed == e.checksum {
        true => Ok(()),
        false => Err(Error::SectionChecksum { kind: e.kind, index: e.index, stored: e.checksum, computed }),
    }
}
