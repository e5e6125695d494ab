//! `vdbcook validate` and `vdbcook render`: the GPU check of what a cook cost.

use crate::inputs::{self, FrameRange};
use crate::progress::Bars;
use crate::{exit, Usage};
use anyhow::{anyhow, Context, Result};
use rayon::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use vdbcook_cook::Progress;
use vdbcook_encode::ErrorStats;
use vdbcook_validate::flip::DEFAULT_PPD;
use vdbcook_validate::{compare, flip, report, BcDecode, FlipMap, GpuAsset, Image, ImageMetrics, Renderer, Scene};
use vdbcook_vpak::Asset;

pub const AFTER_HELP: &str = "\
Without --source, the source files the asset records are used (and the report says
so): cook records each frame's file as it was named on its command line (a relative
path is relative to the directory cook ran in), bake relative to the manifest's
directory; a relative path is looked up in the current directory, then in the asset's.
A recorded file that is missing here, or whose size or bytes differ from those
recorded, is an error naming it: give the sources with --source. The asset may also
come last: validate --source SRC... ASSET.vpak.

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
    /// The channel that gives extinction in the validation scene (default: `density`, else
    /// the first scalar fog channel that is not a glow channel; see below).
    #[arg(long, value_name = "NAME")]
    pub extinction: Option<String>,
    /// Asset frames to render, counted from 0: A-B or A-B:STEP (default: all).
    #[arg(long, value_name = "RANGE")]
    pub frames: Option<FrameRange>,
    /// Cameras orbiting the volume.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=360))]
    pub views: u32,
    /// Image size.
    #[arg(long, default_value = "512x512", value_name = "WxH", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Exit with code 3 when any image's RMSE is above X.
    #[arg(long, value_name = "X", allow_negative_numbers = true, value_parser = vdbcook_bake::options::parse_rmse_budget)]
    pub max_rmse: Option<f64>,
    /// Exit with code 3 when any image's PSNR (dB) is below Y.
    #[arg(long, value_name = "Y", allow_negative_numbers = true, value_parser = vdbcook_bake::options::parse_psnr_floor)]
    pub min_psnr: Option<f64>,
    /// Exit with code 3 when any image's mean FLIP error (0 to 1, at 67 pixels per degree) is above F.
    #[arg(long, value_name = "F", allow_negative_numbers = true, value_parser = vdbcook_bake::options::parse_flip_budget)]
    pub max_flip: Option<f64>,
    /// Write report.json, PNGs and report.html into DIR (with --every-lod: a row per level
    /// and the worst view at every level, side by side).
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Level of detail to check (0: the frames themselves; k: the asset's level k against the
    /// source filtered losslessly to level k, as `cook --lods` does). Default: the asset's
    /// finest level (0 unless `cook --max-bytes` left finer ones out).
    #[arg(long, value_name = "K", value_parser = vdbcook_bake::options::parse_lod)]
    pub lod: Option<u32>,
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
    /// The validation a cook's settings ask for (`--validate` and its gate, views and
    /// size): every level of an asset with levels of detail, the gate holding at each.
    pub fn of_cook(s: &vdbcook_bake::CookSettings, asset: PathBuf, source: Vec<String>, report: Option<PathBuf>, gpu: GpuArgs, json: bool) -> ValidateArgs {
        ValidateArgs {
            asset: Some(asset),
            source,
            extinction: s.extinction.clone(),
            source_frames: s.frames,
            frames: None,
            views: s.views,
            size: (s.size.width, s.size.height),
            max_rmse: s.max_rmse,
            min_psnr: s.min_psnr,
            max_flip: s.max_flip,
            report,
            lod: None,
            every_lod: s.lods > 1,
            gpu,
            json,
        }
    }
}

/// The GPU options of `validate` and `render`.
#[derive(clap::Args, Clone, Default)]
pub struct GpuArgs {
    /// Use the first GPU adapter whose name contains NAME (e.g. "llvmpipe").
    #[arg(long, value_name = "NAME")]
    pub adapter: Option<String>,
    /// Where BC4/BC7 bricks are decoded: the GPU's texture unit, the shader (raw blocks
    /// decoded in WGSL), or auto: the texture unit of a GPU with BC 3D textures, the
    /// shader on other adapters and on CPU drivers (faster there).
    #[arg(long, value_name = "WHERE", value_enum, default_value_t = BcDecodeArg::Auto)]
    pub bc_decode: BcDecodeArg,
}

#[derive(clap::ValueEnum, Clone, Copy, Default)]
pub enum BcDecodeArg {
    #[default]
    Auto,
    Texture,
    Shader,
}

impl GpuArgs {
    pub fn renderer(&self) -> Result<Renderer> {
        let decode = match self.bc_decode {
            BcDecodeArg::Auto => BcDecode::Auto,
            BcDecodeArg::Texture => BcDecode::Texture,
            BcDecodeArg::Shader => BcDecode::Shader,
        };
        Ok(Renderer::new(self.adapter.as_deref())?.with_bc_decode(decode))
    }
}

pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("invalid size \"{s}\" (expected WxH, e.g. 512x512, each 8 to 8192)");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h) = (w.trim().parse::<u32>().map_err(|_| bad())?, h.trim().parse::<u32>().map_err(|_| bad())?);
    if !(8..=8192).contains(&w) || !(8..=8192).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

