//! Cooking from files: frames read on a thread one frame ahead and pushed
//! into one or more [`Cooker`]s (an asset and its lossless reference share
//! one read), from typed [`CookSettings`].

use crate::grids::{read_frame, Channels, Frame, FrameFile, GridSelection};
use crate::options::CookSettings;
use crate::{Context, Error, Result};
use std::path::PathBuf;
use std::time::Instant;
use vdbcook_cook::{CookOptions, CookReport, Cooker, Format, Progress};
use vdbcook_vpak::SourceFile;

/// Reads `files` on a thread that stays one frame ahead (at most two source
/// frames live at once) and pushes each frame into one cooker per entry of
/// `opts` (an asset and its lossless reference share one read), made for the
/// channels the first frame with a file resolves. Source paths are recorded
/// relative to `base` when they are below it. Returns the cookers, their
/// channels and the seconds spent waiting for frames.
pub fn feed(opts: Vec<CookOptions>, files: Vec<FrameFile>, sel: GridSelection, base: Option<PathBuf>, bars: &dyn Progress) -> Result<(Vec<Cooker>, Option<Channels>, f64)> {
    // Each frame comes with the channels when they are first resolved.
    let (tx, rx) = std::sync::mpsc::sync_channel::<(Result<Frame>, Option<Channels>)>(0);
    let total = files.len() as u64;
    // A thread that cannot start (no memory for its stack) is an error, not a panic.
    let reader = std::thread::Builder::new()
        .name("frame reader".into())
        .spawn(move || {
            let mut channels = None;
            let mut sent = false;
            for f in files {
                let r = read_frame(f, &sel, &mut channels).map(|mut frame| {
                    if let (Some(s), Some(b)) = (frame.source.as_mut(), base.as_deref()) {
                        if let Ok(rel) = frame.path.strip_prefix(b) {
                            s.path = rel.display().to_string();
                        }
                    }
                    frame
                });
                let stop = r.is_err();
                let first = if sent { None } else { channels.clone() };
                sent |= first.is_some();
                if tx.send((r, first)).is_err() || stop {
                    break;
                }
            }
        })
        .map_err(|e| Error::Failed(format!("cannot start the frame reader thread: {e}")))?;
    bars.start("reading frames", total);
    let mut read_secs = 0.0;
    let mut wait = Instant::now();
    let mut failure = None;
    let mut cookers: Vec<Cooker> = Vec::new();
    let mut channels: Option<Channels> = None;
    // Frames before the first one whose file resolves the channels: empty.
    let mut leading: Vec<Option<SourceFile>> = Vec::new();
    // The cookers, for the channels (or, when no frame resolved any, one
    // channel named by nothing), with the leading empty frames.
    let start = |specs: Option<&Channels>, leading: &mut Vec<Option<SourceFile>>| -> Vec<Cooker> {
        let mut made: Vec<Cooker> = opts.iter().map(|o| specs.map_or_else(|| Cooker::new(o.clone()), |ch| Cooker::with_channels(o.clone(), ch.specs.clone()))).collect();
        for s in leading.drain(..) {
            made.iter_mut().for_each(|c| c.push_empty(s.clone()));
        }
        made
    };
    for (r, ch) in rx {
        read_secs += wait.elapsed().as_secs_f64();
        let pushed = r.and_then(|frame| {
            if let Some(ch) = ch {
                cookers = start(Some(&ch), &mut leading);
                channels = Some(ch);
            }
            if cookers.is_empty() {
                leading.push(frame.source);
                return Ok(());
            }
            for c in cookers.iter_mut() {
                let n = c.frame_count();
                match &frame.grids {
                    Some(g) => c.push_channels(&g.iter().map(Option::as_ref).collect::<Vec<_>>(), frame.source.clone()).with_context(|| format!("{}: frame {n}", frame.path.display()))?,
                    None => c.push_empty(frame.source.clone()),
                }
            }
            Ok(())
        });
        if let Err(e) = pushed {
            failure = Some(e);
            break;
        }
        bars.advance(1);
        wait = Instant::now();
    }
    bars.finish();
    reader.join().map_err(|_| Error::Failed("the frame reader thread panicked".into()))?;
    if let Some(e) = failure {
        return Err(e);
    }
    if cookers.is_empty() {
        cookers = start(None, &mut leading);
    }
    Ok((cookers, channels, read_secs))
}

