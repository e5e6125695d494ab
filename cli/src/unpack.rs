//! `vdbcook unpack`: one frame of an asset as a .vdb file OpenVDB reads.

use crate::exit;
use anyhow::{Context, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct UnpackArgs {
    /// The asset.
    #[arg(value_name = "ASSET.vpak")]
    pub asset: PathBuf,
    /// Frame to decode, counted from 0 in the asset's frame order.
    #[arg(long, value_name = "N")]
    pub frame: usize,
    /// The .vdb file to write (one float grid, zip-compressed).
    #[arg(short, long, value_name = "OUT.vdb")]
    pub output: PathBuf,
    /// Write values uncompressed instead of zip.
    #[arg(long)]
    pub no_zip: bool,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
}

pub fn run(args: UnpackArgs, quiet: bool) -> Result<u8> {
    let name = args.asset.display().to_string();
    crate::refuse_existing(&args.output, args.force)?;
    let asset = vdbcook_vpak::Asset::open(&args.asset).with_context(|| name.clone())?;
    let grid = vdbcook_cook::unpack_frame(&asset, args.frame).with_context(|| name.clone())?;
    let bytes = vdbcook_vdb::write_vdb(&grid, vdbcook_vdb::WriteOptions { version: 224, zip: !args.no_zip }).with_context(|| args.output.display().to_string())?;
    vdbcook_vpak::write_atomic(&args.output, &bytes, args.force).with_context(|| args.output.display().to_string())?;
    if !quiet {
        let st = grid.stats();
        crate::emit_final(&format!("wrote frame {} of {} to {} ({} active voxels, {} leaves)\n", args.frame, name, args.output.display(), st.active_voxels, st.leaf_count))?;
    }
    Ok(exit::SUCCESS)
}