/// Cooks `files` losslessly in memory: the reference asset.
fn reference(meta: &vdbcook_vpak::Metadata, files: Vec<PathBuf>, allow_missing: bool, lod: u32, bars: &Bars) -> Result<Asset> {
    let allow_missing = allow_missing || meta.settings.iter().any(|(k, v)| k == "allow_missing" && v == "true");
    crate::cook::cook_lossless_levels(files, crate::cook::selection_of(meta), allow_missing, lod + 1, bars).context("cooking the reference")
}

/// Voxel-domain error of each channel of the asset's frame against the
/// reference's, over the reference's active voxels; and channel `shown`'s
/// active voxels in the reference whose values are finite and not zero (what
/// its images must show something of).
fn voxel_errors(asset: &Asset, reference: &Asset, frame: usize, lod: u32, shown: usize) -> Result<(Vec<ErrorStats>, u64)> {
    let a = vdbcook_cook::unpack_level(asset, frame, lod).map_err(|e| anyhow!(e))?;
    let r = vdbcook_cook::unpack_level(reference, frame, lod).map_err(|e| anyhow!(e))?;
    let errors = r
        .iter()
        .zip(&a)
        .map(|(r, a)| {
            let mut e = ErrorStats::default();
            for leaf in &r.leaves {
                for i in leaf.mask.iter_on() {
                    let (x, y, z) = vdbcook_grid::leaf_local(i);
                    e.add(leaf.values[i], a.probe(leaf.origin.offset(x, y, z)).0);
                }
            }
            e
        })
        .collect();
    let visible = |v: f32| v.is_finite() && v != 0.0;
    let nonzero = r.get(shown).map_or(0, |g| {
        let leaves: u64 = g.leaves.iter().map(|l| l.mask.iter_on().filter(|&i| visible(l.values[i])).count() as u64).sum();
        let tiles: u64 = g.tiles.iter().filter(|t| t.active && visible(t.value)).map(|t| t.voxel_count()).sum();
        leaves + tiles
    });
    Ok((errors, nonzero))
}

#[derive(Clone, Copy)]
struct Shot {
    frame: usize,
    view: usize,
    metrics: ImageMetrics,
    /// Mean FLIP error of the image.
    flip: f64,
    /// Share of the reference image's pixels that differ from the empty scene.
    coverage: f64,
}

/// A view kept for the report: its figures, both images and the FLIP map.
struct Kept {
    shot: Shot,
    reference: Image,
    asset: Image,
    flip: FlipMap,
}

/// What a validation found: the JSON document, a human summary, and the
/// gate failure message, if any.
pub struct Outcome {
    pub doc: serde_json::Value,
    pub text: String,
    pub gate_failure: Option<String>,
    /// The worst image figures (none without images).
    pub worst: Option<Worst>,
}

/// The worst image figures of a validation: the largest RMSE (so the lowest
/// PSNR) and the largest mean FLIP error, each over every image.
#[derive(Clone, Copy, Debug)]
pub struct Worst {
    pub rmse: f64,
    pub psnr: f64,
    pub flip: f64,
}

pub fn run(args: ValidateArgs, quiet: bool) -> Result<u8> {
    let json_out = args.json;
    let o = evaluate(args, quiet)?;
    if !quiet {
        let text = if json_out { format!("{}\n", serde_json::to_string_pretty(&o.doc).unwrap_or_default()) } else { o.text };
        crate::emit_final(&text)?;
    }
    Ok(gate(&o.gate_failure))
}

/// Prints a gate failure; the exit code.
pub fn gate(failure: &Option<String>) -> u8 {
    match failure {
        Some(msg) => {
            eprintln!("vdbcook: quality gate failed: {msg}");
            exit::QUALITY_GATE
        }
        None => exit::SUCCESS,
    }
}

/// Renders and compares; `quiet` hides progress bars.
pub fn evaluate(mut args: ValidateArgs, quiet: bool) -> Result<Outcome> {
    let (path, source) = crate::recorded::asset_and_sources(args.asset.take(), std::mem::take(&mut args.source)).map_err(Usage)?;
    let name = path.display().to_string();
    let asset = Asset::open(&path).with_context(|| name.clone())?;
    let meta = asset.metadata().with_context(|| name.clone())?;
    let bars = Bars::new(quiet || args.json);
    let lod = args.lod.unwrap_or(meta.first_level);
    if let Some(why) = meta.missing_level(lod) {
        return Err(anyhow!("{name}: {why}"));
    }
    // One reference, filtered down to the coarsest level checked, serves every level.
    let coarsest = if args.every_lod { meta.stored_levels().end.saturating_sub(1) } else { lod };
    let recorded = source.is_empty();
    let files = if recorded { crate::recorded::frame_files(&meta, &path)? } else { inputs::expand(&source, args.source_frames)? };
    let reference = reference(&meta, files.clone(), recorded, coarsest, &bars)?;
    let mut o = compare_assets(&asset, &name, &reference, &args, || args.gpu.renderer().map(Box::new), &bars)?;
    let read = files.iter().filter(|f| f.exists()).count();
    if recorded {
        o.text += &format!("  sources  the {read} file(s) the asset records (no --source given)\n");
    }
    o.doc["sources"] = json!({"recorded": recorded, "files": read});
    Ok(o)
}

