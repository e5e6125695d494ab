//! `vdbcook cook`: a VDB sequence into one .vpak asset.

use crate::grids::{read_frame, Channels, Frame, GridSelection};
use crate::inputs::{self, FrameRange};
use crate::progress::Bars;
use crate::validate::ValidateArgs;
use crate::{exit, report_error, Usage};
use anyhow::{anyhow, Context, Result};
use std::path::PathBuf;
use std::time::Instant;
use vdbcook_cook::{ChannelGroup, CookOptions, CookReport, Cooker, Format, Progress, Quality};
use vdbcook_vpak::SourceFile;

pub const AFTER_HELP: &str = "\
INPUT is a .vdb file, a directory (every .vdb inside), a glob (\"smoke_*.vdb\") or a
frame pattern (smoke_####.vdb, smoke_%04d.vdb, smoke_$F4.vdb) expanded over --frames.
Several files are one animation; files, directories and globs are taken in natural
order (frame_2 before frame_10), pattern frames in --frames order.

Formats (storage per voxel in the brick atlas):
  f32     32 bits  exact
  f16     16 bits  IEEE half (default)
  unorm8   8 bits  8-bit levels over each brick's own [min, max]
  bc4      4 bits  BC4 block compression of those levels, one z-slice per texture slice
  bc7      2 bits  BC7 with four consecutive z-slices packed into RGBA

Quality presets (--quality), for the block formats:
  ultra-fast  very-fast (default)  fast  basic  slow
For bc7 they are the alpha settings of intel_tex_2 (ISPC BC7): slower presets search
more BC7 modes and refine more. For bc4 (vdbcook's own encoder) they widen the search
for each block's endpoints around the least-squares fit: 0, 1, 2, 3 or 4 levels. See
docs/benchmarks.md for their measured speed and error.

Clustering (--clusters K): every brick's normalised variance (variance / mean) is
computed; constant bricks and bricks above --variance-threshold are kept as they are;
the rest go through k-means with the normalised Manhattan distance (seeded k-means++,
then --iterations rounds), and each is replaced by its centroid unless that moves a
voxel by more than --max-brick-error. The report gives bricks before and after and the
voxel RMSE with and without clustering.

Frames are streamed: at most two source frames are held at once. Identical bricks,
L3 and L2 nodes and frames are stored once. The output is written to a temporary
file and renamed; an existing OUT is replaced only with --force.

--validate renders the new asset against its sources on the GPU afterwards (see
`vdbcook validate --help`); with --max-rmse / --min-psnr a failed gate exits with 3.";

#[derive(clap::Args)]
pub struct CookArgs {
    /// Frame files, directories, globs or frame patterns.
    #[arg(required = true, value_name = "INPUT")]
    pub inputs: Vec<String>,
    /// The asset to write.
    #[arg(short, long, value_name = "OUT.vpak")]
    pub output: PathBuf,
    /// Frames of a frame pattern: A-B or A-B:STEP (e.g. 1-120:2).
    #[arg(long, value_name = "RANGE")]
    pub frames: Option<FrameRange>,
    /// Grid to cook (default: "density", else the first float grid).
    #[arg(long, value_name = "NAME", conflicts_with = "grids")]
    pub grid: Option<String>,
    /// Grids to cook into one asset, as channels of one tree: names as in the files,
    /// comma-separated, or "all" (every float, double and half grid of the first frame).
    #[arg(long, value_name = "A,B,...|all")]
    pub grids: Option<String>,
    /// Store these channels together in their own format (repeatable), e.g.
    /// --group temperature,flames=bc7 --group density=bc4; other channels take --format.
    #[arg(long, value_name = "CHANNELS=FORMAT", value_parser = parse_group)]
    pub group: Vec<ChannelGroup>,
    /// A frame whose file or grid is missing becomes an empty frame instead of an error.
    #[arg(long)]
    pub allow_missing: bool,
    /// Voxel format of the brick atlas.
    #[arg(long, default_value = "f16", value_parser = ["f32", "f16", "unorm8", "bc4", "bc7"])]
    pub format: String,
    /// Encoder preset of bc7 and bc4 (see the notes below).
    #[arg(long, default_value = "very-fast", value_parser = ["ultra-fast", "very-fast", "fast", "basic", "slow"])]
    pub quality: String,
    /// Merge similar bricks with variance-gated k-means into K centroid bricks (off by default).
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub clusters: Option<u32>,
    /// k-means iterations.
    #[arg(long, default_value_t = 5, value_name = "N", value_parser = clap::value_parser!(u32).range(0..=1000))]
    pub iterations: u32,
    /// Bricks whose variance / mean exceeds T are never clustered.
    #[arg(long, default_value_t = 0.01, value_name = "T")]
    pub variance_threshold: f64,
    /// A clustered brick whose largest voxel difference from its centroid exceeds E stays unique.
    #[arg(long, value_name = "E")]
    pub max_brick_error: Option<f32>,
    /// Largest 3D texture edge in texels; bigger brick pools are split into several atlases.
    #[arg(long, default_value_t = 2048, value_name = "TEXELS", value_parser = clap::value_parser!(u32).range(8..=16384))]
    pub max_texture_dim: u32,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// After cooking, run `vdbcook validate` on the asset against the inputs (8 views, 512×512).
    #[arg(long)]
    pub validate: bool,
    /// With --validate: exit with code 3 when any image's RMSE is above X.
    #[arg(long, value_name = "X", requires = "validate")]
    pub max_rmse: Option<f64>,
    /// With --validate: exit with code 3 when any image's PSNR (dB) is below Y.
    #[arg(long, value_name = "Y", requires = "validate")]
    pub min_psnr: Option<f64>,
}

/// Reads `files` on a thread that stays one frame ahead (at most two source
/// frames live at once) and pushes each frame into a cooker made with `opts`
/// for the channels the first frame resolves. Returns the cooker, its
/// channels and the seconds spent waiting for frames.
pub fn feed(opts: CookOptions, files: Vec<PathBuf>, sel: GridSelection, allow_missing: bool, bars: &Bars) -> Result<(Cooker, Option<Channels>, f64)> {
    let (tx, rx) = std::sync::mpsc::sync_channel::<(Result<Frame>, Option<Channels>)>(0);
    let total = files.len() as u64;
    let reader = std::thread::spawn(move || {
        let mut channels = None;
        for f in files {
            let r = read_frame(f, &sel, &mut channels, allow_missing);
            let stop = r.is_err();
            if tx.send((r, channels.clone())).is_err() || stop {
                break;
            }
        }
    });
    bars.start("reading frames", total);
    let mut read_secs = 0.0;
    let mut wait = Instant::now();
    let mut failure = None;
    let mut cooker: Option<Cooker> = None;
    let mut channels: Option<Channels> = None;
    // Frames before the first one whose file resolves the channels: empty.
    let mut leading: Vec<Option<SourceFile>> = Vec::new();
    for (r, ch) in rx {
        read_secs += wait.elapsed().as_secs_f64();
        let pushed = r.and_then(|frame| {
            if cooker.is_none() {
                if let Some(ch) = ch {
                    let mut c = Cooker::with_channels(opts.clone(), ch.specs.clone());
                    for s in leading.drain(..) {
                        c.push_empty(s);
                    }
                    cooker = Some(c);
                    channels = Some(ch);
                }
            }
            let Some(c) = cooker.as_mut() else {
                leading.push(frame.source);
                return Ok(());
            };
            let n = c.frame_count();
            match &frame.grids {
                Some(g) => c.push_channels(&g.iter().map(Option::as_ref).collect::<Vec<_>>(), frame.source).with_context(|| format!("{}: frame {n}", frame.path.display())),
                None => {
                    c.push_empty(frame.source);
                    Ok(())
                }
            }
        });
        if let Err(e) = pushed {
            failure = Some(e);
            break;
        }
        bars.advance(1);
        wait = Instant::now();
    }
    bars.finish();
    reader.join().map_err(|_| anyhow!("the frame reader thread panicked"))?;
    if let Some(e) = failure {
        return Err(e);
    }
    let cooker = cooker.unwrap_or_else(|| {
        let mut c = Cooker::new(opts);
        for s in leading {
            c.push_empty(s);
        }
        c
    });
    Ok((cooker, channels, read_secs))
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
        1 if meta.channels.len() == 1 && !grids[0].is_empty() => GridSelection::One(grids.remove(0)),
        _ => GridSelection::Many(grids),
    }
}

/// Cooks `files` losslessly in memory (f32, no clustering): the reference
/// asset `validate` compares with, and what `render` draws for a .vdb.
pub fn cook_lossless(files: Vec<PathBuf>, sel: GridSelection, allow_missing: bool, bars: &Bars) -> Result<vdbcook_vpak::Asset> {
    let (cooker, _, _) = feed(CookOptions { format: Format::F32, clustering: None, ..CookOptions::default() }, files, sel, allow_missing, bars)?;
    let (sections, _) = cooker.finish(&vdbcook_cook::NoProgress).map_err(|e| anyhow!(e))?;
    Ok(vdbcook_vpak::Asset::from_bytes(&vdbcook_vpak::assemble(&sections))?)
}

/// `--group CHANNELS=FORMAT`: channels given their own format, stored together.
pub fn parse_group(s: &str) -> Result<ChannelGroup, String> {
    let bad = || format!("invalid group \"{s}\" (expected CHANNELS=FORMAT, e.g. temperature,flames=bc7; formats: f32, f16, unorm8, bc4, bc7)");
    let (names, format) = s.rsplit_once('=').ok_or_else(bad)?;
    let format = Format::parse(format.trim()).ok_or_else(bad)?;
    let channels: Vec<String> = names.split(',').map(|n| n.trim().to_string()).filter(|n| !n.is_empty()).collect();
    if channels.is_empty() {
        return Err(bad());
    }
    Ok(ChannelGroup { channels, format })
}

pub fn run(args: CookArgs, quiet: bool) -> Result<u8> {
    crate::refuse_existing(&args.output, args.force)?;
    let format = Format::parse(&args.format).ok_or_else(|| Usage(format!("unknown format {}", args.format)))?;
    let quality = Quality::parse(&args.quality).ok_or_else(|| Usage(format!("unknown quality {}", args.quality)))?;
    if args.variance_threshold.is_nan() || args.variance_threshold < 0.0 {
        return Err(Usage(format!("--variance-threshold must be a number >= 0, not {}", args.variance_threshold)).into());
    }
    if args.max_brick_error.is_some_and(|e| e.is_nan() || e < 0.0) {
        return Err(Usage("--max-brick-error must be a number >= 0".into()).into());
    }
    let clustering = args.clusters.map(|k| vdbcook_cluster::Options {
        clusters: k as usize,
        iterations: args.iterations as usize,
        variance_threshold: args.variance_threshold,
        max_brick_error: args.max_brick_error,
        ..vdbcook_cluster::Options::default()
    });
    let files = inputs::expand(&args.inputs, args.frames)?;
    let sel = GridSelection::from_flags(args.grid.as_deref(), args.grids.as_deref());
    let started = Instant::now();
    let bars = Bars::new(quiet);

    let settings = vec![
        ("format".to_string(), format.name().to_string()),
        ("quality".to_string(), if format.is_block() { quality.name().to_string() } else { String::new() }),
        ("grid".to_string(), sel.setting()),
        ("groups".to_string(), args.group.iter().map(|g| format!("{}={}", g.channels.join(","), g.format.name())).collect::<Vec<_>>().join(" ")),
        ("frames".to_string(), args.frames.map(|f| format!("{}-{}:{}", f.first, f.last, f.step)).unwrap_or_default()),
        ("allow_missing".to_string(), args.allow_missing.to_string()),
        ("max_texture_dim".to_string(), args.max_texture_dim.to_string()),
        ("clusters".to_string(), args.clusters.map(|k| k.to_string()).unwrap_or_default()),
        ("iterations".to_string(), if args.clusters.is_some() { args.iterations.to_string() } else { String::new() }),
        ("variance_threshold".to_string(), if args.clusters.is_some() { args.variance_threshold.to_string() } else { String::new() }),
        ("max_brick_error".to_string(), args.max_brick_error.map(|e| e.to_string()).unwrap_or_default()),
        ("inputs".to_string(), args.inputs.join(" ")),
    ];
    let opts = CookOptions { format, groups: args.group.clone(), quality, max_texture_dim: args.max_texture_dim, clustering, settings };
    let (cooker, channels, read_secs) = feed(opts, files, sel, args.allow_missing, &bars)?;
    if let Some(ch) = &channels {
        check_groups(&args.group, ch)?;
        if args.clusters.is_some() && ch.specs.len() > vdbcook_cook::MAX_CLUSTER_CHANNELS {
            return Err(Usage(format!("--clusters takes at most {} channels; this cook has {}", vdbcook_cook::MAX_CLUSTER_CHANNELS, ch.specs.len())).into());
        }
    }
    let grid_name = channels.as_ref().map(|c| c.specs.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", "));
    if cooker.frame_count() == 0 {
        return Err(anyhow!("no frames to cook"));
    }
    let (sections, mut report) = cooker.finish(&bars).map_err(|e| anyhow!(e))?;
    report.timings.insert(0, ("read".into(), read_secs));
    let t0 = Instant::now();
    vdbcook_vpak::write_file(&args.output, &sections, args.force).with_context(|| args.output.display().to_string())?;
    report.timings.push(("write".into(), t0.elapsed().as_secs_f64()));
    report.timings.push(("total".into(), started.elapsed().as_secs_f64()));
    let validation = if args.validate {
        let v = ValidateArgs {
            asset: args.output.clone(),
            source: args.inputs.clone(),
            source_frames: args.frames,
            frames: None,
            views: 8,
            size: (512, 512),
            max_rmse: args.max_rmse,
            min_psnr: args.min_psnr,
            report: None,
            gpu: Default::default(),
            json: args.json,
        };
        Some(crate::validate::evaluate(v, quiet)?)
    } else {
        None
    };
    if !quiet {
        let mut text = if args.json { summary_json(&args, grid_name.as_deref(), &report, validation.as_ref().map(|o| &o.doc)) } else { summary_text(&args, grid_name.as_deref(), &report) };
        if let (Some(o), false) = (&validation, args.json) {
            text += &o.text;
        }
        crate::write_stdout(&text).ok();
    }
    Ok(validation.map_or(exit::SUCCESS, |o| crate::validate::gate(&o.gate_failure)))
}

