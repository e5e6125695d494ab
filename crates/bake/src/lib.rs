//! `vdbcook bake`'s library half: the manifest (`bake.toml`), the plan (assets,
//! their expanded inputs and outputs), content-addressed cache keys, sharding,
//! and the reports (JSON, JUnit XML, HTML), merged across shards.
//!
//! No terminal, no exit codes, no environment: the caller lists and reads files
//! (through [`Sources`]), cooks and validates, and writes what this crate returns.
//!
//! ```text
//! bake.toml ─parse─▶ Manifest ─plan(Sources)─▶ [PlannedAsset { files, settings, key }]
//!   ─shard/only─▶ the caller cooks (or takes from the cache) ─▶ [AssetReport] ─▶ Report ─▶ json | junit | html
//! ```

pub mod key;
pub mod manifest;
pub mod parts;
/// The typed cook settings (vdbcook-pipeline owns them; manifests are built from them).
pub use vdbcook_pipeline::options;
pub mod place;
pub mod report;
pub mod step;
pub mod table;

pub use key::{cache_key, KeyContext};
pub use manifest::{line_column, plan, Manifest, ManifestError, PlannedAsset, Sources};
pub use options::{CookSettings, FrameRange, SettingText, Size};
pub use parts::{units, PartNo, Unit};
pub use report::{AssetReport, ChannelFormats, FormatBricks, Gate, PartRef, Record, Report, Status, Summary, Validation};
pub use step::{bake_one, bake_unit, cached, join_parts, preview, skipped, skipped_unit, whole_cached, Baker};
pub use table::{AssetTable, SettingsTable};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("invalid shard \"{0}\" (expected I/N with 1 <= I <= N, e.g. 2/3)")]
    Shard(String),
    #[error("report {0}: {1}")]
    Report(String, String),
}

/// One part of a bake split across `count` machines: `--shard index/count`, from 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl std::str::FromStr for Shard {
    type Err = Error;
    fn from_str(s: &str) -> Result<Shard, Error> {
        let bad = || Error::Shard(s.to_string());
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count) = (i.trim().parse::<u32>().map_err(|_| bad())?, n.trim().parse::<u32>().map_err(|_| bad())?);
        if index == 0 || index > count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Shard {
    /// Whether the unit at `index` (its position in the manifest's units,
    /// [`parts::units`], from 0; an asset's position when no asset has
    /// `parts`) belongs to this shard: round robin, so shards differ by at
    /// most one unit and the split depends on nothing but the manifest.
    pub fn takes(&self, index: usize) -> bool {
        index % self.count as usize == (self.index - 1) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_cover_every_asset_once() {
        for n in 1..=7u32 {
            let shards: Vec<Shard> = (1..=n).map(|i| format!("{i}/{n}").parse().unwrap()).collect();
            for asset in 0..50 {
                assert_eq!(shards.iter().filter(|s| s.takes(asset)).count(), 1);
            }
        }
        for bad in ["0/3", "4/3", "1", "a/b", "1/0", "-1/2"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }
}
