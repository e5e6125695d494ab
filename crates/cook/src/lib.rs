//! The cooking pipeline, free of I/O and terminals: frames are pushed in one
//! at a time ([`Cooker::push`], or [`Cooker::push_channels`] for several
//! grids per frame), and [`Cooker::finish`] returns the sections of a `.vpak`
//! asset and a [`CookReport`].  [`unpack_frame`] turns a frame of an asset
//! back into one [`Grid`] per channel.
//!
//! ```text
//! push(frame) ─▶ flipbook::Builder (union tree of the channels, exact brick dedup, L3 interning)
//! finish ─▶ encode every plane (parallel) ─▶ dedup encoded bricks ─▶ node arrays
//!        ─▶ atlases (vpak::layout) ─▶ vpak sections
//! ```

mod unpack;

pub use unpack::{unpack_frame, unpack_level};
pub use vdbcook_encode::{Format, Quality};

use rayon::prelude::*;
use std::time::Instant;
pub use vdbcook_encode::NonFinite;
use vdbcook_encode::{Brick, Encoded, ErrorStats, PlaneSpec};
use vdbcook_flipbook::{Builder, Built, HashIndex};
use vdbcook_grid::lod::{self, Filter};
use vdbcook_grid::{Grid, GridClass, Transform};
use vdbcook_vpak::layout::{pack_atlas, plan_atlases, AtlasLayout};
use vdbcook_vpak::nodes::Nodes;
use vdbcook_vpak::{kind, Channel, FrameInfo, LevelFigures, LevelFilter, Metadata, PlaneInfo, Section, SourceFile};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Tree(#[from] vdbcook_flipbook::Error),
    #[error(transparent)]
    Asset(#[from] vdbcook_vpak::Error),
    /// Every grid of every frame needs the asset's transform, which the first
    /// grid pushed set (`first`: its frame, and the frame's source path).
    #[error("grid \"{grid}\" has transform {found}, but the asset's transform, set by grid \"{first_grid}\" of {first}, is {expected}")]
    Transform { grid: String, found: String, first: String, first_grid: String, expected: String },
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
    #[error("a maximum error of {0} is not a bound (need a finite value of 0 or more)")]
    MaxError(f32),
    #[error("a maximum error chooses every brick's format: it takes no channel groups")]
    MaxErrorGroups,
    #[error("a plane of {0} bricks is more than a channel table can address")]
    TooManyPlaneBricks(u32),
    #[error("{0} levels of detail asked for: an asset has 1 (no coarser level) to {max} (level {top}'s voxels are {scale} source voxels wide and its bricks span a whole L1 slot, the coarsest the tree's 128-voxel alignment allows)", max = vdbcook_vpak::MAX_LEVELS, top = vdbcook_vpak::MAX_LEVELS - 1, scale = 1u32 << (vdbcook_vpak::MAX_LEVELS - 1))]
    Levels(u32),
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
        matches!(self, Error::UnknownChannel { .. } | Error::TwiceGrouped(_) | Error::MultiChannelClustering(_) | Error::ConstantFormat | Error::MaxError(_) | Error::MaxErrorGroups | Error::Levels(_))
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
    pub max_error: Option<f32>,
    /// Every setting, recorded verbatim in the asset's metadata.
    pub settings: Vec<(String, String)>,
    /// A byte budget for the asset: the finest levels of detail that do not
    /// fit are left out (the coarsest always stays; [`Error::OverBudget`] when it alone does not fit).
    pub max_bytes: Option<u64>,
    /// Levels of detail (1: none; at most `vdbcook_vpak::MAX_LEVELS`): levels
    /// 1 … levels − 1 of every frame, each filtered from the one before
    /// (`vdbcook_grid::lod`), are trees of the asset too.
    pub levels: u32,
}

impl Default for CookOptions {
    fn default() -> Self {
        CookOptions { format: Format::F16, groups: Vec::new(), quality: Quality::VeryFast, max_texture_dim: 2048, clustering: None, max_error: None, settings: Vec::new(), levels: 1, max_bytes: None }
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

/// A figure as JSON: a number, or (JSON has none, and serde_json would
/// write `null`, which also means "no value") `"NaN"`, `"Infinity"` or
/// `"-Infinity"`, the spellings JavaScript's `Number()`, Python's `float()`
/// and Rust's `f64::from_str` read back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Figure(pub f64);

impl Figure {
    /// The string for a non-finite figure; `None` for a finite one.
    pub fn non_finite_name(x: f64) -> Option<&'static str> {
        match x {
            x if x.is_nan() => Some("NaN"),
            f64::INFINITY => Some("Infinity"),
            f64::NEG_INFINITY => Some("-Infinity"),
            _ => None,
        }
    }
}

impl serde::Serialize for Figure {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match Figure::non_finite_name(self.0) {
            Some(name) => s.serialize_str(name),
            None => s.serialize_f64(self.0),
        }
    }
}

/// `serialize_with` helpers: figures as [`Figure`]s (f32s keep their shortest f32 spelling).
pub mod figure {
    use super::Figure;
    use serde::Serializer;

    pub fn f64<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
        serde::Serialize::serialize(&Figure(*x), s)
    }

    pub fn range<S: Serializer>(r: &[f32; 2], s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(2)?;
        for &x in r {
            match Figure::non_finite_name(f64::from(x)) {
                Some(name) => t.serialize_element(name)?,
                None => t.serialize_element(&x)?,
            }
        }
        t.end()
    }
}

/// One format of a channel: its plane's distinct bricks and bytes (shared
/// equally among the plane's channels).
#[derive(Clone, Debug, serde::Serialize)]
pub struct FormatShare {
    pub format: Format,
    pub bricks: u32,
    pub bytes: u64,
}

/// One channel's figures.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ChannelReport {
    pub name: String,
    /// Its format, or its formats cheapest first ("constant+bc7+unorm16", per-brick formats).
    pub format: String,
    /// Bytes of the planes the channel is stored in (atlases, ranges, brick
    /// tables; a plane's shared equally among its channels) and of its channel table.
    pub bytes: u64,
    /// Distinct bricks of the channel's planes.
    pub bricks: u32,
    /// Per format: the channel's bricks and bytes in it.
    pub formats: Vec<FormatShare>,
    #[serde(serialize_with = "figure::range")]
    pub value_range: [f32; 2],
    /// Voxel-domain error against the source, over the channel's own active
    /// voxels of leaves whose source value is finite.
    #[serde(serialize_with = "figure::f64")]
    pub voxel_rmse: f64,
    #[serde(serialize_with = "figure::f64")]
    pub voxel_psnr: f64,
    #[serde(serialize_with = "figure::f64")]
    pub voxel_max_error: f64,
    /// Active voxels of leaves (over every frame) whose source value is NaN
    /// or ±∞: left out of the error figures; `f32` and `f16` keep them, the
    /// ranged formats store the mean of their finite neighbours.
    pub non_finite: NonFinite,
}

