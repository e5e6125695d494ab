//! The `vdbcook` binary: flags in, library calls, human or JSON text out.

mod bake;
mod cook;
mod diff;
mod gpu;
mod inspect;
mod join;
mod play;
mod progress;
mod recompress;
mod unpack;
mod validate;
mod view;

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

/// Running out of memory is one line and exit code 1, not an abort.
#[global_allocator]
static ALLOCATOR: vdbcook_grid::mem::ReportingAllocator = vdbcook_grid::mem::ReportingAllocator { program: "vdbcook" };

/// Exit codes (documented in the README and in --help).
pub mod exit {
    pub const SUCCESS: u8 = 0;
    /// Unreadable or invalid input, I/O failure.
    pub const FAILURE: u8 = 1;
    /// Bad command line (clap exits with 2 itself).
    pub const USAGE: u8 = 2;
    /// A quality gate (`validate --max-rmse` / `--min-psnr` / `--max-flip`) failed.
    pub const QUALITY_GATE: u8 = 3;
}

const AFTER_HELP: &str = "\
Exit codes:
  0  success
  1  failure: unreadable or invalid input, I/O error (a failed write to stdout too;
     a closed pipe just ends the output), or an asset of a bake failed to cook
  2  usage error (bad flags or arguments, an invalid bake manifest: nothing done)
  3  quality gate failed (validate / cook --validate / bake with max_rmse, min_psnr or
     max_flip; cook --auto: no format met the gate), and nothing else did";

#[derive(Parser)]
#[command(name = "vdbcook", version, about = "Cook OpenVDB volume sequences into compact GPU-ready assets", after_help = AFTER_HELP)]
struct Cli {
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(short = 'j', long, global = true, value_name = "N")]
    threads: Option<usize>,
    /// Print nothing but errors.
    #[arg(short, long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Describe .vdb files (grids, transforms, active voxels, value ranges) and .vpak assets (sections, nodes, checksums).
    #[command(after_help = inspect::AFTER_HELP)]
    Inspect {
        /// .vdb or .vpak files to describe.
        #[arg(required = true, value_name = "FILE")]
        files: Vec<PathBuf>,
        /// Print one JSON document on stdout (schema: docs/inspect-json.md).
        #[arg(long)]
        json: bool,
    },
    /// Cook a VDB sequence into one packed .vpak asset.
    #[command(after_help = cook::AFTER_HELP)]
    Cook(cook::CookArgs),
    /// Decode one frame of a .vpak asset into a .vdb file that OpenVDB reads.
    Unpack(unpack::UnpackArgs),
    /// Compare two .vdb grids voxel by voxel (RMSE, PSNR, max error).
    #[command(after_help = diff::AFTER_HELP)]
    Diff(diff::DiffArgs),
    /// Render asset and source with the same GPU ray-marcher and report what the compression cost.
    #[command(after_help = validate::AFTER_HELP)]
    Validate(validate::ValidateArgs),
    /// Render one frame of a .vpak (or a .vdb) to a PNG preview.
    Render(validate::RenderArgs),
    /// Play a .vpak's frames in order through the GPU, streaming its segments (timings, PNG frames).
    #[command(after_help = play::AFTER_HELP)]
    Play(play::PlayArgs),
    /// Join the part files of `cook --part I/N` into one asset, copying their segments.
    Join(join::JoinArgs),
    /// Store an asset's sections another way on disk (supercompressed or not), without its sources.
    Recompress(recompress::RecompressArgs),
    /// Cook (and validate) every asset of a bake.toml manifest, with a cache, shards and one report.
    #[command(after_help = bake::AFTER_HELP)]
    Bake(bake::BakeArgs),
    /// Play an asset in a window: step, scrub, orbit, zoom, switch level and channel.
    #[command(after_help = view::AFTER_HELP)]
    View(view::ViewArgs),
}

/// A usage problem found after parsing (exit code 2).
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// Fails before any work when `path` exists and `--force` was not given
/// (the atomic write checks again, racing writers included).
pub fn refuse_existing(path: &std::path::Path, force: bool) -> anyhow::Result<()> {
    if path.exists() && !force {
        anyhow::bail!("{} already exists (use --force to replace it)", path.display());
    }
    Ok(())
}

