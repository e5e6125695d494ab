//! `vdbcook cook`: a VDB sequence into one .vpak asset.

use crate::gpu::GpuArgs;
use crate::progress::Bars;
use crate::{exit, Usage};
use anyhow::{Context, Result};
use std::path::PathBuf;
use std::time::Instant;
use vdbcook_pipeline::options::CookSettings;
use vdbcook_pipeline::summary::{json_text, summary_json, summary_text};
use vdbcook_pipeline::{auto::search, cook_asset, inputs, CookJob, SettingError, Sources};

pub const AFTER_HELP: &str = "\
INPUT is a .vdb file, a directory (every .vdb inside), a glob (\"smoke_*.vdb\") or a
frame pattern (smoke_####.vdb, smoke_%04d.vdb, smoke_$F4.vdb) expanded over --frames.
Several files are one animation; files, directories and globs are taken in natural
order (frame_2 before frame_10), pattern frames in --frames order.

Several files per frame (--with, repeatable): each --with INPUT is another sequence whose
files give every frame more grids, e.g. Blender's smoke with noise:
  vdbcook cook noise/fluid_noise_####.vdb --frames 1-120 \\
      --with data/fluid_data_####.vdb --grids density@0,flame,vel -o fire.vpak
INPUT's frames are the asset's; a --with sequence's files are matched to them by the
number in their names (fluid_data_0007.vdb with fluid_noise_0007.vdb), or by position
when the names carry none (the counts must then be equal). A frame a --with sequence
has no file for is an error (exit 1); with --allow-missing that sequence's channels are
empty there. Each name of --grids (or --grid) is found in whichever file of the frame has
it; a name in several files is a usage error (exit 2) unless NAME@N says which: sequence
N, 0 for INPUT, 1 for the first --with, and so on. The channel keeps the grid's name
(density@1 is the channel density). --grids all takes every grid of every file and
refuses a name found in two. The frame's grids, from all its files, are cooked as one
frame. Every file read is recorded in the asset's sources and the
--with inputs in its settings: validate finds them again, and --part, --auto and
--validate read the same files.

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

Grids at their own voxel size (Houdini's vel at a velocity voxel scale of 2, Blender's
data cache beside its finer noise cache): a grid whose voxels are 2, 4 or 8 times the
finest grid's, offset from them by a whole or half voxel, is stored at the level of
detail whose voxels are its own (not multiplied up: an eighth of the bytes per factor
of 2), and --lods N gives it N levels from there. The asset's transform is the finest
grid's; unpack writes each channel on its own. Other ratios, rotations and offsets are
a usage error (exit 2) naming both grids and their voxel sizes.

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

--segment-frames N cuts the flip-book into segments of N frames, each with its own
bricks, atlases, ranges and tables, contiguous in the file (format version 7): a player
needs one segment at a time, and the cook holds one segment's bricks at a time (its
memory follows N, not the sequence's length). Deduplication and --clusters (K centroids
per segment) work within a segment; the summary gives each segment's bytes and bricks.
--part I/N then cooks only the I-th of N contiguous groups of segments into a part file,
and `vdbcook join PART... -o OUT.vpak` joins the parts (in order) into the asset that
one cook writes, byte for byte: one sequence on several machines (docs/ci.md).

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
// The comparison's flags (Viewing, Gate) mean nothing without a comparison.
#[command(group(clap::ArgGroup::new("comparison").args(["extinction", "views", "size", "max_rmse", "min_psnr", "max_flip"]).multiple(true).requires("checks")))]
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
    #[arg(long, conflicts_with_all = ["format", "max_error", "max_bytes"], help_heading = "Options")]
    pub auto: bool,
    /// Cook only the I-th of N contiguous groups of segments (of --segment-frames) into a
    /// part file OUT, e.g. --part 2/4 on the second of four machines; `vdbcook join` joins
    /// the parts into the asset, byte for byte what one cook writes. Not with --validate,
    /// --auto or --max-bytes (they decide over the whole asset: validate the joined one).
    #[arg(long, value_name = "I/N", requires = "segment_frames", conflicts_with_all = ["validate", "auto", "max_bytes"], help_heading = "Options")]
    pub part: Option<vdbcook_pipeline::cook::Part>,
    /// Replace OUT if it exists.
    #[arg(long, help_heading = "Options")]
    pub force: bool,
    /// Print the summary as JSON on stdout.
    #[arg(long, help_heading = "Options")]
    pub json: bool,
}