/// The two assets of a comparison, on the host and on the GPU.
struct Pair<'a> {
    name: &'a str,
    asset: &'a Asset,
    reference: &'a Asset,
    meta: &'a vdbcook_vpak::Metadata,
    ref_meta: &'a vdbcook_vpak::Metadata,
    gpu_asset: &'a GpuAsset,
    gpu_ref: &'a GpuAsset,
    renderer: &'a Renderer,
    scene: &'a Scene,
}

/// One level's comparison: its outcome (a document with one `levels` row)
/// and, for the report, every image's figures and the views kept.
struct LevelRun {
    lod: u32,
    outcome: Outcome,
    shots: Vec<Shot>,
    /// The finest level's three worst views (worst first); a coarser level's
    /// view of the finest level's worst one.
    kept: Vec<Kept>,
}

/// Renders `asset` and its lossless `reference` with the same ray-marcher and
/// compares them (the work of `validate`, `cook --validate`, `cook --auto`
/// and `bake` once both assets are at hand): at `args.lod` (default: the first stored level), or with
/// `args.every_lod` at every stored level, each against the reference
/// filtered to it (the reference must hold them), the gate holding at each.
/// `renderer` is asked for once the frames are known to be in range.
pub fn compare_assets<R: std::ops::Deref<Target = Renderer>>(
    asset: &Asset,
    name: &str,
    reference: &Asset,
    args: &ValidateArgs,
    renderer: impl FnOnce() -> Result<R>,
    bars: &dyn Progress,
) -> Result<Outcome> {
    let meta = asset.metadata().with_context(|| name.to_string())?;
    let ref_meta = reference.metadata()?;
    let lod = args.lod.unwrap_or(meta.first_level);
    if ref_meta.frame_count != meta.frame_count {
        return Err(anyhow!("{name}: the asset has {} frames, the source {}", meta.frame_count, ref_meta.frame_count));
    }
    if ref_meta.channels.len() != meta.channels.len() {
        return Err(anyhow!("{name}: the asset has {} channels, the source gives {}", meta.channels.len(), ref_meta.channels.len()));
    }
    let frames: Vec<usize> = match args.frames {
        Some(r) => r.frames().map(|f| usize::try_from(f).unwrap_or(usize::MAX)).collect(),
        None => (0..meta.frame_count as usize).collect(),
    };
    if let Some(&bad) = frames.iter().find(|&&f| f >= meta.frame_count as usize) {
        return Err(Usage(format!("--frames: frame {bad} is out of range (the asset has {} frames, numbered from 0)", meta.frame_count)).into());
    }
    let levels = if args.every_lod { meta.stored_levels() } else { lod..lod + 1 };
    if levels.end > ref_meta.levels.min(meta.levels) {
        return Err(anyhow!("{name}: level {} is out of range (the asset has {} levels of detail, the reference {})", levels.end - 1, meta.levels, ref_meta.levels));
    }
    // The scene is the reference's: what the source is decides what is drawn.
    let scene = Scene::for_asset_with(&ref_meta, args.extinction.as_deref()).map_err(|e| Usage(format!("--extinction: {e}")))?;
    let renderer = renderer()?;
    let gpu_asset = renderer.upload_for(asset, &scene).with_context(|| name.to_string())?;
    let gpu_ref = renderer.upload_for(reference, &scene).context("reference")?;
    let pair = Pair { name, asset, reference, meta: &meta, ref_meta: &ref_meta, gpu_asset: &gpu_asset, gpu_ref: &gpu_ref, renderer: &renderer, scene: &scene };
    let mut runs: Vec<LevelRun> = Vec::new();
    for lod in levels {
        // Coarser levels keep the finest level's worst view: the report shows it at every level.
        let focus = runs.first().and_then(|r| r.kept.first()).map(|k| (k.shot.frame, k.shot.view));
        runs.push(compare_level(&pair, args, lod, &frames, focus, bars)?);
    }
    let mut out = combine(&runs, args)?;
    if let Some(dir) = &args.report {
        write_report(dir, &out.doc, &runs, gated(args)).with_context(|| dir.display().to_string())?;
        out.text += &format!("  report   {}\n", dir.join("report.html").display());
    }
    Ok(out)
}

/// Whether any gate was given.
fn gated(args: &ValidateArgs) -> bool {
    args.max_rmse.is_some() || args.min_psnr.is_some() || args.max_flip.is_some()
}

