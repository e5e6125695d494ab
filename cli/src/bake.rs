//! `vdbcook bake`: every asset of a manifest, cooked (and validated) in
//! parallel through the same code as `cook` and `validate`, with a
//! content-addressed cache, shards, and one report. The plan, the keys and the
//! reports come from `vdbcook_bake`; this file does the I/O.

use crate::gpu::GpuArgs;
use crate::{exit, one_line, Usage};
use anyhow::{anyhow, Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;
use vdbcook_bake::parts::Unit;
use vdbcook_bake::place;
use vdbcook_bake::{bake_unit, join_parts, skipped_unit, whole_cached, AssetReport, Baker, KeyContext, Manifest, PlannedAsset, Report, Shard, Sources, Status};
use vdbcook_pipeline::inputs;

mod parts;
mod plan;
use plan::{dry_run, print_plan};

pub const AFTER_HELP: &str = "\
The manifest (TOML) has a [defaults] table and [[asset]] entries. Each entry has a
name, an output (relative to --out-dir) and inputs (files, directories, globs or frame
patterns, relative to the manifest), and any cook setting under its flag's name with
'_' for '-' (frames, grid, grids, with, allow_missing, format, quality, clusters, iterations,
variance_threshold, max_brick_error, max_texture_dim, lods, max_bytes, segment_frames, supercompress, optimize, fps, spill_above),
and a quality gate: validate
(true/false), max_rmse, min_psnr, max_flip, views, size. An entry's setting overrides
[defaults], which overrides the built-in default (the same as `vdbcook cook`'s).
`with` lists the other sequences of each frame's files (cook --with), relative to the
manifest like inputs; their files' bytes are part of the asset's key.

  [defaults]
  format = \"bc7\"
  validate = true
  max_rmse = 0.02

  [[asset]]
  name = \"smoke\"
  output = \"smoke.vpak\"
  inputs = [\"vdb/smoke_####.vdb\"]
  frames = \"1-120\"

  [[asset]]
  name = \"fire\"
  output = \"fire.vpak\"
  inputs = [\"blender/noise/fluid_noise_####.vdb\"]
  with = [\"blender/data/fluid_data_####.vdb\"]
  frames = \"1-120\"
  grids = \"density@0,flame,vel\"

Cache: an asset's key is an XXH3-128 hash of its input files' bytes, every setting,
vdbcook's version and the .vpak format version, and is recorded in the asset. An asset
whose output already carries its key (and whose checksums hold) is left in place; with
--cache DIR, one found there is copied; otherwise it is cooked, and stored in DIR.

Where a bake writes: every output stays inside --out-dir. An output that is absolute,
or that leaves --out-dir through '..' or a symbolic link (the longest existing part of
the path is resolved, the rest read as written), is a manifest error (exit 2, nothing
baked) unless --allow-outside is given. Outputs are written atomically; a file already
at an output path is replaced only when it is a .vpak (its header says so), else that
asset fails and the file is left as it is, unless --force. The same holds for cache
entries (DIR/KEY.vpak). --out-dir, --report-dir and --cache must be directories (or
not exist yet); report.json, report.xml and report.html replace only earlier bake
reports (unless --force), checked before anything is baked.

Reports: report.json (docs/bake-json.md; --json prints the same), report.xml (JUnit)
and report.html (sortable, self-contained, 1280 px wide: each channel's formats with
their share of its bricks, 256-pixel previews exposed from each volume) in
--report-dir, default --out-dir; each
validated asset's own page in validation/NAME/ there.

Scale-out: --shard I/N takes every N-th unit (round robin in manifest order), so N
CI jobs bake each asset once; `vdbcook bake --merge shard*/report.json` joins their
reports. `--plan --json` lists each asset's inputs, output and key, for build systems
that run `vdbcook bake bake.toml --only NAME` per asset (see docs/ci.md).

Parts: an asset with `parts = N` (an entry's key, with segment_frames, at most one part
per segment, and without validate) is N units, each the `cook --part I/N` part file
OUTPUT.partIofN, cached under its own key; the units of a manifest are its assets in
order, such an asset as N units in a row, so shards share its parts. A bake that bakes
every part (no --shard) joins them into OUTPUT (the part files then go; an asset already
in place or in the cache is not cooked again); shards each write their parts, and
`bake --merge` joins them, finding each part file relative to the report that lists it,
into --out-dir (default: the report directory). A missing part is a one-line error
naming the asset and the part, and nothing is written. The joined asset is byte for byte
the unsplit bake's, its key and record included.

Exit codes: 0 every asset baked or cached and every gate held; 1 an asset failed
(bad input, I/O); 3 only quality gates failed; 2 usage or manifest errors (nothing is
baked or written).";

#[derive(clap::Args)]
pub struct BakeArgs {
    /// The manifest (see below).
    #[arg(value_name = "bake.toml", required_unless_present = "merge")]
    pub manifest: Option<PathBuf>,
    /// Directory the manifest's outputs are relative to (default: the manifest's directory);
    /// with --merge, where the assets joined from parts go (default: --report-dir).
    #[arg(long, value_name = "DIR")]
    pub out_dir: Option<PathBuf>,
    /// Directory for report.json, report.xml, report.html and validation pages (default: --out-dir).
    #[arg(long, value_name = "DIR")]
    pub report_dir: Option<PathBuf>,
    /// Content-addressed cache: assets are looked up as DIR/KEY.vpak before cooking, and stored there after.
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Assets baked at once (default: the number of cores); each cook is parallel over --threads as well.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub jobs: Option<u32>,
    /// Bake only part I of N (from 1): the assets whose manifest position is I-1 modulo N.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<Shard>,
    /// Bake only these assets (repeat the flag or separate names with commas).
    #[arg(long, value_name = "NAME", value_delimiter = ',')]
    pub only: Vec<String>,
    /// Let outputs be absolute or leave --out-dir (through '..' or symbolic links).
    #[arg(long)]
    pub allow_outside: bool,
    /// Replace whatever is at an output path (or a report or cache file), not only a .vpak (or a report).
    #[arg(long)]
    pub force: bool,
    /// Check the manifest and the cache and say what would be baked; write nothing.
    #[arg(long)]
    pub dry_run: bool,
    /// Print each asset's inputs, output and cache key (with --json: as JSON); bake nothing.
    #[arg(long)]
    pub plan: bool,
    /// Print the report (or the plan, or the dry run) as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Stop starting new assets after the first failure (the rest are reported as skipped).
    #[arg(long)]
    pub fail_fast: bool,
    /// Join the report.json files of shards into one report (written to --report-dir, default "."),
    /// and the part files they list into their assets (see Parts below).
    #[arg(long, value_name = "REPORT.json", num_args = 1.., conflicts_with_all = ["manifest", "plan", "dry_run", "shard", "only", "cache", "fail_fast"])]
    pub merge: Vec<PathBuf>,
    #[command(flatten)]
    pub gpu: GpuArgs,
}

/// The version that cache keys include: vdbcook's own, unless the hidden
/// VDBCOOK_BAKE_TOOL_VERSION variable replaces it (tests use it to play a
/// newer release; see docs/bake-json.md).
fn tool_version() -> String {
    match std::env::var("VDBCOOK_BAKE_TOOL_VERSION") {
        Ok(v) if !v.is_empty() => format!("vdbcook {v}"),
        _ => concat!("vdbcook ", env!("CARGO_PKG_VERSION")).to_string(),
    }
}

/// The planner's view of the file system.
struct FsSources;

impl Sources for FsSources {
    fn expand(&self, inputs: &[String], frames: Option<vdbcook_bake::FrameRange>) -> Result<Vec<PathBuf>, String> {
        inputs::expand(inputs, frames).map_err(|e| one_line(&e.into()))
    }
    fn is_pattern(&self, input: &str) -> bool {
        inputs::is_pattern(input)
    }
    fn read(&self, path: &Path) -> std::io::Result<Option<Vec<u8>>> {
        match std::fs::read(path) {
            Ok(b) => Ok(Some(b)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(e),
        }
    }
}

pub fn run(args: BakeArgs, quiet: bool) -> Result<u8> {
    if !args.merge.is_empty() {
        return merge(&args, quiet);
    }
    let started = Instant::now();
    let manifest_path = args.manifest.clone().ok_or_else(|| Usage("a manifest (bake.toml) is needed".into()))?;
    let mname = manifest_path.display().to_string();
    let text = std::fs::read_to_string(&manifest_path).map_err(|e| Usage(format!("{mname}: {e}")))?;
    let base = manifest_path.parent().map(Path::to_path_buf).unwrap_or_default();
    let m = Manifest::parse(&text).map_err(|e| Usage(format!("{mname}:{}", e.located(&text))))?;
    let planned = vdbcook_bake::plan(&m, &base, &FsSources, &KeyContext::new(tool_version())).map_err(|e| Usage(format!("{mname}:{}", e.located(&text))))?;
    if let Some(n) = args.only.iter().find(|n| !planned.iter().any(|a| a.name == **n)) {
        let names: Vec<&str> = planned.iter().map(|a| a.name.as_str()).collect();
        return Err(Usage(format!("--only: no asset named \"{n}\" in {mname} (it has: {})", names.join(", "))).into());
    }
    let units = parts::choose(&planned, &args.only, args.shard);
    let selected: Vec<PlannedAsset> = planned.iter().enumerate().filter(|(i, _)| units.iter().any(|u| u.asset == *i)).map(|(_, a)| a.clone()).collect();
    let out_dir = args.out_dir.clone().unwrap_or_else(|| base.clone());
    let report_dir = args.report_dir.clone().unwrap_or_else(|| out_dir.clone());
    if !args.allow_outside {
        place::check_outputs(&m, &selected, &out_dir).map_err(|e| Usage(format!("{mname}:{}", e.located(&text))))?;
    }
    if args.plan {
        return print_plan(&args, &mname, &out_dir, &planned, &units, quiet);
    }
    preflight(&args, &out_dir, &report_dir)?;
    let joins = parts::complete(&planned, &units);
    if args.dry_run {
        return dry_run(&args, &out_dir, &planned, &units, &joins, quiet);
    }

    let gpu = args.gpu.clone();
    let ctx = Baker::new(out_dir, report_dir.clone(), args.cache.clone(), base, args.force, move || gpu.renderer().map_err(Into::into));
    // An asset this run joins that is already in place (or in the cache) is one unit: no part is cooked.
    let whole: Vec<usize> = joins.iter().copied().filter(|&i| whole_cached(&planned[i], &ctx)).collect();
    let mut work: Vec<Unit> = units.iter().copied().filter(|u| !whole.contains(&u.asset)).collect();
    work.extend(whole.iter().map(|&asset| Unit { asset, part: None }));
    work.sort_by_key(|u| (u.asset, u.part.map_or(0, |p| p.index)));
    let jobs = args.jobs.map_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()), |j| j as usize).clamp(1, work.len().max(1));
    let show = Shown::new(quiet || args.json, work.len());
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let results: Mutex<Vec<AssetReport>> = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..jobs {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(u) = work.get(i) else { break };
                let a = &planned[u.asset];
                let r = if stop.load(Ordering::SeqCst) { skipped_unit(a, u.part) } else { bake_unit(a, u.part, &ctx) };
                if args.fail_fast && r.status == Status::Failed {
                    stop.store(true, Ordering::SeqCst);
                }
                show.finished(&r);
                if let Ok(mut v) = results.lock() {
                    v.push(r);
                }
            });
        }
    });
    show.done();
    let mut assets = results.into_inner().map_err(|_| anyhow!("a bake worker panicked"))?;
    // The assets whose every part this run baked are joined (after every part, as a merge would).
    for &i in joins.iter().filter(|i| !whole.contains(i)) {
        let (mine, rest): (Vec<AssetReport>, Vec<AssetReport>) = assets.into_iter().partition(|r| r.index == planned[i].index && r.part.is_some());
        let mut mine = mine;
        mine.sort_by_key(AssetReport::order);
        let joined = join_parts(&planned[i], &mine.iter().collect::<Vec<_>>(), &ctx);
        show.finished(&joined);
        assets = rest;
        assets.push(joined);
    }
    let report = Report::new(tool_version(), mname, args.shard, assets, started.elapsed().as_secs_f64());
    write_reports(&report_dir, &report)?;
    finish(&report, &report_dir, args.json, quiet)
}

