//! The typed cook options: one struct, [`CookSettings`], built from `cook`'s
//! flags (clap) or from a manifest entry (serde), with one default per setting.
//!
//! Every setting is declared once, in the `settings!` list at the bottom:
//! its type, its default, its flag's help and value checks. The macro derives
//! the struct, its defaults, the manifest tables (every field optional, with
//! its position in the file) and the canonical `(name, value)` list that cache
//! keys hash. Adding a setting is one entry there.

use std::fmt;
use std::ops::RangeInclusive;
use std::str::FromStr;
use toml::Spanned;
pub use vdbcook_cook::ChannelGroup;
pub use vdbcook_encode::{Format, Quality};
// The gate's budgets and the image size are the comparison's (vdbcook-validate owns them).
pub use vdbcook_validate::options::{flip_budget, parse_flip_budget, parse_psnr_floor, parse_rmse_budget, psnr_floor, rmse_budget};
pub use vdbcook_validate::{Gate, Size};

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

/// A manifest writes it as a number of bytes or as the flag's text.
impl<'de> serde::Deserialize<'de> for ByteBudget {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Bytes(u64),
            Text(String),
        }
        match Raw::deserialize(d)? {
            Raw::Bytes(0) => Err(serde::de::Error::custom("a byte budget must be at least 1 byte")),
            Raw::Bytes(b) => Ok(ByteBudget(b)),
            Raw::Text(t) => t.parse().map_err(serde::de::Error::custom),
        }
    }
}

/// Types written as a string in a manifest and parsed like the flag.
macro_rules! deserialize_from_str {
    ($($t:ty),*) => {$(
        impl<'de> serde::Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let s = String::deserialize(d)?;
                s.parse().map_err(serde::de::Error::custom)
            }
        }
    )*};
}
deserialize_from_str!(FrameRange);

/// A setting's value as canonical text (for cache keys and metadata).
pub trait SettingText {
    fn text(&self) -> String;
}

macro_rules! text_by_display {
    ($($t:ty),*) => {$( impl SettingText for $t { fn text(&self) -> String { self.to_string() } } )*};
}
text_by_display!(bool, u32, f32, f64, String, FrameRange, Size, ChannelGroup, ByteBudget);

impl SettingText for Format {
    fn text(&self) -> String {
        self.name().to_string()
    }
}

impl SettingText for Quality {
    fn text(&self) -> String {
        self.name().to_string()
    }
}

impl<T: SettingText> SettingText for Option<T> {
    fn text(&self) -> String {
        self.as_ref().map(SettingText::text).unwrap_or_default()
    }
}

impl<T: SettingText> SettingText for Vec<T> {
    fn text(&self) -> String {
        self.iter().map(SettingText::text).collect::<Vec<_>>().join(",")
    }
}

/// Accepted ranges, shared by the flags' parsers and the manifest's checks.
pub const CLUSTERS: RangeInclusive<i64> = 1..=1_000_000;
pub const ITERATIONS: RangeInclusive<i64> = 0..=1000;
pub const MAX_TEXTURE_DIM: RangeInclusive<i64> = 8..=16384;
pub const VIEWS: RangeInclusive<i64> = 1..=360;

/// A level count (`--lods`, `lods`): 1 to `vdbcook_vpak::MAX_LEVELS`.
pub fn lods(n: u32) -> Result<u32, String> {
    let max = vdbcook_vpak::MAX_LEVELS;
    match n {
        0 => Err("0 is not a level count: 1 keeps the frames alone, N adds levels 1 to N-1".into()),
        n if n > max => {
            Err(format!("{n} is more levels than the tree has: at most {max} (level {}'s voxels are {} source voxels wide, and its bricks span a whole L1 slot)", max - 1, 1u32 << (max - 1)))
        }
        n => Ok(n),
    }
}

