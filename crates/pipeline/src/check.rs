//! Validating an asset file against its sources: the sources cooked
//! losslessly in memory (the reference), then the comparison.

use crate::grids::{split_sequence, FrameFile, GridSelection};
use crate::inputs::{self, FrameRange};
use crate::{recorded, Context, Error, Result};
use serde_json::json;
use std::path::{Path, PathBuf};
use vdbcook_cook::Progress;
use vdbcook_validate::{compare_assets, CompareOptions, Comparison, Levels, Renderer};
use vdbcook_vpak::{Asset, Metadata};

/// Where the source frames of a validation come from.
pub enum Sources {
    /// INPUT arguments (files, directories, globs, patterns), the `--with`
    /// inputs (one sequence each) and the frames of a pattern.
    Inputs { inputs: Vec<String>, with: Vec<String>, frames: Option<FrameRange> },
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
    // Frames out of range are refused before the reference is cooked.
    vdbcook_validate::check_frames(opts, meta.frame_count)?;
    // One reference, filtered down to the coarsest level checked, serves every level.
    let coarsest = if opts.levels == Levels::Every { meta.stored_levels().end.saturating_sub(1) } else { lod };
    let recorded = matches!(sources, Sources::Recorded);
    let (files, with) = match sources {
        Sources::Recorded => {
            let files = recorded::frame_files(&meta, path)?;
            let with = recorded::with_files(&meta, path, &files)?;
            (files, with)
        }
        Sources::Inputs { inputs, with, frames } => {
            let files = inputs::expand_main(&inputs, &with, frames)?;
            // A file missing where the asset was cooked without it (--allow-missing) leaves its channels empty.
            let with = inputs::with_files(&files, &with, None, frames, recorded::setting(&meta, "allow_missing") == "true")?;
            (files.into_iter().map(Some).collect(), with)
        }
    };
    let read = files.iter().chain(with.iter().flatten()).flatten().filter(|f| f.exists()).count();
    // The reference cut as the asset is, so it holds one segment's bricks at a time too.
    let segment = asset.segments().with_context(|| name.clone())?.first().filter(|_| asset.segment_count() > 1).map(|e| e.frame_count as usize);
    let reference = reference(&meta, files, with, coarsest, segment, bars)?;
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
/// Each frame's `--with` files (`with[frame]`) come with it.
fn reference(meta: &Metadata, files: Vec<Option<PathBuf>>, with: Vec<Vec<Option<PathBuf>>>, lod: u32, segment: Option<usize>, bars: &dyn Progress) -> Result<Asset> {
    let mut with = with.into_iter();
    let frames = files
        .into_iter()
        .enumerate()
        .map(|(f, path)| FrameFile { path, allow_missing: meta.frames.get(f).is_some_and(|fr| fr.active_voxels == 0), number: None, with: with.next().unwrap_or_default() })
        .collect();
    // Levels of detail from each channel's own level: a channel with coarser
    // voxels than the asset's adds levels of its own to the trees.
    let coarsest_channel = meta.levels - meta.detail_levels();
    let levels = vdbcook_vpak::LevelCount::new((lod + 1).saturating_sub(coarsest_channel).max(1)).map_err(Error::Failed)?;
    crate::cook_lossless_levels(frames, picked(crate::selection_of(meta), meta), levels, segment, bars).context("cooking the reference")
}

/// The selection with the sequences the cook picked (`vel@1`, in its
/// recorded `grid` setting) for the grids it names.
fn picked(sel: GridSelection, meta: &Metadata) -> GridSelection {
    let recorded = recorded::setting(meta, "grid");
    let pick = |g: String| recorded.split(',').map(str::trim).find(|t| matches!(split_sequence(t), (n, Some(_)) if n == g)).map_or(g, str::to_string);
    match sel {
        GridSelection::One(g) => GridSelection::One(pick(g)),
        GridSelection::Many(v) => GridSelection::Many(v.into_iter().map(pick).collect()),
        other => other,
    }
}