const REPORT_FILES: [&str; 3] = ["report.json", "report.xml", "report.html"];

/// Before anything is baked: the directories the bake writes into are
/// directories (or do not exist yet), and the report files there are earlier
/// bake reports (or absent, or --force): a usage error otherwise.
fn preflight(args: &BakeArgs, out_dir: &Path, report_dir: &Path) -> Result<()> {
    place::check_dir(out_dir, "--out-dir").map_err(Usage)?;
    place::check_dir(report_dir, "--report-dir").map_err(Usage)?;
    if let Some(c) = &args.cache {
        place::check_dir(c, "--cache").map_err(Usage)?;
    }
    check_reports(report_dir, args.force)
}

fn check_reports(dir: &Path, force: bool) -> Result<()> {
    for f in REPORT_FILES {
        place::may_replace_report(&dir.join(f), force).map_err(Usage)?;
    }
    Ok(())
}

/// Writes report.json, report.xml and report.html into `dir`, each atomically.
fn write_reports(dir: &Path, report: &Report) -> Result<()> {
    let d = dir.display().to_string();
    std::fs::create_dir_all(dir).with_context(|| d.clone())?;
    for (file, text) in [("report.json", report.to_json()), ("report.xml", report.to_junit()), ("report.html", report.to_html())] {
        let p = dir.join(file);
        vdbcook_vpak::write_atomic(&p, text.as_bytes(), true).with_context(|| p.display().to_string())?;
    }
    Ok(())
}

