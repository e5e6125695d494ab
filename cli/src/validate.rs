//! `vdbcook validate` and `vdbcook render`: the GPU check of what a cook cost.

use crate::gpu::GpuArgs;
use crate::progress::Bars;
use crate::{exit, Usage};
use anyhow::{anyhow, Context, Result};
use std::path::PathBuf;
use vdbcook_pipeline::options::FrameRange;
use vdbcook_pipeline::{recorded, FrameFile, GridSelection, Sources};
use vdbcook_validate::{report, CompareOptions, Comparison, Gate, Levels, Scene, Viewing};
use vdbcook_vpak::Asset;
use vdbcook_vpak::{Level, LevelCount};

pub const AFTER_HELP: &str = "\
Without --source, the source files the asset records are used (and the report says
so): cook records each frame's file as it was named on its command line (a relative
path is relative to the directory cook ran in), bake relative to the manifest's
directory; a relative path is looked up in the current directory, then in the asset's.
A recorded file that is missing here, or whose size or bytes differ from those
recorded, is an error naming it: give the sources with --source. The asset may also
come last: validate --source SRC... ASSET.vpak. An asset cooked with --with records those
inputs too: they are expanded again from where its main files are found and matched as
cook matched them, each file checked against its record; with --source, give them again
with --with, in the cook's order.

The source frames are cooked again in memory, losslessly (f32, no clustering), and
both assets are rendered by the same deterministic wgpu ray-marcher (emission and
absorption, one directional light with shadow rays, hierarchical empty-space skipping;
no noise), from --views cameras orbiting the volume. For each frame and view it
reports RMSE, PSNR and the largest difference of the images (linear values in [0, 1]),
the mean FLIP error (NVIDIA's perceptual LDR-FLIP, 0 to 1, at 67 pixels per degree:
a 0.7 m wide 4K monitor seen from 0.7 m), and for each frame the voxel-domain RMSE,
PSNR and max error; the worst frame is named. FLIP sees the images as the report's
PNGs show them: linear values clamped to [0, 1], sRGB-encoded, 8 bits.

--max-rmse, --min-psnr and --max-flip make validate exit with code 3 when any image
is over budget. --report DIR writes report.json, PNGs of the reference, the asset, an
error heat-map and the FLIP error map for the worst views, and a self-contained
report.html.

--lod K checks level of detail K (of an asset cooked with --lods) against the source
filtered losslessly to it; --every-lod checks every level so, the gate holding at each
(a failure names the level), with a table of the levels' worst image and voxel figures.
With --report, report.html gains a summary row per level (voxel size, figures, pass or
fail) and a section with the first stored level's worst view rendered at every level:
a column per level (its PNGs level{K}_frame{F}_view{V}_{reference,asset,error,flip}.png;
the difference maps on one scale). cook --lods N --validate (N > 1) checks every level
too.

A GPU is not required: Mesa's CPU Vulkan driver (Debian: mesa-vulkan-drivers) works.";

