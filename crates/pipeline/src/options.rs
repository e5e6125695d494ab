//! The typed cook options: one struct, [`CookSettings`], built from `cook`'s
//! flags (clap) or from a manifest entry (serde), with one default per setting.
//!
//! Every setting is declared once, in the `settings_group!` below: its type,
//! its default and its flag's help. Each value type checks its own range when
//! it is built (`vdbcook_vpak::settings`), so the flags, the manifest and a
//! library caller share one check. The comparison's settings ([`Viewing`],
//! [`Gate`]) are vdbcook-validate's groups, included flat.

use std::fmt;
use std::str::FromStr;
pub use vdbcook_cook::ChannelGroup;
pub use vdbcook_encode::{ErrorBound, Format, Optimize, Quality};
pub use vdbcook_validate::options::{FlipBudget, PsnrFloor, RmseBudget, Viewing, Views};
pub use vdbcook_validate::{Gate, Size};
pub use vdbcook_vpak::coding::Supercompress;
pub use vdbcook_vpak::settings::{SettingText, Settings};
use vdbcook_vpak::{bounded, settings_group};
pub use vdbcook_vpak::{Fps, Level, LevelCount};

/// A setting out of its range or at odds with another; `name` is the setting's.
#[derive(Debug, thiserror::Error)]
#[error("{name}: {message}")]
pub struct SettingError {
    pub name: &'static str,
    pub message: String,
}

/// An inclusive frame range with a step (`A-B` or `A-B:STEP`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRange {
    pub first: i64,
    pub last: i64,
    pub step: i64,
}

impl FromStr for FrameRange {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("invalid frame range \"{s}\" (expected A-B or A-B:STEP, e.g. 1-120:2)");
        let (range, step) = match s.split_once(':') {
            Some((r, st)) => (r, st.parse::<i64>().map_err(|_| bad())?),
            None => (s, 1),
        };
        // Allow negative frame numbers: split on the '-' that follows the first number.
        let cut = range.char_indices().skip(1).find(|&(_, c)| c == '-').map(|(i, _)| i);
        let (a, b) = match cut {
            Some(i) => (&range[..i], &range[i + 1..]),
            None => (range, range),
        };
        let (first, last) = (a.trim().parse::<i64>().map_err(|_| bad())?, b.trim().parse::<i64>().map_err(|_| bad())?);
        if step < 1 || last < first {
            return Err(bad());
        }
        if i128::from(last) - i128::from(first) > 1_000_000 * i128::from(step) {
            return Err(format!("frame range \"{s}\" has more than a million frames"));
        }
        Ok(FrameRange { first, last, step })
    }
}

impl fmt::Display for FrameRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-{}:{}", self.first, self.last, self.step)
    }
}

impl FrameRange {
    pub fn frames(&self) -> impl Iterator<Item = i64> + '_ {
        (self.first..=self.last).step_by(self.step as usize)
    }
}

/// A byte budget (`--max-bytes`, `max_bytes`): a whole number of bytes, or a
/// number with a unit: kB, MB, GB (powers of 1000; k, M, G alone too) or
/// KiB, MiB, GiB (powers of 1024). More than 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ByteBudget(pub u64);

impl FromStr for ByteBudget {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("invalid byte budget \"{s}\" (expected bytes, or a number with kB, MB, GB, KiB, MiB or GiB, e.g. 1.5MB)");
        let t = s.trim();
        let split = t.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(t.len());
        let (number, unit) = (t[..split].trim(), t[split..].trim());
        let scale: u128 = match unit {
            "" | "B" | "b" => 1,
            "k" | "K" | "kB" | "KB" => 1_000,
            "M" | "MB" => 1_000_000,
            "G" | "GB" => 1_000_000_000,
            "KiB" => 1 << 10,
            "MiB" => 1 << 20,
            "GiB" => 1 << 30,
            _ => return Err(bad()),
        };
        // Decimal digits exactly (1.001kB is 1001 bytes, not a float's 1000.99…).
        let (whole, frac) = number.split_once('.').unwrap_or((number, ""));
        let digits = |d: &str| d.len() <= 18 && d.bytes().all(|b| b.is_ascii_digit());
        if whole.is_empty() && frac.is_empty() || !digits(whole) || !digits(frac) {
            return Err(bad());
        }
        let value = |d: &str| d.parse::<u128>().unwrap_or(0);
        let den = 10u128.pow(frac.len() as u32);
        let num = value(whole) * den + value(frac);
        if !(num * scale).is_multiple_of(den) {
            return Err(format!("byte budget \"{s}\" is not a whole number of bytes"));
        }
        match u64::try_from(num * scale / den) {
            Ok(0) => Err(format!("byte budget \"{s}\" must be at least 1 byte")),
            Ok(b) => Ok(ByteBudget(b)),
            Err(_) => Err(format!("byte budget \"{s}\" is too large")),
        }
    }
}