/// Prints the outcome (failures on stderr, the summary or the JSON on stdout); the exit code.
fn finish(report: &Report, report_dir: &Path, as_json: bool, quiet: bool) -> Result<u8> {
    for a in &report.assets {
        match a.status {
            Status::Failed => eprintln!("vdbcook: error: asset {}: {}", a.name, a.message.as_deref().unwrap_or("failed")),
            Status::GateFailed => eprintln!("vdbcook: quality gate failed: asset {}: {}", a.name, a.message.as_deref().unwrap_or("")),
            _ => {}
        }
    }
    if !quiet {
        let s = &report.summary;
        let text = if as_json {
            report.to_json()
        } else {
            format!(
                "{}: {} asset{} in {:.1} s: {} baked, {} cached, {} failed, {} failed a quality gate, {} skipped\n  report  {}\n",
                report.manifest,
                s.assets,
                if s.assets == 1 { "" } else { "s" },
                report.seconds,
                s.baked,
                s.cached,
                s.failed,
                s.gate_failed,
                s.skipped,
                report_dir.join("report.html").display()
            )
        };
        crate::emit_final(&text)?;
    }
    let s = &report.summary;
    Ok(if s.failed + s.skipped > 0 {
        exit::FAILURE
    } else if s.gate_failed > 0 {
        exit::QUALITY_GATE
    } else {
        exit::SUCCESS
    })
}