/// Every channel an explicit group names exists, once.
fn check_groups(groups: &[ChannelGroup], ch: &Channels) -> Result<()> {
    let mut seen = std::collections::HashSet::new();
    for name in groups.iter().flat_map(|g| &g.channels) {
        let named = vdbcook_cook::channels_named(&ch.specs, name);
        if named.is_empty() {
            let names: Vec<&str> = ch.specs.iter().map(|s| s.name.as_str()).collect();
            return Err(Usage(format!("--group names \"{name}\", which is not a channel of this cook (channels: {})", names.join(", "))).into());
        }
        if !named.into_iter().all(|c| seen.insert(c)) {
            return Err(Usage(format!("--group names \"{name}\" twice")).into());
        }
    }
    Ok(())
}

fn mb(b: u64) -> String {
    format!("{:.2} MB", b as f64 / 1e6)
}

fn summary_text(args: &CookArgs, grid: Option<&str>, r: &CookReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let what = if r.channels.len() == 1 { format!("grid \"{}\"", grid.unwrap_or("")) } else { format!("{} channels", r.channels.len()) };
    let _ = writeln!(s, "cooked {} frame{} of {what} into {} ({}, {})", r.frames, if r.frames == 1 { "" } else { "s" }, args.output.display(), r.format, mb(r.file_bytes));
    let _ = writeln!(s, "  active voxels   {} ({:.3} bits per active voxel)", r.active_voxels, r.bits_per_active_voxel);
    let _ = writeln!(s, "  bricks          {} leaves -> {} unique -> {} stored in {} atlas{}", r.bricks, r.unique_bricks, r.stored_bricks, r.atlases, if r.atlases == 1 { "" } else { "es" });
    let _ = writeln!(s, "  nodes           L1 {}, L2 {}, L3 {}, tiles {}; tree {} (thesis layout: {})", r.l1_nodes, r.l2_nodes, r.l3_nodes, r.tiles, mb(r.tree_bytes), mb(r.thesis_tree_bytes));
    if r.channels.len() == 1 {
        let _ = writeln!(s, "  voxel error     rmse {:.3e}, psnr {:.1} dB, max {:.3e}", r.voxel_rmse, r.voxel_psnr, r.voxel_max_error);
    } else {
        for c in &r.channels {
            let _ = writeln!(
                s,
                "  {:<16}{:<7} {:>10}, values [{:.4}, {:.4}], rmse {:.3e}, psnr {:.1} dB, max {:.3e}",
                c.name,
                c.format,
                mb(c.bytes),
                c.value_range[0],
                c.value_range[1],
                c.voxel_rmse,
                c.voxel_psnr,
                c.voxel_max_error
            );
        }
    }
    if let Some(c) = &r.clustering {
        let _ = writeln!(
            s,
            "  clustering      {} -> {} bricks ({:.2}x; {} constant, {} high variance, {} over the error bound kept), rmse {:.3e} without, {:.3e} with",
            c.stats.bricks_in, c.stats.bricks_out, c.ratio, c.stats.constant, c.stats.high_variance, c.stats.over_error, c.rmse_without, c.rmse_with
        );
    }
    let t: Vec<String> = r.timings.iter().map(|(k, v)| format!("{k} {v:.2}s")).collect();
    let _ = writeln!(s, "  time            {}", t.join(", "));
    s
}

