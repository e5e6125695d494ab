//! The `.vpak` asset: everything an engine needs to sample a cooked volume
//! sequence, laid out to be memory-mapped and uploaded without parsing.
//! Specified in `docs/format.md`.
//!
//! ```text
//! offset  size   field
//! 0       8      magic "VPAK\r\n\x1a\n"
//! 8       4      format version (6: one body, as below; 7: a segment table
//!                  of version-6 bodies, see [`segments`])
//! 12      4      flags (0; reserved)
//! 16      4      section count n
//! 20      4      reserved (0)
//! 24      8      file size in bytes
//! 32      8      header checksum: XXH3-64 of bytes [0, 32) followed by the section table
//! 40      24     reserved (0)
//! 64      32·n   section table, per section:
//!                  u32 kind, u32 index, u64 offset, u64 size, u64 XXH3-64 of the section's bytes
//! ...            sections, each at an offset that is a multiple of 256, zero padding between
//! ```
//! All integers are little-endian.  This crate has no CLI or GPU dependency:
//! it owns the container ([`Asset`], [`write_file`]), the node arrays
//! ([`nodes`]), the voxel formats, planes, atlas shapes and texel packing
//! ([`layout`]), and the one validator every reader calls ([`Checked`]).

mod asset;
mod atomic;
mod check;
pub mod coding;
mod context;
mod direct;
mod head;
mod l3_filter;
pub mod layout;
pub mod masks;
pub mod nodes;
pub mod resolution;
pub mod runtime;
pub mod segments;
pub mod settings;
mod shown;
mod tiles;
pub mod time;
pub mod wrap;

pub use asset::Asset;
pub use atomic::{directory_of, write_atomic, write_atomic_with, write_file, AtomicFile};
pub use check::{Checked, GpuChannel, GPU_CHANNEL_WORDS, MAX_CHANNELS};
pub use direct::DirectWriter;
pub use layout::{AtlasInfo, AtlasLayout, BrickSource, Format, Plane, PlaneInfo, BRICK_VOXELS, MAX_BRICK_BYTES};
pub use resolution::Resolution;
pub use segments::{assemble_segments, SegmentEntry, Writer};
pub use settings::{Fps, Level, LevelCount};
pub use time::{Time, DEFAULT_FPS};

#[doc(hidden)]
pub use serde; // for the settings macros
use serde::{Deserialize, Serialize};

pub const MAGIC: [u8; 8] = *b"VPAK\r\n\x1a\n";
/// 2: compact L3 nodes (sub-block states and sub-masks instead of 512-bit masks).
/// 3: channels (several grids in one tree), planes, per-channel brick ranges and tile values.
/// 4: each plane stores its own distinct bricks (brick tables), ranges and atlases.
/// 5: per-brick formats (a channel in several planes, a channel table choosing per
///    brick), `unorm16` and `constant` planes; levels of detail (a tree per frame
///    and level; `Metadata::levels`, `FrameInfo::coarse`).
/// 6: `Metadata::first_level`: an asset may leave out its finest levels (`cook --max-bytes`);
///    L1 nodes of 4³ to 32³ slots, as many as the tree needs (frame entries are word offsets).
/// 7: segments: a table of version-6 bodies, each a run of frames ([`segments`]).
/// 8: supercompressed sections ([`coding`]). 9: time (frame numbers and rate, [`time`]).
/// 10: channels at their own voxel size ([`resolution`]); the `tiles` coding filter.
pub const VERSION: u32 = segments::VERSION;
/// Levels an asset may have: level 4's bricks span 128³ source voxels, one
/// L1 slot, and the asset's index offset (a multiple of 128) keeps every
/// level's leaves on its L3 grid only up to there.
pub const MAX_LEVELS: u32 = 5;
pub const HEADER_LEN: usize = 64;
pub const ENTRY_LEN: usize = 32;
/// Every section starts at a multiple of this (GPU upload and mmap friendly).
pub const ALIGN: usize = 256;
/// A supercompressed section and the coding section start at a multiple of
/// this instead (they are restored, not uploaded, so 256 would only pad).
pub const CODED_ALIGN: usize = 8;
/// Refuse section tables larger than this (a sanity bound, not a format limit).
const MAX_SECTIONS: u32 = 1 << 16;

