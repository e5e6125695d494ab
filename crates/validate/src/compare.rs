//! The comparison behind `validate`, `cook --validate`, `cook --auto` and
//! `bake`: an asset and its lossless reference (an asset too, cooked by the
//! caller from the source) rendered by the same ray-marcher, with image, FLIP
//! and voxel figures per level, frame and view, and the gate's verdict.

use crate::flip::DEFAULT_PPD;
use crate::options::Viewing;
use crate::resident::Resident;
use crate::{compare, FlipMap, Gate, Image, ImageMetrics, Model, Renderer, Scene, Size};
use rayon::prelude::*;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;
use vdbcook_cook::Progress;
use vdbcook_encode::ErrorStats;
use vdbcook_vpak::{Asset, Metadata};

type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// Why a comparison could not be made.
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    /// An option does not fit the assets (`--frames`, `--extinction`): the caller's usage error.
    #[error("{0}")]
    Usage(String),
    /// The assets cannot be compared (the text says why).
    #[error("{0}")]
    Failed(String),
    /// What failed (an asset's name, a directory), and why.
    #[error("{0}")]
    In(String, #[source] BoxError),
    #[error(transparent)]
    Render(#[from] crate::Error),
    #[error(transparent)]
    Other(BoxError),
}

impl CompareError {
    /// Whether the caller's options were at fault (a usage error).
    pub fn is_usage(&self) -> bool {
        matches!(self, CompareError::Usage(_))
    }
}

/// Which levels of detail to compare.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Levels {
    /// One level (default: the asset's first stored level).
    #[default]
    First,
    At(vdbcook_vpak::Level),
    /// Every stored level, the gate holding at each.
    Every,
}

/// What to compare and how.
#[derive(Clone, Debug, Default)]
pub struct CompareOptions {
    /// Asset frames to render, counted from 0 (default: all).
    pub frames: Option<Vec<usize>>,
    /// The medium, the cameras and the image size.
    pub viewing: Viewing,
    pub gate: Gate,
    pub levels: Levels,
    /// Write report.json, PNGs and report.html here.
    pub report: Option<PathBuf>,
}

/// One image's figures.
#[derive(Clone, Copy, Debug)]
pub struct Shot {
    pub frame: usize,
    pub view: usize,
    pub metrics: ImageMetrics,
    /// Mean FLIP error of the image.
    pub flip: f64,
    /// Share of the reference image's pixels that differ from the empty scene.
    pub coverage: f64,
}

/// The worst image figures of a comparison: the largest RMSE (so the lowest
/// PSNR) and the largest mean FLIP error, each over every image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Worst {
    pub rmse: f64,
    pub psnr: f64,
    pub flip: f64,
}

/// One level's figures.
#[derive(Clone, Debug)]
pub struct LevelFigures {
    pub lod: u32,
    /// Every image, frame by frame, view by view.
    pub shots: Vec<Shot>,
    /// The image with the largest RMSE (the last of equals).
    pub worst_shot: Option<Shot>,
    pub worst: Option<Worst>,
    /// Voxel errors of the channel the images show, over every frame compared.
    pub voxel: ErrorStats,
    /// Why the gate failed at this level.
    pub gate_failure: Option<String>,
}

/// What a comparison found: per level figures, the gate's verdict, the JSON
/// document (docs/validate-json.md) and a human summary built from them.
#[derive(Clone, Debug)]
pub struct Comparison {
    pub adapter: String,
    pub views: u32,
    pub size: Size,
    pub levels: Vec<LevelFigures>,
    /// The first level over budget, in words.
    pub gate_failure: Option<String>,
    /// The worst figures over every level.
    pub worst: Option<Worst>,
    pub doc: serde_json::Value,
    pub text: String,
}

impl Comparison {
    pub fn passed(&self) -> bool {
        self.gate_failure.is_none()
    }
}

/// A view kept for the report: its figures, both images and the FLIP map.
pub(crate) struct Kept {
    pub shot: Shot,
    pub reference: Image,
    pub asset: Image,
    pub flip: FlipMap,
}

/// One level's comparison, as the report needs it.
pub(crate) struct LevelRun {
    pub figures: LevelFigures,
    pub doc: serde_json::Value,
    pub text: String,
    /// The finest level's three worst views (worst first); a coarser level's
    /// view of the finest level's worst one.
    pub kept: Vec<Kept>,
}