/// Writes an asset to `path` through `write` (given the unnamed file, it
/// returns it written), checks it whole (every segment, and what segments
/// must share), and only then gives it its name: the asset's metadata and
/// size. Nothing is left behind when any step fails.
pub fn write_checked(path: &std::path::Path, force: bool, write: impl FnOnce(std::fs::File) -> anyhow::Result<std::fs::File>) -> anyhow::Result<(vdbcook_vpak::Metadata, usize)> {
    use anyhow::Context;
    let out = path.display().to_string();
    let mut file = vdbcook_vpak::AtomicFile::create(path, force).with_context(|| out.clone())?;
    let f = write(file.file().try_clone().with_context(|| out.clone())?)?;
    let asset = vdbcook_vpak::Asset::from_file(&f).with_context(|| out.clone())?;
    let meta = asset.check().with_context(|| out.clone())?;
    let bytes = asset.bytes().len();
    drop(asset);
    file.commit().with_context(|| out.clone())?;
    Ok((meta, bytes))
}

/// Stdout was closed by its reader (`| head`): the output ends there, and the
/// command exits with 0, as ripgrep does.
#[derive(Debug)]
pub struct PipeClosed;

impl std::fmt::Display for PipeClosed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("stdout was closed")
    }
}

impl std::error::Error for PipeClosed {}

/// Writes to stdout. A closed pipe is [`PipeClosed`]; any other failure (a
/// full disk: `> /dev/full`) is an error, so a script never gets an empty
/// report with exit code 0.
pub fn emit(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(PipeClosed.into()),
        Err(e) => Err(anyhow::anyhow!("cannot write to stdout: {e}")),
    }
}

/// [`emit`] for a command's last output: a closed pipe ends it quietly and the
/// command's exit code stands (a bake with a failed asset still exits 1).
pub fn emit_final(text: &str) -> anyhow::Result<()> {
    match emit(text) {
        Err(e) if e.is::<PipeClosed>() => Ok(()),
        r => r,
    }
}

/// Mesa's Vulkan drivers print a warning on every start when
/// XDG_RUNTIME_DIR is unset (common in CI and containers); give them a
/// private one. Runs before any thread exists. Unix only: other systems'
/// drivers do not look for it.
#[cfg(unix)]
fn ensure_runtime_dir() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_some() {
        return;
    }
    use std::os::unix::fs::{DirBuilderExt, MetadataExt};
    // The user id: the owner of /proc/self, or of $HOME where there is no
    // /proc (macOS, the BSDs).
    let home = std::env::var_os("HOME").unwrap_or_default();
    let uid = std::fs::metadata("/proc/self").or_else(|_| std::fs::metadata(&home)).map(|m| m.uid()).unwrap_or(0);
    let dir = std::env::temp_dir().join(format!("vdbcook-runtime-{uid}"));
    let _ = std::fs::DirBuilder::new().mode(0o700).create(&dir);
    if dir.is_dir() {
        std::env::set_var("XDG_RUNTIME_DIR", &dir);
    }
}

#[cfg(not(unix))]
fn ensure_runtime_dir() {}