/// Section kinds.
pub mod kind {
    /// bincode-2 (standard config) serialisation of [`super::Metadata`].
    pub const METADATA: u32 = 1;
    /// u32 per frame and stored level: the word its L1 node starts at; level k of frame f at
    /// `(k − first_level) · frame_count + f` ([`super::Metadata::tree_index`]).
    pub const FRAMES: u32 = 2;
    pub const L1_NODES: u32 = 3;
    pub const L1_ENTRIES: u32 = 4;
    pub const L2_NODES: u32 = 5;
    pub const L2_ENTRIES: u32 = 6;
    pub const L3_NODES: u32 = 7;
    /// One f32 per channel per tile.
    pub const TILES: u32 = 8;
    /// Per plane (`index` = plane): (f32 min, f32 max) per plane brick per channel slot.
    pub const BRICK_RANGES: u32 = 9;
    /// One atlas of one plane (a 3D texture); `index` counts the atlases of
    /// plane 0, then of plane 1, … ([`super::Metadata::atlas_section`]).
    pub const ATLAS: u32 = 10;
    /// Per plane with a table (`index` = plane): its plane brick, u32 per brick.
    pub const BRICK_TABLE: u32 = 11;
    /// Per channel stored in several planes (`index` = channel): u32 per
    /// brick, the plane (bits 28 to 31: 0 the channel's `plane`, j its
    /// `alternates[j − 1]`) and the plane brick there (bits 0 to 27).
    pub const CHANNEL_TABLE: u32 = 12;
    /// Which sections of a body are supercompressed and how: one record per
    /// section ([`super::coding::Coding`]); version 8.
    pub const CODING: u32 = 13;

    /// Whether a renderer uploads sections of kind `k` (restored): every one
    /// but the metadata and the record of how the others are stored.
    pub fn uploaded(k: u32) -> bool {
        !matches!(k, METADATA | CODING)
    }

    pub fn name(k: u32) -> &'static str {
        match k {
            METADATA => "metadata",
            FRAMES => "frames",
            L1_NODES => "l1 nodes",
            L1_ENTRIES => "l1 entries",
            L2_NODES => "l2 nodes",
            L2_ENTRIES => "l2 entries",
            L3_NODES => "l3 nodes",
            TILES => "tiles",
            BRICK_RANGES => "brick ranges",
            ATLAS => "brick atlas",
            BRICK_TABLE => "brick table",
            CHANNEL_TABLE => "channel table",
            CODING => "coding",
            _ => "unknown",
        }
    }

    /// A section's name for people: "l3 nodes", or with its index where a
    /// kind has several ("brick atlas 3", "brick ranges 0").
    pub fn label(k: u32, index: u32) -> String {
        match k {
            ATLAS | BRICK_RANGES | BRICK_TABLE | CHANNEL_TABLE => format!("{} {index}", name(k)),
            _ => name(k).to_string(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    // Transparent: the I/O error is the message and has no source of its own,
    // so a `{:#}` chain prints it once.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error("not a .vpak file (bad magic)")]
    Magic,
    #[error("unsupported .vpak version {0} (this build reads versions 6 to {VERSION}: cook the asset again)")]
    Version(u32),
    #[error("truncated: the header says {expected} bytes, the file has {actual}")]
    Size { expected: u64, actual: u64 },
    #[error("header checksum mismatch (stored {stored:#018x}, computed {computed:#018x})")]
    HeaderChecksum { stored: u64, computed: u64 },
    #[error("implausible section count {0}")]
    SectionCount(u32),
    #[error("section {kind} #{index} ({name}) at {offset}+{size} is outside the file or misaligned", name = kind::name(*kind))]
    SectionBounds { kind: u32, index: u32, offset: u64, size: u64 },
    #[error("section {name} #{index} checksum mismatch (stored {stored:#018x}, computed {computed:#018x})", name = kind::name(*kind))]
    SectionChecksum { kind: u32, index: u32, stored: u64, computed: u64 },
    #[error("byte {0} lies between sections and is not zero (the file is damaged)")]
    Padding(u64),
    #[error("section {name} #{index} is listed twice", name = kind::name(*kind))]
    DuplicateSection { kind: u32, index: u32 },
    #[error("missing section {name} #{index}", name = kind::name(*kind))]
    Missing { kind: u32, index: u32 },
    #[error("section {name} is {size} bytes, not a whole number of {unit}-byte items", name = kind::name(*kind))]
    Shape { kind: u32, size: usize, unit: usize },
    #[error("metadata: {0}")]
    Metadata(String),
    #[error("{0} already exists (use --force to replace it)")]
    Exists(String),
    #[error("the asset is inconsistent: {0}")]
    Invalid(String),
    #[error("implausible segment count {0}")]
    SegmentCount(u32),
    #[error("segment {segment} at {offset}+{size} is outside the file, misaligned or overlaps the one before")]
    SegmentBounds { segment: usize, offset: u64, size: u64 },
    #[error("segment {segment} is out of range (the asset has {count})")]
    NoSegment { segment: usize, count: usize },
    #[error("segment {0}: {1}")]
    InSegment(usize, Box<Error>),
    #[error("the asset has {0} segments: read its sections segment by segment")]
    Segmented(usize),
    #[error("this is a part of an asset (cook --part), not an asset: join the parts with `vdbcook join`")]
    Part,
    #[error("{0}")]
    Join(String),
    #[error("not a part file (cook --part writes them)")]
    NotPart,
    #[error("part header checksum mismatch (the part file is damaged)")]
    PartChecksum,
    #[error("supercompressed section {name} #{index} {problem}", name = kind::name(*kind))]
    Coding { kind: u32, index: u32, problem: String },
}

/// A source file and its content hash.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SourceFile {
    pub path: String,
    pub bytes: u64,
    /// XXH3-128 of the file's bytes, hex.
    pub xxh3_128: String,
}

/// Per-frame figures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameInfo {
    /// Index into `sources`, or `None` for an empty (missing) frame.
    pub source: Option<u32>,
    /// Voxels active in any channel (tile voxels included).
    pub active_voxels: u64,
    pub leaves: u32,
    pub tiles: u32,
    /// The same figures for levels 1, 2, … (`Metadata::levels` − 1 of them).
    pub coarse: Vec<LevelFigures>,
}

