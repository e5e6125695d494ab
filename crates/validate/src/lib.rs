//! The validation renderer: one deterministic wgpu ray-marcher for any two
//! `.vpak` assets (the cooked one and a lossless reference cooked from the
//! source), image metrics, and a CPU twin of the same march for tests.
//!
//! The WGSL lives in the top-level `shaders/` folder: `vpak.wgsl` samples an
//! asset (the library an engine can include) with `vpak_atlas_texture.wgsl`,
//! or with `vpak_atlas_buffer.wgsl` and `bcdec.wgsl` where BC bricks are
//! decoded in the shader; `march.wgsl` is the marcher.

pub mod compare;
mod cpu;
pub mod flip;
mod gpu;
mod html;
pub mod options;
pub mod play;
pub mod report;
mod resident;
mod scene;

pub use compare::{check_frames, compare_assets, CompareError, CompareOptions, Comparison, LevelFigures, Levels, Shot, Worst};
pub use cpu::{render_cpu, render_cpu_level};
pub use flip::{flip, FlipMap};
pub use gpu::{open_adapter, open_device, open_gpu, shader_sources, wanted_features, BcDecode, Gpu, GpuAsset, Renderer};
pub use options::{Gate, Size, Viewing, Views};
pub use play::{play, FrameStats, PlayOptions, PlaySummary};
pub use resident::{PlacedSegment, Resident};
pub use scene::{coverage, Model};
/// The wgpu the renderer is built with, for callers that present its images (`vdbcook view`).
pub use wgpu;

use vdbcook_vpak::{Asset, Checked, Metadata};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("no GPU adapter found{0}; on Debian, install Mesa's Vulkan drivers (CPU rendering works too): apt-get install mesa-vulkan-drivers libvulkan1")]
    NoAdapter(String),
    #[error("cannot open the GPU device: {0}")]
    Device(String),
    #[error("the adapter \"{adapter}\" cannot sample {format} bricks: it lacks {feature}")]
    Unsupported { adapter: String, format: String, feature: &'static str },
    #[error("the channels the render shows are in {planes} planes of {textures} atlas textures; the renderer binds at most {MAX_TEXTURES} (a larger --max-texture-dim puts a plane in fewer atlases; cook --max-error gives a channel a texture per format its bricks chose, so several shown channels cooked with it may need more)")]
    Textures { planes: usize, textures: usize },
    #[error("channel {0} is not on the GPU (the asset was uploaded for the channels another scene shows: upload it for this one)")]
    NotUploaded(u32),
    #[error("a brick atlas of {size:?} texels exceeds the adapter's 3D texture limit of {limit} (cook with a smaller --max-texture-dim)")]
    Texture { size: [u32; 3], limit: u32 },
    #[error("the asset's {what} ({bytes} bytes) exceeds the adapter's limit of {limit} bytes")]
    TooLarge { what: &'static str, bytes: u64, limit: u64 },
    #[error("the asset is inconsistent: {0}")]
    Corrupt(String),
    #[error("frame {frame} is out of range (the asset has {count})")]
    Frame { frame: usize, count: usize },
    /// A level the asset does not store (the text says which it does).
    #[error("{0}")]
    Level(String),
    #[error("GPU error: {0}")]
    Gpu(String),
    #[error(transparent)]
    Asset(#[from] vdbcook_vpak::Error),
    #[error("{0}")]
    Flip(String),
    /// `--extinction` (manifest key `extinction`) names a channel the asset lacks.
    #[error("the asset has no channel \"{name}\" to give extinction (its channels: {channels})")]
    Extinction { name: String, channels: String },
}

/// Atlas textures the renderer binds (those of the planes holding the channels a render shows).
pub const MAX_TEXTURES: usize = 8;

/// No channel (`VPAK_NONE` in the shaders).
pub const NONE: u32 = u32::MAX;
use scene::{find, FLAMES, TEMPERATURE};

/// The channel the validation render shows ([`Scene::shown`] of
/// [`Scene::for_asset`]): `density`; else the first scalar fog volume (or
/// unknown-class) channel that does not glow; else the first scalar level
/// set; else `flames` (or `flame`), else `temperature` (or `heat`); else the
/// first channel.
pub fn extinction_channel(meta: &Metadata) -> usize {
    scene::choose_default(meta).0
}

/// The channels that glow in the validation render: (temperature, flames).
pub fn emission_channels(meta: &Metadata) -> (Option<usize>, Option<usize>) {
    (find(meta, &TEMPERATURE), find(meta, &FLAMES))
}

/// A camera looking at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    /// Vertical field of view in degrees.
    pub fov_deg: f32,
}

/// What every image of one comparison shares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scene {
    /// Asset index-space box to march: [min, max) in voxels.
    pub box_min: [f32; 3],
    pub box_max: [f32; 3],
    /// Extinction per unit of value per voxel.
    pub density_scale: f32,
    /// Direction towards the light (normalised).
    pub light: [f32; 3],
    pub step: f32,
    pub shadow_step: f32,
    pub max_steps: u32,
    /// Edge of a shadow-grid cell in voxels.
    pub shadow_cell: f32,
    /// Channels: extinction (or the level set of the surface model),
    /// temperature, flames ([`NONE`] when absent or not drawn).
    pub channels: [u32; 3],
    /// 1 / the largest temperature and flames value, the light emitted per
    /// voxel of path at full scale, and the albedo of the extinguishing
    /// medium (1 when it scatters; 0 in the glow model, where flames or
    /// temperature stand in for a missing fog: fire absorbs and glows).
    pub emission: [f32; 4],
    /// How `channels[0]` is drawn.
    model: Model,
    /// Where the drawn channel's voxels are from its level's (its offset,
    /// docs/format.md "Channel resolutions"), in level-0 voxels: the
    /// renderers draw it there, moving the camera by as much the other way.
    pub shift: [f32; 3],
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt().max(1e-20);
    [a[0] / l, a[1] / l, a[2] / l]
}

