//! `parts = N`: one long asset cooked as N part units (the `cook --part I/N`
//! part files), spread over a bake's shards like assets, and joined
//! (`vdbcook join`'s copy of the segments) by the step that has them all: a
//! bake that baked every part, or `bake --merge` of the shards' reports.
//!
//! A part file carries, in every segment's metadata, its own cache key and a
//! `bake_part` note (the asset's key and the part's record); the join takes
//! both out again and writes the asset's key and record, so the joined asset
//! is the unsplit bake's byte for byte: the note carries each segment's error
//! sums, which add up (in segment order) to the figures one cook gives
//! (`vdbcook_cook::Sums::sequence_error`).

use crate::report::{ChannelFormats, FormatBricks};
use crate::{place, PlannedAsset, Record};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use vdbcook_pipeline::{Context, Error, Result};
use vdbcook_vpak::segments::{part_writer, rewrite_into, rewrite_metadata, PartInfo};
use vdbcook_vpak::{Asset, AtomicFile, Metadata};

/// Part `index` (from 1) of `count`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct PartNo {
    pub index: u32,
    pub count: u32,
}

impl std::fmt::Display for PartNo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// One unit of a bake's work: an asset, or one part of an asset with `parts`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unit {
    /// Position in the plan.
    pub asset: usize,
    pub part: Option<PartNo>,
}

/// The plan's units in manifest order, an asset with `parts = N` as N units
/// in a row: `--shard` deals these out round robin, so the parts of an asset
/// go to different shards, and the deal depends on the manifest alone.
pub fn units(planned: &[PlannedAsset]) -> Vec<Unit> {
    let mut out = Vec::new();
    for (asset, a) in planned.iter().enumerate() {
        match a.parts {
            Some(count) => out.extend((1..=count).map(|index| Unit { asset, part: Some(PartNo { index, count }) })),
            None => out.push(Unit { asset, part: None }),
        }
    }
    out
}

/// The cache key of one part of the asset whose key is `asset_key`.
pub fn part_key(asset_key: &str, part: PartNo) -> String {
    crate::key::key_of(&[b"vdbcook-bake-part 1", asset_key.as_bytes(), &part.index.to_le_bytes(), &part.count.to_le_bytes()])
}

/// Where a part file goes, beside the asset's `output`: "smoke.vpak.part1of4".
pub fn part_output(output: &str, part: PartNo) -> String {
    format!("{output}.part{}of{}", part.index, part.count)
}

/// The settings a bake adds to an asset's metadata.
pub const ASSET_SETTINGS: [&str; 2] = ["cache_key", "bake_record"];
/// The setting of a part file that says what it is a part of.
pub const PART_SETTING: &str = "bake_part";

/// A part's note: the key of the asset it belongs to and what its cook found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PartNote {
    pub asset_key: String,
    pub record: Record,
    /// Each of the part's segments' error sums, in order.
    pub segments: Vec<vdbcook_cook::Sums>,
}

fn setting<'a>(m: &'a Metadata, key: &str) -> Option<&'a str> {
    m.settings.iter().find(|(n, _)| n == key).map(|(_, v)| v.as_str())
}

/// The note and size of a valid part file at `path` whose key is `key`.
pub fn cached_part(path: &Path, key: &str) -> Option<(PartNote, u64)> {
    let (_, asset) = Asset::open_part(path).ok()?;
    let meta = asset.check().ok()?;
    if setting(&meta, "cache_key")? != key {
        return None;
    }
    let note = serde_json::from_str(setting(&meta, PART_SETTING)?).ok()?;
    Some((note, std::fs::metadata(path).ok()?.len()))
}

/// A part file again (header `info`, the segments of `asset` as it stores
/// them: supercompressed, as one process's cook would be), every segment's
/// metadata changed by `edit`, in memory.
pub fn rewrite_part(info: &PartInfo, asset: &Asset, edit: impl FnMut(&mut Metadata)) -> Result<Vec<u8>> {
    let w = part_writer(std::io::Cursor::new(Vec::new()), info, asset.segment_count() as u32)?;
    Ok(rewrite_into(asset, w, edit)?.into_inner())
}