/// A coarser level's figures of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LevelFigures {
    pub active_voxels: u64,
    pub leaves: u32,
    pub tiles: u32,
}

/// How a channel's coarser levels were made from the finer ones (see
/// `vdbcook_grid::lod`): the variant index is the code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum LevelFilter {
    /// The mean of the eight children, an inactive one counting as the background (fog and the rest).
    Mean,
    /// The mean of the active children (level sets).
    ActiveMean,
}

impl LevelFilter {
    pub fn name(self) -> &'static str {
        match self {
            LevelFilter::Mean => "mean",
            LevelFilter::ActiveMean => "active mean",
        }
    }
}

/// One channel: a scalar grid, or one component of a vec3 grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Channel {
    /// "density", or "vel.x" for component x of the vec3 grid "vel".
    pub name: String,
    /// The source grid's name.
    pub grid: String,
    /// 0, 1, 2 for the x, y, z component of a vec3 grid; `None` for a scalar grid.
    pub component: Option<u32>,
    /// The source grid's value type: "float", "double", "half", "vec3s", "vec3d".
    pub value_type: String,
    /// The source grid's class: "fog volume", "level set", "staggered", "unknown".
    pub class: String,
    /// The value of a voxel outside the channel's active set.
    pub background: f32,
    /// Smallest and largest stored value over every frame (the background if none).
    pub value_range: [f32; 2],
    /// Channel group (the channels whose format was chosen together).
    pub group: u32,
    /// Plane holding the channel, and its first lane there.
    pub plane: u32,
    pub lane: u32,
    /// Further planes holding some of the channel's bricks (per-brick
    /// formats), each with the channel alone from lane 0; when there are
    /// any, the channel's table (section [`kind::CHANNEL_TABLE`]) says which
    /// plane holds each brick.
    pub alternates: Vec<u32>,
}

/// Channel table entries: the choice of plane in the top bits, the plane brick below.
pub const CHOICE_SHIFT: u32 = 28;
/// The plane brick bits of a channel table entry.
pub const PLANE_BRICK_MASK: u32 = (1 << CHOICE_SHIFT) - 1;
/// Alternates a channel may have (choices 1 to 15).
pub const MAX_ALTERNATES: usize = 15;

/// Everything about the asset that is not a GPU array.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metadata {
    /// "vdbcook x.y.z".
    pub tool: String,
    pub frame_count: u32,
    /// OpenVDB map type of the source transform.
    pub map_type: String,
    /// Index-to-world matrix of the source grids (row-vector convention: world = [i j k 1] · M).
    pub transform: [[f64; 4]; 4],
    /// Source index of the L1 node origin: source index = asset index + offset.
    pub index_offset: [i32; 3],
    /// Union of every frame's active bbox in source index space (inclusive), if any.
    pub index_bbox: Option<([i32; 3], [i32; 3])>,
    pub channels: Vec<Channel>,
    /// The planes, each with its bricks and atlases.
    pub planes: Vec<PlaneInfo>,
    /// Bricks (what L3 nodes index; a brick has a plane brick in every plane).
    pub brick_count: u32,
    /// Every cook setting, as (name, value) text pairs.
    pub settings: Vec<(String, String)>,
    pub sources: Vec<SourceFile>,
    pub frames: Vec<FrameInfo>,
    /// Levels of detail: 1 (no coarser level) to [`MAX_LEVELS`]. Level k has
    /// voxels 2^k source voxels wide; see docs/format.md, "Levels".
    pub levels: u32,
    /// Per channel, the filter of its coarser levels (empty when `levels` is 1).
    pub level_filters: Vec<LevelFilter>,
    /// The finest level stored: 0, unless finer levels were left out to fit
    /// a byte budget (`cook --max-bytes`); levels `first_level .. levels` are stored.
    pub first_level: u32,
    /// When the frames are (version 9): encoded after the record, not in it,
    /// so the record reads as before; `None` in older assets.
    #[serde(skip)]
    pub time: Option<Time>,
    /// Per channel, where its voxels are (version 10; encoded after the time
    /// record): empty when every channel has the asset's voxels.
    #[serde(skip)]
    pub resolutions: Vec<Resolution>,
}

impl Metadata {
    pub fn to_bytes(&self) -> Result<Vec<u8>, Error> {
        let cfg = bincode::config::standard();
        let mut b = bincode::serde::encode_to_vec(self, cfg).map_err(|e| Error::Metadata(e.to_string()))?;
        if let Some(t) = &self.time {
            b.extend(bincode::serde::encode_to_vec(t, cfg).map_err(|e| Error::Metadata(e.to_string()))?);
        }
        if !self.resolutions.is_empty() {
            if self.time.is_none() {
                return Err(Error::Metadata("channel resolutions without a time record".into()));
            }
            b.extend(bincode::serde::encode_to_vec(&self.resolutions, cfg).map_err(|e| Error::Metadata(e.to_string()))?);
        }
        Ok(b)
    }

