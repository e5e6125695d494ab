//! Channels at their own voxel size (version 10): a channel whose voxels are
//! 2, 4 or 8 times the asset's lives at a level of detail of the tree, the
//! level whose voxels are its own, and may sit half a voxel (or more) off
//! that level's voxel centres. Encoded after the time record.

use crate::{Metadata, MAX_LEVELS};
use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Where a channel's voxels are, relative to the asset's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Resolution {
    /// The level whose voxels are the channel's own (0: the asset's voxel
    /// size; k: 2^k times as wide); the channel has no finer level.
    pub level: u32,
    /// The channel's voxel centres minus those of its level's voxels, in
    /// half voxels of level 0, per axis.
    pub half_offset: [i32; 3],
}

/// The coarsest level a channel's own voxels may be (8 times the asset's).
pub const MAX_CHANNEL_LEVEL: u32 = 3;
/// Bound on a channel's offset (half voxels of level 0): twice the index space.
pub const MAX_HALF_OFFSET: i32 = 1 << 14;

impl Resolution {
    /// The offset in voxels of level 0 (a multiple of 0.5).
    pub fn offset(&self) -> [f64; 3] {
        self.half_offset.map(|h| f64::from(h) / 2.0)
    }
}

/// "0.1", or "0.1×0.1×0.2" for voxels that are not cubes: a voxel's edge
/// along each index axis in world units, to six decimals (so 2 × 0.1 reads 0.2).
pub fn voxel_size_text(size: [f64; 3]) -> String {
    let v = size.map(|v| format!("{}", (v * 1e6).round() / 1e6));
    if v[0] == v[1] && v[1] == v[2] {
        v[0].clone()
    } else {
        v.join("×")
    }
}

/// Why `res` cannot be the resolutions of `meta`'s channels, if it cannot.
pub(crate) fn problem(meta: &Metadata, res: &[Resolution]) -> Option<String> {
    if res.is_empty() {
        return Some("an empty record (an asset without one has every channel at level 0)".into());
    }
    if res.len() != meta.channels.len() {
        return Some(format!("{} channel resolutions for {} channels", res.len(), meta.channels.len()));
    }
    if let Some((c, r)) = res.iter().enumerate().find(|(_, r)| r.level > MAX_CHANNEL_LEVEL) {
        return Some(format!("channel {c} at level {} (at most {MAX_CHANNEL_LEVEL})", r.level));
    }
    if let Some((c, _)) = res.iter().enumerate().find(|(_, r)| r.half_offset.iter().any(|h| h.abs() > MAX_HALF_OFFSET)) {
        return Some(format!("channel {c}'s offset is more than {} voxels", MAX_HALF_OFFSET / 2));
    }
    let finest = res.iter().map(|r| r.level).min().unwrap_or(0);
    let coarsest = res.iter().map(|r| r.level).max().unwrap_or(0);
    if finest != 0 {
        return Some(format!("no channel at level 0 (the finest is at level {finest})"));
    }
    if coarsest >= meta.levels.min(MAX_LEVELS) {
        return Some(format!("a channel at level {coarsest} of an asset of {} levels", meta.levels));
    }
    if meta.first_level >= meta.levels - coarsest {
        return Some(format!("first stored level {} leaves the level-0 channels no level ({} levels, the coarsest channel at level {coarsest})", meta.first_level, meta.levels));
    }
    None
}

impl Metadata {
    /// Channel `c`'s resolution (level 0, no offset, when the asset records none).
    pub fn resolution(&self, c: usize) -> Resolution {
        self.resolutions.get(c).copied().unwrap_or_default()
    }

    /// Whether some channel is not at the asset's own voxels.
    pub fn is_multi_resolution(&self) -> bool {
        self.resolutions.iter().any(|r| *r != Resolution::default())
    }

    /// Levels of detail each channel has, counted from its own level:
    /// `levels` less the coarsest channel's level.
    pub fn detail_levels(&self) -> u32 {
        let coarsest = self.resolutions.iter().map(|r| r.level).max().unwrap_or(0);
        self.levels.saturating_sub(coarsest).max(1)
    }

    /// The levels at which channel `c` is stored, finest first: from its own
    /// level (or `first_level`, when finer levels were left out) for
    /// [`Metadata::detail_levels`] levels from its own. Elsewhere its bricks
    /// hold its background and a reader must not sample it.
    pub fn channel_levels(&self, c: usize) -> Range<u32> {
        let own = self.resolution(c).level;
        own.max(self.first_level)..own + self.detail_levels()
    }

    /// The stored level of channel `c` nearest to `level`.
    pub fn channel_level_near(&self, c: usize, level: u32) -> u32 {
        let r = self.channel_levels(c);
        level.clamp(r.start, r.end.saturating_sub(1).max(r.start))
    }

    /// Index to world of channel `c`'s voxels at `level` (one of its
    /// [`Metadata::channel_levels`]): the level's transform, its origin moved
    /// by the channel's offset.
    pub fn channel_transform(&self, c: usize, level: u32) -> [[f64; 4]; 4] {
        let mut m = self.level_transform(level);
        let d = self.resolution(c).offset();
        let t = &self.transform;
        for (col, v) in m[3].iter_mut().enumerate() {
            *v += d[0] * t[0][col] + d[1] * t[1][col] + d[2] * t[2][col];
        }
        m
    }

    /// "0.1" or "0.1 × 0.1 × 0.2": the world edge of channel `c`'s voxels at its own level.
    pub fn channel_voxel_size(&self, c: usize) -> [f64; 3] {
        let m = self.level_transform(self.resolution(c).level);
        [0, 1, 2].map(|r| (m[r][0] * m[r][0] + m[r][1] * m[r][1] + m[r][2] * m[r][2]).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_and_levels() {
        let r = Resolution { level: 1, half_offset: [-1, 0, 3] };
        assert_eq!(r.offset(), [-0.5, 0.0, 1.5]);
    }
}
