//! An opened asset: a file mapped (or bytes in memory), its header and
//! section or segment table checked; a segment is an `Asset` over part of
//! the same mapping.

use crate::segments::{self, SegmentEntry};
use crate::{checksum, kind, Checked, Error, Metadata, Section, SectionEntry, ENTRY_LEN, HEADER_LEN, MAX_SECTIONS};
use std::path::Path;

enum Bytes {
    Mapped(memmap2::Mmap),
    /// Owned bytes in 8-byte-aligned storage, `len` of them.
    Owned(Vec<u64>, usize),
}

impl Bytes {
    fn all(&self) -> &[u8] {
        match self {
            Bytes::Mapped(m) => m,
            Bytes::Owned(w, len) => &bytemuck::cast_slice(w)[..*len],
        }
    }
}

/// An opened asset: header checked, sections (or segments) located (and,
/// with [`Asset::verify`], checksummed).  Slices point into the file's
/// mapping. A version-6 file is one body of sections; a version-7 file is a
/// table of segments, each a body read through [`Asset::segment`] (an
/// `Asset` over the same mapping).
#[derive(Clone)]
pub struct Asset {
    bytes: std::sync::Arc<Bytes>,
    /// The window of `bytes` this asset is: the whole file, or one segment's body.
    start: usize,
    len: usize,
    /// A body's sections (none in a file with a segment table).
    pub sections: Vec<SectionEntry>,
    /// A segmented file's table (empty for a body).
    table: Vec<SegmentEntry>,
    /// The file's version (a segment's: its file's).
    version: u32,
}

impl Asset {
    /// Maps a file and checks its header, section (or segment) table and every checksum.
    pub fn open(path: &Path) -> Result<Asset, Error> {
        let a = Asset::open_unverified(path)?;
        a.verify()?;
        Ok(a)
    }

    /// Maps a file and checks its header and section (or segment) table only.
    pub fn open_unverified(path: &Path) -> Result<Asset, Error> {
        let f = std::fs::File::open(path)?;
        if f.metadata()?.len() < HEADER_LEN as u64 {
            return Err(Error::Magic);
        }
        // SAFETY: read-only mapping; the asset is assumed not to change while open.
        let map = unsafe { memmap2::Mmap::map(&f)? };
        Asset::parse(Bytes::Mapped(map))
    }

    /// Maps an open file (an unnamed temporary one, say) and checks its header
    /// and section (or segment) table only.
    pub fn from_file(f: &std::fs::File) -> Result<Asset, Error> {
        if f.metadata()?.len() < HEADER_LEN as u64 {
            return Err(Error::Magic);
        }
        // SAFETY: read-only mapping of a file this process wrote and no longer changes.
        let map = unsafe { memmap2::Mmap::map(f)? };
        Asset::parse(Bytes::Mapped(map))
    }