    /// The record, then the [`Time`] record when bytes follow it, then the
    /// channels' [`Resolution`]s when bytes follow that (nothing else may).
    pub fn from_bytes(b: &[u8]) -> Result<Metadata, Error> {
        // A fixed cap on what a (possibly hostile) length prefix can make the
        // decoder allocate; real metadata is kilobytes.
        let cfg = bincode::config::standard().with_limit::<{ 64 << 20 }>();
        let (mut m, used): (Metadata, usize) = bincode::serde::decode_from_slice(b, cfg).map_err(|e| Error::Metadata(e.to_string()))?;
        let rest = &b[used.min(b.len())..];
        if !rest.is_empty() {
            let (t, n): (Time, usize) = bincode::serde::decode_from_slice(rest, cfg).map_err(|e| Error::Metadata(format!("time: {e}")))?;
            if let Some(p) = t.problem(m.frame_count) {
                return Err(Error::Metadata(format!("time: {p}")));
            }
            m.time = Some(t);
            let rest = &rest[n.min(rest.len())..];
            if !rest.is_empty() {
                let (r, n): (Vec<Resolution>, usize) = bincode::serde::decode_from_slice(rest, cfg).map_err(|e| Error::Metadata(format!("channel resolutions: {e}")))?;
                if n != rest.len() {
                    return Err(Error::Metadata(format!("{} bytes after the channel resolutions", rest.len() - n)));
                }
                if let Some(p) = resolution::problem(&m, &r) {
                    return Err(Error::Metadata(format!("channel resolutions: {p}")));
                }
                m.resolutions = r;
            }
        }
        Ok(m)
    }

    /// [`Metadata::from_bytes`] of a body of a file of version `version`:
    /// channel resolutions are refused in a version-7, 8 or 9 file (a body
    /// read on its own, as a version-6 file, keeps its record).
    pub fn from_bytes_of(b: &[u8], version: u32) -> Result<Metadata, Error> {
        let m = Metadata::from_bytes(b)?;
        match (segments::VERSION_7..segments::VERSION_10).contains(&version) && !m.resolutions.is_empty() {
            true => Err(Error::Metadata(format!("channel resolutions in a version-{version} file (they are version {} and later)", segments::VERSION_10))),
            false => Ok(m),
        }
    }

    /// Frame `f`'s number in the source sequence (`f` itself when the asset records none).
    pub fn frame_number(&self, f: usize) -> i64 {
        self.time.as_ref().and_then(|t| t.numbers.get(f).copied()).unwrap_or(f as i64)
    }

    /// The frame with source number `n`, if there is one.
    pub fn frame_of_number(&self, n: i64) -> Option<usize> {
        match &self.time {
            Some(t) => t.numbers.binary_search(&n).ok(),
            None => usize::try_from(n).ok().filter(|&f| f < self.frame_count as usize),
        }
    }

    /// [`Metadata::frame_of_number`], or why there is none, naming the numbers there are.
    pub fn frame_by_number(&self, n: i64) -> Result<usize, String> {
        self.frame_of_number(n).ok_or_else(|| {
            let numbers: Vec<i64> = (0..self.frame_count as usize).map(|f| self.frame_number(f)).collect();
            format!("no frame has source number {n} (its frames are {})", time::numbers_text(&numbers))
        })
    }

    /// The frame rate ([`DEFAULT_FPS`] when the asset records none).
    pub fn fps(&self) -> f64 {
        self.time.as_ref().map_or(DEFAULT_FPS, |t| t.fps)
    }

    /// The section index of atlas `atlas` of plane `plane`: the atlases of
    /// the planes before it, plus `atlas`.
    pub fn atlas_section(&self, plane: usize, atlas: usize) -> u32 {
        let before: usize = self.planes.iter().take(plane).map(|p| p.atlases.len()).sum();
        (before + atlas) as u32
    }

    /// The plane and atlas of atlas section `section` ([`Metadata::atlas_section`]'s inverse).
    pub fn section_atlas(&self, section: u32) -> Option<(usize, usize)> {
        let mut first = 0usize;
        for (p, info) in self.planes.iter().enumerate() {
            if (section as usize) < first + info.atlases.len() {
                return Some((p, section as usize - first));
            }
            first += info.atlases.len();
        }
        None
    }

    /// Atlas textures over all planes.
    pub fn texture_count(&self) -> usize {
        self.planes.iter().map(|p| p.atlases.len()).sum()
    }

    /// Channel `c`'s planes: its `plane`, then its `alternates` (choice 0, 1, …).
    pub fn channel_planes(&self, c: usize) -> Vec<u32> {
        self.channels.get(c).map_or_else(Vec::new, |ch| std::iter::once(ch.plane).chain(ch.alternates.iter().copied()).collect())
    }