impl View {
    /// The view in an index space whose origin is `d` voxels from this one's
    /// (a segment's, `d` = its index offset − the scene's).
    pub fn shifted(&self, d: [i32; 3]) -> View {
        self.moved(d.map(|v| v as f32))
    }

    /// The view in an index space whose origin is `d` voxels from this one's.
    pub fn moved(&self, d: [f32; 3]) -> View {
        let m = |p: [f32; 3]| std::array::from_fn(|i| p[i] - d[i]);
        View { eye: m(self.eye), target: m(self.target), fov_deg: self.fov_deg }
    }

    /// Camera basis: right, up, forward.
    pub fn basis(&self) -> ([f32; 3], [f32; 3], [f32; 3]) {
        let f = normalize(sub(self.target, self.eye));
        let world_up = if f[1].abs() > 0.99 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let r = normalize(cross(f, world_up));
        let u = cross(r, f);
        (r, u, f)
    }
}

impl Scene {
    /// The scene in an index space whose origin is `d` voxels from this one's
    /// (see [`View::shifted`]): the same box in the world.
    pub fn shifted(&self, d: [i32; 3]) -> Scene {
        let m = |p: [f32; 3]| std::array::from_fn(|i| p[i] - d[i] as f32);
        Scene { box_min: m(self.box_min), box_max: m(self.box_max), ..*self }
    }

    /// The scene for an asset, its medium chosen by the rule of
    /// [`extinction_channel`]: see [`Scene::for_asset_with`].
    pub fn for_asset(meta: &Metadata) -> Scene {
        Self::with_medium(meta, scene::choose_default(meta))
    }

    /// The scene for an asset: its union bbox (from the metadata), a density
    /// scale giving an optical depth of 4 across the box at the largest value,
    /// and a fixed light. The channel `extinction` names (an error when the
    /// asset lacks it), else the channel [`extinction_channel`] picks, is the
    /// medium, drawn as [`Scene::model`] says.
    pub fn for_asset_with(meta: &Metadata, extinction: Option<&str>) -> Result<Scene, Error> {
        Ok(Self::with_medium(meta, scene::choose(meta, extinction)?))
    }

    fn with_medium(meta: &Metadata, (extinction, model): (usize, Model)) -> Scene {
        let o = meta.index_offset.map(i64::from);
        let (lo, hi) = match meta.index_bbox {
            Some((a, b)) => ([0, 1, 2].map(|i| i64::from(a[i]) - o[i]), [0, 1, 2].map(|i| i64::from(b[i]) - o[i] + 1)),
            None => ([0; 3], [1; 3]),
        };
        // Asset index space is [0, 4096): clamp what a corrupt bbox could claim.
        let box_min = lo.map(|v| v.clamp(0, 4096) as f32);
        let box_max = hi.map(|v| v.clamp(0, 4096) as f32);
        let ext = sub(box_max, box_min);
        let diag = (ext[0] * ext[0] + ext[1] * ext[1] + ext[2] * ext[2]).sqrt().max(1.0);
        // The largest magnitude of a channel's values. The recorded range
        // takes in non-finite voxels (which the march ignores): past an
        // infinite end, the other end if it is not zero, else 1.
        let peak_of = |c: usize| {
            meta.channels.get(c).map_or(1.0, |c| match c.value_range.map(f32::abs) {
                [lo, hi] if lo.is_finite() && hi.is_finite() => hi.max(lo).max(1e-6),
                [lo, hi] => [lo, hi].into_iter().find(|v| v.is_finite() && *v > 0.0).unwrap_or(1.0),
            })
        };
        let peak = peak_of(extinction);
        // A surface neither glows nor scatters; a glow channel is drawn only
        // on the voxels of the channel drawn (a coarse one is left out).
        let (temperature, flames) = if model == Model::Surface { (None, None) } else { emission_channels(meta) };
        let same_voxels = |c: &Option<usize>| c.filter(|&c| meta.resolution(c) == meta.resolution(extinction));
        let (temperature, flames) = (same_voxels(&temperature), same_voxels(&flames));
        Scene {
            box_min,
            box_max,
            density_scale: 4.0 / (peak * diag),
            light: normalize([0.4, 1.0, 0.3]),
            step: 1.0,
            shadow_step: 1.0,
            max_steps: 4 * (diag.min(1e6) as u32 + 8),
            // At most 128 cells along the longest axis, at least 4 voxels a cell.
            shadow_cell: (ext[0].max(ext[1]).max(ext[2]) / 128.0).ceil().max(4.0),
            channels: [extinction as u32, temperature.map_or(NONE, |c| c as u32), flames.map_or(NONE, |c| c as u32)],
            // A ray across the box through full-scale fire gathers about 6.
            emission: [1.0 / temperature.map_or(1.0, peak_of), 1.0 / flames.map_or(1.0, peak_of), 6.0 / diag, if model == Model::Scatter { 1.0 } else { 0.0 }],
            model,
            shift: meta.resolution(extinction).offset().map(|v| v as f32),
        }
    }