/// What a cook did, for people and for `--json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CookReport {
    /// The channels' formats: "f16", or "bc4+bc7" for a mix.
    pub format: String,
    pub frames: usize,
    pub empty_frames: usize,
    /// Voxels active in any channel, over all frames.
    pub active_voxels: u64,
    /// Leaves over all frames: the bricks a cooker without deduplication would store.
    pub bricks: u64,
    /// Distinct bricks after exact deduplication of the source values.
    pub unique_bricks: usize,
    /// Bricks stored (after deduplicating encoded bricks too): what L3 nodes
    /// index; each plane stores its own distinct ones of these (`channels[c].bricks`).
    pub stored_bricks: usize,
    pub l1_nodes: usize,
    pub l2_nodes: usize,
    pub l3_nodes: usize,
    pub tiles: usize,
    /// Atlas textures over all planes.
    pub textures: usize,
    /// (section name, bytes) in file order.
    pub sections: Vec<(String, u64)>,
    pub file_bytes: u64,
    /// Node arrays (frames, L1, L2, L3, entries, tiles) in bytes.
    pub tree_bytes: u64,
    /// What the seed thesis's layout needs for the same frames.
    pub thesis_tree_bytes: u64,
    pub bits_per_active_voxel: f64,
    /// The first channel's value range.
    #[serde(serialize_with = "figure::range")]
    pub value_range: [f32; 2],
    /// Voxel-domain error of the channel with the lowest PSNR (the only one, for one channel).
    #[serde(serialize_with = "figure::f64")]
    pub voxel_rmse: f64,
    #[serde(serialize_with = "figure::f64")]
    pub voxel_psnr: f64,
    #[serde(serialize_with = "figure::f64")]
    pub voxel_max_error: f64,
    /// Non-finite source voxels left out of the error figures, over every channel.
    pub non_finite_voxels: u64,
    /// Per frame: (rmse, max error) of that channel.
    pub frame_errors: Vec<(f64, f64)>,
    /// The stored levels coarser than the first (levels of detail), finest
    /// first; empty without them.  The figures above are the first level's.
    pub levels: Vec<LevelReport>,
    /// The finest level stored: 0 unless `max_bytes` left levels out.
    pub first_level: u32,
    /// What `max_bytes` did, when it was given.
    pub budget: Option<BudgetReport>,
    pub channels: Vec<ChannelReport>,
    /// What clustering did, when it ran.
    pub clustering: Option<ClusterReport>,
    /// (stage, seconds).
    pub timings: Vec<(String, f64)>,
}

/// How `CookOptions::max_bytes` was met.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BudgetReport {
    pub max_bytes: u64,
    /// The levels left out (the finest ones), none when everything fit.
    pub dropped: Vec<u32>,
    /// The asset sizes tried, finest first level first; the last one is the asset written.
    pub tries: Vec<BudgetTry>,
}

/// One size `max_bytes` tried: the asset of levels `first_level` and coarser.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct BudgetTry {
    pub first_level: u32,
    pub bytes: u64,
}

/// A coarser level's figures, over every frame.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LevelReport {
    pub level: u32,
    /// Source voxels per level voxel along each axis (2^level).
    pub voxel_scale: u32,
    pub leaves: u64,
    pub tiles: u64,
    pub active_voxels: u64,
    /// Voxel-domain error of what is stored against the level filtered from
    /// the source (the channel with the lowest PSNR).
    #[serde(serialize_with = "figure::f64")]
    pub voxel_rmse: f64,
    #[serde(serialize_with = "figure::f64")]
    pub voxel_psnr: f64,
    #[serde(serialize_with = "figure::f64")]
    pub voxel_max_error: f64,
}

/// The thesis's Figure 19 table for one cook: bricks before (`bricks_in`) and
/// after (`bricks_out`), their ratio, and the voxel RMSE with and without
/// clustering (of the first channel; the per-channel figures are in `channels`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ClusterReport {
    pub clusters: usize,
    pub iterations: usize,
    pub variance_threshold: f64,
    pub max_brick_error: Option<f32>,
    #[serde(flatten)]
    pub stats: vdbcook_cluster::Stats,
    pub ratio: f64,
    #[serde(serialize_with = "figure::f64")]
    pub rmse_without: f64,
    #[serde(serialize_with = "figure::f64")]
    pub rmse_with: f64,
}

/// Streams frames into an asset.
pub struct Cooker {
    opts: CookOptions,
    channels: Vec<ChannelSpec>,
    /// Channel names and classes still to be taken from the first grid (single-channel cooks).
    infer: bool,
    builder: Builder,
    transform: Option<FirstTransform>,
    frames: Vec<FrameInfo>,
    sources: Vec<SourceFile>,
    ranges: Vec<[f32; 2]>,
    build_secs: f64,
    /// Time spent filtering and pushing the coarser levels.
    level_secs: f64,
}

/// The asset's transform and the grid that set it.
#[derive(Clone, Debug)]
struct FirstTransform {
    frame: usize,
    grid: String,
    transform: Transform,
}

fn transform_text(t: &Transform) -> String {
    format!("{} {:?}", t.map_type.vdb_name(), t.matrix)
}

impl Cooker {
    /// A cooker of one channel, named after the first grid pushed.
    pub fn new(opts: CookOptions) -> Cooker {
        let mut c = Cooker::with_channels(opts, vec![ChannelSpec { value_type: "float".into(), ..ChannelSpec::default() }]);
        c.infer = true;
        c
    }

    /// A cooker of the given channels (one grid each per frame).
    pub fn with_channels(opts: CookOptions, channels: Vec<ChannelSpec>) -> Cooker {
        let n = channels.len().max(1);
        Cooker {
            opts,
            channels,
            infer: false,
            builder: Builder::new(n),
            transform: None,
            frames: Vec::new(),
            sources: Vec::new(),
            ranges: vec![[f32::INFINITY, f32::NEG_INFINITY]; n],
            build_secs: 0.0,
            level_secs: 0.0,
        }
    }

    /// Records a source file once (a file listed twice is one source).
    fn add_source(&mut self, source: Option<SourceFile>) -> Option<u32> {
        source.map(|s| match self.sources.iter().position(|o| *o == s) {
            Some(i) => i as u32,
            None => {
                self.sources.push(s);
                (self.sources.len() - 1) as u32
            }
        })
    }

