//! What a cook reports: the report types (JSON through `--json`), and the
//! last step of [`Cooker::finish`](crate::Cooker::finish), which fills them in.

use crate::errors::Measured;
use crate::{Cooker, Format};
use std::ops::Deref;
use vdbcook_encode::{ErrorStats, NonFinite, PlaneSpec};
use vdbcook_flipbook::Built;
use vdbcook_vpak::nodes::Nodes;
use vdbcook_vpak::{kind, LevelFigures, Metadata, Section};

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

/// Voxel-domain error figures of a channel, a level or a whole cook (the
/// channel with the lowest PSNR), as every report spells them.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ErrorFigures {
    #[serde(serialize_with = "figure::f64")]
    pub voxel_rmse: f64,
    #[serde(serialize_with = "figure::f64")]
    pub voxel_psnr: f64,
    #[serde(serialize_with = "figure::f64")]
    pub voxel_max_error: f64,
}

impl ErrorFigures {
    /// The figures of `stats`, PSNR against `peak`.
    pub fn of(stats: &ErrorStats, peak: f64) -> ErrorFigures {
        ErrorFigures { voxel_rmse: stats.rmse(), voxel_psnr: stats.psnr(peak), voxel_max_error: stats.max_abs }
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
    /// The level whose voxels are the channel's own (0: the asset's voxel
    /// size; k: 2^k times as wide), and that voxel size in world units.
    pub level: u32,
    pub voxel_size: [f64; 3],
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
    #[serde(flatten)]
    pub error: ErrorFigures,
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
    /// (section name, bytes) in file order: the bytes a reader restores.
    pub sections: Vec<(String, u64)>,
    /// (section name, bytes in the file): `sections` unless supercompressed
    /// (then smaller, and with the coding section). The JSON gives them in `sections`.
    #[serde(skip)]
    pub disk_sections: Vec<(String, u64)>,
    /// The file's bytes (on disk).
    pub file_bytes: u64,
    /// Bytes of every section but the metadata, restored: what a renderer
    /// uploads to the GPU to draw any frame.
    pub gpu_bytes: u64,
    /// Node arrays (frames, L1, L2, L3, entries, tiles) in bytes.
    pub tree_bytes: u64,
    /// What the seed thesis's layout needs for the same frames.
    pub thesis_tree_bytes: u64,
    pub bits_per_active_voxel: f64,
    /// The first channel's value range.
    #[serde(serialize_with = "figure::range")]
    pub value_range: [f32; 2],
    /// Voxel-domain error of the channel with the lowest PSNR (the only one, for one channel).
    #[serde(flatten)]
    pub error: ErrorFigures,
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
    /// Per segment (one for an asset cut into none): its frames, bricks and bytes.
    pub segments: Vec<SegmentReport>,
    /// What the sources' metadata said of time, when they said anything (set by the caller that read them).
    pub source_time: Option<SourceTime>,
    /// The most bytes the cook's buffers held in spill files at once (0: none spilled; see `vdbcook_grid::spill`).
    pub spilled_bytes: u64,
    /// The asset's metadata as written in its first section (typed, so that a
    /// caller adding settings, as bake does, need not read the bytes back);
    /// for an asset of several segments, the whole sequence's (`vdbcook_vpak::segments::merged`).
    #[serde(skip)]
    pub metadata: vdbcook_vpak::Metadata,
    /// What the figures were computed from, to add up segments' reports exactly.
    #[serde(skip)]
    pub(crate) sums: Sums,
}

/// What the source files' metadata said of time (EmberGen writes
/// `simulation_time`): reported, not used (`--fps` sets the asset's rate).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SourceTime {
    /// The metadata key read (file-level first, then the first grid's).
    pub key: String,
    /// Frames whose file states it, and the first and last values (seconds).
    pub frames: usize,
    pub first: f64,
    pub last: f64,
    /// Frames per second those times imply (frames − 1 over the time they span), when they span any.
    pub implied_fps: Option<f64>,
    /// A frame rate a file states (key `fps`, `frame_rate` or `framerate`), when one does.
    pub stated_fps: Option<f64>,
}

/// One segment of an asset: its frames, distinct and stored bricks, and bytes.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SegmentReport {
    pub first_frame: usize,
    pub frames: usize,
    pub unique_bricks: usize,
    pub stored_bricks: usize,
    /// The segment's body in the file.
    pub bytes: u64,
    /// Its sections but the metadata, restored (uploaded to draw its frames).
    pub gpu_bytes: u64,
    /// Its error sums: segments cooked apart (parts) add up to the figures
    /// of one cook ([`Sums::sequence_error`]).
    #[serde(skip)]
    pub sums: Sums,
}

/// Error sums behind a report's figures.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sums {
    /// Per channel, the first stored level over every frame.
    pub(crate) totals: Vec<ErrorStats>,
    /// Per coarser stored level, per channel.
    pub(crate) levels: Vec<Vec<ErrorStats>>,
    /// Per channel, the peak its PSNR is taken against.
    pub(crate) peaks: Vec<f64>,
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
    #[serde(flatten)]
    pub error: ErrorFigures,
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
    /// The error sums behind `rmse_without`.
    #[serde(skip)]
    pub(crate) without: ErrorStats,
}

// The reports read as before (`report.voxel_rmse`): their figures are flattened into them, in JSON too.
macro_rules! figures_deref {
    ($($t:ty),*) => {$(
        impl Deref for $t {
            type Target = ErrorFigures;
            fn deref(&self) -> &ErrorFigures {
                &self.error
            }
        }
    )*};
}
figures_deref!(ChannelReport, CookReport, LevelReport);