    /// The level the renderers draw when asked for `level`: the drawn
    /// channel's stored level nearest it (a channel with coarser voxels than
    /// the asset's has no finer level than its own).
    pub fn drawn_level(&self, meta: &Metadata, level: u32) -> u32 {
        meta.channel_level_near(self.shown(), level)
    }

    /// Shadow-grid cells along each axis.
    pub fn shadow_grid(&self) -> [u32; 3] {
        [0, 1, 2].map(|a| (((self.box_max[a] - self.box_min[a]) / self.shadow_cell).ceil() as u32).max(1))
    }

    /// `n` views orbiting the box centre at 20° elevation, evenly spaced in azimuth.
    pub fn orbit(&self, n: usize) -> Vec<View> {
        let c = [(self.box_min[0] + self.box_max[0]) * 0.5, (self.box_min[1] + self.box_max[1]) * 0.5, (self.box_min[2] + self.box_max[2]) * 0.5];
        let ext = sub(self.box_max, self.box_min);
        let radius = 0.5 * (ext[0] * ext[0] + ext[1] * ext[1] + ext[2] * ext[2]).sqrt().max(1.0);
        let fov_deg = 40.0f32;
        let dist = radius / (fov_deg.to_radians() * 0.5).sin() * 1.05;
        let elev = 20f32.to_radians();
        (0..n)
            .map(|i| {
                let az = std::f32::consts::TAU * i as f32 / n as f32;
                let eye = [c[0] + dist * elev.cos() * az.cos(), c[1] + dist * elev.sin(), c[2] + dist * elev.cos() * az.sin()];
                View { eye, target: c, fov_deg }
            })
            .collect()
    }
}

/// A linear RGB image, row-major from the top: `pixels` holds R, G, B per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<f32>,
}

/// RMSE, PSNR (peak 1) and max absolute difference of two images over every
/// colour component, values clamped to [0, 1].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ImageMetrics {
    pub rmse: f64,
    pub psnr: f64,
    pub max_error: f64,
}

pub fn compare(reference: &Image, other: &Image) -> ImageMetrics {
    let mut sq = 0.0f64;
    let mut mx = 0.0f64;
    for (a, b) in reference.pixels.iter().zip(&other.pixels) {
        let d = f64::from(a.clamp(0.0, 1.0)) - f64::from(b.clamp(0.0, 1.0));
        sq += d * d;
        mx = mx.max(d.abs());
    }
    let n = reference.pixels.len().max(1) as f64;
    let rmse = (sq / n).sqrt();
    ImageMetrics { rmse, psnr: if rmse > 0.0 { -20.0 * rmse.log10() } else { f64::INFINITY }, max_error: mx }
}

/// A validated asset, as the renderers read it.
pub(crate) struct AssetData<'a> {
    pub c: Checked<'a>,
}

impl<'a> AssetData<'a> {
    pub fn new(asset: &'a Asset) -> Result<AssetData<'a>, Error> {
        Ok(AssetData { c: Checked::new(asset)? })
    }

    pub fn meta(&self) -> &Metadata {
        &self.c.meta
    }

    /// The L1 node of frame `frame` at level of detail `level`.
    pub fn tree_l1(&self, frame: usize, level: u32) -> Result<u32, Error> {
        if let Some(why) = self.c.meta.missing_level(level) {
            return Err(Error::Level(why));
        }
        self.c.tree(frame, level).ok_or(Error::Frame { frame, count: self.c.meta.frame_count as usize })
    }
}