#[derive(clap::Args, Clone)]
pub struct ValidateArgs {
    /// The cooked asset (it may also come last, after --source's inputs).
    #[arg(value_name = "ASSET.vpak")]
    pub asset: Option<PathBuf>,
    /// The source frames the asset was cooked from (files, directories, globs or patterns).
    /// Default: the source files the asset records (see below).
    #[arg(long, num_args = 1.., value_name = "INPUT")]
    pub source: Vec<String>,
    /// Frames of a source frame pattern: A-B or A-B:STEP.
    #[arg(long, value_name = "RANGE", requires = "source")]
    pub source_frames: Option<FrameRange>,
    /// Another sequence the asset's frames were cooked from (`cook --with`; repeatable, in
    /// the cook's order), matched to --source's frames as cook matched them.
    #[arg(long, value_name = "INPUT", requires = "source")]
    pub with: Vec<String>,
    /// Asset frames to render, counted from 0: A-B or A-B:STEP (default: all).
    #[arg(long, value_name = "RANGE")]
    pub frames: Option<FrameRange>,
    /// Render only the asset frame whose number in the source sequence is S (fire_1001.vdb:
    /// 1001; see `inspect`), instead of --frames. (--source-frames is another thing: the range
    /// a --source frame pattern expands over.)
    #[arg(long, value_name = "S", conflicts_with = "frames", allow_negative_numbers = true)]
    pub source_frame: Option<i64>,
    #[command(flatten)]
    pub viewing: Viewing,
    #[command(flatten)]
    pub gate: Gate,
    /// Write report.json, PNGs and report.html into DIR (with --every-lod: a row per level
    /// and the worst view at every level, side by side).
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Level of detail to check (0: the frames themselves; k: the asset's level k against the
    /// source filtered losslessly to level k, as `cook --lods` does). Default: the asset's
    /// finest level (0 unless `cook --max-bytes` left finer ones out).
    #[arg(long, value_name = "K")]
    pub lod: Option<Level>,
    /// Check every level of detail of the asset, each against the source filtered to it
    /// (the gate holds at every level), and show the levels side by side: a table in the
    /// text, `levels` in the JSON, and with --report a row per level and the finest level's
    /// worst view at every level (the rest of the report is the finest level's).
    #[arg(long, conflicts_with = "lod")]
    pub every_lod: bool,
    #[command(flatten)]
    pub gpu: GpuArgs,
    /// Print the report as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

impl ValidateArgs {
    /// The comparison these flags ask for.
    pub fn compare_options(&self) -> CompareOptions {
        CompareOptions {
            frames: self.frames.map(|r| r.frames().map(|f| usize::try_from(f).unwrap_or(usize::MAX)).collect()),
            viewing: self.viewing.clone(),
            gate: self.gate,
            levels: match (self.every_lod, self.lod) {
                (true, _) => Levels::Every,
                (false, Some(k)) => Levels::At(k),
                (false, None) => Levels::First,
            },
            report: self.report.clone(),
        }
    }
}

pub fn run(args: ValidateArgs, quiet: bool) -> Result<u8> {
    let json_out = args.json;
    let o = evaluate(args, quiet)?;
    if !quiet {
        let text = if json_out { format!("{}\n", serde_json::to_string_pretty(&o.doc).unwrap_or_default()) } else { o.text };
        crate::emit_final(&text)?;
    }
    Ok(crate::gate_exit(&o.gate_failure))
}

/// Renders and compares; `quiet` hides progress bars.
pub fn evaluate(mut args: ValidateArgs, quiet: bool) -> Result<Comparison> {
    let (path, source) = recorded::asset_and_sources(args.asset.take(), std::mem::take(&mut args.source)).map_err(Usage)?;
    let bars = Bars::new(quiet || args.json);
    let sources = if source.is_empty() { Sources::Recorded } else { Sources::Inputs { inputs: source, with: std::mem::take(&mut args.with), frames: args.source_frames } };
    let mut opts = args.compare_options();
    if let Some(n) = args.source_frame {
        // The frame's index, from the asset's time (its tables and metadata alone).
        let name = path.display().to_string();
        let meta = Asset::open_unverified(&path).and_then(|a| a.metadata()).with_context(|| name.clone())?;
        opts.frames = Some(vec![meta.frame_by_number(n).map_err(|e| anyhow!("{name}: {e}"))?]);
    }
    Ok(vdbcook_pipeline::validate_file(&path, sources, &opts, || args.gpu.renderer().map(Box::new), &bars)?)
}

#[derive(clap::Args)]
pub struct RenderArgs {
    /// A .vpak asset or a .vdb file.
    #[arg(value_name = "ASSET|VDB")]
    pub input: PathBuf,
    /// Frame of the asset (counted from 0); a .vdb file has one.
    #[arg(long, default_value_t = 0)]
    pub frame: usize,
    /// Frame of the asset by its number in the source sequence (fire_1001.vdb: 1001; see
    /// `inspect`), instead of --frame.
    #[arg(long, value_name = "S", conflicts_with = "frame", allow_negative_numbers = true)]
    pub source_frame: Option<i64>,
    /// The PNG to write.
    #[arg(short, long, value_name = "OUT.png")]
    pub output: PathBuf,
    /// Which of --views orbiting cameras to use (from 0).
    #[arg(long, default_value_t = 0)]
    pub view: u32,
    #[command(flatten)]
    pub viewing: Viewing,
    /// Grid of a .vdb input (default: "density", else the first float grid).
    #[arg(long, value_name = "NAME")]
    pub grid: Option<String>,
    /// Level of detail to draw (0: the frame itself; k: voxels 2^k times as large, each
    /// sample reading the level's voxel that covers it). Default: the asset's finest level
    /// (0 unless `cook --max-bytes` left finer ones out). A .vdb input is filtered to that
    /// level as `cook --lods` does.
    #[arg(long, value_name = "K")]
    pub lod: Option<Level>,
    #[command(flatten)]
    pub gpu: GpuArgs,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
}

pub fn render(args: RenderArgs, quiet: bool) -> Result<u8> {
    let name = args.input.display().to_string();
    crate::refuse_existing(&args.output, args.force)?;
    let (views, size) = (args.viewing.views, args.viewing.size);
    if args.view >= views.get() {
        return Err(Usage(format!("--view {} is out of range (0 to {})", args.view, views.get() - 1)).into());
    }
    if !args.input.exists() {
        return Err(anyhow!("{name}: no such file"));
    }
    let asset = if vdbcook_pipeline::is_vpak(&args.input) {
        Asset::open(&args.input).with_context(|| name.clone())?
    } else {
        vdbcook_pipeline::cook_lossless_levels(
            FrameFile::each(vec![args.input.clone()], false),
            GridSelection::from_flags(args.grid.as_deref(), None),
            args.lod.map_or(LevelCount::ONE, Level::count),
            None,
            &Bars::new(true),
        )?
    };
    let meta = asset.metadata().with_context(|| name.clone())?;
    let lod = args.lod.map_or(meta.first_level, Level::get);
    let frame = match args.source_frame {
        Some(n) => meta.frame_by_number(n).map_err(|e| anyhow!("{name}: {e}"))?,
        None => args.frame,
    };
    if frame >= meta.frame_count as usize {
        return Err(anyhow!("{name}: frame {frame} is out of range (it has {} frames, numbered from 0)", meta.frame_count));
    }
    if let Some(why) = meta.missing_level(lod) {
        let hint = if lod >= meta.levels { format!("; cook it with --lods {}", lod + 1) } else { String::new() };
        return Err(anyhow!("{name}: {why}{hint}"));
    }
    let scene = Scene::for_asset_with(&meta, args.viewing.extinction.as_deref()).map_err(|e| Usage(format!("--extinction: {e}")))?;
    let renderer = args.gpu.renderer()?;
    let view = scene.orbit(views.count())[args.view as usize];
    let img = vdbcook_validate::Resident::new(&asset, meta.index_offset)
        .draw(&renderer, &scene, (frame, lod), &[view], (size.width(), size.height()))
        .with_context(|| name.clone())?
        .pop()
        .ok_or_else(|| anyhow!("no image"))?;
    vdbcook_vpak::write_atomic(&args.output, &report::png_rgb(&img), args.force).with_context(|| args.output.display().to_string())?;
    if !quiet {
        let level = if lod > 0 { format!(" at level {lod}") } else { String::new() };
        let number = meta.frame_number(frame);
        crate::emit_final(&format!("rendered frame {frame} (source frame {number}){level} of {name} to {} ({}×{}, {})\n", args.output.display(), size.width(), size.height(), renderer.adapter))?;
    }
    Ok(exit::SUCCESS)
}