/// The selection that reads back every channel of an asset's metadata.
pub fn selection_of(meta: &vdbcook_vpak::Metadata) -> GridSelection {
    let mut grids: Vec<String> = Vec::new();
    for c in &meta.channels {
        if !grids.contains(&c.grid) {
            grids.push(c.grid.clone());
        }
    }
    match grids.len() {
        0 => GridSelection::Default,
        1 if !grids[0].is_empty() => GridSelection::One(grids.remove(0)),
        _ => GridSelection::Many(grids),
    }
}

/// Cooks `files` losslessly in memory (f32, no clustering) with `levels` levels of detail: the reference
/// asset `validate` compares with, and what `render` draws for a .vdb.
pub fn cook_lossless_levels(files: Vec<FrameFile>, sel: GridSelection, levels: vdbcook_vpak::LevelCount, bars: &dyn Progress) -> Result<vdbcook_vpak::Asset> {
    let (cookers, _, _) = feed(vec![CookOptions { levels, ..reference_options() }], files, sel, None, bars)?;
    let cooker = cookers.into_iter().next().ok_or_else(|| Error::Failed("no cooker".into()))?;
    finish_reference(cooker)
}

fn reference_options() -> CookOptions {
    CookOptions { format: Format::F32, clustering: None, ..CookOptions::default() }
}

fn finish_reference(cooker: Cooker) -> Result<vdbcook_vpak::Asset> {
    let (sections, _) = cooker.finish(&vdbcook_cook::NoProgress)?;
    Ok(vdbcook_vpak::Asset::from_bytes(&vdbcook_vpak::assemble(&sections))?)
}

/// One asset to cook: typed settings, its frame files and what to record.
pub struct CookJob<'a> {
    pub settings: &'a CookSettings,
    /// The frame files, in order.
    pub files: Vec<PathBuf>,
    /// The inputs as the user wrote them (recorded in the metadata).
    pub inputs: &'a [String],
    /// Source paths are recorded relative to this directory (a bake's manifest directory).
    pub base: Option<PathBuf>,
    /// Also cook the lossless reference (f32, no clustering) from the same reads.
    pub reference: bool,
}

/// What [`cook_asset`] made: the sections to write, the report, the channels
/// cooked (names joined by ", ") and, when asked, the reference asset.
pub struct Cooked {
    pub sections: Vec<vdbcook_vpak::Section>,
    pub report: CookReport,
    pub grid: Option<String>,
    pub reference: Option<vdbcook_vpak::Asset>,
}

/// Cooks one asset from typed settings: the one cook path of `cook` and `bake`.
pub fn cook_asset(job: CookJob, bars: &dyn Progress) -> Result<Cooked> {
    let format = job.settings.format;
    cook_formats(job, &[format], bars)?.into_iter().next().ok_or_else(|| Error::Failed("no cooker".into()))
}

/// Cooks the asset once per format of `formats` (every other setting as
/// given) from one read of the frames, in the order given; the reference, when
/// asked for, comes with the first.
pub fn cook_formats(job: CookJob, formats: &[Format], bars: &dyn Progress) -> Result<Vec<Cooked>> {
    let s = job.settings;
    let mut all: Vec<CookOptions> = formats.iter().map(|&format| CookSettings { format, ..s.clone() }.cook_options(job.inputs)).collect();
    if job.reference {
        // As many levels as the asset: its validation checks each.
        all.push(CookOptions { levels: s.lods, ..reference_options() });
    }
    let sel = GridSelection::from_flags(s.grid.as_deref(), s.grids.as_deref());
    let (cookers, channels, read_secs) = feed(all, FrameFile::each(job.files, s.allow_missing), sel, job.base, bars)?;
    let grid_name = channels.as_ref().map(|c| c.specs.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", "));
    let mut cookers = cookers.into_iter();
    let mut out = Vec::new();
    for cooker in cookers.by_ref().take(formats.len()) {
        if cooker.frame_count() == 0 {
            return Err(Error::Failed("no frames to cook".into()));
        }
        // A group naming no channel, or too many channels to cluster, is the settings' fault.
        let (sections, mut report) = cooker.finish(bars).map_err(|e| if e.is_settings_error() { Error::Usage(e.to_string()) } else { Error::from(e) })?;
        report.timings.insert(0, ("read".into(), read_secs));
        out.push(Cooked { sections, report, grid: grid_name.clone(), reference: None });
    }
    let reference = cookers.next().map(finish_reference).transpose().context("cooking the reference")?;
    if let Some(first) = out.first_mut() {
        first.reference = reference;
    }
    Ok(out)
}