    /// Channel `c`'s formats: "bc4", or "constant+bc7+unorm16" for a channel with alternates.
    pub fn channel_format_names(&self, c: usize) -> String {
        self.channel_planes(c).iter().filter_map(|&p| self.planes.get(p as usize)).map(|p| p.plane.format.name()).collect::<Vec<_>>().join("+")
    }

    /// True when plane `p` holds a channel stored in several planes (whose
    /// channel table, not a brick table of the plane's own, addresses it).
    pub fn is_mixed_plane(&self, p: usize) -> bool {
        self.channels.iter().any(|ch| !ch.alternates.is_empty() && (ch.plane as usize == p || ch.alternates.iter().any(|&a| a as usize == p)))
    }

    /// True when plane `p` has a brick table: it stores fewer bricks than the
    /// asset has, and no channel table addresses it.
    pub fn plane_has_table(&self, p: usize) -> bool {
        self.planes.get(p).is_some_and(|i| i.bricks != self.brick_count) && !self.is_mixed_plane(p)
    }

    /// Index-to-world matrix of level `level`: index i of the level is at
    /// source index `2^level · i + (2^level − 1) / 2` (a coarse voxel's centre
    /// is its children's centre).
    pub fn level_transform(&self, level: u32) -> [[f64; 4]; 4] {
        let m = &self.transform;
        let s = f64::from(1u32 << level.min(31));
        let mut c = *m;
        for (row, src) in c.iter_mut().zip(m).take(3) {
            for (v, w) in row.iter_mut().zip(src) {
                *v = s * w;
            }
        }
        for col in 0..4 {
            c[3][col] = m[3][col] + (s - 1.0) / 2.0 * (m[0][col] + m[1][col] + m[2][col]);
        }
        c
    }

    /// Level `level`'s index offset: level index = level asset index + offset >> level.
    pub fn level_offset(&self, level: u32) -> [i32; 3] {
        self.index_offset.map(|o| o >> level.min(31))
    }

    /// The levels the asset stores, finest first.
    pub fn stored_levels(&self) -> std::ops::Range<u32> {
        self.first_level..self.levels
    }

    /// "levels 2 to 4", "level 3", or "levels 0 to 1" for the level range: how
    /// errors and reports name what an asset stores.
    pub fn stored_levels_text(&self) -> String {
        let r = self.stored_levels();
        match r.len() {
            1 => format!("level {}", r.start),
            _ => format!("levels {} to {}", r.start, r.end.saturating_sub(1)),
        }
    }

    /// Why level `level` cannot be read, when the asset does not store it.
    pub fn missing_level(&self, level: u32) -> Option<String> {
        if self.stored_levels().contains(&level) {
            return None;
        }
        Some(match level >= self.levels {
            true => format!("level {level} is out of range: the asset stores {}", self.stored_levels_text()),
            false => format!("level {level} is not in the asset: it stores {} (finer levels were left out to fit a byte budget)", self.stored_levels_text()),
        })
    }

    /// The L1 node of frame `frame` at stored level `level` is entry
    /// `(level − first_level) · frame_count + frame` of the frames section;
    /// `None` for a frame or a level the asset does not store.
    pub fn tree_index(&self, frame: usize, level: u32) -> Option<usize> {
        let stored = self.stored_levels().contains(&level) && frame < self.frame_count as usize;
        stored.then(|| (level - self.first_level) as usize * self.frame_count as usize + frame)
    }

    /// Leaves of frame `frame` at level `level` (0 past the end).
    pub fn level_leaves(&self, frame: usize, level: u32) -> u32 {
        let Some(f) = self.frames.get(frame) else { return 0 };
        match level {
            0 => f.leaves,
            k => f.coarse.get(k as usize - 1).map_or(0, |c| c.leaves),
        }
    }

    /// The channel named `name`.
    pub fn channel(&self, name: &str) -> Option<usize> {
        self.channels.iter().position(|c| c.name == name)
    }

    /// The planes' formats: "f16", or "bc4+bc7" for a mix (consecutive repeats once).
    pub fn format_names(&self) -> String {
        let mut f: Vec<&str> = self.planes.iter().map(|p| p.plane.format.name()).collect();
        f.dedup();
        f.join("+")
    }
}

/// Two lists of names joined by "+" ("bc4+bc7"), as one: `a` as it is, then
/// each name of `b` that is not in it yet. How the formats of several
/// segments are named (one segment's stay as [`Metadata::format_names`] gives them).
pub fn union_names(a: &str, b: &str) -> String {
    let mut names: Vec<&str> = a.split('+').filter(|n| !n.is_empty()).collect();
    let given = names.len();
    for n in b.split('+') {
        if !n.is_empty() && !names.contains(&n) {
            names.push(n);
        }
    }
    match given {
        0 => b.to_string(),
        _ => names.join("+"),
    }
}

/// A section to write.
pub struct Section {
    pub kind: u32,
    pub index: u32,
    pub data: Bytes,
}

