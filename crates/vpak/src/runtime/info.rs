//! What the runtime reader says of a segment and its sections, and owned
//! buffers for them.

use crate::{kind, Format, Metadata};

/// One section of a segment as a GPU is given it (restored).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SectionInfo {
    /// What it holds ([`crate::kind`]) and which of its kind it is.
    pub kind: u32,
    pub index: u32,
    /// Bytes of the restored section: what to allocate and upload.
    pub size: u64,
    /// Its offset in the restored body ([`Reader::segment_asset`]'s bytes).
    pub offset: u64,
    /// XXH3-64 of the restored bytes.
    pub checksum: u64,
    /// Bytes the source stores (fewer when it is supercompressed; in a
    /// wrapped segment, what the body inside the frame stores).
    pub stored_size: u64,
    /// Whether it is stored supercompressed (restored on reading).
    pub compressed: bool,
    /// For an atlas (kind 10): the 3D texture it is.
    pub texture: Option<TextureInfo>,
}

/// The 3D texture an atlas section is (docs/format.md, "Bricks, planes and atlases").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextureInfo {
    /// The plane it belongs to, and which of the plane's atlases it is.
    pub plane: u32,
    pub atlas: u32,
    /// Its texels' format, and lanes per texel (1, 2 or 4).
    pub format: Format,
    pub lanes: u32,
    /// Its size in texels (x, y, z); BC formats: in texels too, 4×4 blocks along x and y.
    pub extent: [u32; 3],
}

impl TextureInfo {
    /// The texture of atlas section `index` of a body with metadata `meta`.
    pub(crate) fn of(meta: &Metadata, index: u32) -> Option<TextureInfo> {
        let mut first = 0usize;
        for (p, info) in meta.planes.iter().enumerate() {
            if let Some(a) = (index as usize).checked_sub(first).filter(|&a| a < info.atlases.len()) {
                let layout = crate::AtlasLayout { plane: info.plane, atlas: info.atlases[a] };
                return Some(TextureInfo { plane: p as u32, atlas: a as u32, format: info.plane.format, lanes: info.plane.lanes, extent: layout.texels() });
            }
            first += info.atlases.len();
        }
        None
    }
}

impl SectionInfo {
    /// Whether a renderer uploads it: every section but the metadata ([`kind::uploaded`]).
    pub fn uploaded(&self) -> bool {
        kind::uploaded(self.kind)
    }

    /// "l3 nodes", "brick atlas 3".
    pub fn label(&self) -> String {
        kind::label(self.kind, self.index)
    }
}

/// One segment: its frames, where it lies, its own metadata and its sections.
#[derive(Clone, Debug)]
pub struct SegmentInfo {
    /// Its first frame, counted over the whole asset, and its frame count.
    pub first_frame: u32,
    pub frame_count: u32,
    /// Where its stored body lies in the source, and its size there.
    pub offset: u64,
    pub stored_size: u64,
    /// Bytes of its restored body ([`Reader::segment_asset`]).
    pub body_size: u64,
    /// Whether the source stores the body wrapped in one zstd frame (version
    /// 13): it was read and decompressed when the asset was opened, and its
    /// sections are read from memory, not from the source.
    pub wrapped: bool,
    /// The body's own metadata: its planes, channel placement, index offset
    /// and frames (numbered from 0), which the GPU records of the segment are made from.
    pub metadata: Metadata,
    /// Its sections (the coding record left out), in the body's table order.
    pub sections: Vec<SectionInfo>,
}

impl SegmentInfo {
    /// Its frames, counted over the whole asset.
    pub fn frames(&self) -> std::ops::Range<usize> {
        self.first_frame as usize..self.first_frame as usize + self.frame_count as usize
    }

    /// The position of section (`kind`, `index`) in [`SegmentInfo::sections`].
    pub fn section(&self, kind: u32, index: u32) -> Option<usize> {
        self.sections.iter().position(|s| (s.kind, s.index) == (kind, index))
    }

    /// Bytes a renderer uploads to draw any of its frames (its sections but the metadata).
    pub fn gpu_bytes(&self) -> u64 {
        self.sections.iter().filter(|s| s.uploaded()).map(|s| s.size).sum()
    }

    /// Whether any section is stored supercompressed.
    pub fn supercompressed(&self) -> bool {
        self.sections.iter().any(|s| s.compressed)
    }
}

/// Owned buffers for one segment's sections ([`Reader::fill_buffers`]):
/// section `i` of [`SegmentInfo::sections`] is [`SectionBuffers::section`]`(i)`.
#[derive(Default)]
pub struct SectionBuffers {
    pub(super) words: Vec<Vec<u32>>,
    pub(super) sizes: Vec<usize>,
}

impl SectionBuffers {
    /// Section `i`'s bytes (empty past the last).
    pub fn section(&self, i: usize) -> &[u8] {
        self.words.get(i).zip(self.sizes.get(i)).map_or(&[], |(w, &n)| &bytemuck::cast_slice::<u32, u8>(w)[..n])
    }

    /// Sections held.
    pub fn len(&self) -> usize {
        self.sizes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.sizes.is_empty()
    }
}