fn merge(args: &BakeArgs, quiet: bool) -> Result<u8> {
    let mut parts = Vec::new();
    for p in &args.merge {
        let name = p.display().to_string();
        let text = std::fs::read_to_string(p).map_err(|e| Usage(format!("{name}: {e}")))?;
        let mut r = Report::from_json(&name, &text).map_err(|e| Usage(e.to_string()))?;
        // A shard's part files are in its output directory: where its report is, unless it was given --report-dir.
        let dir = p.parent().unwrap_or(Path::new(""));
        for pr in r.assets.iter_mut().filter_map(|a| a.part.as_mut()) {
            pr.file = dir.join(&pr.file).display().to_string();
        }
        parts.push((name.clone(), r));
    }
    let mut report = Report::merge(parts).map_err(|e| Usage(e.to_string()))?;
    let dir = args.report_dir.clone().or_else(|| args.out_dir.clone()).unwrap_or_else(|| PathBuf::from("."));
    let out_dir = args.out_dir.clone().unwrap_or_else(|| dir.clone());
    place::check_dir(&dir, "--report-dir").map_err(Usage)?;
    place::check_dir(&out_dir, "--out-dir").map_err(Usage)?;
    check_reports(&dir, args.force)?;
    parts::join_merged(&mut report, &out_dir, args.allow_outside, args.force, &args.gpu)?;
    write_reports(&dir, &report)?;
    finish(&report, &dir, args.json, quiet)
}

/// Progress on a terminal: one overall bar and a line per finished asset.
struct Shown {
    bar: Option<ProgressBar>,
}

impl Shown {
    fn new(hidden: bool, total: usize) -> Shown {
        let visible = !hidden && std::io::stderr().is_terminal() && std::io::stdout().is_terminal();
        let bar = visible.then(|| {
            let bar = ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
            let style = ProgressStyle::with_template("{prefix:>15} [{bar:30}] {pos}/{len} {elapsed_precise} (eta {eta})").unwrap_or_else(|_| ProgressStyle::default_bar());
            bar.set_style(style.progress_chars("=> "));
            bar.set_prefix("baking");
            bar
        });
        Shown { bar }
    }

    fn finished(&self, r: &AssetReport) {
        if let Some(bar) = &self.bar {
            let size = r.bytes.map(vdbcook_bake::report::human_bytes).unwrap_or_default();
            bar.println(format!("{:>12} {} {} ({:.1} s)", r.status.name(), r.label(), size, r.seconds));
            bar.inc(1);
        }
    }

    fn done(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}