impl fmt::Display for ByteBudget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// A value a manifest writes as a number or as the flag's text: the number
/// is read as its decimal text, so both go through the one `FromStr`.
fn number_or_text<'de, D: serde::Deserializer<'de>, T: FromStr<Err = String>>(d: D) -> Result<T, D::Error> {
    #[derive(serde::Deserialize)]
    #[serde(untagged)]
    enum Raw {
        Number(u64),
        Text(String),
    }
    let text = match <Raw as serde::Deserialize>::deserialize(d)? {
        Raw::Number(n) => n.to_string(),
        Raw::Text(t) => t,
    };
    text.parse().map_err(serde::de::Error::custom)
}

/// A manifest writes it as a number of bytes or as the flag's text.
impl<'de> serde::Deserialize<'de> for ByteBudget {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        number_or_text(d)
    }
}

/// When a cook's large buffers (brick pools, atlases) leave memory
/// (`--spill-above`, `spill_above`): past a byte size (as [`ByteBudget`]
/// writes it), past a quarter of the memory the process may use (`auto`),
/// or `never`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpillAbove {
    Auto,
    Bytes(u64),
    Never,
}

impl SpillAbove {
    /// The size in bytes (`None`: never).
    pub fn bytes(self) -> Option<u64> {
        match self {
            SpillAbove::Auto => Some(vdbcook_grid::mem::usable_memory() / 4),
            SpillAbove::Bytes(b) => Some(b),
            SpillAbove::Never => None,
        }
    }
}

impl FromStr for SpillAbove {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "auto" => Ok(SpillAbove::Auto),
            "never" => Ok(SpillAbove::Never),
            t => t
                .parse::<ByteBudget>()
                .map(|b| SpillAbove::Bytes(b.0))
                .map_err(|_| format!("invalid size \"{t}\" (expected auto, never, bytes, or a number with kB, MB, GB, KiB, MiB or GiB, e.g. 512MiB)")),
        }
    }
}

impl fmt::Display for SpillAbove {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SpillAbove::Auto => f.write_str("auto"),
            SpillAbove::Never => f.write_str("never"),
            SpillAbove::Bytes(b) => write!(f, "{b}"),
        }
    }
}

/// A manifest writes it as a number of bytes or as the flag's text.
impl<'de> serde::Deserialize<'de> for SpillAbove {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        number_or_text(d)
    }
}

