//! The cooking pipeline, free of I/O and terminals: frames are pushed in one
//! at a time ([`Cooker::push`], or [`Cooker::push_channels`] for several
//! grids per frame), and [`Cooker::finish`] returns the sections of a `.vpak`
//! asset and a [`CookReport`].  [`unpack_frame`] turns a frame of an asset
//! back into one [`Grid`](vdbcook_grid::Grid) per channel.
//!
//! ```text
//! build     push(frame) ─▶ flipbook::Builder (union tree of the channels, exact brick dedup, L3 interning; coarser levels)
//! assemble  choose (planes, or per-brick formats) ─▶ cluster (optional) ─▶ encode (parallel) ─▶ dedup (encoded bricks, remap)
//!           ─▶ node arrays ─▶ errors ─▶ layout (atlases: vpak::layout) ─▶ metadata ─▶ report
//! ```

mod assemble;
mod build;
mod choose;
mod cluster;
mod dedup;
mod encode;
mod errors;
mod layout;
mod merge;
mod metadata;
mod report;
mod unpack;

pub use assemble::Deliver;
pub use build::Cooker;
pub use report::{figure, BudgetReport, BudgetTry, ChannelReport, ClusterReport, CookReport, ErrorFigures, Figure, FormatShare, LevelReport, SegmentReport, SourceTime, Sums};
pub use unpack::{unpack_frame, unpack_level, unpack_near};
pub use vdbcook_encode::NonFinite;
pub use vdbcook_encode::{ErrorBound, Format, Quality};
pub use vdbcook_vpak::LevelCount;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Tree(#[from] vdbcook_flipbook::Error),
    #[error(transparent)]
    Store(#[from] vdbcook_grid::spill::StoreError),
    #[error(transparent)]
    Asset(#[from] vdbcook_vpak::Error),
    /// Every grid of every frame needs the asset's transform, which the first
    /// grid pushed set (`first`: its frame, and the frame's source path).
    #[error("grid \"{grid}\" has transform {found}, but the channel's transform, set by grid \"{first_grid}\" of {first}, is {expected}")]
    Transform { grid: String, found: String, first: String, first_grid: String, expected: String },
    /// A grid whose voxels cannot be stored at a level of the asset's.
    /// (`found`, `first`: each grid's voxel size and transform, the first's grid and frame too.)
    #[error("grid \"{grid}\" has {found}, grid {first}: a channel's voxels must be 1, 2, 4 or 8 times the finest grid's along the same axes, offset from them by a whole or half voxel")]
    Resolution { grid: String, found: String, first: String },
    #[error("grid \"{grid}\" has voxels 2^{level} times the asset's, so {lods} levels of detail from its own would need {} levels, more than {}: ask for fewer levels (--lods)", level + lods, vdbcook_vpak::MAX_LEVELS)]
    TooManyLevels { grid: String, level: u32, lods: u32 },
    #[error("grid \"{grid}\" first appears after the first frame with voxels 2^{level} times the asset's, coarser than every channel of the first frame: give it in the first frame (an empty grid will do)")]
    LateCoarseChannel { grid: String, level: u32 },
    #[error("{grid} has background {found}, earlier frames {expected} (a channel keeps one background)")]
    Background { grid: String, found: f32, expected: f32 },
    #[error("frame {frame} is out of range (the asset has {count} frames, numbered from 0)")]
    NoFrame { frame: usize, count: usize },
    #[error("frame {frame} unpacks to {leaves} leaves ({} MiB in memory), more than the {} MiB this machine has to spare", .bytes >> 20, .budget >> 20)]
    TooBig { frame: usize, leaves: u64, bytes: u64, budget: u64 },
    #[error("the asset is inconsistent: {0}")]
    Corrupt(String),
    #[error("a channel group names \"{name}\", which is not a channel of this cook (channels: {channels})")]
    UnknownChannel { name: String, channels: String },
    #[error("channel \"{0}\" is in two channel groups")]
    TwiceGrouped(String),
    #[error("clustering takes at most {MAX_CLUSTER_CHANNELS} channels, this cook has {0}")]
    MultiChannelClustering(usize),
    #[error("format constant is chosen per brick by a maximum error, not for a whole channel")]
    ConstantFormat,
    #[error("a maximum error chooses every brick's format: it takes no channel groups")]
    MaxErrorGroups,
    #[error("a plane of {0} bricks is more than a channel table can address")]
    TooManyPlaneBricks(u32),
    #[error("frame number {number} after {after}: a sequence's frame numbers must increase")]
    FrameNumber { number: i64, after: i64 },
    #[error("{0}")]
    NoLevel(String),
    #[error("no asset fits in {budget} bytes: the smallest reachable, level {level} alone, is {smallest} bytes")]
    OverBudget { budget: u64, smallest: u64, level: u32 },
    #[error("the channels' bricks need {0} texture planes, more than an asset may have ({max}): cook fewer channels at once", max = vdbcook_vpak::MAX_CHANNELS)]
    TooManyPlanes(usize),
}

impl Error {
    /// True for errors in the settings a cook was given (its channel groups,
    /// clustering of too many channels) rather than in its input.
    pub fn is_settings_error(&self) -> bool {
        matches!(
            self,
            Error::UnknownChannel { .. }
                | Error::TwiceGrouped(_)
                | Error::MultiChannelClustering(_)
                | Error::ConstantFormat
                | Error::MaxErrorGroups
                | Error::Resolution { .. }
                | Error::TooManyLevels { .. }
        )
    }
}

/// Receives progress from long stages; every method does nothing by default.
pub trait Progress: Sync {
    fn start(&self, _stage: &str, _total: u64) {}
    fn advance(&self, _n: u64) {}
    fn finish(&self) {}
}

/// A [`Progress`] that reports nothing.
pub struct NoProgress;
impl Progress for NoProgress {}

/// Channels stored together in one format: `CHANNELS=FORMAT` as text, e.g.
/// `temperature,flames=bc7` (a vec3 grid's name stands for its three channels).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(try_from = "String")]
pub struct ChannelGroup {
    pub channels: Vec<String>,
    pub format: Format,
}

impl std::str::FromStr for ChannelGroup {
    type Err = String;
    fn from_str(s: &str) -> Result<ChannelGroup, String> {
        let bad = || format!("invalid group \"{s}\" (expected CHANNELS=FORMAT, e.g. temperature,flames=bc7; formats: f32, f16, unorm16, unorm8, bc4, bc7)");
        let (names, format) = s.rsplit_once('=').ok_or_else(bad)?;
        let format = Format::parse(format.trim()).filter(|f| Format::ALL.contains(f)).ok_or_else(bad)?;
        let channels: Vec<String> = names.split(',').map(|n| n.trim().to_string()).filter(|n| !n.is_empty()).collect();
        if channels.is_empty() {
            return Err(bad());
        }
        Ok(ChannelGroup { channels, format })
    }
}

impl TryFrom<String> for ChannelGroup {
    type Error = String;
    fn try_from(s: String) -> Result<ChannelGroup, String> {
        s.parse()
    }
}

vdbcook_vpak::setting_text_by_display!(ChannelGroup);

impl std::fmt::Display for ChannelGroup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}={}", self.channels.join(","), self.format.name())
    }
}