/// The record of an asset from its parts' records (in order): frames, voxels
/// and each channel's bricks per format added up, the formats' union (in
/// order of first appearance, as a segmented cook adds up its segments).
/// The voxel error (from the segments' sums), bits per voxel, GPU bytes,
/// thumbnail and validation are the caller's (they are of the whole asset).
pub fn merged_record(parts: &[Record]) -> Record {
    let mut r = Record { grid: parts.first().and_then(|p| p.grid.clone()), ..Record::default() };
    for p in parts {
        r.frames = Some(r.frames.unwrap_or(0) + p.frames.unwrap_or(0));
        r.active_voxels = Some(r.active_voxels.unwrap_or(0) + p.active_voxels.unwrap_or(0));
        r.format = match (r.format.take(), &p.format) {
            (Some(a), Some(b)) => Some(vdbcook_vpak::union_names(&a, b)),
            (a, b) => a.or(b.clone()),
        };
        if let Some(pc) = &p.channels {
            let acc = r.channels.get_or_insert_with(Vec::new);
            for c in pc {
                match acc.iter_mut().find(|a| a.name == c.name) {
                    Some(a) => {
                        for f in &c.formats {
                            match a.formats.iter_mut().find(|g| g.format == f.format) {
                                Some(g) => g.bricks += f.bricks,
                                None => a.formats.push(FormatBricks { format: f.format.clone(), bricks: f.bricks }),
                            }
                        }
                    }
                    None => acc.push(ChannelFormats { name: c.name.clone(), formats: c.formats.clone() }),
                }
            }
        }
    }
    r
}

/// An asset joined from its part files.
pub struct Joined {
    pub record: Record,
    pub bytes: u64,
    /// The asset's key (from its parts).
    pub key: String,
}

