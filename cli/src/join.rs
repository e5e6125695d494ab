//! `vdbcook join`: the part files of `cook --part I/N` into one asset.

use crate::exit;
use anyhow::{Context, Result};
use std::path::PathBuf;
use std::time::Instant;
use vdbcook_vpak::Asset;

#[derive(clap::Args)]
#[command(after_help = "\
The parts are given in order, 1/N to N/N, each once. Their segments are copied as they
are (no re-encoding), so the asset is byte for byte what one `cook` with the same
settings and --segment-frames writes. Parts of different cooks (other settings, inputs
or vdbcook version), missing, repeated or out-of-order parts are refused and nothing is
written. See docs/ci.md for a CI matrix of one job per part and one join.")]
pub struct JoinArgs {
    /// The part files, in order.
    #[arg(required = true, value_name = "PART")]
    pub parts: Vec<PathBuf>,
    /// The asset to write.
    #[arg(short, long, value_name = "OUT.vpak")]
    pub output: PathBuf,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
}

pub fn run(args: JoinArgs, quiet: bool) -> Result<u8> {
    crate::refuse_existing(&args.output, args.force)?;
    let started = Instant::now();
    let names: Vec<String> = args.parts.iter().map(|p| p.display().to_string()).collect();
    let files = args.parts.iter().zip(&names).map(|(p, n)| std::fs::File::open(p).with_context(|| n.clone())).collect::<Result<Vec<_>>>()?;
    let parts = files.iter().zip(&names).map(|(f, n)| Asset::from_part_file(f).with_context(|| n.clone())).collect::<Result<Vec<_>>>()?;
    let out = args.output.display().to_string();
    let (meta, bytes) = crate::write_checked(&args.output, args.force, |handle| vdbcook_vpak::segments::join(&parts, &names, handle).with_context(|| out.clone()))?;
    if !quiet {
        crate::emit_final(&format!(
            "joined {} parts into {out}: {} frames in {} segments, {:.2} MB, {:.2}s\n",
            parts.len(),
            meta.frame_count,
            parts.iter().map(|(_, a)| a.segment_count()).sum::<usize>(),
            bytes as f64 / 1e6,
            started.elapsed().as_secs_f64()
        ))?;
    }
    Ok(exit::SUCCESS)
}