/// One outcome of the levels compared: the first level's report with every
/// level's row in `levels` (and, for several levels, a table of them in the
/// text), the first level over budget as the gate failure, and the worst
/// figures over every level.
fn combine(runs: &[LevelRun], args: &ValidateArgs) -> Result<Outcome> {
    let first = runs.first().ok_or_else(|| anyhow!("no level to compare"))?;
    if !args.every_lod {
        let o = &first.outcome;
        return Ok(Outcome { doc: o.doc.clone(), text: o.text.clone(), gate_failure: o.gate_failure.clone(), worst: o.worst });
    }
    let rows: Vec<serde_json::Value> = runs.iter().filter_map(|r| r.outcome.doc["levels"].get(0).cloned()).collect();
    let mut doc = first.outcome.doc.clone();
    doc["levels"] = json!(rows);
    let f = |v: &serde_json::Value| v.as_f64().map_or("-".to_string(), |x| format!("{x:.3e}"));
    let db = |v: &serde_json::Value| v.as_f64().map_or("inf".to_string(), |x| format!("{x:.1}"));
    let gate_col = |r: &LevelRun| match (gated(args), &r.outcome.gate_failure) {
        (false, _) => String::new(),
        (true, None) => format!(" {:>5}", "pass"),
        (true, Some(_)) => format!(" {:>5}", "FAIL"),
    };
    let mut text = first.outcome.text.clone();
    let head = if gated(args) { format!(" {:>5}", "gate") } else { String::new() };
    text += &format!("  levels   {:>5} {:>6} {:>11} {:>9} {:>8} {:>11} {:>9}{head}\n", "level", "voxel", "worst rmse", "psnr dB", "flip", "voxel rmse", "psnr dB");
    for (r, row) in runs.iter().zip(&rows) {
        text += &format!(
            "           {:>5} {:>6} {:>11} {:>9} {:>8} {:>11} {:>9}{}\n",
            r.lod,
            format!("{}x", 1u64 << r.lod),
            f(&row["worst"]["rmse"]),
            db(&row["worst"]["psnr"]),
            row["worst_flip"]["flip"].as_f64().map_or("-".to_string(), |x| format!("{x:.4}")),
            f(&row["voxel"]["rmse"]),
            db(&row["voxel"]["psnr"]),
            gate_col(r)
        );
    }
    let over: Vec<&LevelRun> = runs.iter().filter(|r| r.outcome.gate_failure.is_some()).collect();
    let gate_failure = over.first().and_then(|r| r.outcome.gate_failure.as_ref().map(|g| (r.lod, g))).map(|(lod, g)| {
        let also = if over.len() > 1 { format!(" (levels over budget: {})", over.iter().map(|r| r.lod.to_string()).collect::<Vec<_>>().join(", ")) } else { String::new() };
        format!("level {lod}: {g}{also}")
    });
    // The gate holds at every level, so a search (`cook --auto`) ranks by the worst of them.
    let worst = runs
        .iter()
        .map(|r| r.outcome.worst)
        .collect::<Option<Vec<Worst>>>()
        .and_then(|w| w.into_iter().reduce(|a, b| Worst { rmse: a.rmse.max(b.rmse), psnr: a.psnr.min(b.psnr), flip: a.flip.max(b.flip) }));
    Ok(Outcome { doc, text, gate_failure, worst })
}