/// Parses a level flag (`render --lod`, `unpack --lod`): 0 to `MAX_LEVELS` − 1.
pub fn parse_lod(s: &str) -> Result<u32, String> {
    let max = vdbcook_vpak::MAX_LEVELS - 1;
    match s.trim().parse::<u32>() {
        Ok(k) if k <= max => Ok(k),
        _ => Err(format!("invalid level \"{s}\" (expected 0 to {max}: 0 is the frame itself)")),
    }
}

/// Parses a level count flag.
pub fn parse_lods(s: &str) -> Result<u32, String> {
    lods(s.trim().parse::<u32>().map_err(|_| format!("invalid level count \"{s}\" (expected a whole number, 1 to {})", vdbcook_vpak::MAX_LEVELS))?)
}

fn parse_number(s: &str) -> Result<f64, String> {
    vdbcook_validate::options::parse_number(s)
}

/// A per-voxel error bound (`--max-error`, `max_error`): a finite number >= 0.
pub fn max_error_bound(e: f32) -> Result<f32, String> {
    if e >= 0.0 && e.is_finite() {
        Ok(e)
    } else {
        Err(format!("must be a finite number >= 0, not {e}"))
    }
}

/// Parses a per-voxel error bound flag.
pub fn parse_max_error(s: &str) -> Result<f32, String> {
    max_error_bound(parse_number(s)? as f32)
}