/// A section's bytes: owned, or held by another owner (a cook's atlas in a
/// buffer that may live in a spill file).
pub enum Bytes {
    Owned(Vec<u8>),
    Held(Box<dyn AsRef<[u8]> + Send + Sync>),
}

impl Bytes {
    /// The bytes as an owned vector to change (held bytes are copied first).
    pub fn to_mut(&mut self) -> &mut Vec<u8> {
        if let Bytes::Held(h) = self {
            *self = Bytes::Owned((**h).as_ref().to_vec());
        }
        match self {
            Bytes::Owned(v) => v,
            Bytes::Held(_) => unreachable!("made owned above"),
        }
    }
}

impl Default for Bytes {
    fn default() -> Self {
        Bytes::Owned(Vec::new())
    }
}

impl From<Vec<u8>> for Bytes {
    fn from(v: Vec<u8>) -> Self {
        Bytes::Owned(v)
    }
}

/// Words held as their little-endian bytes, without a copy.
struct Words(Vec<u32>);

impl AsRef<[u8]> for Words {
    fn as_ref(&self) -> &[u8] {
        bytemuck::cast_slice(&self.0)
    }
}

impl Bytes {
    /// A section of `u32` words (node arrays, ranges, tables): their bytes
    /// are the vector's own on a little-endian machine, not a copy.
    pub fn from_words(mut v: Vec<u32>) -> Bytes {
        v.iter_mut().for_each(|w| *w = w.to_le());
        Bytes::Held(Box::new(Words(v)))
    }
}

impl std::ops::Deref for Bytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Bytes::Owned(v) => v,
            Bytes::Held(h) => (**h).as_ref(),
        }
    }
}

impl std::fmt::Debug for Bytes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} bytes", self.len())
    }
}

pub(crate) fn checksum(b: &[u8]) -> u64 {
    twox_hash::XxHash3_64::oneshot(b)
}

fn align(n: usize) -> usize {
    n.div_ceil(ALIGN) * ALIGN
}

/// Offsets of each section, the table's end and the file's length: every
/// section at a multiple of [`ALIGN`], or of [`CODED_ALIGN`] in a body with
/// a coding section ([`section_align`]).
fn plan(sections: &[Section]) -> (Vec<usize>, usize, usize) {
    let to = section_align(sections);
    plan_lens(sections.iter().map(|s| (s.data.len(), to)))
}

/// Where a body's sections start: at multiples of [`ALIGN`], so that each
/// can be uploaded from a mapping of the file as it is; in a body with a
/// coding section (version 11), at multiples of [`CODED_ALIGN`], since a
/// reader restores such a body before use and a small asset would be mostly
/// padding otherwise.
fn section_align(sections: &[Section]) -> usize {
    match sections.iter().any(|s| s.kind == kind::CODING) {
        true => CODED_ALIGN,
        false => ALIGN,
    }
}

/// [`plan`] of sections of these lengths and alignments.
fn plan_lens(lens: impl ExactSizeIterator<Item = (usize, usize)>) -> (Vec<usize>, usize, usize) {
    let table_end = HEADER_LEN + ENTRY_LEN * lens.len();
    let mut offsets = Vec::with_capacity(lens.len());
    let mut pos = table_end;
    let mut end = align(table_end);
    for (len, to) in lens {
        pos = pos.div_ceil(to) * to;
        offsets.push(pos);
        end = pos + len;
        pos = end;
    }
    (offsets, table_end, end)
}

/// Length of the file `sections` make.
pub fn file_len(sections: &[Section]) -> u64 {
    plan(sections).2 as u64
}

/// Writes a complete one-body file (the version-6 layout) to `w`, section
/// by section (no copy of the whole file).
pub fn write_to<W: std::io::Write + ?Sized>(w: &mut W, sections: &[Section]) -> std::io::Result<()> {
    write_body(w, sections, &body_head(sections))
}

/// A body's header and section table (every section's checksum computed once, here).
pub(crate) fn body_head(sections: &[Section]) -> Vec<u8> {
    let to = section_align(sections);
    let entries: Vec<Entry> = sections.iter().map(|s| (s.kind, s.index, s.data.len(), checksum(&s.data), to)).collect();
    head_of(&entries).0
}

/// A section of a body to lay out: kind, index, length, checksum, alignment.
pub(crate) type Entry = (u32, u32, usize, u64, usize);