/// Compares level `lod` of the pair over `frames`; with a report, keeps the
/// three worst views, or only the `focus` view (frame, view) when one is given.
fn compare_level(p: &Pair, args: &ValidateArgs, lod: u32, frames: &[usize], focus: Option<(usize, usize)>, bars: &dyn Progress) -> Result<LevelRun> {
    let (name, meta, ref_meta, renderer, scene) = (p.name, p.meta, p.ref_meta, p.renderer, p.scene);
    let started = Instant::now();
    let views = scene.orbit(args.views as usize);
    let (w, h) = args.size;
    // What each view shows with no volume: coverage is measured against it.
    let empty: Vec<Image> = views.iter().map(|v| scene.empty_image(v, w, h)).collect();
    let shown = scene.shown();
    let shown_name = ref_meta.channels.get(shown).map_or(String::new(), |c| c.name.clone());

    let mut shots = Vec::new();
    let mut voxel = Vec::new();
    let mut kept: Vec<Kept> = Vec::new();
    let mut flip_secs = 0.0;
    bars.start("rendering", (frames.len() * views.len()) as u64);
    for &f in frames {
        let (errors, nonzero) = voxel_errors(p.asset, p.reference, f, lod, shown)?;
        voxel.push((f, errors));
        let refs = renderer.render_views_level(p.gpu_ref, scene, f, lod, &views, w, h)?;
        let imgs = renderer.render_views_level(p.gpu_asset, scene, f, lod, &views, w, h)?;
        let coverage: Vec<f64> = refs.iter().zip(&empty).map(|(r, e)| vdbcook_validate::coverage(r, e)).collect();
        // Two blank pictures are equal: a frame with something to show must show it somewhere.
        if nonzero > 0 && coverage.iter().all(|&c| c == 0.0) {
            return Err(anyhow!(
                "{name}: frame {f}{at}: the reference is blank in all {n} view(s), though channel \"{shown_name}\" ({model}) has {nonzero} active voxel(s) with non-zero values; name the channel that gives extinction with --extinction NAME, or try other --views or a larger --size",
                at = if lod > 0 { format!(" at level {lod}") } else { String::new() },
                n = views.len(),
                model = scene.model().name(),
            ));
        }
        // FLIP runs on the CPU, one image per thread: the views of a frame in parallel.
        let t = Instant::now();
        let maps: Vec<FlipMap> = refs.par_iter().zip(&imgs).map(|(r, a)| flip(r, a, DEFAULT_PPD)).collect::<Result<_, _>>()?;
        flip_secs += t.elapsed().as_secs_f64();
        for (vi, ((r, a), map)) in refs.into_iter().zip(imgs).zip(maps).enumerate() {
            let shot = Shot { frame: f, view: vi, metrics: compare(&r, &a), flip: map.mean(), coverage: coverage[vi] };
            if args.report.is_some() {
                let k = Kept { shot, reference: r, asset: a, flip: map };
                match focus {
                    Some(fv) if fv != (f, vi) => {}
                    Some(_) => kept.push(k),
                    None => {
                        kept.push(k);
                        kept.sort_by(|x, y| y.shot.metrics.rmse.total_cmp(&x.shot.metrics.rmse));
                        kept.truncate(3);
                    }
                }
            }
            shots.push(shot);
            bars.advance(1);
        }
    }
    bars.finish();
    let worst = shots.iter().max_by(|a, b| a.metrics.rmse.total_cmp(&b.metrics.rmse));
    let worst_flip = shots.iter().max_by(|a, b| a.flip.total_cmp(&b.flip));
    let peak = |c: usize| ref_meta.channels.get(c).map_or(1.0, |ch| f64::from(ch.value_range[1] - ch.value_range[0]).max(1e-12));
    let channel_totals: Vec<ErrorStats> = (0..meta.channels.len())
        .map(|c| {
            let mut t = ErrorStats::default();
            for (_, e) in &voxel {
                t.merge(&e[c]);
            }
            t
        })
        .collect();
    // The voxel figures of the channel the images show.
    let vox_total = channel_totals.get(shown).copied().unwrap_or_default();
    let format = meta.format_names();
    let num = |v: f64| if v.is_finite() { json!(v) } else { serde_json::Value::Null };
    let doc = json!({
        "asset": name,
        "adapter": renderer.adapter,
        "bc_decode": if p.gpu_asset.decodes_in_shader() { "shader" } else { "texture" },
        "format": format,
        "channels": meta.channels.iter().map(|c| c.name.clone()).collect::<Vec<_>>(),
        "shown": meta.channels.get(shown).map(|c| c.name.clone()),
        "model": scene.model().name(),
        "frames": meta.frame_count,
        "level": lod,
        "views": args.views,
        "size": [w, h],
        "flip_ppd": DEFAULT_PPD,
        "images": shots.iter().map(|s| json!({"frame": s.frame, "view": s.view, "rmse": s.metrics.rmse, "psnr": num(s.metrics.psnr), "max_error": s.metrics.max_error, "flip": s.flip, "coverage": s.coverage})).collect::<Vec<_>>(),
        "coverage": coverage_figures(&shots).map(|(min, mean)| json!({"min": min, "mean": mean})),
        "worst": worst.map(|s| json!({"frame": s.frame, "view": s.view, "rmse": s.metrics.rmse, "psnr": num(s.metrics.psnr), "flip": s.flip})),
        "worst_flip": worst_flip.map(|s| json!({"frame": s.frame, "view": s.view, "flip": s.flip})),
        "voxel": {
            "rmse": vox_total.rmse(), "psnr": num(vox_total.psnr(peak(shown))), "max_error": vox_total.max_abs,
            "frames": voxel.iter().map(|(f, e)| { let e = e.get(shown).copied().unwrap_or_default(); json!({"frame": f, "rmse": e.rmse(), "psnr": num(e.psnr(peak(shown))), "max_error": e.max_abs}) }).collect::<Vec<_>>(),
        },
        "voxel_channels": meta.channels.iter().zip(&channel_totals).enumerate().map(|(c, (ch, e))| json!({"name": ch.name, "format": meta.channel_format_names(c), "rmse": e.rmse(), "psnr": num(e.psnr(peak(c))), "max_error": e.max_abs})).collect::<Vec<_>>(),
        "gate": {"max_rmse": args.max_rmse, "min_psnr": args.min_psnr, "max_flip": args.max_flip},
        "levels": [{
            "level": lod,
            "worst": worst.map(|s| json!({"rmse": s.metrics.rmse, "psnr": num(s.metrics.psnr), "flip": s.flip})),
            "worst_flip": worst_flip.map(|s| json!({"flip": s.flip})),
            "voxel": {"rmse": vox_total.rmse(), "psnr": num(vox_total.psnr(peak(shown))), "max_error": vox_total.max_abs},
        }],
    });
    let failed: Vec<&Shot> =
        shots.iter().filter(|s| args.max_rmse.is_some_and(|x| s.metrics.rmse > x) || args.min_psnr.is_some_and(|y| s.metrics.psnr < y) || args.max_flip.is_some_and(|x| s.flip > x)).collect();
    let decoder = if p.gpu_asset.decodes_in_shader() { ", BC decoded in the shader" } else { "" };
    let level = if lod > 0 { format!(" at level {lod}") } else { String::new() };
    let mut text = format!("{name}: {format} vs lossless reference{level}, {} frame(s) × {} view(s) at {w}×{h} on {}{decoder}\n", frames.len(), args.views, renderer.adapter);
    text += &format!("  scene    channel \"{shown_name}\" drawn as {}", scene_words(scene.model()));
    if let Some((min, mean)) = coverage_figures(&shots) {
        text += &format!("; coverage {:.1} % of the pixels on average, {:.1} % in the emptiest view", 100.0 * mean, 100.0 * min);
    }
    text += "\n";
    if let Some(s) = worst {
        text += &format!("  images   worst: frame {} view {}: rmse {:.3e}, psnr {:.1} dB, max {:.3e}, flip {:.4}\n", s.frame, s.view, s.metrics.rmse, s.metrics.psnr, s.metrics.max_error, s.flip);
        let mean = |f: fn(&Shot) -> f64| shots.iter().map(f).sum::<f64>() / shots.len() as f64;
        text += &format!("           mean rmse {:.3e}, mean flip {:.4}\n", mean(|s| s.metrics.rmse), mean(|s| s.flip));
    }
    if let Some(s) = worst_flip {
        text += &format!("  flip     worst: frame {} view {}: flip {:.4} (at {DEFAULT_PPD} pixels per degree)\n", s.frame, s.view, s.flip);
    }
    for (c, (ch, e)) in meta.channels.iter().zip(&channel_totals).enumerate() {
        let label = if meta.channels.len() == 1 { "voxels".to_string() } else { ch.name.clone() };
        text += &format!("  {label:<8} rmse {:.3e}, psnr {:.1} dB, max {:.3e}\n", e.rmse(), e.psnr(peak(c)), e.max_abs);
    }
    text += &format!("  time     {:.2} s to render and compare, FLIP {:.2} s of it\n", started.elapsed().as_secs_f64(), flip_secs);
    let gate_failure = failed
        .first()
        .map(|s| format!("{} image(s) over budget, first frame {} view {} (rmse {:.3e}, psnr {:.1} dB, flip {:.4})", failed.len(), s.frame, s.view, s.metrics.rmse, s.metrics.psnr, s.flip));
    let worst = worst.zip(worst_flip).map(|(w, f)| Worst { rmse: w.metrics.rmse, psnr: w.metrics.psnr, flip: f.flip });
    Ok(LevelRun { lod, outcome: Outcome { doc, text, gate_failure, worst }, shots, kept })
}