macro_rules! settings {
    ($( $(#[$attr:meta])* $name:ident : $ty:ty = $default:expr ; )*) => {
        /// Every cook setting of one asset (flags of `vdbcook cook`, keys of a bake manifest).
        #[derive(Clone, Debug, PartialEq)]
        #[cfg_attr(feature = "clap", derive(clap::Args))]
        pub struct CookSettings {
            $( $(#[$attr])* pub $name: $ty, )*
        }

        impl Default for CookSettings {
            fn default() -> Self {
                CookSettings { $( $name: $default, )* }
            }
        }

        impl CookSettings {
            /// Setting names in canonical order (the manifest's keys).
            pub const NAMES: &'static [&'static str] = &[$( stringify!($name), )*];

            /// Every setting as (name, value) text, in canonical order.
            pub fn pairs(&self) -> Vec<(&'static str, String)> {
                vec![$( (stringify!($name), SettingText::text(&self.$name)), )*]
            }
        }

        /// A manifest's `[defaults]` table: any setting, each optional.
        #[derive(Clone, Debug, Default, serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct SettingsTable {
            $( #[serde(default)] pub $name: Option<Spanned<$ty>>, )*
        }

        /// One `[[asset]]` entry: name, output, inputs and any setting.
        #[derive(Clone, Debug, serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct AssetTable {
            pub name: Spanned<String>,
            pub output: Spanned<String>,
            pub inputs: Spanned<Vec<Spanned<String>>>,
            $( #[serde(default)] pub $name: Option<Spanned<$ty>>, )*
        }

        impl SettingsTable {
            /// Overrides `s` with the settings this table gives.
            pub fn apply(&self, s: &mut CookSettings) {
                $( if let Some(v) = &self.$name { s.$name = v.get_ref().clone(); } )*
            }
            /// Where the table gives `name`.
            pub fn span(&self, name: &str) -> Option<std::ops::Range<usize>> {
                $( if name == stringify!($name) { return self.$name.as_ref().map(|v| v.span()); } )*
                None
            }
        }

        impl AssetTable {
            pub fn apply(&self, s: &mut CookSettings) {
                $( if let Some(v) = &self.$name { s.$name = v.get_ref().clone(); } )*
            }
            pub fn span(&self, name: &str) -> Option<std::ops::Range<usize>> {
                $( if name == stringify!($name) { return self.$name.as_ref().map(|v| v.span()); } )*
                None
            }
        }
    };
}

fn cook_defaults() -> vdbcook_cook::CookOptions {
    vdbcook_cook::CookOptions::default()
}

fn cluster_defaults() -> vdbcook_cluster::Options {
    vdbcook_cluster::Options::default()
}

// The one list of settings. Defaults come from the libraries that use them
// (CookOptions, cluster::Options) or are written here; the flags show them.
// The gate flags `requires = "checks"`: cook's group of --validate and
// --auto (a flag of cook alone: a bake does not search formats).
settings! {
    /// Frames of a frame pattern: A-B or A-B:STEP (e.g. 1-120:2).
    #[cfg_attr(feature = "clap", arg(long, value_name = "RANGE"))]
    frames: Option<FrameRange> = None;
    /// Grid to cook (default: "density", else the first float grid; a vec3 grid gives three channels).
    #[cfg_attr(feature = "clap", arg(long, value_name = "NAME", conflicts_with = "grids"))]
    grid: Option<String> = None;
    /// Grids to cook into one asset, as channels of one tree: names as in the files,
    /// comma-separated, or "all" (every float, double, half and vec3 grid of the first frame).
    #[cfg_attr(feature = "clap", arg(long, value_name = "A,B,...|all"))]
    grids: Option<String> = None;
    /// Pack these channels into shared textures in their own format (repeatable), e.g.
    /// --group temperature,flames=bc7 --group density=bc4; other channels take --format, a texture each.
    #[cfg_attr(feature = "clap", arg(long, value_name = "CHANNELS=FORMAT"))]
    group: Vec<ChannelGroup> = Vec::new();
    /// A frame whose file or grid is missing becomes an empty frame instead of an error.
    #[cfg_attr(feature = "clap", arg(long))]
    allow_missing: bool = false;
    /// Voxel format of the brick atlas.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = CookSettings::default().format))]
    format: Format = cook_defaults().format;
    /// Store every brick in the cheapest format (constant, bc7, bc4, unorm8, unorm16, f16, f32)
    /// whose active voxels all decode within E of the source (absolute); --format is not used.
    #[cfg_attr(feature = "clap", arg(long, value_name = "E", allow_negative_numbers = true, value_parser = parse_max_error, conflicts_with_all = ["format", "group"]))]
    max_error: Option<f32> = None;
    /// Encoder preset of bc7 and bc4 (see the notes below).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = CookSettings::default().quality))]
    quality: Quality = cook_defaults().quality;
    /// Merge similar bricks with variance-gated k-means into K centroid bricks (off by default).
    #[cfg_attr(feature = "clap", arg(long, value_name = "K", value_parser = clap::value_parser!(u32).range(CLUSTERS)))]
    clusters: Option<u32> = None;
    /// k-means iterations.
    #[cfg_attr(feature = "clap", arg(long, value_name = "N", default_value_t = CookSettings::default().iterations, value_parser = clap::value_parser!(u32).range(ITERATIONS)))]
    iterations: u32 = cluster_defaults().iterations as u32;
    /// Bricks whose variance / mean exceeds T are never clustered.
    #[cfg_attr(feature = "clap", arg(long, value_name = "T", default_value_t = CookSettings::default().variance_threshold))]
    variance_threshold: f64 = cluster_defaults().variance_threshold;
    /// A clustered brick whose largest voxel difference from its centroid exceeds E stays unique.
    #[cfg_attr(feature = "clap", arg(long, value_name = "E"))]
    max_brick_error: Option<f32> = cluster_defaults().max_brick_error;
    /// Levels of detail: N > 1 adds levels 1 to N-1 to every frame, level k with voxels 2^k
    /// times as large (each the mean of its 2x2x2 children; level sets: of the active ones).
    #[cfg_attr(feature = "clap", arg(long, value_name = "N", default_value_t = CookSettings::default().lods, value_parser = parse_lods))]
    lods: u32 = cook_defaults().levels;
    /// Byte budget B (bytes, or e.g. 500kB, 1.5MB, 2MiB): keep the finest levels of detail
    /// (of --lods) whose asset fits, leaving out the finer ones; the coarsest always stays, and
    /// when even it alone is larger the cook fails (exit 1) naming the smallest size reachable.
    #[cfg_attr(feature = "clap", arg(long, value_name = "B"))]
    max_bytes: Option<ByteBudget> = None;
    /// Largest 3D texture edge in texels; bigger brick pools are split into several atlases.
    #[cfg_attr(feature = "clap", arg(long, value_name = "TEXELS", default_value_t = CookSettings::default().max_texture_dim, value_parser = clap::value_parser!(u32).range(MAX_TEXTURE_DIM)))]
    max_texture_dim: u32 = cook_defaults().max_texture_dim;
    /// After cooking, render the asset against its sources on the GPU (see `vdbcook validate`).
    #[cfg_attr(feature = "clap", arg(long))]
    validate: bool = false;
    /// With --validate (or cook --auto): exit with code 3 when any image's RMSE is above X.
    #[cfg_attr(feature = "clap", arg(long, value_name = "X", requires = "checks", allow_negative_numbers = true, value_parser = parse_rmse_budget))]
    max_rmse: Option<f64> = None;
    /// With --validate (or cook --auto): exit with code 3 when any image's PSNR (dB) is below Y.
    #[cfg_attr(feature = "clap", arg(long, value_name = "Y", requires = "checks", allow_negative_numbers = true, value_parser = parse_psnr_floor))]
    min_psnr: Option<f64> = None;
    /// With --validate (or cook --auto): exit with code 3 when any image's mean FLIP error (0 to 1, at 67 pixels per degree) is above F.
    #[cfg_attr(feature = "clap", arg(long, value_name = "F", requires = "checks", allow_negative_numbers = true, value_parser = parse_flip_budget))]
    max_flip: Option<f64> = None;
    /// With --validate (or cook --auto): cameras orbiting the volume.
    #[cfg_attr(feature = "clap", arg(long, value_name = "N", default_value_t = CookSettings::default().views, requires = "checks", value_parser = clap::value_parser!(u32).range(VIEWS)))]
    views: u32 = 8;
    /// With --validate (or cook --auto): image size.
    #[cfg_attr(feature = "clap", arg(long, value_name = "WxH", default_value_t = CookSettings::default().size, requires = "checks"))]
    size: Size = Size { width: 512, height: 512 };
    /// With --validate (or cook --auto): the channel that gives extinction in the validation
    /// scene (default: "density", else the first scalar fog channel that does not glow).
    #[cfg_attr(feature = "clap", arg(long, value_name = "NAME", requires = "checks"))]
    extinction: Option<String> = None;
}

impl CookSettings {
    /// Checks what the types do not: ranges and numbers. The error names the setting.
    pub fn check(&self) -> Result<(), SettingError> {
        let bad = |name: &'static str, message: String| Err(SettingError { name, message });
        let within = |v: u32, r: &RangeInclusive<i64>| r.contains(&i64::from(v));
        if let Some(k) = self.clusters.filter(|&k| !within(k, &CLUSTERS)) {
            return bad("clusters", format!("{k} is not in {}..={}", CLUSTERS.start(), CLUSTERS.end()));
        }
        if !within(self.iterations, &ITERATIONS) {
            return bad("iterations", format!("{} is not in {}..={}", self.iterations, ITERATIONS.start(), ITERATIONS.end()));
        }
        if !within(self.max_texture_dim, &MAX_TEXTURE_DIM) {
            return bad("max_texture_dim", format!("{} is not in {}..={}", self.max_texture_dim, MAX_TEXTURE_DIM.start(), MAX_TEXTURE_DIM.end()));
        }
        if let Err(message) = lods(self.lods) {
            return bad("lods", message);
        }
        if !within(self.views, &VIEWS) {
            return bad("views", format!("{} is not in {}..={}", self.views, VIEWS.start(), VIEWS.end()));
        }
        if self.variance_threshold.is_nan() || self.variance_threshold < 0.0 {
            return bad("variance_threshold", format!("must be a number >= 0, not {}", self.variance_threshold));
        }
        if let Some(e) = self.max_brick_error.filter(|e| e.is_nan() || *e < 0.0) {
            return bad("max_brick_error", format!("must be a number >= 0, not {e}"));
        }
        if let Some(Err(message)) = self.max_error.map(max_error_bound) {
            return bad("max_error", message);
        }
        if self.max_error.is_some() && !self.group.is_empty() {
            return bad("max_error", "chooses every brick's format: it takes no channel groups".into());
        }
        if let Err((name, message)) = Gate::new(self.max_rmse, self.min_psnr, self.max_flip) {
            return bad(name, message);
        }
        Ok(())
    }

    /// The quality gate of `validate`, checked by [`CookSettings::check`].
    pub fn gate(&self) -> Gate {
        Gate { max_rmse: self.max_rmse, min_psnr: self.min_psnr, max_flip: self.max_flip }
    }

    /// The comparison `cook --validate`, `cook --auto` and `bake` make: every
    /// frame, and every level of an asset with levels of detail (the gate
    /// holding at each); a report in `report` when given.
    pub fn compare_options(&self, report: Option<std::path::PathBuf>) -> vdbcook_validate::CompareOptions {
        vdbcook_validate::CompareOptions {
            frames: None,
            views: self.views,
            size: self.size,
            gate: self.gate(),
            levels: if self.lods > 1 { vdbcook_validate::Levels::Every } else { vdbcook_validate::Levels::First },
            report,
            extinction: self.extinction.clone(),
        }
    }

    /// The clustering options, when `clusters` is set.
    pub fn clustering(&self) -> Option<vdbcook_cluster::Options> {
        self.clusters.map(|k| vdbcook_cluster::Options {
            clusters: k as usize,
            iterations: self.iterations as usize,
            variance_threshold: self.variance_threshold,
            max_brick_error: self.max_brick_error,
            ..vdbcook_cluster::Options::default()
        })
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
            ("allow_missing".into(), self.allow_missing.text()),
            ("max_texture_dim".into(), self.max_texture_dim.text()),
            ("lods".into(), self.lods.text()),
            ("max_bytes".into(), self.max_bytes.text()),
            ("clusters".into(), self.clusters.text()),
            ("iterations".into(), if clustered { self.iterations.text() } else { String::new() }),
            ("variance_threshold".into(), if clustered { self.variance_threshold.text() } else { String::new() }),
            ("max_brick_error".into(), self.max_brick_error.text()),
            ("inputs".into(), inputs.join(" ")),
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
        assert_eq!("64x48".parse::<Size>().unwrap(), Size { width: 64, height: 48 });
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
        assert_eq!(d.variance_threshold, vdbcook_cluster::Options::default().variance_threshold);
        assert_eq!(d.variance_threshold, 0.01);
        assert_eq!(d.format, Format::F16);
        assert_eq!(d.quality, Quality::VeryFast);
        assert_eq!(d.pairs().len(), CookSettings::NAMES.len());
        assert!(d.check().is_ok());
        let bad = CookSettings { variance_threshold: -1.0, ..d.clone() };
        assert!(matches!(bad.check(), Err(SettingError { name: "variance_threshold", .. })));
        assert_eq!(d.max_flip, None);
        for x in [-0.1, f64::NAN, f64::INFINITY] {
            let bad = CookSettings { max_flip: Some(x), ..d.clone() };
            assert!(matches!(bad.check(), Err(SettingError { name: "max_flip", .. })), "{x}");
            assert!(parse_flip_budget(&x.to_string()).is_err(), "{x}");
        }
        assert!(CookSettings { max_flip: Some(0.0), ..d.clone() }.check().is_ok());
        assert_eq!(parse_flip_budget("0.05"), Ok(0.05));
        assert!(parse_flip_budget("x").is_err());
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