/// The two assets of a comparison, on the host and on the GPU.
struct Pair<'a> {
    name: &'a str,
    asset: &'a Asset,
    reference: &'a Asset,
    meta: &'a Metadata,
    ref_meta: &'a Metadata,
    gpu_asset: std::cell::RefCell<Resident<'a>>,
    gpu_ref: std::cell::RefCell<Resident<'a>>,
    renderer: &'a Renderer,
    scene: &'a Scene,
}

/// Whether the frames `opts` asks for are an asset of `frame_count` frames'
/// (a usage error naming the first that is not): callers check before the
/// reference is cooked, and [`compare_assets`] again.
pub fn check_frames(opts: &CompareOptions, frame_count: u32) -> Result<(), CompareError> {
    match opts.frames.iter().flatten().find(|&&f| f >= frame_count as usize) {
        Some(&bad) => Err(CompareError::Usage(format!("--frames: frame {bad} is out of range (the asset has {frame_count} frames, numbered from 0)"))),
        None => Ok(()),
    }
}

/// Renders `asset` (called `name`) and its lossless `reference` with the same
/// ray-marcher and compares them at the levels `opts` asks for, each against
/// the reference filtered to it (the reference must hold them). `renderer` is
/// asked for once the frames are known to be in range.
pub fn compare_assets<R: std::ops::Deref<Target = Renderer>, E: Into<BoxError>>(
    asset: &Asset,
    name: &str,
    reference: &Asset,
    opts: &CompareOptions,
    renderer: impl FnOnce() -> Result<R, E>,
    bars: &dyn Progress,
) -> Result<Comparison, CompareError> {
    let meta = asset.metadata().map_err(|e| CompareError::In(name.to_string(), e.into()))?;
    let ref_meta = reference.metadata().map_err(crate::Error::from)?;
    let lod = match opts.levels {
        Levels::At(k) => k.get(),
        _ => meta.first_level,
    };
    if ref_meta.frame_count != meta.frame_count {
        return Err(CompareError::Failed(format!("{name}: the asset has {} frames, the source {}", meta.frame_count, ref_meta.frame_count)));
    }
    if ref_meta.channels.len() != meta.channels.len() {
        return Err(CompareError::Failed(format!("{name}: the asset has {} channels, the source gives {}", meta.channels.len(), ref_meta.channels.len())));
    }
    check_frames(opts, meta.frame_count)?;
    let frames: Vec<usize> = opts.frames.clone().unwrap_or_else(|| (0..meta.frame_count as usize).collect());
    // The scene is the reference's: what the source is decides what is drawn.
    let scene = Scene::for_asset_with(&ref_meta, opts.viewing.extinction.as_deref()).map_err(|e| CompareError::Usage(format!("--extinction: {e}")))?;
    // Every level the drawn channel has (with channels at their own voxel sizes, not every level of the trees).
    let levels = if opts.levels == Levels::Every { meta.channel_levels(scene.shown()) } else { lod..lod + 1 };
    if levels.end > ref_meta.levels.min(meta.levels) {
        return Err(CompareError::Failed(format!("{name}: level {} is out of range (the asset has {} levels of detail, the reference {})", levels.end - 1, meta.levels, ref_meta.levels)));
    }
    let renderer = renderer().map_err(|e| CompareError::Other(e.into()))?;
    let mut gpu_asset = Resident::new(asset, ref_meta.index_offset);
    let first = gpu_asset.at(&renderer, &scene, frames.first().copied().unwrap_or(0)).map_err(|e| CompareError::In(name.to_string(), e.into()))?.0;
    let gpu_ref = Resident::new(reference, ref_meta.index_offset);
    let pair = Pair { name, asset, reference, meta: &meta, ref_meta: &ref_meta, gpu_asset: gpu_asset.into(), gpu_ref: gpu_ref.into(), renderer: &renderer, scene: &scene };
    let runs = std::thread::scope(|s| {
        // The driver compiles the asset's pipelines (on the CPU, mostly on one
        // core) while the reference renders, not between the two renders.
        let r: &Renderer = &renderer;
        s.spawn(|| r.prepare(&first.gpu, &scene));
        let mut runs: Vec<LevelRun> = Vec::new();
        for lod in levels {
            // Coarser levels keep the finest level's worst view: the report shows it at every level.
            let focus = runs.first().and_then(|r| r.kept.first()).map(|k| (k.shot.frame, k.shot.view));
            runs.push(compare_level(&pair, opts, lod, &frames, focus, bars)?);
        }
        Ok::<_, CompareError>(runs)
    })?;
    let mut out = combine(&runs, opts, &renderer.adapter)?;
    if let Some(dir) = &opts.report {
        crate::html::write_report(dir, &out.doc, &runs, opts.gate.is_set()).map_err(|e| CompareError::In(dir.display().to_string(), e))?;
        out.text += &format!("  report   {}\n", dir.join("report.html").display());
    }
    out.levels = runs.into_iter().map(|r| r.figures).collect();
    Ok(out)
}