pub fn run(args: CookArgs, quiet: bool) -> Result<u8> {
    crate::refuse_existing(&args.output, args.force)?;
    let s = &args.settings;
    if let Err(SettingError { name, message }) = s.check() {
        return Err(Usage(format!("--{} {message}", name.replace('_', "-"))).into());
    }
    if args.auto && !s.gate.is_set() {
        return Err(Usage("--auto needs a quality gate: --min-psnr, --max-rmse or --max-flip".into()).into());
    }
    let files = inputs::expand_main(&args.inputs, &s.with, s.frames)?;
    let started = Instant::now();
    let bars = Bars::new(quiet);
    if args.auto {
        return auto(&args, files, started, &bars, quiet);
    }
    let mut cooked = cook_asset(CookJob { settings: s, files, inputs: &args.inputs, base: None, reference: false, output: Some((&args.output, args.force)), part: args.part }, &bars)?;
    cooked.commit().with_context(|| args.output.display().to_string())?;
    let report = &mut cooked.report;
    report.timings.push(("total".into(), started.elapsed().as_secs_f64()));
    let validation = if s.validate {
        let sources = Sources::Inputs { inputs: args.inputs.clone(), with: s.with.clone(), frames: s.frames };
        Some(vdbcook_pipeline::validate_file(&args.output, sources, &s.compare_options(None), || GpuArgs::default().renderer().map(Box::new), &Bars::new(quiet || args.json))?)
    } else {
        None
    };
    if !quiet {
        let mut text = if args.json {
            json_text(&summary_json(&args.output, cooked.grid.as_deref(), report, validation.as_ref().map(|o| &o.doc)))
        } else {
            summary_text(&args.output, cooked.grid.as_deref(), report)
        };
        if let (Some(o), false) = (&validation, args.json) {
            text += &o.text;
        }
        crate::emit_final(&text)?;
    }
    Ok(validation.map_or(exit::SUCCESS, |o| crate::gate_exit(&o.gate_failure)))
}

/// `--auto`: the search, then the chosen format written (or nothing, exit 3).
fn auto(args: &CookArgs, files: Vec<PathBuf>, started: Instant, bars: &Bars, quiet: bool) -> Result<u8> {
    let s = &args.settings;
    // The GPU first: without one, no cooking time is spent for nothing.
    let renderer = GpuArgs::default().renderer()?;
    let name = args.output.display().to_string();
    let job = CookJob { settings: s, files, inputs: &args.inputs, base: None, reference: true, output: Some((&args.output, args.force)), part: None };
    let mut found = search(job, &s.compare_options(None), &name, &renderer, bars)?;
    let (doc, table) = (found.doc(), found.table());
    let Some(i) = found.chosen else {
        if !quiet {
            let text = if args.json { json_text(&serde_json::json!({"output": name, "auto": doc})) } else { table };
            crate::emit_final(&text)?;
        }
        return Ok(crate::gate_exit(&found.failure()));
    };
    let c = &mut found.candidates[i];
    c.cooked.commit().with_context(|| name.clone())?;
    let report = &mut c.cooked.report;
    report.timings.push(("total".into(), started.elapsed().as_secs_f64()));
    let o = c.outcome.as_ref().ok_or_else(|| anyhow::anyhow!("no validation"))?;
    if !quiet {
        let text = if args.json {
            let mut v = summary_json(&args.output, c.cooked.grid.as_deref(), &c.cooked.report, Some(&o.doc));
            if let Some(m) = v.as_object_mut() {
                m.insert("auto".into(), doc);
            }
            json_text(&v)
        } else {
            summary_text(&args.output, c.cooked.grid.as_deref(), &c.cooked.report) + &o.text + &table
        };
        crate::emit_final(&text)?;
    }
    Ok(exit::SUCCESS)
}