/// The smallest and the mean coverage of the images, if any.
fn coverage_figures(shots: &[Shot]) -> Option<(f64, f64)> {
    let min = shots.iter().map(|s| s.coverage).reduce(f64::min)?;
    Some((min, shots.iter().map(|s| s.coverage).sum::<f64>() / shots.len() as f64))
}

/// How a model draws its channel, in the report's words.
fn scene_words(model: vdbcook_validate::Model) -> &'static str {
    match model {
        vdbcook_validate::Model::Scatter => "a scattering fog (scatter)",
        vdbcook_validate::Model::Glow => "an absorbing, glowing medium before a backdrop (glow)",
        vdbcook_validate::Model::Surface => "a lit surface at its zero crossing (surface)",
    }
}

/// Writes a view's four images into the report directory as
/// `{stem}_reference.png`, `_asset`, `_error` (|difference| over `scale`) and
/// `_flip`; returns their figures (inline image and caption) for the HTML.
fn view_figures(write: &dyn Fn(&str, &[u8]) -> Result<()>, stem: &str, k: &Kept, format: &str, scale: f32) -> Result<Vec<String>> {
    let max_flip = k.flip.errors.iter().copied().fold(0.0f32, f32::max);
    [
        ("reference", report::png_rgb(&k.reference), "reference (lossless)".to_string()),
        ("asset", report::png_rgb(&k.asset), format!("asset ({})", report::esc(format))),
        ("error", report::png_heat(&k.reference, &k.asset, scale), format!("|difference|, full scale {scale:.2e}")),
        ("flip", report::png_flip(&k.flip), format!("FLIP error map (magma, 0 to 1): mean {:.4}, max {max_flip:.3}", k.shot.flip)),
    ]
    .into_iter()
    .map(|(kind, png, caption)| {
        write(&format!("{stem}_{kind}.png"), &png)?;
        Ok(format!("<figure><img src='data:image/png;base64,{}'><figcaption>{caption}</figcaption></figure>", report::base64(&png)))
    })
    .collect()
}