    /// Adds the next frame of a one-channel cook.
    pub fn push(&mut self, grid: &Grid, source: Option<SourceFile>) -> Result<(), Error> {
        self.push_channels(&[Some(grid)], source)
    }

    /// Adds the next frame: one grid per channel (`None`: empty in this frame).
    pub fn push_channels(&mut self, grids: &[Option<&Grid>], source: Option<SourceFile>) -> Result<(), Error> {
        let t0 = Instant::now();
        let frame = self.frames.len();
        for (c, g) in grids.iter().enumerate() {
            let Some(g) = g else { continue };
            match &self.transform {
                None => self.transform = Some(FirstTransform { frame, grid: g.name.clone(), transform: g.transform }),
                Some(first) if first.transform != g.transform => {
                    // Name the other frame by its file too: inputs are put in
                    // natural order, so it need not be the first one given.
                    let file = self.frames.get(first.frame).and_then(|f| f.source).and_then(|s| self.sources.get(s as usize));
                    let first_name = match file {
                        _ if first.frame == frame => "this frame".to_string(),
                        Some(s) => format!("frame {} ({})", first.frame, s.path),
                        None => format!("frame {}", first.frame),
                    };
                    return Err(Error::Transform {
                        grid: g.name.clone(),
                        found: transform_text(&g.transform),
                        first: first_name,
                        first_grid: first.grid.clone(),
                        expected: transform_text(&first.transform),
                    });
                }
                Some(_) => {}
            }
            if let Some(spec) = self.channels.get_mut(c) {
                if self.infer && spec.name.is_empty() {
                    spec.name = g.name.clone();
                    spec.grid = g.name.clone();
                }
                if spec.class.is_empty() {
                    spec.class = g.class.vdb_name().to_string();
                }
            }
        }
        let fs = self.builder.push(grids).map_err(|e| match e {
            // The caller names this frame and its file; name the grid.
            vdbcook_flipbook::Error::Background { channel, found, expected, .. } => {
                let grid = self.channels.get(channel).map_or_else(|| format!("channel {channel}"), |s| format!("grid \"{}\"", s.name));
                Error::Background { grid, found, expected }
            }
            e => e.into(),
        })?;
        for (acc, r) in self.ranges.iter_mut().zip(&fs.ranges) {
            if let Some([lo, hi]) = r {
                *acc = [acc[0].min(*lo), acc[1].max(*hi)];
            }
        }
        let coarse = self.push_levels(grids)?;
        let source = self.add_source(source);
        self.frames.push(FrameInfo { source, active_voxels: fs.active_voxels, leaves: fs.leaves as u32, tiles: fs.tiles as u32, coarse });
        self.build_secs += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// The filter of each channel's coarser levels, by its class.
    fn filters(&self) -> Vec<Filter> {
        self.channels.iter().map(|s| Filter::for_class(GridClass::from_vdb_name(&s.class))).collect()
    }

    /// Filters a frame's grids to levels 1 … levels − 1 (each from the one
    /// before) and pushes each level's tree.
    fn push_levels(&mut self, grids: &[Option<&Grid>]) -> Result<Vec<LevelFigures>, Error> {
        let levels = self.opts.levels;
        if levels == 0 || levels > vdbcook_vpak::MAX_LEVELS {
            return Err(Error::Levels(levels));
        }
        let t0 = Instant::now();
        let filters = self.filters();
        let mut figures = Vec::with_capacity(levels as usize - 1);
        let mut prev: Vec<Option<Grid>> = Vec::new();
        for k in 1..levels {
            let next: Vec<Option<Grid>> = grids
                .par_iter()
                .enumerate()
                .map(|(c, g)| {
                    let filter = filters.get(c).copied().unwrap_or(Filter::Mean);
                    match prev.get(c) {
                        Some(p) => p.as_ref().map(|p| lod::coarsen(p, filter)),
                        None => g.map(|g| lod::coarsen(g, filter)),
                    }
                })
                .collect();
            let refs: Vec<Option<&Grid>> = next.iter().map(Option::as_ref).collect();
            let fs = self.builder.push_level(k, &refs)?;
            figures.push(LevelFigures { active_voxels: fs.active_voxels, leaves: fs.leaves as u32, tiles: fs.tiles as u32 });
            prev = next;
        }
        self.level_secs += t0.elapsed().as_secs_f64();
        Ok(figures)
    }

    /// Adds an empty frame (a source without the grids, with `--allow-missing`).
    pub fn push_empty(&mut self, source: Option<SourceFile>) {
        self.builder.push_empty();
        let levels = self.opts.levels.clamp(1, vdbcook_vpak::MAX_LEVELS);
        for k in 1..levels {
            self.builder.push_empty_level(k);
        }
        let source = self.add_source(source);
        self.frames.push(FrameInfo { source, active_voxels: 0, leaves: 0, tiles: 0, coarse: vec![LevelFigures::default(); levels as usize - 1] });
    }

    pub fn frame_count(&self) -> usize {
        self.frames.len()
    }

    /// The planes of every channel group, in order: explicit groups first,
    /// then each other channel alone in `format`, in a texture of its own
    /// (measured, docs/benchmarks.md: a plane deduplicates its own bricks, so
    /// a channel alone is stored as compactly as in an asset of its own, where
    /// channels sharing a texture are stored once per distinct combination;
    /// and packing uncorrelated channels into BC7's lanes raises their error,
    /// up to 2.5x on c42).  Packing is asked for with a group.  Returns the
    /// specs and each channel's group.
    fn plan_planes(&self) -> Result<(Vec<PlaneSpec>, Vec<u32>), Error> {
        if self.opts.format == Format::Constant || self.opts.groups.iter().any(|g| g.format == Format::Constant) {
            return Err(Error::ConstantFormat);
        }
        if let Some(e) = self.opts.max_error {
            if !(e >= 0.0 && e.is_finite()) {
                return Err(Error::MaxError(e));
            }
            if !self.opts.groups.is_empty() {
                return Err(Error::MaxErrorGroups);
            }
        }
        let mut group_of: Vec<Option<u32>> = vec![None; self.channels.len()];
        let mut groups: Vec<(Format, Vec<usize>)> = Vec::new();
        for g in &self.opts.groups {
            let mut members = Vec::new();
            for name in &g.channels {
                let named = channels_named(&self.channels, name);
                if named.is_empty() {
                    let channels = self.channels.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ");
                    return Err(Error::UnknownChannel { name: name.clone(), channels });
                }
                for c in named {
                    if group_of[c].is_some() {
                        return Err(Error::TwiceGrouped(self.channels[c].name.clone()));
                    }
                    group_of[c] = Some(groups.len() as u32);
                    members.push(c);
                }
            }
            groups.push((g.format, members));
        }
        for (c, g) in group_of.iter_mut().enumerate() {
            if g.is_none() {
                *g = Some(groups.len() as u32);
                groups.push((self.opts.format, vec![c]));
            }
        }
        let specs = groups.iter().flat_map(|(f, m)| vdbcook_encode::group_planes(*f, m)).collect();
        Ok((specs, group_of.into_iter().map(|g| g.unwrap_or(0)).collect()))
    }

    /// Encodes, lays out and serialises the asset.
    /// Returns the asset's sections (write them with `vdbcook_vpak::write_file`) and the report.
    /// With `max_bytes`, the finest levels that fit are kept (see [`CookReport::budget`]).
    pub fn finish(mut self, progress: &dyn Progress) -> Result<(Vec<Section>, CookReport), Error> {
        let levels = self.opts.levels;
        if levels == 0 || levels > vdbcook_vpak::MAX_LEVELS {
            return Err(Error::Levels(levels));
        }
        let timings = vec![("build".to_string(), self.build_secs - self.level_secs), ("levels".to_string(), self.level_secs)];
        let built = std::mem::take(&mut self.builder).finish()?;
        let Some(budget) = self.opts.max_bytes else { return self.assemble(&built, 0, timings, progress) };
        // Each try leaves out one more of the finest levels (and the bricks
        // only they used); the coarsest level always stays.
        let started = Instant::now();
        let mut tries = Vec::new();
        let mut candidate = built;
        for first in 0..levels {
            if first > 0 {
                candidate = candidate.from_level(first)?;
            }
            let t0 = Instant::now();
            let (sections, mut report) = self.assemble(&candidate, first, timings.clone(), progress)?;
            tries.push(BudgetTry { first_level: first, bytes: report.file_bytes });
            if report.file_bytes <= budget {
                report.timings.push(("earlier tries".into(), (t0 - started).as_secs_f64()));
                report.budget = Some(BudgetReport { max_bytes: budget, dropped: (0..first).collect(), tries });
                return Ok((sections, report));
            }
        }
        Err(Error::OverBudget { budget, smallest: tries.last().map_or(0, |t| t.bytes), level: levels - 1 })
    }

    /// Encodes, lays out and serialises the trees of `built`, whose finest level is `first`.
    fn assemble(&self, built: &Built, first: u32, mut timings: Vec<(String, f64)>, progress: &dyn Progress) -> Result<(Vec<Section>, CookReport), Error> {
        let filters = self.filters();
        let channels = self.channels.len().max(1);
        let (specs, group_of) = self.plan_planes()?;
        if self.opts.clustering.is_some() && channels > MAX_CLUSTER_CHANNELS {
            return Err(Error::MultiChannelClustering(channels));
        }
        let any_block = specs.iter().any(|s| s.plane.format.is_block());
        let max_error = self.opts.max_error;

        // Optionally merge similar bricks; then encode every brick and store
        // identical encodings once.
        let pool = built.pool.bricks();
        let mut clustered = self.opts.clustering.as_ref().map(|co| {
            let t0 = Instant::now();
            progress.start("clustering", co.iterations as u64 + 1);
            // Each channel weighs alike: its values divided by its own range.
            let scales: Vec<f32> = (0..channels).map(|c| self.ranges[c][1] - self.ranges[c][0]).map(|s| if s > 0.0 && s.is_finite() { s } else { 1.0 }).collect();
            let c = cluster_channels(pool, &scales, co, &|_, _| progress.advance(1));
            progress.finish();
            timings.push(("cluster".into(), t0.elapsed().as_secs_f64()));
            c
        });
        // Which voxels of each brick some L3 node shows (block encoders may
        // spend nothing on the others; per-brick formats bound only these).
        let pool_masks = (any_block || max_error.is_some()).then(|| union_masks(built.pool.len(), built.l3.iter().map(|l| (l.brick as usize, l.mask))));
        let t0 = Instant::now();
        let encoded = match max_error {
            None => {
                let work: &[Brick] = clustered.as_ref().map_or(pool, |c| &c.bricks[..]);
                let work_masks = pool_masks.as_ref().map(|m| match &clustered {
                    Some(c) => union_masks(work.len() / channels, c.remap.iter().zip(m).map(|(&w, &mask)| (w as usize, mask))),
                    None => m.clone(),
                });
                progress.start("encoding", (work.len() / channels * specs.len()) as u64);
                let encoded = Encoded::new(specs.clone(), self.opts.quality, work, channels, work_masks.as_deref(), &|n| progress.advance(n as u64));
                progress.finish();
                encoded
            }
            Some(e) => {
                let quality = self.opts.quality;
                let choose = |bricks: &[Brick], masks: &[[u64; 8]]| {
                    progress.start("choosing formats", (bricks.len() / channels) as u64);
                    let c = vdbcook_encode::cheapest_all(bricks, channels, masks, e, quality, &|n| progress.advance(n as u64));
                    progress.finish();
                    c
                };
                let pool_masks = pool_masks.as_deref().unwrap_or(&[]);
                let choices = match clustered.as_mut() {
                    None => choose(pool, pool_masks),
                    Some(c) => {
                        let work_masks = union_masks(c.bricks.len() / channels, c.remap.iter().zip(pool_masks).map(|(&w, &mask)| (w as usize, mask)));
                        let mut choices = choose(&c.bricks, &work_masks);
                        // Merged bricks are held to the bound too: one that its
                        // cluster's stored brick leaves past it is stored on its own.
                        let strays: Vec<usize> = (0..c.merged.len())
                            .into_par_iter()
                            .filter(|&i| {
                                let w = c.remap[i] as usize;
                                c.merged[i]
                                    && !(0..channels).all(|ch| {
                                        let choice = &choices[w * channels + ch];
                                        vdbcook_encode::within(&pool[i * channels + ch], &vdbcook_encode::decode_one(choice.format, &choice.bytes, choice.range), &pool_masks[i], e)
                                    })
                            })
                            .collect();
                        let first = c.bricks.len();
                        for (k, &i) in strays.iter().enumerate() {
                            c.remap[i] = (first / channels + k) as u32;
                            c.merged[i] = false;
                            c.bricks.extend_from_slice(&pool[i * channels..(i + 1) * channels]);
                        }
                        let stray_masks: Vec<[u64; 8]> = strays.iter().map(|&i| pool_masks[i]).collect();
                        choices.extend(choose(&c.bricks[first..], &stray_masks));
                        c.stats.over_error += strays.len();
                        c.stats.clustered -= strays.len();
                        // Centroids all of whose bricks strayed are not stored.
                        let merged_into: std::collections::BTreeSet<u32> = c.remap.iter().zip(&c.merged).filter(|(_, &m)| m).map(|(&w, _)| w).collect();
                        c.stats.centroids = merged_into.len();
                        c.stats.bricks_out = c.merged.iter().filter(|&&m| !m).count() + merged_into.len();
                        choices
                    }
                };
                let work: &[Brick] = clustered.as_ref().map_or(pool, |c| &c.bricks[..]);
                Encoded::from_choices(work, channels, choices, &used_work(&clustered, work.len() / channels))
            }
        };
        let used = used_work(&clustered, encoded.len());
        let specs = encoded.specs.clone();
        if specs.len() > vdbcook_vpak::MAX_CHANNELS {
            return Err(Error::TooManyPlanes(specs.len()));
        }
        // Each plane stores its own distinct bricks (a table maps bricks to
        // them), so a channel that repeats where others change (a constant
        // flame, a static shadow) is stored once, as in an asset of its own.
        // With per-brick formats a plane holds only the bricks that chose it
        // (the others map to u32::MAX).
        let plane_ids: Vec<(Vec<usize>, Vec<u32>)> = (0..specs.len())
            .map(|p| {
                let members: Vec<usize> = (0..encoded.len()).filter(|&i| used[i] && encoded.holds(p, i)).collect();
                let (keep, ids) = distinct(members.len(), &|j, buf| plane_brick_bytes(&encoded, p, members[j], buf));
                let mut all = vec![u32::MAX; encoded.len()];
                for (&i, id) in members.iter().zip(ids) {
                    all[i] = id;
                }
                (keep.into_iter().map(|j| members[j]).collect(), all)
            })
            .collect();
        // A brick is its plane bricks: the distinct bricks are the distinct
        // combinations. Plane bricks, numbered by first use, are then numbered
        // by first use among the distinct bricks too (a plane without repeats
        // maps brick b to plane brick b).
        let used_bricks: Vec<usize> = (0..encoded.len()).filter(|&i| used[i]).collect();
        let (keep, used_remap) = distinct(used_bricks.len(), &|j, buf| {
            buf.clear();
            buf.extend(plane_ids.iter().flat_map(|(_, ids)| ids[used_bricks[j]].to_le_bytes()));
        });
        let keep: Vec<usize> = keep.into_iter().map(|j| used_bricks[j]).collect();
        let mut enc_remap = vec![u32::MAX; encoded.len()];
        for (&i, id) in used_bricks.iter().zip(used_remap) {
            enc_remap[i] = id;
        }
        let plane_keep: Vec<(Vec<usize>, Vec<u32>)> = plane_ids.into_iter().map(|(k, ids)| (k, keep.iter().map(|&i| ids[i]).collect())).collect();
        // Pool brick -> stored brick.
        let remap: Vec<u32> = match &clustered {
            Some(c) => c.remap.iter().map(|&w| enc_remap[w as usize]).collect(),
            None => enc_remap,
        };
        timings.push(("encode".into(), t0.elapsed().as_secs_f64()));

        // Node arrays over the final brick ids.
        let t0 = Instant::now();
        progress.start("building nodes", built.frames.len() as u64);
        let nodes = built.nodes(|b| remap.get(b as usize).copied().unwrap_or(0))?;
        progress.finish();
        timings.push(("nodes".into(), t0.elapsed().as_secs_f64()));

        // Voxel-domain error of what is stored, per frame and channel (and,
        // with clustering, what it would have been without: merged bricks
        // encoded on their own).
        let t0 = Instant::now();
        let decode_stored = |b: u32| remap.get(b as usize).and_then(|&i| keep.get(i as usize)).and_then(|&k| encoded.decode(k));
        // Per tree (frames and levels, in push order); the frame figures are the first stored level's.
        let tree_err = voxel_errors(built, &decode_stored);
        let tree_level: Vec<u32> = built.frames.iter().map(|f| f.level).collect();
        let frame_err: Vec<&Vec<ErrorStats>> = tree_err.iter().zip(&tree_level).filter(|(_, &l)| l == first).map(|(e, _)| e).collect();
        let level_err: Vec<Vec<ErrorStats>> = (first + 1..self.opts.levels)
            .map(|k| {
                let mut t = vec![ErrorStats::default(); channels];
                for (e, _) in tree_err.iter().zip(&tree_level).filter(|(_, &l)| l == k) {
                    t.iter_mut().zip(e).for_each(|(t, e)| t.merge(e));
                }
                t
            })
            .collect();
        let totals: Vec<ErrorStats> = (0..channels)
            .map(|c| {
                let mut t = ErrorStats::default();
                for f in &frame_err {
                    t.merge(&f[c]);
                }
                t
            })
            .collect();
        let cluster_report = clustered.as_ref().zip(self.opts.clustering.as_ref()).map(|(c, co)| {
            let merged: Vec<usize> = (0..c.merged.len()).filter(|&i| c.merged[i]).collect();
            let own: Vec<Brick> = merged.iter().flat_map(|&i| built.pool.brick(i).unwrap_or(&[]).iter().copied()).collect();
            let own_masks: Option<Vec<[u64; 8]>> = pool_masks.as_ref().map(|m| merged.iter().map(|&i| m[i]).collect());
            let own_enc = match self.opts.max_error {
                None => Encoded::new(specs.clone(), self.opts.quality, &own, channels, own_masks.as_deref(), &|_| {}),
                Some(e) => {
                    Encoded::from_choices(&own, channels, vdbcook_encode::cheapest_all(&own, channels, own_masks.as_deref().unwrap_or(&[]), e, self.opts.quality, &|_| {}), &vec![true; merged.len()])
                }
            };
            let mut slot = vec![u32::MAX; c.merged.len()];
            for (k, &i) in merged.iter().enumerate() {
                slot[i] = k as u32;
            }
            let decode_unclustered = |b: u32| match slot.get(b as usize) {
                Some(&k) if k != u32::MAX => own_enc.decode(k as usize),
                _ => decode_stored(b),
            };
            let mut without = ErrorStats::default();
            for (e, _) in voxel_errors(built, &decode_unclustered).iter().zip(&tree_level).filter(|(_, &l)| l == first) {
                without.merge(&e[0]);
            }
            ClusterReport {
                clusters: co.clusters,
                iterations: co.iterations,
                variance_threshold: co.variance_threshold,
                max_brick_error: co.max_brick_error,
                stats: c.stats.clone(),
                ratio: c.stats.bricks_in as f64 / c.stats.bricks_out.max(1) as f64,
                rmse_without: without.rmse(),
                rmse_with: totals[0].rmse(),
            }
        });
        timings.push(("error".into(), t0.elapsed().as_secs_f64()));

        let unique_bricks = built.pool.len();
        let t0 = Instant::now();
        let mut sections = node_sections(&nodes);
        let mut plane_infos = Vec::with_capacity(specs.len());
        let mut plane_bytes = vec![0u64; specs.len()];
        let mut atlas_sections = Vec::new();
        let enc = &encoded;
        // Each channel's planes, in spec order: the first is its `plane`, the
        // others (per-brick formats) its alternates, reached through its channel table.
        let mut planes_of: Vec<Vec<usize>> = vec![Vec::new(); channels];
        for (p, spec) in specs.iter().enumerate() {
            for &c in &spec.channels {
                planes_of[c].push(p);
            }
        }
        let mixed_plane = |p: usize| specs[p].channels.first().is_some_and(|&c| planes_of[c].len() > 1);
        for (p, (spec, (pkeep, table))) in specs.iter().zip(&plane_keep).enumerate() {
            let atlases = match spec.plane.format {
                Format::Constant => Vec::new(),
                _ => plan_atlases(spec.plane.slices_per_brick(), pkeep.len() as u32, self.opts.max_texture_dim),
            };
            let info = PlaneInfo { plane: spec.plane, bricks: pkeep.len() as u32, atlases };
            let slots = info.range_slots() as usize;
            let ranges: Vec<u32> = pkeep.iter().flat_map(|&k| (0..slots).flat_map(move |s| spec.channels.get(s).map_or([0.0; 2], |&c| enc.range(k, c)))).map(f32::to_bits).collect();
            plane_bytes[p] += 4 * ranges.len() as u64;
            sections.push(Section { kind: kind::BRICK_RANGES, index: p as u32, data: words(&ranges) });
            if info.bricks as usize != keep.len() && !mixed_plane(p) {
                plane_bytes[p] += 4 * table.len() as u64;
                sections.push(Section { kind: kind::BRICK_TABLE, index: p as u32, data: words(table) });
            }
            let bricks = encoded.plane(p, pkeep);
            for atlas in &info.atlases {
                let data = pack_atlas(&AtlasLayout { plane: spec.plane, atlas: *atlas }, &bricks);
                plane_bytes[p] += data.len() as u64;
                atlas_sections.push(Section { kind: kind::ATLAS, index: atlas_sections.len() as u32, data });
            }
            plane_infos.push(info);
        }
        let mut channel_table_bytes = vec![0u64; channels];
        for (c, planes) in planes_of.iter().enumerate().filter(|(_, planes)| planes.len() > 1) {
            let mut table = vec![0u32; keep.len()];
            for (j, &p) in planes.iter().enumerate() {
                if plane_infos[p].bricks > vdbcook_vpak::PLANE_BRICK_MASK {
                    return Err(Error::TooManyPlaneBricks(plane_infos[p].bricks));
                }
                for (entry, &pb) in table.iter_mut().zip(&plane_keep[p].1) {
                    if pb != u32::MAX {
                        *entry = (j as u32) << vdbcook_vpak::CHOICE_SHIFT | pb;
                    }
                }
            }
            channel_table_bytes[c] = 4 * table.len() as u64;
            sections.push(Section { kind: kind::CHANNEL_TABLE, index: c as u32, data: words(&table) });
        }
        sections.extend(atlas_sections);
        let stored_bricks = keep.len();
        let channel_range = |c: usize| if self.ranges[c][0] <= self.ranges[c][1] { self.ranges[c] } else { [built.backgrounds[c]; 2] };
        // PSNR's peak: the channel's value range over its finite values (an
        // infinite range would make every PSNR infinite).
        let peaks: Vec<f64> = (0..channels)
            .map(|c| {
                let [lo, hi] = match channel_range(c) {
                    r if r.iter().all(|v| v.is_finite()) => r,
                    _ => finite_range(built, c),
                };
                let peak = f64::from(hi - lo);
                if peak > 0.0 && peak.is_finite() {
                    peak
                } else {
                    1.0
                }
            })
            .collect();
        // The source-precision bricks are not needed any more.
        drop(encoded);
        drop(clustered);
        let transform = self.transform.as_ref().map_or_else(Transform::identity, |f| f.transform);
        // Each channel's place: its (first) plane and first lane there.
        let place: Vec<(u32, u32)> = planes_of
            .iter()
            .enumerate()
            .map(|(c, planes)| {
                let p = planes.first().copied().unwrap_or(0);
                let slot = specs[p].channels.iter().position(|&k| k == c).unwrap_or(0) as u32;
                (p as u32, slot * specs[p].plane.z_per_texel)
            })
            .collect();
        let meta = Metadata {
            tool: concat!("vdbcook ", env!("CARGO_PKG_VERSION")).to_string(),
            frame_count: self.frames.len() as u32,
            map_type: transform.map_type.vdb_name().to_string(),
            transform: transform.matrix,
            index_offset: nodes.offset,
            index_bbox: built.bbox.map(|b| (b.min.to_array(), b.max.to_array())),
            channels: self
                .channels
                .iter()
                .enumerate()
                .map(|(c, s)| Channel {
                    name: s.name.clone(),
                    grid: s.grid.clone(),
                    component: s.component,
                    value_type: s.value_type.clone(),
                    class: if s.class.is_empty() { "unknown".into() } else { s.class.clone() },
                    background: built.backgrounds[c],
                    value_range: channel_range(c),
                    group: group_of[c],
                    plane: place[c].0,
                    lane: place[c].1,
                    alternates: planes_of[c].iter().skip(1).map(|&p| p as u32).collect(),
                })
                .collect(),
            planes: plane_infos,
            brick_count: stored_bricks as u32,
            settings: self.opts.settings.clone(),
            sources: self.sources.clone(),
            frames: self.frames.clone(),
            levels: self.opts.levels,
            level_filters: if self.opts.levels > 1 { filters.into_iter().map(level_filter).collect() } else { Vec::new() },
            first_level: first,
        };
        sections.insert(0, Section { kind: kind::METADATA, index: 0, data: meta.to_bytes()? });
        let report_sections: Vec<(String, u64)> = sections.iter().map(|s| (kind::label(s.kind, s.index), s.data.len() as u64)).collect();
        let file_bytes = vdbcook_vpak::file_len(&sections);
        timings.push(("layout".into(), t0.elapsed().as_secs_f64()));

        let tree_bytes: u64 = nodes.byte_sizes().iter().map(|(_, b)| *b as u64).sum();
        let active: u64 = self.frames.iter().map(|f| f.active_voxels).sum();
        let psnr = |c: usize| totals[c].psnr(peaks[c]);
        let channel_reports: Vec<ChannelReport> = meta
            .channels
            .iter()
            .enumerate()
            .map(|(c, ch)| {
                let formats: Vec<FormatShare> =
                    planes_of[c].iter().map(|&p| FormatShare { format: specs[p].plane.format, bricks: meta.planes[p].bricks, bytes: plane_bytes[p] / specs[p].channels.len().max(1) as u64 }).collect();
                ChannelReport {
                    name: ch.name.clone(),
                    format: formats.iter().map(|f| f.format.name()).collect::<Vec<_>>().join("+"),
                    bytes: formats.iter().map(|f| f.bytes).sum::<u64>() + channel_table_bytes[c],
                    bricks: formats.iter().map(|f| f.bricks).sum(),
                    formats,
                    value_range: ch.value_range,
                    voxel_rmse: totals[c].rmse(),
                    voxel_psnr: psnr(c),
                    voxel_max_error: totals[c].max_abs,
                    non_finite: totals[c].non_finite,
                }
            })
            .collect();
        let worst = (0..channels).min_by(|&a, &b| psnr(a).total_cmp(&psnr(b))).unwrap_or(0);
        let report = CookReport {
            format: meta.format_names(),
            frames: self.frames.len(),
            empty_frames: self.frames.iter().filter(|f| f.leaves == 0 && f.tiles == 0).count(),
            active_voxels: active,
            bricks: built.leaves_in,
            unique_bricks,
            stored_bricks,
            l1_nodes: nodes.l1_count(),
            l2_nodes: nodes.l2_count(),
            l3_nodes: nodes.l3_count(),
            tiles: nodes.tile_count(),
            textures: meta.texture_count(),
            sections: report_sections,
            file_bytes,
            tree_bytes,
            thesis_tree_bytes: vdbcook_flipbook::thesis_tree_bytes(self.frames.len(), built.leaves_in),
            bits_per_active_voxel: if active > 0 { file_bytes as f64 * 8.0 / active as f64 } else { 0.0 },
            value_range: channel_range(0),
            voxel_rmse: totals[worst].rmse(),
            voxel_psnr: psnr(worst),
            voxel_max_error: totals[worst].max_abs,
            non_finite_voxels: totals.iter().map(|t| t.non_finite.total()).sum(),
            frame_errors: frame_err.iter().map(|e| (e[worst].rmse(), e[worst].max_abs)).collect(),
            levels: level_err
                .iter()
                .enumerate()
                .map(|(i, e)| {
                    let k = first + 1 + i as u32;
                    let w = (0..channels).min_by(|&a, &b| e[a].psnr(peaks[a]).total_cmp(&e[b].psnr(peaks[b]))).unwrap_or(0);
                    let fig = |f: fn(&LevelFigures) -> u64| self.frames.iter().filter_map(|fr| fr.coarse.get(k as usize - 1)).map(f).sum::<u64>();
                    LevelReport {
                        level: k,
                        voxel_scale: 1 << k,
                        leaves: fig(|f| u64::from(f.leaves)),
                        tiles: fig(|f| u64::from(f.tiles)),
                        active_voxels: fig(|f| f.active_voxels),
                        voxel_rmse: e[w].rmse(),
                        voxel_psnr: e[w].psnr(peaks[w]),
                        voxel_max_error: e[w].max_abs,
                    }
                })
                .collect(),
            first_level: first,
            budget: None,
            channels: channel_reports,
            clustering: cluster_report,
            timings,
        };
        Ok((sections, report))
    }
}

fn level_filter(f: Filter) -> LevelFilter {
    match f {
        Filter::Mean => LevelFilter::Mean,
        Filter::ActiveMean => LevelFilter::ActiveMean,
    }
}

/// Channel `c`'s range over the finite values of the pool's bricks (their
/// inactive voxels are filled from the active ones, within their range) and
/// of the frames' tiles; `[0, 0]` when it has none.
fn finite_range(built: &Built, c: usize) -> [f32; 2] {
    let bricks = (0..built.pool.len()).filter_map(|b| built.pool.brick(b)).filter_map(|b| b.get(c)).flat_map(|b| b.iter().copied());
    let tiles = built.frames.iter().flat_map(|f| f.tiles.iter().filter_map(|t| t.2.get(c).copied()));
    let [lo, hi] = bricks.chain(tiles).filter(|v| v.is_finite()).fold([f32::INFINITY, f32::NEG_INFINITY], |[lo, hi], v| [lo.min(v), hi.max(v)]);
    if lo <= hi {
        [lo, hi]
    } else {
        [0.0, 0.0]
    }
}

/// Per work brick (`n` of them), whether some pool brick uses it: with
/// per-brick formats, a centroid all of whose bricks strayed past the bound
/// is not stored.
fn used_work(clustered: &Option<Clustered>, n: usize) -> Vec<bool> {
    match clustered {
        Some(c) => {
            let mut used = vec![false; n];
            for &w in &c.remap {
                if let Some(u) = used.get_mut(w as usize) {
                    *u = true;
                }
            }
            used
        }
        None => vec![true; n],
    }
}

/// Channels `--clusters` takes (k-means items of 512 values per channel).
pub const MAX_CLUSTER_CHANNELS: usize = 8;

/// The clustered pool, `channels` [`Brick`]s per brick.
struct Clustered {
    bricks: Vec<Brick>,
    remap: Vec<u32>,
    merged: Vec<bool>,
    stats: vdbcook_cluster::Stats,
}

/// Variance-gated k-means over bricks of `scales.len()` channels: each brick
/// is one item of its channels' values, each divided by its channel's
/// `scale` (so distances weigh every channel alike; `max_brick_error` stays
/// in the channels' units), and the centroids are scaled back.
fn cluster_channels(pool: &[Brick], scales: &[f32], opts: &vdbcook_cluster::Options, progress: &(dyn Fn(usize, usize) + Sync)) -> Clustered {
    fn run<const N: usize>(pool: &[Brick], scales: &[f32], opts: &vdbcook_cluster::Options, progress: &(dyn Fn(usize, usize) + Sync)) -> Clustered {
        let c = scales.len();
        let items: Vec<[f32; N]> = pool.par_chunks(c).map(|b| std::array::from_fn(|v| b[v / 512][v % 512] / scales[v / 512])).collect();
        let out = vdbcook_cluster::cluster_scaled(&items, opts, scales, progress);
        let mut bricks: Vec<Brick> = out.bricks.iter().flat_map(|item| (0..c).map(move |k| std::array::from_fn(|v| item[k * 512 + v] * scales[k]))).collect();
        // A brick not merged keeps its own values exactly (v / s · s need not be v).
        for (i, _) in out.merged.iter().enumerate().filter(|(_, &m)| !m) {
            let w = out.remap[i] as usize;
            bricks[w * c..(w + 1) * c].copy_from_slice(&pool[i * c..(i + 1) * c]);
        }
        Clustered { bricks, remap: out.remap, merged: out.merged, stats: out.stats }
    }
    match scales.len() {
        1 => {
            // One channel: the values as they are (same results as before channels existed).
            let out = vdbcook_cluster::cluster(pool, opts, progress);
            Clustered { bricks: out.bricks, remap: out.remap, merged: out.merged, stats: out.stats }
        }
        2 => run::<1024>(pool, scales, opts, progress),
        3 => run::<1536>(pool, scales, opts, progress),
        4 => run::<2048>(pool, scales, opts, progress),
        5 => run::<2560>(pool, scales, opts, progress),
        6 => run::<3072>(pool, scales, opts, progress),
        7 => run::<3584>(pool, scales, opts, progress),
        _ => run::<4096>(pool, scales, opts, progress),
    }
}

/// The channels a group's name stands for: the channel of that name, or
/// the three components of the vec3 grid of that name.
pub fn channels_named(specs: &[ChannelSpec], name: &str) -> Vec<usize> {
    match specs.iter().position(|s| s.name == name) {
        Some(c) => vec![c],
        None => (0..specs.len()).filter(|&c| specs[c].component.is_some() && specs[c].grid == name).collect(),
    }
}

/// Per item `0..n`, the union of the masks given for it.
fn union_masks(n: usize, masks: impl Iterator<Item = (usize, [u64; 8])>) -> Vec<[u64; 8]> {
    let mut out = vec![[0u64; 8]; n];
    for (i, m) in masks {
        if let Some(o) = out.get_mut(i) {
            for (o, m) in o.iter_mut().zip(m) {
                *o |= m;
            }
        }
    }
    out
}

/// Brick `i`'s bytes in plane `p`: its encoding, then the range of each of the plane's channels.
fn plane_brick_bytes(encoded: &Encoded, p: usize, i: usize, buf: &mut Vec<u8>) {
    let spec = &encoded.specs[p];
    buf.clear();
    buf.resize(spec.plane.brick_bytes(), 0);
    encoded.write(p, i, buf);
    for &c in &spec.channels {
        for v in encoded.range(i, c) {
            buf.extend_from_slice(&v.to_bits().to_le_bytes());
        }
    }
}

/// Finds the distinct items `0..n` by their bytes (`bytes_of`; the first of
/// equal ones, in order): returns their indices and, per item, its distinct index.
fn distinct(n: usize, bytes_of: &(dyn Fn(usize, &mut Vec<u8>) + Sync)) -> (Vec<usize>, Vec<u32>) {
    let hashes: Vec<u64> = (0..n)
        .into_par_iter()
        .map_init(Vec::new, |buf, i| {
            bytes_of(i, buf);
            xxhash_rust::xxh3::xxh3_64(buf)
        })
        .collect();
    let mut index = HashIndex::default();
    index.reserve(n);
    let mut keep: Vec<usize> = Vec::new();
    let mut remap = Vec::with_capacity(n);
    for (i, &h) in hashes.iter().enumerate() {
        let same = |k: u32| {
            // Equal hashes are rare: make both again to compare.
            let (mut x, mut y) = (Vec::new(), Vec::new());
            bytes_of(keep[k as usize], &mut x);
            bytes_of(i, &mut y);
            x == y
        };
        let id = match index.find(h, same) {
            Some(k) => k,
            None => {
                let k = keep.len() as u32;
                index.add(h, k);
                keep.push(i);
                k
            }
        };
        remap.push(id);
    }
    (keep, remap)
}

/// Error of decoded bricks (`decoded(pool brick)`, one [`Brick`] per
/// channel) against the source, per frame and channel, over each channel's
/// own active voxels.
fn voxel_errors(built: &Built, decoded: &(dyn Fn(u32) -> Option<Vec<Brick>> + Sync)) -> Vec<Vec<ErrorStats>> {
    let channels = built.channels;
    let source = |b: u32| built.pool.brick(b as usize);
    if channels == 1 {
        // Per L3 node: its error over its own active voxels (the channel's mask).
        let per_l3: Vec<ErrorStats> = built
            .l3
            .par_iter()
            .map(|l| {
                let mut e = ErrorStats::default();
                if let (Some(src), Some(dec)) = (source(l.brick), decoded(l.brick)) {
                    e.add_masked(&src[0], &dec[0], &l.mask);
                }
                e
            })
            .collect();
        return built
            .frames
            .iter()
            .map(|f| {
                let mut e = ErrorStats::default();
                for &(_, id) in &f.leaves {
                    e.merge(&per_l3[id as usize]);
                }
                vec![e]
            })
            .collect();
    }
    // Several channels: each leaf over each channel's own mask.
    built
        .frames
        .iter()
        .map(|f| {
            let per_leaf: Vec<Vec<ErrorStats>> = f
                .leaves
                .par_iter()
                .enumerate()
                .map(|(k, &(_, id))| {
                    let mut e = vec![ErrorStats::default(); channels];
                    let brick = built.l3[id as usize].brick;
                    if let (Some(src), Some(dec)) = (source(brick), decoded(brick)) {
                        for (c, e) in e.iter_mut().enumerate() {
                            if let Some(mask) = f.channel_masks.get(k * channels + c) {
                                e.add_masked(&src[c], &dec[c], mask);
                            }
                        }
                    }
                    e
                })
                .collect();
            let mut total = vec![ErrorStats::default(); channels];
            for leaf in &per_leaf {
                for (t, e) in total.iter_mut().zip(leaf) {
                    t.merge(e);
                }
            }
            total
        })
        .collect()
}

/// Little-endian bytes of `u32`s (a plain copy on little-endian machines).
fn words(v: &[u32]) -> Vec<u8> {
    if cfg!(target_endian = "little") {
        bytemuck::cast_slice(v).to_vec()
    } else {
        v.iter().flat_map(|w| w.to_le_bytes()).collect()
    }
}

fn node_sections(n: &Nodes) -> Vec<Section> {
    [
        (kind::FRAMES, &n.frames),
        (kind::L1_NODES, &n.l1),
        (kind::L1_ENTRIES, &n.l1_entries),
        (kind::L2_NODES, &n.l2),
        (kind::L2_ENTRIES, &n.l2_entries),
        (kind::L3_NODES, &n.l3),
        (kind::TILES, &n.tiles),
    ]
    .into_iter()
    .map(|(k, v)| Section { kind: k, index: 0, data: words(v) })
    .collect()
}

#[cfg(test)]
mod tests;