/// A file-size limit (`ulimit -f`) makes a write fail, reported like a full
/// disk, instead of killing the process with SIGXFSZ.
#[cfg(unix)]
fn ignore_file_size_signal() {
    // SAFETY: setting a signal's disposition to "ignore" before any thread exists.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

#[cfg(not(unix))]
fn ignore_file_size_signal() {}

/// Large blocks straight from the system, past a fixed size. glibc's
/// threshold otherwise rises to each large block freed (up to 32 MiB), after
/// which blocks that size come from its arenas and, freed, stay in the
/// process: a long segment's cook held tens of MB it no longer used
/// (`docs/benchmarks.md`, "memory freed but kept").
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn fix_mmap_threshold() {
    // SAFETY: an allocator setting, made before any thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 4 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn fix_mmap_threshold() {}

fn main() -> ExitCode {
    fix_mmap_threshold();
    ensure_runtime_dir();
    ignore_file_size_signal();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return ExitCode::from(clap_exit(&e)),
    };
    if let Some(n) = cli.threads {
        if n == 0 {
            eprintln!("vdbcook: error: --threads must be at least 1");
            return ExitCode::from(exit::USAGE);
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n).build_global() {
            eprintln!("vdbcook: error: cannot start {n} threads: {e}");
            return ExitCode::from(exit::FAILURE);
        }
    }
    let code = match cli.command {
        Command::Inspect { files, json } => inspect::run(&files, json, cli.quiet),
        Command::Cook(args) => cook::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Unpack(args) => unpack::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Diff(args) => diff::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Validate(args) => validate::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Render(args) => validate::render(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Play(args) if !args.headless => play_in_window(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Play(args) => play::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Bake(args) => bake::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Join(args) => join::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::Recompress(args) => recompress::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
        Command::View(args) => view::run(args, cli.quiet).unwrap_or_else(|e| fail(&e)),
    };
    ExitCode::from(code)
}

/// `play` without `--headless`: the asset plays in `view`'s window, from the
/// first frame asked for, looping; what only a headless play does is refused.
fn play_in_window(args: play::PlayArgs, quiet: bool) -> anyhow::Result<u8> {
    let headless_only = [(args.json, "--json"), (args.out.is_some(), "--out"), (args.loops != 1, "--loop"), (args.frames.is_some_and(|r| r.step != 1 || r.first != r.last), "--frames")];
    if let Some((_, flag)) = headless_only.iter().find(|(given, _)| *given) {
        return Err(Usage(format!("{flag} needs --headless (in a window, play loops the whole asset from --frames N: the keys of `vdbcook view` apply)")).into());
    }
    let frame = args.frames.map_or(0, |r| usize::try_from(r.first).unwrap_or(usize::MAX));
    let size = args.viewing.size;
    view::run(view::ViewArgs { asset: args.asset, fps: args.fps, size, frame, lod: args.lod, extinction: args.viewing.extinction, paused: false, gpu: args.gpu }, quiet)
}

/// Prints what clap has to say; the exit code. Help and version go to stdout,
/// where a failed write is an error like any other (a closed pipe is not).
fn clap_exit(e: &clap::Error) -> u8 {
    use std::io::IsTerminal;
    if e.use_stderr() {
        let _ = e.print();
        return exit::USAGE;
    }
    if std::io::stdout().is_terminal() {
        let _ = e.print();
        return exit::SUCCESS;
    }
    match emit(&e.render().to_string()) {
        Ok(()) => exit::SUCCESS,
        Err(err) => fail(&err),
    }
}

/// Prints a gate failure; the exit code.
pub fn gate_exit(failure: &Option<String>) -> u8 {
    match failure {
        Some(msg) => {
            eprintln!("vdbcook: quality gate failed: {msg}");
            exit::QUALITY_GATE
        }
        None => exit::SUCCESS,
    }
}

/// Reports a failure; the exit code. A closed stdout is not one.
pub fn fail(e: &anyhow::Error) -> u8 {
    if e.is::<PipeClosed>() {
        return exit::SUCCESS;
    }
    report_error(e);
    if e.downcast_ref::<Usage>().is_some()
        || e.downcast_ref::<vdbcook_validate::CompareError>().is_some_and(vdbcook_validate::CompareError::is_usage)
        || e.downcast_ref::<vdbcook_pipeline::Error>().is_some_and(vdbcook_pipeline::Error::is_usage)
    {
        exit::USAGE
    } else {
        exit::FAILURE
    }
}

/// Prints an error the house way: one line, prefixed, causes joined by ": ".
pub fn report_error(err: &anyhow::Error) {
    eprintln!("vdbcook: error: {}", one_line(err));
}

/// The error and its causes on one line (see [`vdbcook_pipeline::one_line`]).
pub fn one_line(err: &anyhow::Error) -> String {
    vdbcook_pipeline::one_line(err.as_ref())
}

#[cfg(test)]
mod tests {
    #[test]
    fn each_fact_once() {
        let io = || std::io::Error::new(std::io::ErrorKind::StorageFull, "No space left on device (os error 28)");
        // An error type that prints its source and also returns it.
        #[derive(Debug, thiserror::Error)]
        #[error("{0}")]
        struct Wraps(#[source] std::io::Error);
        let e = anyhow::Error::new(Wraps(io())).context("x.vpak");
        assert_eq!(super::one_line(&e), "x.vpak: No space left on device (os error 28)");
        let e = anyhow::Error::new(vdbcook_vpak::Error::Io(io())).context("x.vpak");
        assert_eq!(super::one_line(&e), "x.vpak: No space left on device (os error 28)");
        let e = anyhow::Error::new(vdbcook_vpak::Error::Exists("/out/a.vpak".into())).context("/out/a.vpak");
        assert_eq!(super::one_line(&e), "/out/a.vpak already exists (use --force to replace it)");
        let e = anyhow::anyhow!("bad magic").context("frame 3").context("a.vdb");
        assert_eq!(super::one_line(&e), "a.vdb: frame 3: bad magic");
    }
}
