//! The validation renderer: one deterministic wgpu ray-marcher for any two
//! `.vpak` assets (the cooked one and a lossless reference cooked from the
//! source), image metrics, and a CPU twin of the same march for tests.
//!
//! The WGSL lives in the top-level `shaders/` folder: `vpak.wgsl` samples an
//! asset (the library an engine can include) with `vpak_atlas_texture.wgsl`,
//! or with `vpak_atlas_buffer.wgsl` and `bcdec.wgsl` where BC bricks are
//! decoded in the shader; `march.wgsl` is the marcher.

mod cpu;
mod gpu;
pub mod report;

pub use cpu::render_cpu;
pub use gpu::{shader_sources, BcDecode, GpuAsset, Renderer};

use vdbcook_vpak::{kind, Asset, Metadata};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("no GPU adapter found{0}; on Debian, install Mesa's Vulkan drivers (CPU rendering works too): apt-get install mesa-vulkan-drivers libvulkan1")]
    NoAdapter(String),
    #[error("cannot open the GPU device: {0}")]
    Device(String),
    #[error("the adapter \"{adapter}\" cannot sample {format} bricks: it lacks {feature}")]
    Unsupported { adapter: String, format: String, feature: &'static str },
    #[error("the asset has {0} brick atlases; the renderer binds at most {MAX_ATLASES} (cook with a larger --max-texture-dim)")]
    Atlases(usize),
    #[error("a brick atlas of {size:?} texels exceeds the adapter's 3D texture limit of {limit} (cook with a smaller --max-texture-dim)")]
    Texture { size: [u32; 3], limit: u32 },
    #[error("the asset's {what} ({bytes} bytes) exceeds the adapter's limit of {limit} bytes")]
    TooLarge { what: &'static str, bytes: u64, limit: u64 },
    #[error("unsupported voxel format \"{0}\"")]
    Format(String),
    #[error("the asset is inconsistent: {0}")]
    Corrupt(String),
    #[error("frame {frame} is out of range (the asset has {count})")]
    Frame { frame: usize, count: usize },
    #[error("GPU error: {0}")]
    Gpu(String),
    #[error(transparent)]
    Asset(#[from] vdbcook_vpak::Error),
}

/// Brick atlases the renderer binds.
pub const MAX_ATLASES: usize = 4;

/// Voxel format codes shared with `vpak.wgsl`.
pub fn format_code(name: &str) -> Option<u32> {
    Some(match name {
        "f32" => 0,
        "f16" => 1,
        "unorm8" => 2,
        "bc4" => 3,
        "bc7" => 4,
        _ => return None,
    })
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
    /// The scene for an asset: its union bbox (from the metadata), a density
    /// scale giving an optical depth of 4 across the box at the largest value,
    /// and a fixed light.
    pub fn for_asset(meta: &Metadata) -> Scene {
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
        let peak = meta.value_range[1].abs().max(meta.value_range[0].abs()).max(1e-6);
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
        }
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

/// A single-channel linear image, row-major from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<f32>,
}

/// RMSE, PSNR (peak 1) and max absolute difference of two images, values clamped to [0, 1].
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

/// Atlas metadata must describe the sections exactly, and every atlas but the
/// last must have the first one's shape (the samplers assume both).
fn check_atlases(meta: &Metadata, format: u32, sections: &[&[u8]]) -> Result<(), Error> {
    let spb: u64 = if format == 4 { 2 } else { 8 };
    let first = meta.atlases.first();
    let mut next_brick = 0u64;
    for (i, (a, bytes)) in meta.atlases.iter().zip(sections).enumerate() {
        let bad = |what: String| Err(Error::Corrupt(format!("atlas {i}: {what}")));
        let [bx, by, bz] = a.bricks.map(u64::from);
        if bx == 0 || by == 0 || bz == 0 || u64::from(a.count) > bx * by * bz {
            return bad(format!("{:?} bricks cannot hold {}", a.bricks, a.count));
        }
        if a.texels.map(u64::from) != [bx * 8, by * 8, bz * spb] {
            return bad(format!("texture size {:?} does not match {:?} bricks", a.texels, a.bricks));
        }
        // Samplers place brick i of any atlas with the first atlas's shape:
        // every atlas but the last has that shape, and the last must hold
        // every position it gives.
        if let Some(f) = first {
            let [fx, fy, _] = f.bricks.map(|b| u64::from(b).max(1));
            let n = u64::from(a.count);
            let need = [n.min(fx), n.div_ceil(fx).min(fy), n.div_ceil(fx * fy)];
            let fits = if i + 1 < meta.atlases.len() { a.bricks == f.bricks } else { (0..3).all(|k| u64::from(a.bricks[k]) >= need[k]) };
            if !fits || u64::from(a.first_brick) != next_brick {
                return bad("its layout does not follow the first atlas's".into());
            }
        }
        next_brick += u64::from(a.count);
        let [w, h, d] = a.texels.map(u64::from);
        let expected = match format {
            0 => w * h * d * 4,
            1 => w * h * d * 2,
            2 => w * h * d,
            3 => (w / 4) * (h / 4) * d * 8,
            _ => (w / 4) * (h / 4) * d * 16,
        };
        if bytes.len() as u64 != expected {
            return bad(format!("{} bytes, its size needs {expected}", bytes.len()));
        }
    }
    Ok(())
}

/// The node arrays and bricks of an asset, as the renderers read them.
pub(crate) struct AssetData<'a> {
    pub meta: Metadata,
    pub format: u32,
    pub l1: &'a [u32],
    pub l1_entries: &'a [u32],
    pub l2: &'a [u32],
    pub l2_entries: &'a [u32],
    pub l3: &'a [u32],
    pub tiles: &'a [u32],
    pub ranges: &'a [f32],
    pub frames: &'a [u32],
    pub atlases: Vec<&'a [u8]>,
}

impl<'a> AssetData<'a> {
    pub fn new(asset: &'a Asset) -> Result<AssetData<'a>, Error> {
        let meta = asset.metadata()?;
        let format = format_code(&meta.format).ok_or_else(|| Error::Format(meta.format.clone()))?;
        if meta.atlases.len() > MAX_ATLASES {
            return Err(Error::Atlases(meta.atlases.len()));
        }
        let atlases = (0..meta.atlases.len()).map(|i| asset.section(kind::ATLAS, i as u32)).collect::<Result<Vec<_>, _>>()?;
        check_atlases(&meta, format, &atlases)?;
        Ok(AssetData {
            format,
            l1: asset.u32s(kind::L1_NODES)?,
            l1_entries: asset.u32s(kind::L1_ENTRIES)?,
            l2: asset.u32s(kind::L2_NODES)?,
            l2_entries: asset.u32s(kind::L2_ENTRIES)?,
            l3: asset.u32s(kind::L3_NODES)?,
            tiles: asset.u32s(kind::TILES)?,
            ranges: asset.f32s(kind::BRICK_RANGES)?,
            frames: asset.u32s(kind::FRAMES)?,
            atlases,
            meta,
        })
    }

    /// Size in bricks of the first atlas and the bricks every full atlas holds.
    pub fn atlas_bricks(&self) -> [u32; 4] {
        match self.meta.atlases.first() {
            Some(a) => {
                let [x, y, z] = a.bricks.map(|b| b.max(1));
                [x, y, z, x.saturating_mul(y).saturating_mul(z)]
            }
            None => [1, 1, 1, 1],
        }
    }

    /// The last atlas's number and its own size in bricks along x and y.
    pub fn last_atlas(&self) -> [u32; 4] {
        match self.meta.atlases.last() {
            Some(a) => [(self.meta.atlases.len() - 1) as u32, a.bricks[0].max(1), a.bricks[1].max(1), 0],
            None => [0, 1, 1, 0],
        }
    }

    pub fn frame_l1(&self, frame: usize) -> Result<u32, Error> {
        self.frames.get(frame).copied().ok_or(Error::Frame { frame, count: self.frames.len() })
    }
}