/// report.json, the PNGs and report.html: the summary (a row per level), the
/// first level's per-frame plot and worst views, and with several levels the
/// first level's worst view at every level, side by side.
fn write_report(dir: &Path, doc: &serde_json::Value, runs: &[LevelRun], gated: bool) -> Result<()> {
    let first = runs.first().ok_or_else(|| anyhow!("no level to report"))?;
    let (format, name) = (doc["format"].as_str().unwrap_or(""), doc["asset"].as_str().unwrap_or(""));
    std::fs::create_dir_all(dir)?;
    let write = |file: &str, bytes: &[u8]| vdbcook_vpak::write_atomic(&dir.join(file), bytes, true).map_err(|e| anyhow!(e));
    write("report.json", format!("{}\n", serde_json::to_string_pretty(doc).unwrap_or_default()).as_bytes())?;
    // "at level k" in headings only when there are levels to tell apart.
    let at = |lod: u32| if runs.len() > 1 { format!(", level {lod}") } else { String::new() };
    let mut figures = String::new();
    for k in &first.kept {
        let s = &k.shot;
        let figs = view_figures(&write, &format!("frame{}_view{}", s.frame, s.view), k, format, (s.metrics.max_error as f32).max(1e-6))?;
        figures += &format!(
            "<h3>frame {} view {}: rmse {:.3e}, psnr {:.1} dB, max {:.3e}, FLIP {:.4}, coverage {:.1} %</h3><div class='row'>{}</div>",
            s.frame,
            s.view,
            s.metrics.rmse,
            s.metrics.psnr,
            s.metrics.max_error,
            s.flip,
            100.0 * s.coverage,
            figs.concat()
        );
    }
    let side = if runs.len() > 1 { levels_side_by_side(&write, runs, format)? } else { String::new() };
    // Worst view per frame: RMSE and FLIP; and the emptiest view's coverage.
    let mut per_frame: Vec<(usize, f64, f64, f64)> = Vec::new();
    for s in &first.shots {
        match per_frame.iter_mut().find(|e| e.0 == s.frame) {
            Some(e) => (e.1, e.2, e.3) = (e.1.max(s.metrics.rmse), e.2.max(s.flip), e.3.min(s.coverage)),
            None => per_frame.push((s.frame, s.metrics.rmse, s.flip, s.coverage)),
        }
    }
    let rows: String = per_frame.iter().map(|(f, r, fl, c)| format!("<tr><td>{f}</td><td>{r:.4e}</td><td>{fl:.4}</td><td>{:.1} %</td></tr>", 100.0 * c)).collect();
    // A figure of the JSON as people read it: 4 significant digits (RMSE) or 2 decimals (dB).
    let show = |x: &serde_json::Value, sci: bool| match x {
        serde_json::Value::Number(n) => n.as_f64().map(|x| if sci { format!("{x:.4e}") } else { format!("{x:.2}") }).unwrap_or_default(),
        serde_json::Value::String(s) if s == "Infinity" => "∞ (exact)".into(),
        serde_json::Value::String(s) => s.clone(),
        _ => "–".into(),
    };
    let levels = doc["levels"].as_array().map_or(&[][..], |v| &v[..]);
    let summary: String = runs
        .iter()
        .zip(levels)
        .map(|(r, l)| {
            let gate = match (gated, &r.outcome.gate_failure) {
                (false, _) => String::new(),
                (true, None) => "<td class='pass'>pass</td>".into(),
                (true, Some(_)) => "<td class='fail'>fail</td>".into(),
            };
            format!(
                "<tr><td>{}</td><td>{}×</td><td>{g}</td><td>{f}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>{gate}</tr>",
                r.lod,
                1u64 << r.lod,
                show(&l["worst"]["rmse"], true),
                show(&l["worst"]["psnr"], false),
                l["worst_flip"]["flip"].as_f64().map(|x| format!("{x:.4}")).unwrap_or_default(),
                show(&l["voxel"]["rmse"], true),
                show(&l["voxel"]["psnr"], false),
                g = report::esc(&format!("{} ({})", doc["shown"].as_str().unwrap_or(""), doc["model"].as_str().unwrap_or(""))),
                f = report::esc(format),
            )
        })
        .collect();
    let html = format!(
        "<!doctype html><html><head><meta charset='utf-8'><title>vdbcook validation: {n}</title>\
<style>body{{font-family:sans-serif;margin:2em;color:#222}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;text-align:right}}\
.row{{display:flex;gap:1em}}figure{{margin:0}}figcaption{{font-size:small;max-width:300px}}img{{image-rendering:pixelated;max-width:300px;min-width:160px}}\
td.pass{{color:#060}}td.fail{{color:#b00;font-weight:bold}}table.levels td,table.levels th{{text-align:left;vertical-align:top}}table.levels th{{font-weight:normal;font-size:small}}</style></head><body>\
<h1>vdbcook validation</h1><p>{n}, adapter {ad}</p>\
<table><tr><th>level</th><th>voxel size (source voxels)</th><th>model</th><th>format</th><th>worst image RMSE</th><th>worst PSNR (dB)</th><th>worst FLIP</th><th>voxel RMSE</th><th>voxel PSNR (dB)</th>{gh}</tr>{summary}</table>\
<p>FLIP: NVIDIA's perceptual error (LDR-FLIP, mean over the image, 0 to 1) at {ppd} pixels per degree, on the 8-bit sRGB images shown here.{lv}</p>\
<h2>Per-frame error (worst view{l0})</h2>{plot}<table><tr><th>frame</th><th>RMSE</th><th>FLIP</th><th>coverage (emptiest view)</th></tr>{rows}</table>{side}<h2>Worst views{l0}</h2>{figures}</body></html>",
        n = report::esc(name),
        ad = report::esc(doc["adapter"].as_str().unwrap_or("")),
        gh = if gated { "<th>gate</th>" } else { "" },
        ppd = DEFAULT_PPD,
        lv = if runs.len() > 1 { " Level k has voxels 2<sup>k</sup> times the source's, and is compared with the source filtered to it." } else { "" },
        l0 = at(first.lod),
        plot = report::svg_plot(&per_frame.iter().map(|p| p.1).collect::<Vec<_>>(), &per_frame.iter().map(|p| p.0).collect::<Vec<_>>(), "image RMSE per frame"),
    );
    write("report.html", html.as_bytes())
}

