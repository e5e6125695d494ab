//! Voxel encodings of bricks: the texels of each plane of an asset, made from
//! the brick pool.  Which voxel and channel is which texel, lane, block and
//! byte is `vdbcook_vpak::layout`'s to say (the format's one owner); this
//! crate computes the levels and runs the encoders.
//!
//! | format   | texel                                  | per brick and channel                  |
//! |----------|----------------------------------------|----------------------------------------|
//! | `f32`    | R32Float / RG32Float / RGBA32Float      | values as they are                     |
//! | `f16`    | R16Float / RG16Float / RGBA16Float      | IEEE half, round to nearest even       |
//! | `unorm8` | R8Unorm / RG8Unorm / RGBA8Unorm         | `round((v - min) / (max - min) · 255)` with the brick's own channel range |
//! | `bc4`    | Bc4RUnorm, one plane per channel        | our BC4 encoder over those levels      |
//! | `bc7`    | Bc7RgbaUnorm, lanes = channels × z-slices | intel_tex_2's BC7 over those levels  |
//!
//! Every brick records each channel's [min, max] (the brick range) over its
//! finite values: the ranged formats need it to decode, and a renderer can
//! skip empty bricks.  NaN and ±∞ voxels are kept by `f32` and `f16`; the
//! ranged formats cannot hold them and store each as the mean of its finite
//! neighbours ([`fill_non_finite`]), so no block is fitted through one.

pub use vdbcook_vpak::{BrickSource, Format, Plane, BRICK_VOXELS, MAX_BRICK_BYTES};

vdbcook_vpak::bounded!(
    /// An absolute per-voxel error bound (`--max-error`, `--max-brick-error`): a finite number >= 0.
    ErrorBound(f32),
    "number",
    |e| if e >= 0.0 && e.is_finite() { Ok(()) } else { Err(format!("must be a finite number >= 0, not {e}")) }
);

/// One brick of one channel (index `x·64 + y·8 + z`).
pub use vdbcook_grid::{Brick, Bricks};

/// Encoder presets of the block formats: for BC7, intel_tex_2's ISPC "alpha"
/// settings (all four channels carry voxels); for BC4, how far our encoder
/// searches around each block's least-squares endpoints.  `VeryFast` is the
/// default: see docs/benchmarks.md for the measurements behind it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Quality {
    UltraFast,
    VeryFast,
    Fast,
    Basic,
    Slow,
}

impl Quality {
    pub const ALL: [Quality; 5] = [Quality::UltraFast, Quality::VeryFast, Quality::Fast, Quality::Basic, Quality::Slow];

    pub fn name(self) -> &'static str {
        match self {
            Quality::UltraFast => "ultra-fast",
            Quality::VeryFast => "very-fast",
            Quality::Fast => "fast",
            Quality::Basic => "basic",
            Quality::Slow => "slow",
        }
    }

    pub fn parse(s: &str) -> Option<Quality> {
        Quality::ALL.into_iter().find(|q| q.name() == s)
    }
}

/// What `cook --max-error` minimises brick by brick when the asset is
/// supercompressed: the GPU's bytes (the cheapest format within the bound,
/// as without supercompression) or the file's (the format whose texels,
/// filtered and compressed, take the fewest bytes; it may be a larger
/// GPU format).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Optimize {
    #[default]
    Gpu,
    Disk,
}

impl vdbcook_vpak::settings::SettingText for Optimize {
    fn text(&self) -> String {
        match self {
            Optimize::Gpu => "gpu".into(),
            Optimize::Disk => "disk".into(),
        }
    }
}

impl vdbcook_vpak::settings::SettingText for Quality {
    fn text(&self) -> String {
        self.name().to_string()
    }
}

mod bc;
mod choose;
mod encoded;
mod snap;
mod stats;
mod texels;
pub use bc::bc7_kernels;
pub use choose::{cheapest, decode_one, single_plane, within, Choice, Choices, Pick};
pub use encoded::{Encoded, PlaneBricks};
pub use stats::{ErrorStats, NonFinite};
pub use texels::{fill_non_finite, range_of};

/// A plane and the channels in its slots, in lane order (`channel_slots` of
/// them at most; a BC7 plane of 3 channels leaves its fourth slot empty).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlaneSpec {
    pub plane: Plane,
    pub channels: Vec<usize>,
}

/// The planes of a group of channels stored in `format`: chunks of up to
/// four channels in order, a chunk of three split into two and one (no lane
/// to spare). Uncompressed formats put a chunk in one texture (R, RG, RGBA);
/// BC4 takes one plane per channel; BC7 one plane per chunk, each channel
/// with `4 / channels` consecutive z-slices in its lanes (one channel: four
/// z-slices, as single-channel assets; two: two slices each; four: one
/// voxel's channels, the classic channel packing).
pub fn group_planes(format: Format, channels: &[usize]) -> Vec<PlaneSpec> {
    if format == Format::Bc4 {
        return channels.iter().map(|&c| PlaneSpec { plane: Plane { format, lanes: 1, z_per_texel: 1 }, channels: vec![c] }).collect();
    }
    channels
        .chunks(4)
        .flat_map(|k| if k.len() == 3 { vec![&k[..2], &k[2..]] } else { vec![k] })
        .map(|k| {
            let plane = match format {
                Format::Bc7 => Plane { format, lanes: 4, z_per_texel: 4 / k.len() as u32 },
                _ => Plane::uncompressed(format, k.len() as u32),
            };
            PlaneSpec { plane, channels: k.to_vec() }
        })
        .collect()
}

/// Single-channel bricks encoded in `format`, back to back (tests and tools).
pub fn encode_bricks(format: Format, quality: Quality, bricks: &[Brick]) -> Vec<u8> {
    let e = Encoded::new(group_planes(format, &[0]), quality, bricks, 1, None, &|_| {});
    let n = e.specs[0].plane.brick_bytes();
    let mut out = vec![0u8; n * bricks.len()];
    for (i, o) in out.chunks_exact_mut(n).enumerate() {
        e.write(0, i, o);
    }
    out
}

/// Encodes one single-channel brick in `format` and decodes it back (tests and tools).
pub fn round_trip(format: Format, quality: Quality, values: &Brick) -> Brick {
    let e = Encoded::new(group_planes(format, &[0]), quality, std::slice::from_ref(values), 1, None, &|_| {});
    e.decode(0).map_or([0.0; BRICK_VOXELS], |d| d[0])
}

#[cfg(all(test, target_arch = "x86_64"))]
mod bc7_isa;
#[cfg(test)]
mod tests;
