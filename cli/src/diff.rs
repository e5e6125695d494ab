//! `vdbcook diff A B`: how far grid B is from grid A, voxel by voxel.

use crate::exit;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use vdbcook_encode::ErrorStats;
use vdbcook_grid::{leaf_local, Grid};

pub const AFTER_HELP: &str = "\
Over every active voxel of A (tile voxels excluded): RMSE, PSNR (peak = A's value
range) and the largest absolute difference of B's value from A's, and how many of A's
active voxels are inactive in B. Inputs are .vdb files; use `vdbcook unpack` for a
frame of an asset.";

#[derive(clap::Args)]
pub struct DiffArgs {
    /// The reference .vdb.
    #[arg(value_name = "A")]
    pub a: PathBuf,
    /// The .vdb to compare with it.
    #[arg(value_name = "B")]
    pub b: PathBuf,
    /// Grid to compare in both files (default: "density", else the first float grid).
    #[arg(long, value_name = "NAME")]
    pub grid: Option<String>,
    /// Print the figures as JSON.
    #[arg(long)]
    pub json: bool,
}

fn load(path: &Path, grid: Option<&str>) -> Result<Grid> {
    let name = path.display().to_string();
    let f = vdbcook_vdb::open(path).with_context(|| name.clone())?;
    let i = f.select(grid).with_context(|| name.clone())?;
    f.read_grid(i).with_context(|| name)
}

pub fn run(args: DiffArgs, quiet: bool) -> Result<u8> {
    let a = load(&args.a, args.grid.as_deref())?;
    let b = load(&args.b, args.grid.as_deref())?;
    let mut err = ErrorStats::default();
    let mut missing = 0u64;
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for leaf in &a.leaves {
        for i in leaf.mask.iter_on() {
            let (x, y, z) = leaf_local(i);
            let va = leaf.values[i];
            let (vb, on) = b.probe(leaf.origin.offset(x, y, z));
            lo = lo.min(va);
            hi = hi.max(va);
            err.add(va, vb);
            if !on {
                missing += 1;
            }
        }
    }
    let peak = if hi > lo { f64::from(hi - lo) } else { 1.0 };
    if !quiet {
        let text = if args.json {
            let psnr = err.psnr(peak);
            format!(
                "{}\n",
                serde_json::json!({
                    "a": args.a.display().to_string(),
                    "b": args.b.display().to_string(),
                    "voxels": err.count,
                    "rmse": err.rmse(),
                    "psnr": if psnr.is_finite() { serde_json::json!(psnr) } else { serde_json::Value::Null },
                    "max_error": err.max_abs,
                    "inactive_in_b": missing,
                })
            )
        } else {
            format!("{} voxels: rmse {:.4e}, psnr {:.2} dB, max error {:.4e}; {} inactive in {}\n", err.count, err.rmse(), err.psnr(peak), err.max_abs, missing, args.b.display())
        };
        crate::emit_final(&text)?;
    }
    Ok(exit::SUCCESS)
}
