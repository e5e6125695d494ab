//! Validating an asset file against its sources: the sources cooked
//! losslessly in memory (the reference), then the comparison.

use crate::grids::FrameFile;
use crate::inputs::{self, FrameRange};
use crate::{recorded, Context, Error, Result};
use serde_json::json;
use std::path::{Path, PathBuf};
use vdbcook_cook::Progress;
use vdbcook_validate::{compare_assets, CompareOptions, Comparison, Levels, Renderer};
use vdbcook_vpak::{Asset, Metadata};

/// Where the source frames of a validation come from.
pub enum Sources {
    /// INPUT arguments (files, directories, globs, patterns) and the frames of a pattern.
    Inputs(Vec<String>, Option<FrameRange>),
    /// The files the asset records (checked against their recorded size and hash).
    Recorded,
}

/// Compares the asset at `path` with its source frames cooked losslessly,
/// at the levels `opts` asks for. `renderer` is asked for once the frames are
/// known to be in range.
pub fn validate_file<R: std::ops::Deref<Target = Renderer>, E: Into<Box<dyn std::error::Error + Send + Sync>>>(
    path: &Path,
    sources: Sources,
    opts: &CompareOptions,
    renderer: impl FnOnce() -> std::result::Result<R, E>,
    bars: &dyn Progress,
) -> Result<Comparison> {
    let name = path.display().to_string();
    let asset = Asset::open(path).with_context(|| name.clone())?;
    let meta = asset.metadata().with_context(|| name.clone())?;
    let lod = match opts.levels {
        Levels::At(k) => k.get(),
        _ => meta.first_level,
    };
    if let Some(why) = meta.missing_level(lod) {
        return Err(Error::Failed(format!("{name}: {why}")));
    }
    // One reference, filtered down to the coarsest level checked, serves every level.
    let coarsest = if opts.levels == Levels::Every { meta.stored_levels().end.saturating_sub(1) } else { lod };
    let recorded = matches!(sources, Sources::Recorded);
    let files = match sources {
        Sources::Recorded => recorded::frame_files(&meta, path)?,
        Sources::Inputs(inputs, frames) => inputs::expand(&inputs, frames)?.into_iter().map(Some).collect(),
    };
    let read = files.iter().flatten().filter(|f| f.exists()).count();
    // The reference cut as the asset is, so it holds one segment's bricks at a time too.
    let segment = asset.segments().with_context(|| name.clone())?.first().filter(|_| asset.segment_count() > 1).map(|e| e.frame_count as usize);
    let reference = reference(&meta, files, coarsest, segment, bars)?;
    let mut o = compare_assets(&asset, &name, &reference, opts, renderer, bars)?;
    if recorded {
        o.text += &format!("  sources  the {read} file(s) the asset records (no --source given)\n");
    }
    o.doc["sources"] = json!({"recorded": recorded, "files": read});
    Ok(o)
}

/// Cooks `files` losslessly in memory, down to level `lod`: the reference
/// asset. A frame the asset has empty may be missing its file or grid there
/// too (it was cooked with `--allow-missing`); every other frame must read.
fn reference(meta: &Metadata, files: Vec<Option<PathBuf>>, lod: u32, segment: Option<usize>, bars: &dyn Progress) -> Result<Asset> {
    let frames = files.into_iter().enumerate().map(|(f, path)| FrameFile { path, allow_missing: meta.frames.get(f).is_some_and(|fr| fr.active_voxels == 0), number: None }).collect();
    // Levels of detail from each channel's own level: a channel with coarser
    // voxels than the asset's adds levels of its own to the trees.
    let coarsest_channel = meta.levels - meta.detail_levels();
    let levels = vdbcook_vpak::LevelCount::new((lod + 1).saturating_sub(coarsest_channel).max(1)).map_err(Error::Failed)?;
    crate::cook_lossless_levels(frames, crate::selection_of(meta), levels, segment, bars).context("cooking the reference")
}