/// What the report says of the node arrays.
pub(crate) struct TreeFigures {
    bytes: u64,
    l1: usize,
    l2: usize,
    l3: usize,
    tiles: usize,
}

impl TreeFigures {
    pub(crate) fn of(n: &Nodes) -> TreeFigures {
        TreeFigures { bytes: n.byte_sizes().iter().map(|(_, b)| *b as u64).sum(), l1: n.l1_count(), l2: n.l2_count(), l3: n.l3_count(), tiles: n.tile_count() }
    }
}

/// What the report gives of an asset's sections.
pub(crate) struct SectionSizes {
    pub(crate) file_bytes: u64,
    /// What a renderer uploads (the sections are not supercompressed yet).
    pub(crate) gpu_bytes: u64,
    /// Each section's name and bytes.
    pub(crate) sizes: Vec<(String, u64)>,
}

impl SectionSizes {
    pub(crate) fn of(sections: &[Section]) -> SectionSizes {
        SectionSizes {
            file_bytes: vdbcook_vpak::file_len(sections),
            gpu_bytes: sections.iter().filter(|s| kind::uploaded(s.kind)).map(|s| s.data.len() as u64).sum(),
            sizes: sections.iter().map(|s| (kind::label(s.kind, s.index), s.data.len() as u64)).collect(),
        }
    }
}

/// What the report is made of.
pub(crate) struct Parts<'a> {
    pub(crate) built: &'a Built,
    pub(crate) first: u32,
    pub(crate) tree: TreeFigures,
    pub(crate) meta: &'a Metadata,
    /// Every section's size, the metadata's first.
    pub(crate) sections: SectionSizes,
    pub(crate) stored_bricks: usize,
    pub(crate) specs: &'a [PlaneSpec],
    pub(crate) planes_of: &'a [Vec<usize>],
    pub(crate) plane_bytes: &'a [u64],
    pub(crate) channel_table_bytes: &'a [u64],
    pub(crate) measured: &'a Measured,
    pub(crate) peaks: &'a [f64],
}

impl Cooker {
    /// The report of an asset made of `parts`.
    pub(crate) fn report(&self, parts: Parts, clustering: Option<ClusterReport>, timings: Vec<(String, f64)>) -> CookReport {
        let Parts { built, first, tree, meta, sections, stored_bricks, specs, planes_of, plane_bytes, channel_table_bytes, measured, peaks } = parts;
        let channels = peaks.len();
        let totals = &measured.totals;
        let SectionSizes { file_bytes, gpu_bytes, sizes } = sections;
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
                    level: meta.resolution(c).level,
                    voxel_size: meta.channel_voxel_size(c),
                    format: formats.iter().map(|f| f.format.name()).collect::<Vec<_>>().join("+"),
                    bytes: formats.iter().map(|f| f.bytes).sum::<u64>() + channel_table_bytes[c],
                    bricks: formats.iter().map(|f| f.bricks).sum(),
                    formats,
                    value_range: ch.value_range,
                    error: ErrorFigures::of(&totals[c], peaks[c]),
                    non_finite: totals[c].non_finite,
                }
            })
            .collect();
        let worst = (0..channels).min_by(|&a, &b| psnr(a).total_cmp(&psnr(b))).unwrap_or(0);
        let sums = Sums { totals: totals.clone(), levels: measured.levels.clone(), peaks: peaks.to_vec() };
        CookReport {
            metadata: meta.clone(),
            format: meta.format_names(),
            frames: self.frames.len(),
            empty_frames: self.frames.iter().filter(|f| f.leaves == 0 && f.tiles == 0).count(),
            active_voxels: active,
            bricks: built.leaves_in,
            unique_bricks: built.pool.len(),
            stored_bricks,
            l1_nodes: tree.l1,
            l2_nodes: tree.l2,
            l3_nodes: tree.l3,
            tiles: tree.tiles,
            textures: meta.texture_count(),
            disk_sections: sizes.clone(),
            sections: sizes,
            file_bytes,
            gpu_bytes,
            tree_bytes: tree.bytes,
            thesis_tree_bytes: vdbcook_flipbook::thesis_tree_bytes(self.frames.len(), built.leaves_in),
            bits_per_active_voxel: if active > 0 { file_bytes as f64 * 8.0 / active as f64 } else { 0.0 },
            value_range: self.value_ranges(built, 1)[0],
            error: ErrorFigures::of(&totals[worst], peaks[worst]),
            non_finite_voxels: totals.iter().map(|t| t.non_finite.total()).sum(),
            frame_errors: measured.frames.iter().map(|e| (e[worst].rmse(), e[worst].max_abs)).collect(),
            levels: measured
                .levels
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
                        error: ErrorFigures::of(&e[w], peaks[w]),
                    }
                })
                .collect(),
            first_level: first,
            budget: None,
            channels: channel_reports,
            clustering,
            timings,
            segments: vec![SegmentReport {
                first_frame: self.first_frame,
                frames: self.frames.len(),
                unique_bricks: built.pool.len(),
                stored_bricks,
                bytes: file_bytes,
                gpu_bytes,
                sums: sums.clone(),
            }],
            source_time: None,
            spilled_bytes: self.opts.spill.as_ref().map_or(0, vdbcook_grid::spill::SpillPolicy::peak_in_files),
            sums,
        }
    }
}