/// The header and section table of a body of sections, the offset of each
/// and the body's length.
pub(crate) fn head_of(entries: &[Entry]) -> (Vec<u8>, Vec<usize>, usize) {
    let (offsets, table_end, total) = plan_lens(entries.iter().map(|e| (e.2, e.4)));
    let mut head = vec![0u8; table_end];
    head[..8].copy_from_slice(&MAGIC);
    head[8..12].copy_from_slice(&segments::BODY_VERSION.to_le_bytes());
    head[16..20].copy_from_slice(&(entries.len() as u32).to_le_bytes());
    head[24..32].copy_from_slice(&(total as u64).to_le_bytes());
    for (i, (&(kind, index, len, sum, _), &off)) in entries.iter().zip(&offsets).enumerate() {
        let e = HEADER_LEN + i * ENTRY_LEN;
        head[e..e + 4].copy_from_slice(&kind.to_le_bytes());
        head[e + 4..e + 8].copy_from_slice(&index.to_le_bytes());
        head[e + 8..e + 16].copy_from_slice(&(off as u64).to_le_bytes());
        head[e + 16..e + 24].copy_from_slice(&(len as u64).to_le_bytes());
        head[e + 24..e + 32].copy_from_slice(&sum.to_le_bytes());
    }
    let h = header_checksum(&head[..32], &head[HEADER_LEN..table_end]);
    head[32..40].copy_from_slice(&h.to_le_bytes());
    (head, offsets, total)
}

/// Writes a body: its `head` ([`body_head`]), then its sections.
pub(crate) fn write_body<W: std::io::Write + ?Sized>(w: &mut W, sections: &[Section], head: &[u8]) -> std::io::Result<()> {
    w.write_all(head)?;
    write_sections(w, sections)
}

/// Bytes of a body's header and section table.
pub(crate) fn body_head_len(sections: &[Section]) -> usize {
    HEADER_LEN + ENTRY_LEN * sections.len()
}

/// Writes a body's sections (and the zeros between them) after its header and
/// section table, which the caller has written or left room for.
pub(crate) fn write_sections<W: std::io::Write + ?Sized>(w: &mut W, sections: &[Section]) -> std::io::Result<()> {
    let (offsets, table_end, _) = plan(sections);
    let mut pos = table_end;
    let zeros = [0u8; ALIGN];
    for (s, &off) in sections.iter().zip(&offsets) {
        w.write_all(&zeros[..off - pos])?;
        w.write_all(&s.data)?;
        pos = off + s.data.len();
    }
    Ok(())
}

/// Assembles a complete file in memory.
pub fn assemble(sections: &[Section]) -> Vec<u8> {
    let mut out = Vec::with_capacity(file_len(sections) as usize);
    // Writing to a Vec cannot fail.
    let _ = write_to(&mut out, sections);
    out
}

pub(crate) fn header_checksum(head: &[u8], table: &[u8]) -> u64 {
    use std::hash::Hasher;
    let mut h = twox_hash::XxHash3_64::new();
    h.write(head);
    h.write(table);
    h.finish()
}