/// A manifest writes it as the flag's text.
impl<'de> serde::Deserialize<'de> for FrameRange {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

vdbcook_vpak::setting_text_by_display!(FrameRange, ByteBudget, SpillAbove);

bounded!(
    /// k-means clusters (`--clusters`, `clusters`): 1 to 1,000,000.
    Clusters(u32),
    "cluster count",
    |k| if (1..=1_000_000).contains(&k) { Ok(()) } else { Err(format!("{k} is not in 1..=1000000")) }
);

bounded!(
    /// k-means iterations (`--iterations`, `iterations`): 0 to 1000.
    Iterations(u32),
    "iteration count",
    |n| if n <= 1000 { Ok(()) } else { Err(format!("{n} is not in 0..=1000")) }
);

bounded!(
    /// A variance / mean threshold (`--variance-threshold`): a number >= 0.
    VarianceThreshold(f64),
    "number",
    |t| if t >= 0.0 { Ok(()) } else { Err(format!("must be a number >= 0, not {t}")) }
);

bounded!(
    /// The largest 3D texture edge in texels (`--max-texture-dim`): 8 to 16384.
    TextureDim(u32),
    "texel count",
    |n| if (8..=16384).contains(&n) { Ok(()) } else { Err(format!("{n} is not in 8..=16384")) }
);

bounded!(
    /// Frames per segment (`--segment-frames`, `segment_frames`): 1 to 1,000,000.
    SegmentFrames(u32),
    "frame count",
    |n| if (1..=1_000_000).contains(&n) { Ok(()) } else { Err(format!("{n} is not in 1..=1000000")) }
);

fn cook_defaults() -> vdbcook_cook::CookOptions {
    vdbcook_cook::CookOptions::default()
}

fn cluster_defaults() -> vdbcook_cluster::Options {
    vdbcook_cluster::Options::default()
}

// The one list of cook settings. Defaults come from the libraries that use
// them (CookOptions, cluster::Options) or are written here; the flags show
// them. `cook` makes the comparison's flags (Viewing, Gate) require --validate
// or --auto (a group of its own: a bake does not search formats).
settings_group! {
    /// Every cook setting of one asset (flags of `vdbcook cook`, keys of a bake manifest).
    #[cfg_attr(feature = "clap", derive(clap::Args))]
    pub struct CookSettings {
        /// Frames of a frame pattern: A-B or A-B:STEP (e.g. 1-120:2).
        #[cfg_attr(feature = "clap", arg(long, value_name = "RANGE"))]
        pub frames: Option<FrameRange> = None;
        /// Grid to cook (default: "density", else the first float grid; a vec3 grid gives three channels).
        #[cfg_attr(feature = "clap", arg(long, value_name = "NAME", conflicts_with = "grids"))]
        pub grid: Option<String> = None;
        /// Grids to cook into one asset, as channels of one tree: names as in the files,
        /// comma-separated, or "all" (every float, double, half and vec3 grid of the first frame).
        #[cfg_attr(feature = "clap", arg(long, value_name = "A,B,...|all"))]
        pub grids: Option<String> = None;
        /// Another sequence whose files give each frame more grids (repeatable): a file, directory,
        /// glob or frame pattern, as INPUT. Its files are matched to INPUT's frames by the number
        /// in their names (else by position), and each name of --grids is found in whichever
        /// file of the frame has it; NAME@N picks the file of sequence N when several have it
        /// (0: INPUT, 1: the first --with, ...). E.g. noise/fluid_noise_####.vdb --with
        /// data/fluid_data_####.vdb --grids density@0,flame,vel.
        #[cfg_attr(feature = "clap", arg(long, value_name = "INPUT"))]
        pub with: Vec<String> = Vec::new();
        /// Pack these channels into shared textures in their own format (repeatable), e.g.
        /// --group temperature,flames=bc7 --group density=bc4; other channels take --format, a texture each.
        #[cfg_attr(feature = "clap", arg(long, value_name = "CHANNELS=FORMAT"))]
        pub group: Vec<ChannelGroup> = Vec::new();
        /// A frame whose file or grid is missing becomes an empty frame instead of an error (a
        /// --with sequence's missing file: its channels are empty in that frame).
        #[cfg_attr(feature = "clap", arg(long))]
        pub allow_missing: bool = false;
        /// Voxel format of the brick atlas.
        #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = CookSettings::default().format))]
        pub format: Format = cook_defaults().format;
        /// Store every brick in the cheapest format (constant, bc7, bc4, unorm8, unorm16, f16, f32)
        /// whose active voxels all decode within E of the source (absolute); --format is not used.
        #[cfg_attr(feature = "clap", arg(long, value_name = "E", allow_negative_numbers = true, conflicts_with_all = ["format", "group"]))]
        pub max_error: Option<ErrorBound> = None;
        /// Encoder preset of bc7 and bc4 (see the notes below).
        #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = CookSettings::default().quality))]
        pub quality: Quality = cook_defaults().quality;
        /// Merge similar bricks with variance-gated k-means into K centroid bricks (off by default;
        /// with --segment-frames, K per segment).
        #[cfg_attr(feature = "clap", arg(long, value_name = "K"))]
        pub clusters: Option<Clusters> = None;
        /// k-means iterations.
        #[cfg_attr(feature = "clap", arg(long, value_name = "N", default_value_t = CookSettings::default().iterations))]
        pub iterations: Iterations = Iterations(cluster_defaults().iterations as u32);
        /// Bricks whose variance / mean exceeds T are never clustered.
        #[cfg_attr(feature = "clap", arg(long, value_name = "T", allow_negative_numbers = true, default_value_t = CookSettings::default().variance_threshold))]
        pub variance_threshold: VarianceThreshold = VarianceThreshold(cluster_defaults().variance_threshold);
        /// A clustered brick whose largest voxel difference from its centroid exceeds E stays unique.
        #[cfg_attr(feature = "clap", arg(long, value_name = "E", allow_negative_numbers = true))]
        pub max_brick_error: Option<ErrorBound> = cluster_defaults().max_brick_error.and_then(|e| ErrorBound::new(e).ok());
        /// Levels of detail: N > 1 adds levels 1 to N-1 to every frame, level k with voxels 2^k
        /// times as large (each the mean of its 2x2x2 children; level sets: of the active ones).
        /// A grid with voxels 2^j times the finest grid's is stored at level j, its own, and
        /// gets N levels from there (j to j+N-1).
        #[cfg_attr(feature = "clap", arg(long, value_name = "N", default_value_t = CookSettings::default().lods))]
        pub lods: LevelCount = cook_defaults().levels;
        /// Byte budget B (bytes, or e.g. 500kB, 1.5MB, 2MiB): keep the finest levels of detail
        /// (of --lods) whose asset fits, leaving out the finer ones; the coarsest always stays, and
        /// when even it alone is larger the cook fails (exit 1) naming the smallest size reachable.
        /// With --supercompress the budget holds the asset's GPU bytes (the file is smaller).
        #[cfg_attr(feature = "clap", arg(long, value_name = "B"))]
        pub max_bytes: Option<ByteBudget> = None;
        /// Cut the flip-book into segments of N frames, each with its own bricks, atlases and
        /// tables, contiguous in the file: a player holds one segment at a time, and the cook
        /// holds one segment's bricks at a time. Deduplication and --clusters (K per segment)
        /// work within a segment. Default: one segment of every frame.
        #[cfg_attr(feature = "clap", arg(long, value_name = "N"))]
        pub segment_frames: Option<SegmentFrames> = None;
        /// How sections are stored on disk: none, zstd, or zstd:LEVEL (1 to 22; zstd alone is
        /// level 5; up to level 5, sections over 8 MiB take level 1, for speed). Each segment's sections are filtered and zstd-compressed: a smaller file,
        /// the same GPU bytes (a reader restores a segment when it loads it, at zstd's speed).
        /// With --max-error the texels are also moved to the coarsest grid within E (ranged
        /// formats: steps of about 2E; inactive voxels, which no bound holds, at the brick's min;
        /// a range's min and a constant's value floats of few mantissa bits; see --optimize
        /// disk for what it changes).
        #[cfg_attr(feature = "clap", arg(long, value_name = "none|zstd[:LEVEL]", default_value_t = CookSettings::default().supercompress))]
        pub supercompress: Supercompress = Supercompress::None;
        /// With --max-error and --supercompress, what each brick's format choice minimises: gpu
        /// (the cheapest format within E on the GPU, as without --supercompress) or disk (the
        /// format whose texels, filtered, have the least entropy: larger GPU formats, e.g.
        /// unorm8 for BC7, for a smaller file; a longer cook; docs/benchmarks.md). disk also
        /// context-codes unorm8/unorm16 atlases where that beats zstd by 8 % or more (format
        /// v11 and later; restored at about zstd's speed with AVX-512, half of it with AVX2 alone),
        /// and gives those bricks' voxels the levels within E nearest what that coder predicts
        /// (inactive voxels: any level), on a step of 2E or of E, whichever it codes smaller.
        #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = CookSettings::default().optimize))]
        pub optimize: Optimize = Optimize::Gpu;
        /// The sequence's frame rate in frames per second (e.g. 24, 30, 23.976), recorded in the
        /// asset with each frame's number in the source sequence (from its file name:
        /// fire_1001.vdb is frame 1001, when every name has an increasing number; else from 0).
        #[cfg_attr(feature = "clap", arg(long, value_name = "FPS", allow_negative_numbers = true, default_value_t = CookSettings::default().fps))]
        pub fps: Fps = Fps::DEFAULT;
        /// Keep the cook's large buffers (the brick pool: every distinct brick of a segment, 2 kB
        /// a channel; its L3 nodes, 72 bytes each; the per-brick tables, node arrays and atlases
        /// of its last stages) in memory up to SIZE in all (bytes, or e.g. 512MiB, 4GB), then
        /// move them to unnamed temporary files beside the output, so that memory stops growing
        /// with the segment's bricks (the system caches what it can and writes the rest to disk;
        /// the files vanish with the process). auto: a quarter of the memory the process may use
        /// (the machine's, or its control group's limit); never: keep them in memory. The asset
        /// is the same either way.
        #[cfg_attr(feature = "clap", arg(long, value_name = "SIZE|auto|never", default_value_t = CookSettings::default().spill_above))]
        pub spill_above: SpillAbove = SpillAbove::Auto;
        /// Largest 3D texture edge in texels; bigger brick pools are split into several atlases.
        #[cfg_attr(feature = "clap", arg(long, value_name = "TEXELS", default_value_t = CookSettings::default().max_texture_dim))]
        pub max_texture_dim: TextureDim = TextureDim(cook_defaults().max_texture_dim);
        /// After cooking, render the asset against its sources on the GPU (see `vdbcook validate`).
        #[cfg_attr(feature = "clap", arg(long))]
        pub validate: bool = false;
    }
    flatten {
        #[cfg_attr(feature = "clap", command(flatten, next_help_heading = "With --validate or --auto"))]
        pub viewing: Viewing;
        #[cfg_attr(feature = "clap", command(flatten, next_help_heading = "With --validate or --auto"))]
        pub gate: Gate;
    }
}

impl CookSettings {
    /// Checks what one value's type cannot: settings at odds with each other.
    /// The error names the setting.
    pub fn check(&self) -> Result<(), SettingError> {
        if self.max_error.is_some() && !self.group.is_empty() {
            return Err(SettingError { name: "max_error", message: vdbcook_cook::Error::MaxErrorGroups.to_string() });
        }
        if self.optimize == Optimize::Disk && (self.max_error.is_none() || self.supercompress == Supercompress::None) {
            return Err(SettingError { name: "optimize", message: "disk chooses each brick's format for the smallest file: it needs max_error (per-brick formats) and supercompress".into() });
        }
        if self.max_bytes.is_some() && self.segment_frames.is_some() {
            return Err(SettingError { name: "max_bytes", message: "decides which levels of detail the whole asset keeps: it takes no segment_frames (cook one segment)".into() });
        }
        Ok(())
    }

