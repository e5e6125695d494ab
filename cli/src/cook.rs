//! `vdbcook cook`: a VDB sequence into one .vpak asset.

use crate::grids::{read_frame, Channels, Frame, GridSelection};
use crate::inputs;
use crate::progress::Bars;
use crate::validate::ValidateArgs;
use crate::{exit, report_error, Usage};
use anyhow::{anyhow, Context, Result};
use std::path::PathBuf;
use std::time::Instant;
use vdbcook_bake::CookSettings;
use vdbcook_cook::{ChannelReport, CookOptions, CookReport, Cooker, Figure, Format, Progress};
use vdbcook_vpak::SourceFile;

pub const AFTER_HELP: &str = "\
INPUT is a .vdb file, a directory (every .vdb inside), a glob (\"smoke_*.vdb\") or a
frame pattern (smoke_####.vdb, smoke_%04d.vdb, smoke_$F4.vdb) expanded over --frames.
Several files are one animation; files, directories and globs are taken in natural
order (frame_2 before frame_10), pattern frames in --frames order.

Formats (storage per voxel and channel in the brick atlas):
  f32     32 bits  exact
  f16     16 bits  IEEE half (default)
  unorm16 16 bits  16-bit levels over each brick's own [min, max] (error range / 131070,
                   where f16's grows with the value; NanoVDB's Fp16)
  unorm8   8 bits  8-bit levels over each brick's own [min, max]
  bc4      4 bits  BC4 block compression of those levels, one z-slice per texture slice
  bc7      2 bits  BC7: RGBA lanes hold channels x z-slices (one channel: four z-slices)

Several grids (--grids density,temperature,flames or --grids all) are channels of one
tree per frame over the union of their active voxels; a vec3 grid (velocity) gives
three channels NAME.x, NAME.y, NAME.z. Each channel gets a texture of its own, which
stores only its own distinct bricks. --group CHANNELS=FORMAT (repeatable) packs
channels into shared textures in a format of their own: f32/f16/unorm8 up to four
channels in one RG/RGBA texture; bc7 two channels at two z-slices each per texel, or
four in RGBA, which lowers the error of correlated channels (density and temperature;
temperature and flames); bc4 stays one texture per channel.