    /// Parses owned bytes (checks the header; call [`Asset::verify`] for checksums).
    pub fn from_bytes(b: &[u8]) -> Result<Asset, Error> {
        let mut words = vec![0u64; b.len().div_ceil(8)];
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..b.len()].copy_from_slice(b);
        Asset::parse(Bytes::Owned(words, b.len()))
    }

    /// This asset's bytes: the whole file, or a segment's body.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes.all()[self.start..self.start + self.len]
    }

    fn parse(bytes: Bytes) -> Result<Asset, Error> {
        let len = bytes.all().len();
        if bytes.all().starts_with(&segments::PART_MAGIC) {
            return Err(Error::Part);
        }
        Asset::parse_at(std::sync::Arc::new(bytes), 0, len)
    }

    /// Parses the asset that is bytes `[start, start + len)` of `bytes`.
    fn parse_at(bytes: std::sync::Arc<Bytes>, start: usize, len: usize) -> Result<Asset, Error> {
        let mut whole = Asset { bytes, start, len, sections: Vec::new(), table: Vec::new(), version: 0 };
        whole.version = whole.version_field()?;
        match whole.version {
            segments::BODY_VERSION => whole.body(),
            v if segments::is_container_version(v) => whole.container(),
            v => Err(Error::Version(v)),
        }
    }

    /// The file's format version (6 to [`crate::VERSION`]).
    pub fn version(&self) -> u32 {
        self.version
    }

    /// The version field, after the magic and the file size are checked.
    fn version_field(&self) -> Result<u32, Error> {
        crate::head::version(self.bytes(), self.len as u64)
    }

    /// Checks a table of entries of `entry_len` bytes after the header
    /// against the header checksum; returns the table's bytes.
    fn table_bytes(&self, entry_len: usize, max: u32, count_error: fn(u32) -> Error) -> Result<&[u8], Error> {
        let b = self.bytes();
        let n = crate::head::table_len(b, entry_len, max, count_error, b.len() as u64)?;
        let table = &b[HEADER_LEN..HEADER_LEN + n];
        crate::head::check_checksum(b, table)?;
        Ok(table)
    }

    /// A body (version 6): its section table; a coding section only where
    /// the file's version allows one.
    fn body(mut self) -> Result<Asset, Error> {
        let table = self.table_bytes(ENTRY_LEN, MAX_SECTIONS, Error::SectionCount)?;
        self.sections = crate::head::sections(table, self.len as u64, self.version, self.start as u64, |e| Ok(std::borrow::Cow::Borrowed(self.raw(e))))?;
        Ok(self)
    }

    /// A file of segments (version 7): its segment table, each body in
    /// order, inside the file, frames counted on from 0 without a gap.
    fn container(mut self) -> Result<Asset, Error> {
        let table = self.table_bytes(segments::SEGMENT_ENTRY_LEN, segments::MAX_SEGMENTS, Error::SegmentCount)?;
        self.table = crate::head::segments(table, self.len as u64, self.version)?;
        Ok(self)
    }

    /// Maps a part file (`cook --part`): its part header, and the segments it holds as an asset.
    pub fn open_part(path: &Path) -> Result<(segments::PartInfo, Asset), Error> {
        Asset::from_part_file(&std::fs::File::open(path)?)
    }

    /// [`Asset::open_part`] of an open file.
    pub fn from_part_file(f: &std::fs::File) -> Result<(segments::PartInfo, Asset), Error> {
        // SAFETY: read-only mapping; the part is assumed not to change while open.
        Asset::part(Bytes::Mapped(unsafe { memmap2::Mmap::map(f)? }))
    }

    /// [`Asset::open_part`] of bytes in memory.
    pub fn part_from_bytes(b: &[u8]) -> Result<(segments::PartInfo, Asset), Error> {
        let mut words = vec![0u64; b.len().div_ceil(8)];
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..b.len()].copy_from_slice(b);
        Asset::part(Bytes::Owned(words, b.len()))
    }

    fn part(bytes: Bytes) -> Result<(segments::PartInfo, Asset), Error> {
        let info = segments::PartInfo::parse(bytes.all())?;
        let len = bytes.all().len() - segments::PART_HEADER_LEN;
        let asset = Asset::parse_at(std::sync::Arc::new(bytes), segments::PART_HEADER_LEN, len)?;
        if !asset.is_segmented() {
            return Err(Error::NotPart);
        }
        Ok((info, asset))
    }

    /// The page-aligned range of the mapping this asset's bytes lie in.
    #[cfg(unix)]
    fn pages(&self) -> (usize, usize) {
        let start = self.start & !4095;
        (start, self.start + self.len - start)
    }

    /// Reads this asset's (or segment's) pages in with one call, not a fault
    /// per page, where the system can (Linux 5.14+): a hint for a reader
    /// about to read every byte, as `join` is.
    pub fn populate(&self) {
        #[cfg(target_os = "linux")]
        if let Bytes::Mapped(m) = &*self.bytes {
            let (at, len) = self.pages();
            let _ = m.advise_range(memmap2::Advice::PopulateRead, at, len);
        }
    }

    /// Drops this asset's (or segment's) pages from the process's memory; a
    /// later read takes them from the file again. For readers that go
    /// through a large file a segment at a time.
    pub fn release(&self) {
        #[cfg(unix)]
        if let Bytes::Mapped(m) = &*self.bytes {
            let (at, len) = self.pages();
            // SAFETY: a read-only mapping of a file that is not changed while
            // open: dropped pages read back as the same bytes.
            let _ = unsafe { m.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, at, len) };
        }
    }

    /// Whether this is a file with a segment table (version 7).
    pub fn is_segmented(&self) -> bool {
        !self.table.is_empty()
    }

    /// Segments: a version-7 file's table, or one segment for a body.
    pub fn segment_count(&self) -> usize {
        self.table.len().max(1)
    }

    /// The segment table (for a body: one segment of all its frames, from its metadata).
    pub fn segments(&self) -> Result<Vec<SegmentEntry>, Error> {
        if self.is_segmented() {
            return Ok(self.table.clone());
        }
        let frames = self.metadata()?.frame_count;
        let head = self.bytes().get(..segments::head_len(self.sections.len())).unwrap_or_default();
        Ok(vec![SegmentEntry { first_frame: 0, frame_count: frames, offset: 0, size: self.len as u64, head_checksum: checksum(head) }])
    }

    /// Segment `s`'s body ready for use, as an asset of its own (its frames
    /// counted from 0): [`Asset::stored_segment`], its supercompressed
    /// sections restored ([`Asset::restored`]).
    pub fn segment(&self, s: usize) -> Result<Asset, Error> {
        let seg = self.stored_segment(s)?;
        seg.restored().map_err(|e| if self.is_segmented() { Error::InSegment(s, Box::new(e)) } else { e })
    }

    /// Whether this body holds supercompressed sections.
    pub fn is_coded(&self) -> bool {
        self.sections.iter().any(|s| s.kind == kind::CODING)
    }

    /// This body with its supercompressed sections restored to the bytes the
    /// cooker chose (each checked against its checksum): a body in memory.
    /// A body without them is itself.
    pub fn restored(&self) -> Result<Asset, Error> {
        self.restored_into(Vec::new())
    }

    /// [`Asset::restored`], the restored body written into `buf` when it
    /// has room (a buffer given back by [`Asset::into_words`], say).
    pub fn restored_into(&self, buf: Vec<u64>) -> Result<Asset, Error> {
        if !self.is_coded() {
            return Ok(self.clone());
        }
        let stored: Vec<(SectionEntry, &[u8])> = self.sections.iter().map(|e| (*e, self.raw(e))).collect();
        let (words, len) = crate::coding::restore_body(&stored, buf)?;
        Asset::parse(Bytes::Owned(words, len))
    }

    /// A segment's stored body held in `words` (`len` bytes of them) of a
    /// file of version `version`: its header (version 6) and section table checked.
    pub(crate) fn stored_body_from_words(words: Vec<u64>, len: usize, version: u32) -> Result<Asset, Error> {
        let body = Asset { bytes: std::sync::Arc::new(Bytes::Owned(words, len)), start: 0, len, sections: Vec::new(), table: Vec::new(), version };
        crate::head::body_version(body.bytes(), len as u64)?;
        body.body()
    }

    /// The words this asset was read into, for reuse ([`Asset::restored_into`],
    /// the runtime reader's `segment_asset`): `None` for a mapped file, or
    /// while a clone or a segment of it lives.
    pub fn into_words(self) -> Option<Vec<u64>> {
        match std::sync::Arc::try_unwrap(self.bytes).ok()? {
            Bytes::Owned(words, _) => Some(words),
            Bytes::Mapped(_) => None,
        }
    }

    /// Segment `s`'s body as the file stores it (supercompressed sections
    /// left so), as an asset of its own (its frames counted from 0); for a
    /// body, segment 0 is the asset itself. Checks the body's header and
    /// section table, and that they are the ones the segment table names.
    pub fn stored_segment(&self, s: usize) -> Result<Asset, Error> {
        if !self.is_segmented() {
            return match s {
                0 => Ok(self.clone()),
                _ => Err(Error::NoSegment { segment: s, count: 1 }),
            };
        }
        let e = self.table.get(s).ok_or(Error::NoSegment { segment: s, count: self.table.len() })?;
        let seg = Asset { bytes: self.bytes.clone(), start: self.start + e.offset as usize, len: e.size as usize, sections: Vec::new(), table: Vec::new(), version: self.version };
        let in_segment = |err| Error::InSegment(s, Box::new(err));
        if self.is_wrapped(s) {
            if self.table.len() > 1 {
                return Err(in_segment(crate::wrap::among_segments(self.table.len())));
            }
            // The frame is checked whole before it is decompressed; the body inside, as any body.
            let computed = checksum(seg.bytes());
            if computed != e.head_checksum {
                return Err(in_segment(Error::HeaderChecksum { stored: e.head_checksum, computed }));
            }
            let (words, len) = crate::wrap::unwrap(seg.bytes()).map_err(in_segment)?;
            return Asset::stored_body_from_words(words, len, self.version).map_err(in_segment);
        }
        let body = crate::head::body_version(seg.bytes(), seg.len as u64).and_then(|()| seg.body()).map_err(in_segment)?;
        let head = &body.bytes()[..segments::head_len(body.sections.len())];
        let computed = checksum(head);
        if computed != e.head_checksum {
            return Err(in_segment(Error::HeaderChecksum { stored: e.head_checksum, computed }));
        }
        Ok(body)
    }

    /// Segment `s`'s bytes exactly as the file stores them (a wrapped body's
    /// frame, [`crate::wrap`]), for copying (`join`); check them first with
    /// [`Asset::stored_segment`].
    pub fn stored_bytes(&self, s: usize) -> Result<&[u8], Error> {
        match self.table.get(s) {
            Some(e) => Ok(&self.bytes()[e.offset as usize..(e.offset + e.size) as usize]),
            None if !self.is_segmented() && s == 0 => Ok(self.bytes()),
            None => Err(Error::NoSegment { segment: s, count: self.segment_count() }),
        }
    }

    /// Whether segment `s` is stored wrapped in one zstd frame ([`crate::wrap`]).
    pub fn is_wrapped(&self, s: usize) -> bool {
        self.stored_bytes(s).is_ok_and(|b| self.version >= segments::VERSION_13 && crate::wrap::is_wrapped(b))
    }

    /// Bytes a renderer uploads to draw any frame, summed over the segments:
    /// every section but the metadata, at its restored size (from the coding
    /// records; nothing is decompressed).
    pub fn gpu_bytes(&self) -> Result<u64, Error> {
        let mut total = 0;
        for s in 0..self.segment_count() {
            let seg = self.stored_segment(s)?;
            let codings = match seg.section(kind::CODING, 0) {
                Ok(b) => crate::coding::Coding::parse_all(b)?,
                Err(_) => Vec::new(),
            };
            for e in seg.sections.iter().filter(|e| kind::uploaded(e.kind)) {
                total += codings.iter().find(|c| (c.kind, c.index) == (e.kind, e.index)).map_or(e.size, |c| c.raw_size);
            }
        }
        Ok(total)
    }

    /// Frames of the whole asset (from the segment table; a body's from its metadata).
    pub fn frame_count(&self) -> Result<usize, Error> {
        Ok(self.segments()?.last().map_or(0, |e| e.frames().end))
    }

    /// Every segment's planes' formats, each name once ("bc4+bc7"): the merged
    /// metadata's planes are the first segment's only.
    pub fn format_names(&self) -> Result<String, Error> {
        self.over_segments(|m| m.format_names())
    }

    /// Channel `c`'s formats over every segment, each name once.
    pub fn channel_format_names(&self, c: usize) -> Result<String, Error> {
        self.over_segments(|m| m.channel_format_names(c))
    }

    /// `names` of every segment's metadata, joined by [`crate::union_names`].
    fn over_segments(&self, names: impl Fn(&Metadata) -> String) -> Result<String, Error> {
        let mut all = String::new();
        for s in 0..self.segment_count() {
            all = crate::union_names(&all, &names(&self.stored_segment(s)?.metadata()?));
        }
        Ok(all)
    }

    /// The segment holding frame `frame` of the whole asset, and the frame's index within it.
    pub fn locate(&self, frame: usize) -> Option<(usize, usize)> {
        if !self.is_segmented() {
            return Some((0, frame));
        }
        let s = self.table.partition_point(|e| e.first_frame as usize + e.frame_count as usize <= frame);
        let e = self.table.get(s)?;
        (frame >= e.first_frame as usize).then(|| (s, frame - e.first_frame as usize))
    }

    /// Checks every section's checksum and that the padding between sections
    /// (and between segments) is zero, so every byte of a verified file is
    /// the one written (a cache of assets may trust it); the first failure is the error.
    pub fn verify(&self) -> Result<(), Error> {
        if self.is_segmented() {
            let mut spans = Vec::with_capacity(self.table.len());
            for s in 0..self.table.len() {
                // A segment at a time, its pages let go once checked (a long asset is larger than memory).
                let seg = self.stored_segment(s)?;
                let checked = seg.verify().map_err(|e| Error::InSegment(s, Box::new(e)));
                seg.release();
                checked?;
                spans.push((self.table[s].offset, self.table[s].offset + self.table[s].size));
            }
            return self.zero_between(HEADER_LEN + segments::SEGMENT_ENTRY_LEN * self.table.len(), spans);
        }
        for s in &self.sections {
            let computed = checksum(self.raw(s));
            if computed != s.checksum {
                return Err(Error::SectionChecksum { kind: s.kind, index: s.index, stored: s.checksum, computed });
            }
        }
        let spans = self.sections.iter().map(|s| (s.offset, s.offset + s.size)).collect();
        self.zero_between(HEADER_LEN + ENTRY_LEN * self.sections.len(), spans)
    }

    /// Every byte from `from` on outside `spans` is zero.
    fn zero_between(&self, from: usize, mut spans: Vec<(u64, u64)>) -> Result<(), Error> {
        let b = self.bytes();
        spans.sort_unstable();
        let mut at = from as u64;
        for (start, end) in spans.into_iter().chain([(b.len() as u64, b.len() as u64)]) {
            if let Some(k) = b.get(at as usize..start.max(at) as usize).and_then(|gap| gap.iter().position(|&x| x != 0)) {
                return Err(Error::Padding(at + k as u64));
            }
            at = at.max(end);
        }
        Ok(())
    }

    fn raw(&self, s: &SectionEntry) -> &[u8] {
        &self.bytes()[s.offset as usize..(s.offset + s.size) as usize]
    }

    /// Bytes of section (`kind`, `index`).
    pub fn section(&self, kind: u32, index: u32) -> Result<&[u8], Error> {
        if self.is_segmented() {
            return Err(Error::Segmented(self.table.len()));
        }
        self.sections.iter().find(|s| s.kind == kind && s.index == index).map(|s| self.raw(s)).ok_or(Error::Missing { kind, index })
    }

    /// Section (`kind`, 0) as `u32`s, without copying.
    pub fn u32s(&self, kind: u32) -> Result<&[u32], Error> {
        self.words(kind, 0)
    }

    /// Section (`kind`, 0) as `f32`s, without copying.
    pub fn f32s(&self, kind: u32) -> Result<&[f32], Error> {
        self.words(kind, 0)
    }

    /// Section (`kind`, `index`) as 4-byte items, without copying.
    pub fn words<T: bytemuck::Pod>(&self, kind: u32, index: u32) -> Result<&[T], Error> {
        let b = self.section(kind, index)?;
        bytemuck::try_cast_slice(b).map_err(|_| Error::Shape { kind, size: b.len(), unit: std::mem::size_of::<T>() })
    }

    /// The metadata: a body's own, or the whole sequence's merged from every
    /// segment's ([`segments::merged`]: frames, sources and value ranges of
    /// all; planes and placement of the first segment).
    pub fn metadata(&self) -> Result<Metadata, Error> {
        if self.is_segmented() {
            let metas = (0..self.table.len()).map(|s| self.stored_segment(s)?.metadata().map_err(|e| Error::InSegment(s, Box::new(e)))).collect::<Result<Vec<_>, _>>()?;
            if let Some((s, m)) = metas.iter().enumerate().find(|(s, m)| m.frame_count != self.table[*s].frame_count) {
                return Err(Error::InSegment(s, Box::new(Error::Invalid(format!("its metadata has {} frames, the segment table {}", m.frame_count, self.table[s].frame_count)))));
            }
            return segments::merged(&metas);
        }
        Metadata::from_bytes_of(self.section(kind::METADATA, 0)?, self.version)
    }

    /// Validates every segment ([`Checked`]) and returns the whole sequence's metadata.
    pub fn check(&self) -> Result<Metadata, Error> {
        for s in 0..self.segment_count() {
            let seg = self.segment(s)?;
            Checked::new(&seg).map_err(|e| if self.is_segmented() { Error::InSegment(s, Box::new(e)) } else { e })?;
            seg.release();
        }
        self.metadata()
    }

    /// Every section of a body, copied: edit them and `assemble` a new asset
    /// (its checksums are computed afresh).
    pub fn to_sections(&self) -> Vec<Section> {
        self.sections.iter().map(|s| Section { kind: s.kind, index: s.index, data: self.raw(s).to_vec().into() }).collect()
    }
}