fn summary_json(args: &CookArgs, grid: Option<&str>, r: &CookReport, validation: Option<&serde_json::Value>) -> String {
    let mut v = serde_json::to_value(r).unwrap_or_default();
    if let Some(o) = v.as_object_mut() {
        if let Some(val) = validation {
            o.insert("validation".into(), val.clone());
        }
        o.insert("output".into(), serde_json::json!(args.output.display().to_string()));
        o.insert("grid".into(), serde_json::json!(grid));
        o.insert("sections".into(), serde_json::json!(r.sections.iter().map(|(n, b)| serde_json::json!({"name": n, "bytes": b})).collect::<Vec<_>>()));
        o.insert("timings".into(), serde_json::json!(r.timings.iter().map(|(n, s)| (n.clone(), serde_json::json!(s))).collect::<serde_json::Map<_, _>>()));
        o.insert(
            "frame_errors".into(),
            serde_json::json!(r.frame_errors.iter().enumerate().map(|(i, (rmse, max))| serde_json::json!({"frame": i, "rmse": rmse, "max_error": max})).collect::<Vec<_>>()),
        );
        if !r.voxel_psnr.is_finite() {
            o.insert("voxel_psnr".into(), serde_json::Value::Null);
        }
    }
    format!("{}\n", serde_json::to_string_pretty(&v).unwrap_or_default())
}

/// Reports a cook failure.
pub fn fail(e: &anyhow::Error) -> u8 {
    report_error(e);
    if e.downcast_ref::<Usage>().is_some() {
        exit::USAGE
    } else {
        exit::FAILURE
    }
}