/// One comparison of the levels compared: the first level's report with every
/// level's row in `levels` (and, for several levels, a table of them in the
/// text), the first level over budget as the gate failure, and the worst
/// figures over every level. Its `levels` are filled in by the caller.
fn combine(runs: &[LevelRun], opts: &CompareOptions, adapter: &str) -> Result<Comparison, CompareError> {
    let first = runs.first().ok_or_else(|| CompareError::Failed("no level to compare".into()))?;
    let base = Comparison {
        adapter: adapter.to_string(),
        views: opts.viewing.views.get(),
        size: opts.viewing.size,
        levels: Vec::new(),
        gate_failure: first.figures.gate_failure.clone(),
        worst: first.figures.worst,
        doc: first.doc.clone(),
        text: first.text.clone(),
    };
    if opts.levels != Levels::Every {
        return Ok(base);
    }
    let gated = opts.gate.is_set();
    let rows: Vec<serde_json::Value> = runs.iter().filter_map(|r| r.doc["levels"].get(0).cloned()).collect();
    let mut doc = base.doc;
    doc["levels"] = json!(rows);
    let f = |v: &serde_json::Value| v.as_f64().map_or("-".to_string(), |x| format!("{x:.3e}"));
    let db = |v: &serde_json::Value| v.as_f64().map_or("inf".to_string(), |x| format!("{x:.1}"));
    let gate_col = |r: &LevelRun| match (gated, &r.figures.gate_failure) {
        (false, _) => String::new(),
        (true, None) => format!(" {:>5}", "pass"),
        (true, Some(_)) => format!(" {:>5}", "FAIL"),
    };
    let mut text = base.text;
    let head = if gated { format!(" {:>5}", "gate") } else { String::new() };
    text += &format!("  levels   {:>5} {:>6} {:>11} {:>9} {:>8} {:>11} {:>9}{head}\n", "level", "voxel", "worst rmse", "psnr dB", "flip", "voxel rmse", "psnr dB");
    for (r, row) in runs.iter().zip(&rows) {
        text += &format!(
            "           {:>5} {:>6} {:>11} {:>9} {:>8} {:>11} {:>9}{}\n",
            r.figures.lod,
            format!("{}x", 1u64 << r.figures.lod),
            f(&row["worst"]["rmse"]),
            db(&row["worst"]["psnr"]),
            row["worst_flip"]["flip"].as_f64().map_or("-".to_string(), |x| format!("{x:.4}")),
            f(&row["voxel"]["rmse"]),
            db(&row["voxel"]["psnr"]),
            gate_col(r)
        );
    }
    let over: Vec<&LevelRun> = runs.iter().filter(|r| r.figures.gate_failure.is_some()).collect();
    let gate_failure = over.first().and_then(|r| r.figures.gate_failure.as_ref().map(|g| (r.figures.lod, g))).map(|(lod, g)| {
        let also = if over.len() > 1 { format!(" (levels over budget: {})", over.iter().map(|r| r.figures.lod.to_string()).collect::<Vec<_>>().join(", ")) } else { String::new() };
        format!("level {lod}: {g}{also}")
    });
    // The gate holds at every level, so a search (`cook --auto`) ranks by the worst of them.
    let worst = runs
        .iter()
        .map(|r| r.figures.worst)
        .collect::<Option<Vec<Worst>>>()
        .and_then(|w| w.into_iter().reduce(|a, b| Worst { rmse: a.rmse.max(b.rmse), psnr: a.psnr.min(b.psnr), flip: a.flip.max(b.flip) }));
    Ok(Comparison { adapter: adapter.to_string(), views: opts.viewing.views.get(), size: opts.viewing.size, levels: Vec::new(), gate_failure, worst, doc, text })
}