/// Joins the part files `files` (part 1 of N first) of asset `name` into `out`:
/// the parts' segments copied and checked, the parts' notes replaced by the
/// asset's key and record (its thumbnail from `thumbnail`). A missing part, a
/// part of another bake or of another cook, or a damaged one is a one-line
/// error, and nothing is written.
pub fn join(name: &str, files: &[PathBuf], out: &Path, force: bool, thumbnail: &dyn Fn(&Asset) -> Option<String>) -> Result<Joined> {
    let n = files.len();
    if let Some((i, f)) = files.iter().enumerate().find(|(_, f)| !f.is_file()) {
        return Err(Error::Failed(format!("asset {name}: part {}/{n} is missing ({})", i + 1, f.display())));
    }
    let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
    let handles = files.iter().zip(&names).map(|(f, nm)| std::fs::File::open(f).with_context(|| nm.clone())).collect::<Result<Vec<_>>>()?;
    let parts = handles.iter().zip(&names).map(|(h, nm)| Asset::from_part_file(h).with_context(|| nm.clone())).collect::<Result<Vec<_>>>()?;
    let mut notes = Vec::with_capacity(n);
    for ((_, a), nm) in parts.iter().zip(&names) {
        let meta = a.segment(0).and_then(|s| s.metadata()).with_context(|| nm.clone())?;
        let note: PartNote = setting(&meta, PART_SETTING)
            .and_then(|t| serde_json::from_str(t).ok())
            .ok_or_else(|| Error::Failed(format!("{nm}: not a part file of a bake (it has no {PART_SETTING} note; `vdbcook join` joins parts of `cook --part`)")))?;
        notes.push(note);
    }
    if let Some((nm, _)) = names.iter().zip(&notes).find(|(_, x)| x.asset_key != notes[0].asset_key) {
        return Err(Error::Failed(format!("{nm}: is a part of another bake of asset {name} than {} (other inputs or settings)", names[0])));
    }
    let oname = out.display().to_string();
    place::may_replace(out, force).map_err(Error::Failed)?;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| parent.display().to_string())?;
    }
    // Joined into an unnamed scratch file beside `out` that is never given a name.
    let mut scratch = AtomicFile::create(out, true).with_context(|| oname.clone())?;
    let handle = scratch.file().try_clone().with_context(|| oname.clone())?;
    let f = vdbcook_vpak::segments::join(&parts, &names, handle).with_context(|| format!("asset {name}"))?;
    let joined = Asset::from_file(&f).with_context(|| oname.clone())?;
    // The asset as one cook writes it, before the bake's settings.
    let plain = rewrite_metadata(&joined, |m| m.settings.retain(|(k, _)| k != "cache_key" && k != PART_SETTING)).with_context(|| oname.clone())?;
    drop((joined, f, scratch));
    let plain = Asset::from_bytes(&plain).with_context(|| oname.clone())?;
    plain.check().with_context(|| oname.clone())?;
    let mut record = merged_record(&notes.iter().map(|x| x.record.clone()).collect::<Vec<_>>());
    let voxels = record.active_voxels.unwrap_or(0);
    record.bits_per_active_voxel = Some(if voxels > 0 { plain.bytes().len() as f64 * 8.0 / voxels as f64 } else { 0.0 });
    record.thumbnail = thumbnail(&plain);
    // The voxel error one cook of every segment gives: the segments' sums added up in order.
    let segments: Vec<vdbcook_cook::Sums> = notes.iter().flat_map(|x| x.segments.iter().cloned()).collect();
    if let Some(e) = vdbcook_cook::Sums::sequence_error(&segments, &plain.metadata().with_context(|| oname.clone())?) {
        record.voxel_rmse = Some(e.voxel_rmse);
        record.voxel_psnr = e.voxel_psnr.is_finite().then_some(e.voxel_psnr);
    }
    record.gpu_bytes = Some(plain.gpu_bytes().with_context(|| oname.clone())?);
    let key = notes[0].asset_key.clone();
    let extra = [("cache_key".to_string(), key.clone()), ("bake_record".to_string(), record.to_setting())];
    let bytes = rewrite_metadata(&plain, |m| m.settings.extend(extra.iter().cloned())).with_context(|| oname.clone())?;
    place::may_replace(out, force).map_err(Error::Failed)?;
    vdbcook_vpak::write_atomic(out, &bytes, true).with_context(|| oname.clone())?;
    Ok(Joined { record, bytes: bytes.len() as u64, key })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(frames: u32, rmse: f64, psnr: Option<f64>, formats: &[(&str, u32)]) -> Record {
        Record {
            frames: Some(frames),
            format: Some(formats.iter().map(|f| f.0).collect::<Vec<_>>().join("+")),
            active_voxels: Some(100),
            voxel_rmse: Some(rmse),
            voxel_psnr: psnr,
            channels: Some(vec![ChannelFormats { name: "density".into(), formats: formats.iter().map(|(f, b)| FormatBricks { format: (*f).into(), bricks: *b }).collect() }]),
            ..Record::default()
        }
    }

    #[test]
    fn a_record_from_parts_adds_up() {
        let r = merged_record(&[rec(4, 0.01, Some(50.0), &[("bc7", 3), ("bc4", 1)]), rec(2, 0.02, None, &[("unorm8", 2), ("bc7", 5)])]);
        assert_eq!((r.frames, r.active_voxels), (Some(6), Some(200)));
        assert_eq!(r.format.as_deref(), Some(vdbcook_vpak::union_names("bc7+bc4", "unorm8+bc7").as_str()));
        let ch = &r.channels.unwrap()[0];
        let got: Vec<(&str, u32)> = ch.formats.iter().map(|f| (f.format.as_str(), f.bricks)).collect();
        assert_eq!(got, [("bc7", 8), ("bc4", 1), ("unorm8", 2)]);
    }

    #[test]
    fn keys_and_units() {
        let k = "0123456789abcdef0123456789abcdef";
        let p = |index, count| PartNo { index, count };
        assert_ne!(part_key(k, p(1, 2)), part_key(k, p(2, 2)));
        assert_ne!(part_key(k, p(1, 2)), part_key(k, p(1, 3)));
        assert_eq!(part_key(k, p(1, 2)).len(), 32);
        assert_eq!(part_output("sub/a.vpak", p(2, 4)), "sub/a.vpak.part2of4");
    }
}
