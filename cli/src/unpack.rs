//! `vdbcook unpack`: one frame of an asset as a .vdb file OpenVDB reads.

use crate::exit;
use anyhow::{Context, Result};
use std::path::PathBuf;
use vdbcook_vdb::WriteGrid;

#[derive(clap::Args)]
pub struct UnpackArgs {
    /// The asset.
    #[arg(value_name = "ASSET.vpak")]
    pub asset: PathBuf,
    /// Frame to decode, counted from 0 in the asset's frame order (may be left out when the
    /// asset has one frame).
    #[arg(long, value_name = "N")]
    pub frame: Option<usize>,
    /// Frame to decode, by its number in the source sequence (fire_1001.vdb: 1001; see
    /// `inspect`), instead of --frame.
    #[arg(long, value_name = "S", conflicts_with = "frame", allow_negative_numbers = true)]
    pub source_frame: Option<i64>,
    /// Level of detail to decode (0: the frame itself; k: voxels 2^k times as large, in the
    /// level's index space, with a transform to match). Default: the asset's finest level (0
    /// unless `cook --max-bytes` left finer ones out). A channel stored at its own, coarser
    /// voxels (format v10) is written at its stored level nearest K (default: its own).
    #[arg(long, value_name = "K")]
    pub lod: Option<vdbcook_vpak::Level>,
    /// The .vdb file to write: one float grid per scalar channel and one vec3s grid per
    /// vec3 grid, zip-compressed, each with its name, class, background and transform.
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
    let meta = asset.metadata().with_context(|| name.clone())?;
    let lod = args.lod.map(vdbcook_vpak::Level::get);
    if let Some(why) = lod.and_then(|k| meta.missing_level(k)) {
        return Err(anyhow::anyhow!("{name}: {why}"));
    }
    let by_number = args.source_frame.map(|n| meta.frame_by_number(n).map_err(|e| anyhow::anyhow!("{name}: {e}"))).transpose()?;
    let frame = match (args.frame.or(by_number), meta.frame_count) {
        (Some(f), _) => f,
        (None, 1) => 0,
        (None, n) => return Err(crate::Usage(format!("{name} has {n} frames: say which with --frame N (0 to {})", n.saturating_sub(1))).into()),
    };
    // Each channel at its own stored level nearest the one asked for, on its own transform.
    let grids = vdbcook_cook::unpack_near(&asset, frame, lod).with_context(|| name.clone())?;
    // Scalar channels become float grids; the x, y, z channels of a vec3 grid one vec3s grid again.
    let mut out: Vec<WriteGrid> = Vec::new();
    let mut done = vec![false; grids.len()];
    for (c, ch) in meta.channels.iter().enumerate() {
        if done[c] {
            continue;
        }
        let parts: Vec<usize> = match ch.component {
            Some(_) => (0..3).filter_map(|k| meta.channels.iter().position(|o| o.grid == ch.grid && o.component == Some(k))).collect(),
            None => vec![],
        };
        match parts[..] {
            [x, y, z] => {
                for k in [x, y, z] {
                    done[k] = true;
                }
                out.push(WriteGrid::Vec3 { name: &ch.grid, class: grids[c].class, components: [&grids[x], &grids[y], &grids[z]] });
            }
            _ => {
                done[c] = true;
                out.push(WriteGrid::Float(&grids[c]));
            }
        }
    }
    let bytes = vdbcook_vdb::write_vdb_grids(&out, vdbcook_vdb::WriteOptions { version: 224, zip: !args.no_zip }).with_context(|| args.output.display().to_string())?;
    vdbcook_vpak::write_atomic(&args.output, &bytes, args.force).with_context(|| args.output.display().to_string())?;
    if !quiet {
        let (voxels, leaves) = grids.first().map_or((0, 0), |g| {
            let st = g.stats();
            (st.active_voxels, st.leaf_count)
        });
        let what = if out.len() == 1 { "1 grid".to_string() } else { format!("{} grids", out.len()) };
        let levels: Vec<u32> = (0..meta.channels.len()).map(|c| meta.channel_level_near(c, lod.unwrap_or(0))).collect();
        let level = match (meta.is_multi_resolution(), lod.unwrap_or(meta.first_level)) {
            (true, _) => format!(" at levels {}", levels.iter().map(u32::to_string).collect::<Vec<_>>().join(",")),
            (false, 0) => String::new(),
            (false, k) => format!(" at level {k}"),
        };
        crate::emit_final(&format!(
            "wrote frame {} (source frame {}){level} of {} to {} ({what}, {voxels} active voxels, {leaves} leaves)\n",
            frame,
            meta.frame_number(frame),
            name,
            args.output.display()
        ))?;
    }
    Ok(exit::SUCCESS)
}