    /// Setting names in canonical order (the manifest's keys).
    pub fn names() -> Vec<&'static str> {
        let mut k = Vec::new();
        Self::keys(&mut k);
        k
    }

    /// Every setting as (name, value) text, in canonical order.
    pub fn pairs(&self) -> Vec<(&'static str, String)> {
        let mut out = Vec::new();
        Settings::pairs(self, &mut out);
        out
    }

    /// The comparison `cook --validate`, `cook --auto` and `bake` make: every
    /// frame, and every level of an asset with levels of detail (the gate
    /// holding at each); a report in `report` when given.
    pub fn compare_options(&self, report: Option<std::path::PathBuf>) -> vdbcook_validate::CompareOptions {
        vdbcook_validate::CompareOptions {
            frames: None,
            viewing: self.viewing.clone(),
            gate: self.gate,
            levels: if self.lods.get() > 1 { vdbcook_validate::Levels::Every } else { vdbcook_validate::Levels::First },
            report,
        }
    }

    /// The clustering options, when `clusters` is set.
    pub fn clustering(&self) -> Option<vdbcook_cluster::Options> {
        self.clusters.map(|k| vdbcook_cluster::Options {
            clusters: k.get() as usize,
            iterations: self.iterations.get() as usize,
            variance_threshold: self.variance_threshold.get(),
            max_brick_error: self.max_brick_error.map(ErrorBound::get),
            ..vdbcook_cluster::Options::default()
        })
    }