--max-error E chooses the format brick by brick instead of --format: every brick of
every channel is stored in the cheapest of constant (no texels), bc7, bc4, unorm8,
unorm16, f16 and f32 whose voxels all decode within E (absolute, in the grid's units)
of the source, counting the voxels readers see (active in some channel); a voxel that
is NaN or +-inf must decode to itself, so its brick is f16 or f32. A channel's bricks
then sit in one texture per format chosen, and a table per channel says which holds
each brick. With --clusters, a merged brick whose centroid decodes further than E from
it is stored on its own. The summary gives bricks and bytes per format.

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

--lods N adds levels of detail 1 to N-1 to every frame: level k has voxels 2^k source
voxels wide, each the mean of its 2x2x2 children (level sets: of the active ones), in
trees over the same brick pool. --max-bytes B keeps the finest levels whose asset fits
in B bytes: when the whole asset is larger, it is cooked again without level 0 (and the
bricks only level 0 used), then without level 1, and so on; the coarsest level always
stays. The asset then starts at its first kept level (render, unpack and validate read
that one by default); the summary names the levels left out and each size tried. When
even the coarsest level alone is larger than B, nothing is written and the cook exits
with 1, naming that smallest size. Without --lods, --max-bytes only checks the size.

--validate renders the new asset against its sources on the GPU afterwards (see
`vdbcook validate --help`); with --max-rmse / --min-psnr / --max-flip a failed gate
exits with 3. With --lods N (N > 1) every level is checked against the source filtered
to it, as `validate --every-lod` does: the gate holds at every level, and the summary
(and `validation.levels` in the JSON) gives each level's figures.

--auto searches the formats for the smallest asset that meets the gate (at least one
of --min-psnr, --max-rmse, --max-flip; --format is not allowed). The frames are read
once; bc7, bc4, unorm8, f16 and f32 are each cooked in memory at the other settings
(--quality, --grids, --group, --clusters...; a --group keeps its own format), and
validated as --validate would, smallest file first, until one's images all meet the
gate: that one is written, byte for byte what --format would write, and a table gives
each format's bytes, worst image PSNR, RMSE and FLIP, and pass, fail or not tried.
When none meets it, nothing is written, the exit code is 3 and the error names the
best reached: the lowest worst-image RMSE (highest PSNR), or the lowest worst FLIP
when --max-flip is the only gate. f32 renders exactly unless clustered, so without
--clusters (or a --group) the search always ends by f32 at the latest.";

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("checks").args(["validate", "auto"]).multiple(true)))]
pub struct CookArgs {
    /// Frame files, directories, globs or frame patterns.
    #[arg(required = true, value_name = "INPUT")]
    pub inputs: Vec<String>,
    /// The asset to write.
    #[arg(short, long, value_name = "OUT.vpak")]
    pub output: PathBuf,
    /// Every cook setting (the keys of a bake manifest, too).
    #[command(flatten)]
    pub settings: CookSettings,
    /// Cook every format (bc7, bc4, unorm8, f16, f32) at the other settings, validate them
    /// smallest file first and write the first whose images meet the gate (--min-psnr,
    /// --max-rmse and/or --max-flip: at least one is required). Implies --validate; not with
    /// --format, --max-error or --max-bytes.
    #[arg(long, conflicts_with_all = ["format", "max_error", "max_bytes"])]
    pub auto: bool,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Reads `files` on a thread that stays one frame ahead (at most two source
/// frames live at once) and pushes each frame into one cooker per entry of
/// `opts` (an asset and its lossless reference share one read), made for the
/// channels the first frame with a file resolves. Source paths are recorded
/// relative to `base` when they are below it. Returns the cookers, their
/// channels and the seconds spent waiting for frames.
pub fn feed(opts: Vec<CookOptions>, files: Vec<PathBuf>, sel: GridSelection, allow_missing: bool, base: Option<PathBuf>, bars: &dyn Progress) -> Result<(Vec<Cooker>, Option<Channels>, f64)> {
    // Each frame comes with the channels when they are first resolved.
    let (tx, rx) = std::sync::mpsc::sync_channel::<(Result<Frame>, Option<Channels>)>(0);
    let total = files.len() as u64;
    let reader = std::thread::spawn(move || {
        let mut channels = None;
        let mut sent = false;
        for f in files {
            let r = read_frame(f, &sel, &mut channels, allow_missing).map(|mut frame| {
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
    });
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
    reader.join().map_err(|_| anyhow!("the frame reader thread panicked"))?;
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
pub fn cook_lossless_levels(files: Vec<PathBuf>, sel: GridSelection, allow_missing: bool, levels: u32, bars: &Bars) -> Result<vdbcook_vpak::Asset> {
    let (cookers, _, _) = feed(vec![CookOptions { levels, ..reference_options() }], files, sel, allow_missing, None, bars)?;
    let cooker = cookers.into_iter().next().ok_or_else(|| anyhow!("no cooker"))?;
    finish_reference(cooker)
}

fn reference_options() -> CookOptions {
    CookOptions { format: Format::F32, clustering: None, ..CookOptions::default() }
}

fn finish_reference(cooker: Cooker) -> Result<vdbcook_vpak::Asset> {
    let (sections, _) = cooker.finish(&vdbcook_cook::NoProgress).map_err(|e| anyhow!(e))?;
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
    cook_formats(job, &[format], bars)?.into_iter().next().ok_or_else(|| anyhow!("no cooker"))
}

/// Cooks the asset once per format of `formats` (every other setting as
/// given) from one read of the frames, in the order given; the reference, when
/// asked for, comes with the first.
pub fn cook_formats(job: CookJob, formats: &[Format], bars: &dyn Progress) -> Result<Vec<Cooked>> {
    let s = job.settings;
    let mut all: Vec<CookOptions> = formats
        .iter()
        .map(|&format| {
            let fs = CookSettings { format, ..s.clone() };
            CookOptions {
                format,
                groups: s.group.clone(),
                quality: s.quality,
                max_texture_dim: s.max_texture_dim,
                clustering: s.clustering(),
                max_error: s.max_error,
                settings: fs.recorded(job.inputs),
                levels: s.lods,
                max_bytes: s.max_bytes.map(|b| b.0),
            }
        })
        .collect();
    if job.reference {
        // As many levels as the asset: its validation checks each.
        all.push(CookOptions { levels: s.lods, ..reference_options() });
    }
    let sel = GridSelection::from_flags(s.grid.as_deref(), s.grids.as_deref());
    let (cookers, channels, read_secs) = feed(all, job.files, sel, s.allow_missing, job.base, bars)?;
    let grid_name = channels.as_ref().map(|c| c.specs.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", "));
    let mut cookers = cookers.into_iter();
    let mut out = Vec::new();
    for cooker in cookers.by_ref().take(formats.len()) {
        if cooker.frame_count() == 0 {
            return Err(anyhow!("no frames to cook"));
        }
        // A group naming no channel, or too many channels to cluster, is the settings' fault.
        let (sections, mut report) = cooker.finish(bars).map_err(|e| if e.is_settings_error() { Usage(e.to_string()).into() } else { anyhow!(e) })?;
        report.timings.insert(0, ("read".into(), read_secs));
        out.push(Cooked { sections, report, grid: grid_name.clone(), reference: None });
    }
    let reference = cookers.next().map(finish_reference).transpose().context("cooking the reference")?;
    if let Some(first) = out.first_mut() {
        first.reference = reference;
    }
    Ok(out)
}

pub fn run(args: CookArgs, quiet: bool) -> Result<u8> {
    crate::refuse_existing(&args.output, args.force)?;
    let s = &args.settings;
    if let Err(vdbcook_bake::Error::Setting { name, message }) = s.check() {
        return Err(Usage(format!("--{} {message}", name.replace('_', "-"))).into());
    }
    if args.auto {
        crate::auto::check(&args)?;
    }
    let files = inputs::expand(&args.inputs, s.frames)?;
    let started = Instant::now();
    let bars = Bars::new(quiet);
    if args.auto {
        return crate::auto::run(&args, files, started, &bars, quiet);
    }
    let mut cooked = cook_asset(CookJob { settings: s, files, inputs: &args.inputs, base: None, reference: false }, &bars)?;
    let report = &mut cooked.report;
    let t0 = Instant::now();
    vdbcook_vpak::write_file(&args.output, &cooked.sections, args.force).with_context(|| args.output.display().to_string())?;
    report.timings.push(("write".into(), t0.elapsed().as_secs_f64()));
    report.timings.push(("total".into(), started.elapsed().as_secs_f64()));
    let validation = if s.validate {
        let v = ValidateArgs::of_cook(s, args.output.clone(), args.inputs.clone(), None, Default::default(), args.json);
        Some(crate::validate::evaluate(v, quiet)?)
    } else {
        None
    };
    if !quiet {
        let mut text =
            if args.json { json_text(&summary_json(&args, cooked.grid.as_deref(), report, validation.as_ref().map(|o| &o.doc))) } else { summary_text(&args, cooked.grid.as_deref(), report) };
        if let (Some(o), false) = (&validation, args.json) {
            text += &o.text;
        }
        crate::emit_final(&text)?;
    }
    Ok(validation.map_or(exit::SUCCESS, |o| crate::validate::gate(&o.gate_failure)))
}

pub fn mb(b: u64) -> String {
    format!("{:.2} MB", b as f64 / 1e6)
}

pub fn summary_text(args: &CookArgs, grid: Option<&str>, r: &CookReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let what = if r.channels.len() == 1 { format!("grid \"{}\"", grid.unwrap_or("")) } else { format!("{} channels", r.channels.len()) };
    let _ = writeln!(s, "cooked {} frame{} of {what} into {} ({}, {})", r.frames, if r.frames == 1 { "" } else { "s" }, args.output.display(), r.format, mb(r.file_bytes));
    let _ = writeln!(s, "  active voxels   {} ({:.3} bits per active voxel)", r.active_voxels, r.bits_per_active_voxel);
    let _ = writeln!(s, "  bricks          {} leaves -> {} unique -> {} stored in {} texture{}", r.bricks, r.unique_bricks, r.stored_bricks, r.textures, if r.textures == 1 { "" } else { "s" });
    let _ = writeln!(s, "  nodes           L1 {}, L2 {}, L3 {}, tiles {}; tree {} (thesis layout: {})", r.l1_nodes, r.l2_nodes, r.l3_nodes, r.tiles, mb(r.tree_bytes), mb(r.thesis_tree_bytes));
    if r.channels.len() == 1 {
        let _ = writeln!(s, "  voxel error     rmse {:.3e}, psnr {:.1} dB, max {:.3e}", r.voxel_rmse, r.voxel_psnr, r.voxel_max_error);
    } else {
        for c in &r.channels {
            let _ = writeln!(
                s,
                "  {:<16}{:<7} {:>10} ({} brick{}), values [{:.4}, {:.4}], rmse {:.3e}, psnr {:.1} dB, max {:.3e}",
                c.name,
                c.format,
                mb(c.bytes),
                c.bricks,
                if c.bricks == 1 { "" } else { "s" },
                c.value_range[0],
                c.value_range[1],
                c.voxel_rmse,
                c.voxel_psnr,
                c.voxel_max_error
            );
        }
    }
    // Per-brick formats: what each format holds.
    for c in r.channels.iter().filter(|c| c.formats.len() > 1) {
        let f: Vec<String> = c.formats.iter().map(|f| format!("{} {} ({})", f.format.name(), f.bricks, mb(f.bytes))).collect();
        let who = if r.channels.len() > 1 { format!("{}: ", c.name) } else { String::new() };
        let _ = writeln!(s, "  brick formats   {who}{}", f.join(", "));
    }
    for c in &r.channels {
        if let Some(t) = non_finite_text(c, r.channels.len() > 1) {
            let _ = writeln!(s, "  non-finite      {t}");
        }
    }
    if let Some(b) = &r.budget {
        let tries: Vec<String> = b.tries.iter().map(|t| format!("from level {}: {}", t.first_level, mb(t.bytes))).collect();
        let last = r.first_level as usize + r.levels.len();
        let kept = if r.levels.is_empty() { format!("level {last} kept") } else { format!("levels {} to {last} kept", r.first_level) };
        let dropped = match b.dropped.as_slice() {
            [] => String::new(),
            [k] => format!(", level {k} left out"),
            [a, .., z] => format!(", levels {a} to {z} left out"),
        };
        let figures = if r.first_level > 0 { format!("; the error figures above are level {}'s", r.first_level) } else { String::new() };
        let _ = writeln!(s, "  byte budget     {}: {kept}{dropped} ({}){figures}", mb(b.max_bytes), tries.join(", "));
    }
    if !r.levels.is_empty() {
        let per: Vec<String> = r.levels.iter().map(|l| format!("{} ({}x: {} leaves, rmse {:.3e})", l.level, l.voxel_scale, l.leaves, l.voxel_rmse)).collect();
        let _ = writeln!(s, "  levels          {}", per.join(", "));
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

/// What happened to a channel's NaN and ±inf source voxels, if it had any.
fn non_finite_text(c: &ChannelReport, name: bool) -> Option<String> {
    let n = c.non_finite;
    if n.total() == 0 {
        return None;
    }
    let kinds: Vec<String> = [(n.nan, "NaN"), (n.pos_inf, "+inf"), (n.neg_inf, "-inf")].iter().filter(|(k, _)| *k > 0).map(|(k, what)| format!("{k} {what}")).collect();
    // Per-brick formats store bricks with non-finite voxels in f16 or f32, which keep them.
    let stored = if c.formats.iter().all(|f| f.format.is_ranged()) { format!("{} stores each as the mean of its finite neighbours", c.format) } else { format!("{} keeps them", c.format) };
    let who = if name { format!("{}: ", c.name) } else { String::new() };
    Some(format!("{who}{} source voxel{} ({}) left out of the error figures; {stored}", n.total(), if n.total() == 1 { "" } else { "s" }, kinds.join(", ")))
}

/// Pretty JSON and a newline.
pub fn json_text(v: &serde_json::Value) -> String {
    format!("{}\n", serde_json::to_string_pretty(v).unwrap_or_default())
}

pub fn summary_json(args: &CookArgs, grid: Option<&str>, r: &CookReport, validation: Option<&serde_json::Value>) -> serde_json::Value {
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
            serde_json::json!(r.frame_errors.iter().enumerate().map(|(i, (rmse, max))| serde_json::json!({"frame": i, "rmse": Figure(*rmse), "max_error": Figure(*max)})).collect::<Vec<_>>()),
        );
    }
    v
}

/// Reports a failure; the exit code. A closed stdout is not one.
pub fn fail(e: &anyhow::Error) -> u8 {
    if e.is::<crate::PipeClosed>() {
        return exit::SUCCESS;
    }
    report_error(e);
    if e.downcast_ref::<Usage>().is_some() || e.downcast_ref::<vdbcook_validate::CompareError>().is_some_and(vdbcook_validate::CompareError::is_usage) {
        exit::USAGE
    } else {
        exit::FAILURE
    }
}