#[derive(Clone, Debug)]
pub struct CookOptions {
    /// Format of every channel not in `groups`.
    pub format: Format,
    /// Channels given their own format, together (see `vdbcook_encode::group_planes`).
    pub groups: Vec<ChannelGroup>,
    /// Encoder preset of the block formats.
    pub quality: Quality,
    /// Largest 3D texture edge an atlas may use (wgpu's default limit is 2048).
    pub max_texture_dim: u32,
    /// Merge similar bricks with variance-gated k-means before encoding.
    pub clustering: Option<vdbcook_cluster::Options>,
    /// Per-brick formats: every brick channel in the cheapest format whose
    /// shown voxels decode within this absolute error (`format` and `groups`
    /// are not used); merged bricks (`clustering`) are held to it too.
    pub max_error: Option<ErrorBound>,
    /// With `max_error`, for an asset that will be supercompressed: each
    /// brick's texels on the coarsest grid within the bound (fewer distinct
    /// values), and what its format choice minimises (GPU or file bytes).
    pub disk: Option<vdbcook_encode::Optimize>,
    /// Every setting, recorded verbatim in the asset's metadata.
    pub settings: Vec<(String, String)>,
    /// A byte budget for the asset: the finest levels of detail that do not
    /// fit are left out (the coarsest always stays; [`Error::OverBudget`] when it alone does not fit).
    pub max_bytes: Option<u64>,
    /// Levels of detail (1: none): levels 1 … levels − 1 of every frame, each
    /// filtered from the one before (`vdbcook_grid::lod`), are trees of the asset too.
    pub levels: LevelCount,
    /// The sequence's frame rate, recorded with the frames' numbers.
    pub fps: vdbcook_vpak::Fps,
    /// Where the brick pool goes once it passes a size (`None`: it stays in
    /// memory); the asset is the same either way.
    pub spill: Option<vdbcook_grid::spill::SpillPolicy>,
}

impl Default for CookOptions {
    fn default() -> Self {
        CookOptions {
            format: Format::F16,
            groups: Vec::new(),
            quality: Quality::VeryFast,
            max_texture_dim: 2048,
            clustering: None,
            max_error: None,
            disk: None,
            settings: Vec::new(),
            levels: LevelCount::ONE,
            max_bytes: None,
            fps: vdbcook_vpak::Fps::DEFAULT,
            spill: None,
        }
    }
}

/// What a channel is, as its source describes it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChannelSpec {
    /// "density", or "vel.x" for component x of the vec3 grid "vel".
    pub name: String,
    pub grid: String,
    /// 0, 1, 2 for the components of a vec3 grid.
    pub component: Option<u32>,
    /// "float", "double", "half", "vec3s", "vec3d".
    pub value_type: String,
    /// The grid class; empty: taken from the first grid pushed for the channel.
    pub class: String,
}

/// Channels `--clusters` takes (k-means items of 512 values per channel).
pub const MAX_CLUSTER_CHANNELS: usize = 8;

/// The channels a group's name stands for: the channel of that name, or
/// the three components of the vec3 grid of that name.
pub fn channels_named(specs: &[ChannelSpec], name: &str) -> Vec<usize> {
    match specs.iter().position(|s| s.name == name) {
        Some(c) => vec![c],
        None => (0..specs.len()).filter(|&c| specs[c].component.is_some() && specs[c].grid == name).collect(),
    }
}

#[cfg(test)]
mod resolution_tests;
#[cfg(test)]
mod tests;