    /// The cooker's options (the settings recorded in the asset with `inputs`).
    pub fn cook_options(&self, inputs: &[String]) -> vdbcook_cook::CookOptions {
        vdbcook_cook::CookOptions {
            format: self.format,
            groups: self.group.clone(),
            quality: self.quality,
            max_texture_dim: self.max_texture_dim.get(),
            clustering: self.clustering(),
            max_error: self.max_error,
            disk: (self.max_error.is_some() && self.supercompress != Supercompress::None).then_some(self.optimize),
            settings: self.recorded(inputs),
            levels: self.lods,
            fps: self.fps,
            // The cooker budgets the one segment's body; the file adds the segment table.
            max_bytes: self.max_bytes.map(|b| b.0.saturating_sub(vdbcook_vpak::segments::first_offset(1))),
            // Where: beside the output, which only the job knows (`CookJob::spill_dir`).
            spill: None,
        }
    }

    /// Whether the cook may store BC7 blocks (its format, a group's, or a per-brick choice).
    pub fn may_encode_bc7(&self) -> bool {
        self.format == Format::Bc7 || self.max_error.is_some() || self.group.iter().any(|g| g.format == Format::Bc7)
    }

    /// The settings a cook records in the asset's metadata (what `cook` has
    /// always written): settings that do not apply are empty.
    pub fn recorded(&self, inputs: &[String]) -> Vec<(String, String)> {
        let clustered = self.clusters.is_some();
        vec![
            ("format".into(), if self.max_error.is_some() { String::new() } else { self.format.text() }),
            ("max_error".into(), self.max_error.text()),
            ("quality".into(), if self.format.is_block() || self.max_error.is_some() { self.quality.text() } else { String::new() }),
            ("grid".into(), self.grids.clone().or_else(|| self.grid.clone()).unwrap_or_default()),
            ("groups".into(), self.group.iter().map(ChannelGroup::to_string).collect::<Vec<_>>().join(" ")),
            ("frames".into(), self.frames.text()),
            ("fps".into(), self.fps.text()),
            ("allow_missing".into(), self.allow_missing.text()),
            ("max_texture_dim".into(), self.max_texture_dim.text()),
            ("lods".into(), self.lods.text()),
            ("max_bytes".into(), self.max_bytes.text()),
            ("segment_frames".into(), self.segment_frames.text()),
            ("supercompress".into(), self.supercompress.text()),
            ("optimize".into(), if self.optimize == Optimize::Disk { self.optimize.text() } else { String::new() }),
            ("clusters".into(), self.clusters.text()),
            ("iterations".into(), if clustered { self.iterations.text() } else { String::new() }),
            ("variance_threshold".into(), if clustered { self.variance_threshold.text() } else { String::new() }),
            ("max_brick_error".into(), self.max_brick_error.text()),
            ("inputs".into(), inputs.join(" ")),
            // A JSON list (paths may hold spaces): `validate` expands them again.
            ("with".into(), if self.with.is_empty() { String::new() } else { serde_json::to_string(&self.with).unwrap_or_default() }),
            // Machines of another class write other BC7 blocks: parts of one asset must agree.
            ("bc7_kernels".into(), if self.may_encode_bc7() { vdbcook_encode::bc7_kernels().to_string() } else { String::new() }),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_ranges_and_sizes_round_trip() {
        for s in ["1-120:2", "-3-2:1", "5-5:1"] {
            assert_eq!(s.parse::<FrameRange>().unwrap().to_string(), s);
        }
        assert!("9-1".parse::<FrameRange>().is_err());
        assert_eq!("64x48".parse::<Size>().unwrap(), Size::new(64, 48).unwrap());
        assert!("4x4".parse::<Size>().is_err());
    }

    /// A manifest says `format = "bc7"` where the command line says `--format bc7`.
    #[cfg(feature = "clap")]
    #[test]
    fn manifest_values_are_the_flag_values() {
        #[derive(serde::Deserialize)]
        struct T {
            f: Format,
            q: Quality,
        }
        for f in Format::ALL {
            let flag = clap::ValueEnum::to_possible_value(&f).unwrap();
            assert_eq!(flag.get_name(), f.name());
            for q in Quality::ALL {
                let flag_q = clap::ValueEnum::to_possible_value(&q).unwrap();
                let t: T = toml::from_str(&format!("f = \"{}\"\nq = \"{}\"", flag.get_name(), flag_q.get_name())).unwrap();
                assert_eq!((t.f, t.q), (f, q));
            }
        }
    }

    #[test]
    fn one_default_per_setting() {
        let d = CookSettings::default();
        assert_eq!(d.variance_threshold.get(), vdbcook_cluster::Options::default().variance_threshold);
        assert_eq!(d.variance_threshold.get(), 0.01);
        assert_eq!(d.format, Format::F16);
        assert_eq!(d.quality, Quality::VeryFast);
        assert_eq!(d.pairs().len(), CookSettings::names().len());
        assert!(d.check().is_ok());
        assert_eq!(d.gate.max_flip, None);
        assert_eq!(d.viewing.views.get(), 8);
        // The comparison's settings are keys of their own, flat, after cook's.
        let names = CookSettings::names();
        assert!(names.ends_with(&["extinction", "views", "size", "max_rmse", "min_psnr", "max_flip"]), "{names:?}");
        for x in ["-0.1", "NaN", "inf", "x"] {
            assert!(x.parse::<FlipBudget>().is_err(), "{x}");
        }
        assert_eq!("0.05".parse::<FlipBudget>().map(FlipBudget::get), Ok(0.05));
        let groups = CookSettings { max_error: Some(ErrorBound::new(0.1).unwrap()), group: vec!["density=bc4".parse().unwrap()], ..d.clone() };
        assert!(matches!(groups.check(), Err(SettingError { name: "max_error", .. })));
    }

    /// A manifest key and a flag reach the same slot, checked by the same type.
    #[test]
    fn keys_reach_their_slots() {
        struct Json(serde_json::Value);
        impl vdbcook_vpak::settings::SettingVisitor for Json {
            type Out = Result<(), String>;
            fn visit<T: serde::de::DeserializeOwned>(self, slot: &mut T) -> Self::Out {
                *slot = serde_json::from_value(self.0).map_err(|e| e.to_string())?;
                Ok(())
            }
        }
        let mut s = CookSettings::default();
        assert_eq!(s.visit_key("views", Json(serde_json::json!(3))), Some(Ok(())));
        assert_eq!(s.viewing.views.get(), 3);
        assert_eq!(s.visit_key("max_rmse", Json(serde_json::json!(0.5))), Some(Ok(())));
        assert_eq!(s.gate.max_rmse.map(RmseBudget::get), Some(0.5));
        assert!(s.visit_key("clusters", Json(serde_json::json!(0))).unwrap().unwrap_err().contains("0 is not in 1..=1000000"));
        assert!(s.visit_key("lods", Json(serde_json::json!(9))).unwrap().is_err());
        assert!(s.visit_key("nope", Json(serde_json::json!(1))).is_none());
        let mut t = CookSettings::default();
        t.copy_key(&s, "views");
        assert_eq!(t.viewing.views.get(), 3);
        assert_eq!(t.gate.max_rmse, None);
    }

    #[test]
    fn byte_budgets_read_units() {
        for (text, bytes) in [
            ("1000", 1000),
            ("500kB", 500_000),
            ("1.5M", 1_500_000),
            ("1.5 MB", 1_500_000),
            ("2MiB", 2 << 20),
            ("1GiB", 1 << 30),
            ("7 B", 7),
            ("1.001kB", 1001),
            ("128.003kB", 128_003),
            ("1.001MB", 1_001_000),
            ("0.5KiB", 512),
            (".5k", 500),
        ] {
            assert_eq!(text.parse::<ByteBudget>(), Ok(ByteBudget(bytes)), "{text}");
        }
        // Every whole number of kB with three decimals is exact.
        for n in (1u64..200_000).step_by(7) {
            assert_eq!(format!("{}.{:03}kB", n / 1000, n % 1000).parse::<ByteBudget>(), Ok(ByteBudget(n)), "{n}");
        }
        for text in ["0", "-5", "0.5", "2.5", "1.0001kB", "1.5XB", "MB", "", ".", "1.2.3", "nan", "inf", "1e6", "99999999999999999GB"] {
            assert!(text.parse::<ByteBudget>().is_err(), "{text}");
        }
        #[derive(serde::Deserialize)]
        struct T {
            b: ByteBudget,
        }
        assert_eq!(toml::from_str::<T>("b = 250_000").unwrap().b, ByteBudget(250_000));
        assert_eq!(toml::from_str::<T>("b = \"3MiB\"").unwrap().b, ByteBudget(3 << 20));
        assert!(toml::from_str::<T>("b = 0").is_err());
        assert!(toml::from_str::<T>("b = -1").is_err());
    }
}
