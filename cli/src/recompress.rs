//! `vdbcook recompress`: an asset's disk coding changed without its sources.

use crate::exit;
use anyhow::{Context, Result};
use std::path::PathBuf;
use std::time::Instant;
use vdbcook_vpak::coding::Supercompress;
use vdbcook_vpak::Asset;

#[derive(clap::Args)]
#[command(after_help = "\
Every segment is restored to the GPU bytes the cooker chose and stored again as
--supercompress says: the nodes, bricks and texels stay as they are, so the asset draws
the same; only its size on disk changes (and the supercompress setting it records).
An asset cooked with --optimize disk keeps its 8- and 16-bit atlases context-coded where
that is smaller than zstd (format version 11; over the voxels its nodes show where that is
smaller still, version 15) and its L3 array's sub-masks mask-coded where
that is smaller (version 14), and any asset's L3 array takes the l3 nodes
filter (version 12); an asset of one supercompressed segment of at most 64 KiB is wrapped
whole in one zstd frame where that is smaller (version 13). Older assets (version 6 to 14) are read and
written as version 15 (one without a frame rate and frame numbers gets 24 fps and its
frame indices).")]
pub struct RecompressArgs {
    /// The asset to read.
    #[arg(value_name = "IN.vpak")]
    pub input: PathBuf,
    /// The asset to write.
    #[arg(short, long, value_name = "OUT.vpak")]
    pub output: PathBuf,
    /// How the sections are stored: none, zstd, or zstd:LEVEL (1 to 22; zstd alone is level 5;
    /// up to level 5, sections over 8 MiB take level 1, for speed).
    #[arg(long, value_name = "none|zstd[:LEVEL]")]
    pub supercompress: Supercompress,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
}

pub fn run(args: RecompressArgs, quiet: bool) -> Result<u8> {
    crate::refuse_existing(&args.output, args.force)?;
    let started = Instant::now();
    let input = args.input.display().to_string();
    let asset = Asset::open(&args.input).with_context(|| input.clone())?;
    let out = args.output.display().to_string();
    let (_, to) = crate::write_checked(&args.output, args.force, |handle| {
        let written = vdbcook_vpak::coding::recompress(&asset, args.supercompress, std::io::BufWriter::with_capacity(1 << 20, handle)).map_err(|e| match e {
            // A segment that does not restore is the input's fault; writing, the output's.
            e @ vdbcook_vpak::Error::Io(_) => anyhow::Error::from(e).context(out.clone()),
            e => anyhow::Error::from(e).context(input.clone()),
        })?;
        written.into_inner().map_err(|e| anyhow::Error::from(e.into_error()).context(out.clone()))
    })?;
    let from = asset.bytes().len();
    if !quiet {
        crate::emit_final(&format!(
            "recompressed {input} ({:.2} MB) into {out} ({:.2} MB, {:.3}×, supercompress {}), {:.2}s\n",
            from as f64 / 1e6,
            to as f64 / 1e6,
            to as f64 / from.max(1) as f64,
            args.supercompress,
            started.elapsed().as_secs_f64()
        ))?;
    }
    Ok(exit::SUCCESS)
}