/// Voxel-domain error of each channel of the asset's frame against the
/// reference's, over the reference's active voxels; and channel `shown`'s
/// active voxels in the reference whose values are finite and not zero (what
/// its images must show something of).
fn voxel_errors(asset: &Asset, reference: &Asset, frame: usize, lod: u32, shown: usize) -> Result<(Vec<ErrorStats>, u64), CompareError> {
    // Each channel at its stored level nearest `lod`: a coarse channel (a
    // velocity at twice the voxel size) is checked at its own voxels.
    let a = vdbcook_cook::unpack_near(asset, frame, Some(lod)).map_err(|e| CompareError::Other(e.into()))?;
    let r = vdbcook_cook::unpack_near(reference, frame, Some(lod)).map_err(|e| CompareError::Other(e.into()))?;
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

/// Compares level `lod` of the pair over `frames`; with a report, keeps the
/// three worst views, or only the `focus` view (frame, view) when one is given.
fn compare_level(p: &Pair, opts: &CompareOptions, lod: u32, frames: &[usize], focus: Option<(usize, usize)>, bars: &dyn Progress) -> Result<LevelRun, CompareError> {
    let (name, meta, ref_meta, renderer, scene) = (p.name, p.meta, p.ref_meta, p.renderer, p.scene);
    let started = Instant::now();
    let views = scene.orbit(opts.viewing.views.count());
    let (w, h) = (opts.viewing.size.width(), opts.viewing.size.height());
    // What each view shows with no volume, as 8-bit sRGB: coverage is measured against it.
    // Without the backdrop the empty scene is black: zeros, not computed.
    let empty: Vec<Vec<u8>> = match scene.has_backdrop() {
        true => views.iter().map(|v| crate::flip::srgb8(&scene.empty_image(v, w, h))).collect(),
        false => vec![vec![0; w as usize * h as usize * 3]; views.len()],
    };
    let shown = scene.shown();
    let shown_name = ref_meta.channels.get(shown).map_or(String::new(), |c| c.name.clone());

    let mut shots = Vec::new();
    let mut voxel = Vec::new();
    let mut kept: Vec<Kept> = Vec::new();
    let mut flip_secs = 0.0;
    let mut in_shader = false;
    bars.start("rendering", (frames.len() * views.len()) as u64);
    for &f in frames {
        // The voxel errors (one core) are found while the GPU renders (on a
        // CPU driver, the rendering leaves that core some time).
        // The frame's segments on the GPU (uploaded here, so that an upload's error names its asset).
        let (mut gpu_ref, mut gpu_asset) = (p.gpu_ref.borrow_mut(), p.gpu_asset.borrow_mut());
        gpu_ref.at(renderer, scene, f).map_err(|e| CompareError::In("reference".into(), e.into()))?;
        in_shader |= gpu_asset.at(renderer, scene, f).map_err(|e| CompareError::In(name.to_string(), e.into()))?.0.gpu.decodes_in_shader();
        let (vox, rendered) = std::thread::scope(|s| {
            let vox = s.spawn(|| voxel_errors(p.asset, p.reference, f, lod, shown));
            let draw = |r: &mut Resident| r.draw(renderer, scene, (f, lod), &views, (w, h));
            let rendered = draw(&mut gpu_ref).and_then(|refs| Ok((refs, draw(&mut gpu_asset)?)));
            (vox.join().unwrap_or_else(|e| std::panic::resume_unwind(e)), rendered)
        });
        let (errors, nonzero) = vox?;
        voxel.push((f, errors));
        let (refs, imgs) = rendered?;
        // FLIP and coverage run on the CPU, one view per thread, on the 8-bit
        // sRGB images (the reference's encoded once for both).
        let t = Instant::now();
        let measured: Vec<(FlipMap, f64)> = refs
            .par_iter()
            .zip(&imgs)
            .zip(&empty)
            .map(|((r, a), e)| {
                let r8 = crate::flip::srgb8(r);
                let map = crate::flip::flip_srgb8(&r8, &crate::flip::srgb8(a), w, h, DEFAULT_PPD)?;
                Ok((map, crate::scene::coverage_srgb8(&r8, e)))
            })
            .collect::<Result<_, crate::Error>>()?;
        flip_secs += t.elapsed().as_secs_f64();
        let coverage: Vec<f64> = measured.iter().map(|m| m.1).collect();
        // Two blank pictures are equal: a frame with something to show must show it somewhere.
        if nonzero > 0 && coverage.iter().all(|&c| c == 0.0) {
            return Err(CompareError::Failed(format!(
                "{name}: frame {f}{at}: the reference is blank in all {n} view(s), though channel \"{shown_name}\" ({model}) has {nonzero} active voxel(s) with non-zero values; name the channel that gives extinction with --extinction NAME, or try other --views or a larger --size",
                at = if lod > 0 { format!(" at level {lod}") } else { String::new() },
                n = views.len(),
                model = scene.model().name(),
            )));
        }
        for (vi, ((r, a), (map, coverage))) in refs.into_iter().zip(imgs).zip(measured).enumerate() {
            let shot = Shot { frame: f, view: vi, metrics: compare(&r, &a), flip: map.mean(), coverage };
            if opts.report.is_some() {
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
    // Over every segment (the merged metadata's planes are the first segment's).
    let in_asset = |e: vdbcook_vpak::Error| CompareError::In(name.to_string(), e.into());
    let format = p.asset.format_names().map_err(in_asset)?;
    let channel_formats = (0..meta.channels.len()).map(|c| p.asset.channel_format_names(c)).collect::<Result<Vec<_>, _>>().map_err(in_asset)?;
    let num = |v: f64| if v.is_finite() { json!(v) } else { serde_json::Value::Null };
    let doc = json!({
        "asset": name,
        "adapter": renderer.adapter,
        "bc_decode": if in_shader { "shader" } else { "texture" },
        "format": format,
        "channels": meta.channels.iter().map(|c| c.name.clone()).collect::<Vec<_>>(),
        "shown": meta.channels.get(shown).map(|c| c.name.clone()),
        "model": scene.model().name(),
        "frames": meta.frame_count,
        "level": lod,
        "views": opts.viewing.views,
        "size": [w, h],
        "flip_ppd": DEFAULT_PPD,
        "images": shots.iter().map(|s| json!({"frame": s.frame, "number": meta.frame_number(s.frame), "view": s.view, "rmse": s.metrics.rmse, "psnr": num(s.metrics.psnr), "max_error": s.metrics.max_error, "flip": s.flip, "coverage": s.coverage})).collect::<Vec<_>>(),
        "coverage": coverage_figures(&shots).map(|(min, mean)| json!({"min": min, "mean": mean})),
        "worst": worst.map(|s| json!({"frame": s.frame, "number": meta.frame_number(s.frame), "view": s.view, "rmse": s.metrics.rmse, "psnr": num(s.metrics.psnr), "flip": s.flip})),
        "worst_flip": worst_flip.map(|s| json!({"frame": s.frame, "number": meta.frame_number(s.frame), "view": s.view, "flip": s.flip})),
        "voxel": {
            "rmse": vox_total.rmse(), "psnr": num(vox_total.psnr(peak(shown))), "max_error": vox_total.max_abs,
            "frames": voxel.iter().map(|(f, e)| { let e = e.get(shown).copied().unwrap_or_default(); json!({"frame": f, "number": meta.frame_number(*f), "rmse": e.rmse(), "psnr": num(e.psnr(peak(shown))), "max_error": e.max_abs}) }).collect::<Vec<_>>(),
        },
        "voxel_channels": meta.channels.iter().zip(&channel_totals).enumerate().map(|(c, (ch, e))| json!({"name": ch.name, "format": channel_formats[c], "rmse": e.rmse(), "psnr": num(e.psnr(peak(c))), "max_error": e.max_abs})).collect::<Vec<_>>(),
        "gate": {"max_rmse": opts.gate.max_rmse, "min_psnr": opts.gate.min_psnr, "max_flip": opts.gate.max_flip},
        "levels": [{
            "level": lod,
            "worst": worst.map(|s| json!({"rmse": s.metrics.rmse, "psnr": num(s.metrics.psnr), "flip": s.flip})),
            "worst_flip": worst_flip.map(|s| json!({"flip": s.flip})),
            "voxel": {"rmse": vox_total.rmse(), "psnr": num(vox_total.psnr(peak(shown))), "max_error": vox_total.max_abs},
        }],
    });
    let failed: Vec<&Shot> = shots.iter().filter(|s| opts.gate.fails(s.metrics.rmse, s.metrics.psnr, s.flip)).collect();
    // A frame's source number beside its index, where they differ (fire_1007.vdb is frame 2 of a 1001-1010:3 cook).
    let source = |f: usize| match meta.frame_number(f) {
        n if n == f as i64 => String::new(),
        n => format!(" (source frame {n})"),
    };
    let decoder = if in_shader { ", BC decoded in the shader" } else { "" };
    let level = if lod > 0 { format!(" at level {lod}") } else { String::new() };
    let mut text = format!("{name}: {format} vs lossless reference{level}, {} frame(s) × {} view(s) at {w}×{h} on {}{decoder}\n", frames.len(), opts.viewing.views, renderer.adapter);
    text += &format!("  scene    channel \"{shown_name}\" drawn as {}", scene_words(scene.model()));
    if let Some((min, mean)) = coverage_figures(&shots) {
        text += &format!("; coverage {:.1} % of the pixels on average, {:.1} % in the emptiest view", 100.0 * mean, 100.0 * min);
    }
    text += "\n";
    if let Some(s) = worst {
        text += &format!(
            "  images   worst: frame {}{} view {}: rmse {:.3e}, psnr {:.1} dB, max {:.3e}, flip {:.4}\n",
            s.frame,
            source(s.frame),
            s.view,
            s.metrics.rmse,
            s.metrics.psnr,
            s.metrics.max_error,
            s.flip
        );
        let mean = |f: fn(&Shot) -> f64| shots.iter().map(f).sum::<f64>() / shots.len() as f64;
        text += &format!("           mean rmse {:.3e}, mean flip {:.4}\n", mean(|s| s.metrics.rmse), mean(|s| s.flip));
    }
    if let Some(s) = worst_flip {
        text += &format!("  flip     worst: frame {}{} view {}: flip {:.4} (at {DEFAULT_PPD} pixels per degree)\n", s.frame, source(s.frame), s.view, s.flip);
    }
    for (c, (ch, e)) in meta.channels.iter().zip(&channel_totals).enumerate() {
        let label = if meta.channels.len() == 1 { "voxels".to_string() } else { ch.name.clone() };
        text += &format!("  {label:<8} rmse {:.3e}, psnr {:.1} dB, max {:.3e}\n", e.rmse(), e.psnr(peak(c)), e.max_abs);
    }
    text += &format!("  time     {:.2} s to render and compare, FLIP {:.2} s of it\n", started.elapsed().as_secs_f64(), flip_secs);
    let gate_failure = failed.first().map(|s| {
        format!("{} image(s) over budget, first frame {}{} view {} (rmse {:.3e}, psnr {:.1} dB, flip {:.4})", failed.len(), s.frame, source(s.frame), s.view, s.metrics.rmse, s.metrics.psnr, s.flip)
    });
    let worst_shot = worst.copied();
    let worst = worst.zip(worst_flip).map(|(w, f)| Worst { rmse: w.metrics.rmse, psnr: w.metrics.psnr, flip: f.flip });
    Ok(LevelRun { figures: LevelFigures { lod, shots, worst_shot, worst, voxel: vox_total, gate_failure }, doc, text, kept })
}

/// The smallest and the mean coverage of the images, if any.
fn coverage_figures(shots: &[Shot]) -> Option<(f64, f64)> {
    let min = shots.iter().map(|s| s.coverage).reduce(f64::min)?;
    Some((min, shots.iter().map(|s| s.coverage).sum::<f64>() / shots.len() as f64))
}

/// How a model draws its channel, in the report's words.
fn scene_words(model: Model) -> &'static str {
    match model {
        Model::Scatter => "a scattering fog (scatter)",
        Model::Glow => "an absorbing, glowing medium before a backdrop (glow)",
        Model::Surface => "a lit surface at its zero crossing (surface)",
    }
}