/// One entry of the section table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SectionEntry {
    pub kind: u32,
    pub index: u32,
    pub offset: u64,
    pub size: u64,
    pub checksum: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_meta() -> Metadata {
        Metadata {
            tool: "t".into(),
            frame_count: 1,
            map_type: "UniformScaleMap".into(),
            transform: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
            index_offset: [0, -128, 0],
            index_bbox: None,
            channels: vec![],
            planes: vec![],
            brick_count: 0,
            settings: vec![("format".into(), "f32".into())],
            sources: vec![],
            frames: vec![],
            levels: 1,
            level_filters: vec![],
            first_level: 0,
            time: None,
            resolutions: vec![],
        }
    }

    fn sample() -> Vec<u8> {
        let meta = sample_meta();
        assemble(&[
            Section { kind: kind::METADATA, index: 0, data: meta.to_bytes().unwrap().into() },
            Section { kind: kind::FRAMES, index: 0, data: [7u32, 9].iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>().into() },
        ])
    }

    #[test]
    fn round_trip_and_typed_slices() {
        let b = sample();
        let a = Asset::from_bytes(&b).unwrap();
        a.verify().unwrap();
        assert_eq!(a.u32s(kind::FRAMES).unwrap(), &[7, 9]);
        assert_eq!(a.metadata().unwrap().index_offset, [0, -128, 0]);
        assert!(a.sections.iter().all(|s| s.offset % 256 == 0));
        assert!(matches!(a.u32s(kind::L1_NODES), Err(Error::Missing { .. })));
    }

    #[test]
    fn time_follows_the_record() {
        let mut m = sample_meta();
        // Without time, the record alone (as before version 9): frames numbered from 0.
        let old = m.to_bytes().unwrap();
        assert_eq!(Metadata::from_bytes(&old).unwrap(), m);
        assert_eq!((m.frame_number(0), m.fps(), m.frame_of_number(0), m.frame_of_number(1)), (0, DEFAULT_FPS, Some(0), None));
        m.time = Some(Time { fps: 30.0, numbers: vec![1001] });
        let b = m.to_bytes().unwrap();
        assert!(b.starts_with(&old) && b.len() > old.len());
        let back = Metadata::from_bytes(&b).unwrap();
        assert_eq!(back, m);
        assert_eq!((back.frame_number(0), back.fps(), back.frame_of_number(1001), back.frame_of_number(0)), (1001, 30.0, Some(0), None));
        // Bytes after the time record, or a time that does not fit the frames, are refused.
        let mut extra = b.clone();
        extra.push(0);
        assert!(Metadata::from_bytes(&extra).unwrap_err().to_string().contains("channel resolutions: an empty record"));
        m.time = Some(Time { fps: 30.0, numbers: vec![1, 2] });
        assert!(Metadata::from_bytes(&m.to_bytes().unwrap()).unwrap_err().to_string().contains("2 frame numbers for 1 frames"));
    }

    #[test]
    fn resolutions_follow_the_time() {
        let mut m = sample_meta();
        m.channels = vec![crate::Channel {
            name: "vel.x".into(),
            grid: "vel".into(),
            component: Some(0),
            value_type: "vec3s".into(),
            class: "unknown".into(),
            background: 0.0,
            value_range: [0.0, 1.0],
            group: 0,
            plane: 0,
            lane: 0,
            alternates: vec![],
        }];
        m.channels.insert(0, Channel { name: "density".into(), grid: "density".into(), component: None, ..m.channels[0].clone() });
        m.frames = vec![FrameInfo { source: None, active_voxels: 1, leaves: 1, tiles: 0, coarse: vec![LevelFigures::default()] }];
        m.levels = 2;
        m.level_filters = vec![LevelFilter::Mean; 2];
        m.time = Some(Time { fps: 24.0, numbers: vec![0] });
        let timed = m.to_bytes().unwrap();
        m.resolutions = vec![Resolution::default(), Resolution { level: 1, half_offset: [-1, 0, 1] }];
        let b = m.to_bytes().unwrap();
        assert!(b.starts_with(&timed) && b.len() > timed.len());
        let back = Metadata::from_bytes(&b).unwrap();
        assert_eq!(back, m);
        assert_eq!((back.channel_levels(0), back.channel_levels(1), back.detail_levels()), (0..1, 1..2, 1));
        // vel.x's voxel 0 sits half a voxel before level 1's voxel 0 along x, half after along z.
        assert_eq!(back.channel_transform(1, 1)[3], [0.0, 0.5, 1.0, 1.0]);
        // Refused: a count that does not fit, a level no tree has, no channel at level 0, bytes after.
        let refuse = |r: Vec<Resolution>, levels: u32, why: &str| {
            let mut m = m.clone();
            m.resolutions = r;
            m.levels = levels;
            m.level_filters = vec![LevelFilter::Mean; 2];
            m.frames[0].coarse = vec![LevelFigures::default(); levels as usize - 1];
            let e = Metadata::from_bytes(&m.to_bytes().unwrap()).unwrap_err().to_string();
            assert!(e.contains(why), "{e}");
        };
        refuse(vec![Resolution::default()], 2, "1 channel resolutions for 2 channels");
        refuse(vec![Resolution::default(), Resolution { level: 2, half_offset: [0; 3] }], 2, "a channel at level 2 of an asset of 2 levels");
        refuse(vec![Resolution { level: 1, half_offset: [0; 3] }; 2], 2, "no channel at level 0");
        let mut extra = b.clone();
        extra.push(0);
        assert!(Metadata::from_bytes(&extra).unwrap_err().to_string().contains("1 bytes after the channel resolutions"));
    }

    #[test]
    fn every_flipped_byte_is_caught() {
        let b = sample();
        for i in 0..b.len() {
            let mut c = b.clone();
            c[i] ^= 0x10;
            let r = Asset::from_bytes(&c).and_then(|a| a.verify().map(|_| a));
            // Checksums cover the header, the table and the sections, and the
            // padding between sections must be zero: only the reserved bytes 40 to 63 are free.
            let covered = !(40..HEADER_LEN).contains(&i);
            assert_eq!(r.is_err(), covered, "byte {i}");
        }
    }

    #[test]
    fn truncation_is_an_error() {
        let b = sample();
        for n in 0..b.len() {
            assert!(Asset::from_bytes(&b[..n]).is_err());
        }
    }

    #[test]
    fn atomic_write_never_clobbers() {
        let dir = std::env::temp_dir().join(format!("vpak-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.vpak");
        write_atomic(&p, b"one", false).unwrap();
        assert!(matches!(write_atomic(&p, b"two", false), Err(Error::Exists(_))));
        assert_eq!(std::fs::read(&p).unwrap(), b"one");
        write_atomic(&p, b"three", true).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"three");
        let leftovers: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().filter(|e| e.file_name().to_string_lossy().ends_with(".tmp")).collect();
        assert!(leftovers.is_empty());
        // While the data is written it has no name (Linux), and a failed write leaves the old file.
        let names = || std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.file_name()).collect::<Vec<_>>();
        let before = names();
        let failed = write_atomic_with(&p, true, |w| {
            w.write_all(b"four")?;
            if cfg!(target_os = "linux") {
                assert_eq!(names(), before, "a named temporary file exists during the write");
            }
            Err(std::io::Error::other("the writer failed"))
        });
        assert!(failed.is_err());
        assert_eq!((names(), std::fs::read(&p).unwrap()), (before.clone(), b"three".to_vec()));
        let q = dir.join("b.vpak");
        write_atomic_with(&q, false, |w| w.write_all(b"five")).unwrap();
        assert_eq!(std::fs::read(&q).unwrap(), b"five");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