/// The report's "Levels side by side": the first level's worst view at every
/// level, a column per level (its PNGs named `level{k}_frame{f}_view{v}_*.png`)
/// and a row per kind of image.
fn levels_side_by_side(write: &dyn Fn(&str, &[u8]) -> Result<()>, runs: &[LevelRun], format: &str) -> Result<String> {
    let views: Vec<(&LevelRun, &Kept)> = runs.iter().filter_map(|r| r.kept.first().map(|k| (r, k))).collect();
    let Some((first, focus)) = views.first() else { return Ok(String::new()) };
    // One scale for every level's |difference|, so that the levels compare by eye.
    let scale = views.iter().map(|(_, k)| k.shot.metrics.max_error as f32).fold(1e-6, f32::max);
    let mut head = String::new();
    let mut cols = Vec::new();
    for (r, k) in &views {
        let s = &k.shot;
        cols.push(view_figures(write, &format!("level{}_frame{}_view{}", r.lod, s.frame, s.view), k, format, scale)?);
        let w = r.outcome.worst.map_or(String::new(), |w| format!("<br>level's worst image: rmse {:.3e}, FLIP {:.4}", w.rmse, w.flip));
        head += &format!("<th><b>level {}</b> (voxels {}×)<br>this view: rmse {:.3e}, psnr {:.1} dB, FLIP {:.4}{w}</th>", r.lod, 1u64 << r.lod, s.metrics.rmse, s.metrics.psnr, s.flip);
    }
    let body: String =
        (0..cols.first().map_or(0, Vec::len)).map(|i| format!("<tr>{}</tr>", cols.iter().map(|c| format!("<td>{}</td>", c.get(i).map_or("", String::as_str))).collect::<String>())).collect();
    Ok(format!(
        "<h2>Levels side by side</h2><p>Frame {} view {} (the worst view of level {}) at every level, each against the source filtered to that level; \
the |difference| maps share one scale (full scale {scale:.2e}).</p><table class='levels'><tr>{head}</tr>{body}</table>",
        focus.shot.frame, focus.shot.view, first.lod
    ))
}

#[derive(clap::Args)]
pub struct RenderArgs {
    /// A .vpak asset or a .vdb file.
    #[arg(value_name = "ASSET|VDB")]
    pub input: PathBuf,
    /// Frame of the asset (counted from 0); a .vdb file has one.
    #[arg(long, default_value_t = 0)]
    pub frame: usize,
    /// The PNG to write.
    #[arg(short, long, value_name = "OUT.png")]
    pub output: PathBuf,
    /// Image size.
    #[arg(long, default_value = "512x512", value_name = "WxH", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Which of --views orbiting cameras to use (from 0).
    #[arg(long, default_value_t = 0)]
    pub view: u32,
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=360))]
    pub views: u32,
    /// Grid of a .vdb input (default: "density", else the first float grid).
    #[arg(long, value_name = "NAME")]
    pub grid: Option<String>,
    /// Level of detail to draw (0: the frame itself; k: voxels 2^k times as large, each
    /// sample reading the level's voxel that covers it). Default: the asset's finest level
    /// (0 unless `cook --max-bytes` left finer ones out). A .vdb input is filtered to that
    /// level as `cook --lods` does.
    #[arg(long, value_name = "K", value_parser = vdbcook_bake::options::parse_lod)]
    pub lod: Option<u32>,
    /// The channel that gives extinction (default: `density`, else the first scalar fog
    /// channel that is not a glow channel; see `vdbcook validate --help`).
    #[arg(long, value_name = "NAME")]
    pub extinction: Option<String>,
    #[command(flatten)]
    pub gpu: GpuArgs,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
}

pub fn render(args: RenderArgs, quiet: bool) -> Result<u8> {
    let name = args.input.display().to_string();
    crate::refuse_existing(&args.output, args.force)?;
    if args.view >= args.views {
        return Err(Usage(format!("--view {} is out of range (0 to {})", args.view, args.views - 1)).into());
    }
    if !args.input.exists() {
        return Err(anyhow!("{name}: no such file"));
    }
    let asset = if crate::inspect::is_vpak(&args.input) {
        Asset::open(&args.input).with_context(|| name.clone())?
    } else {
        crate::cook::cook_lossless_levels(vec![args.input.clone()], crate::grids::GridSelection::from_flags(args.grid.as_deref(), None), false, args.lod.unwrap_or(0) + 1, &Bars::new(true))?
    };
    let meta = asset.metadata().with_context(|| name.clone())?;
    let lod = args.lod.unwrap_or(meta.first_level);
    if args.frame >= meta.frame_count as usize {
        return Err(anyhow!("{name}: frame {} is out of range (it has {} frames, numbered from 0)", args.frame, meta.frame_count));
    }
    if let Some(why) = meta.missing_level(lod) {
        let hint = if lod >= meta.levels { format!("; cook it with --lods {}", lod + 1) } else { String::new() };
        return Err(anyhow!("{name}: {why}{hint}"));
    }
    let scene = Scene::for_asset_with(&meta, args.extinction.as_deref()).map_err(|e| Usage(format!("--extinction: {e}")))?;
    let renderer = args.gpu.renderer()?;
    let gpu = renderer.upload_for(&asset, &scene).with_context(|| name.clone())?;
    let view = scene.orbit(args.views as usize)[args.view as usize];
    let img = renderer.render_views_level(&gpu, &scene, args.frame, lod, std::slice::from_ref(&view), args.size.0, args.size.1)?.pop().ok_or_else(|| anyhow!("no image"))?;
    vdbcook_vpak::write_atomic(&args.output, &report::png_rgb(&img), args.force).with_context(|| args.output.display().to_string())?;
    if !quiet {
        let level = if lod > 0 { format!(" at level {lod}") } else { String::new() };
        crate::emit_final(&format!("rendered frame {}{level} of {name} to {} ({}×{}, {})\n", args.frame, args.output.display(), args.size.0, args.size.1, renderer.adapter))?;
    }
    Ok(exit::SUCCESS)
}
