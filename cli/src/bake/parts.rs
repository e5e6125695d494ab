//! `bake`'s units (assets, and parts of assets with `parts = N`) and the
//! joins: in a bake that has every part of an asset, and in `bake --merge`
//! of shards' reports.

use crate::gpu::GpuArgs;
use anyhow::{anyhow, Result};
use std::path::{Path, PathBuf};
use vdbcook_bake::parts::{self, PartNo, Unit};
use vdbcook_bake::{place, AssetReport, PlannedAsset, Report, Shard, Status, Summary};

/// The units this run bakes, in manifest order: those of the `only` assets
/// (every asset when empty) that `shard` deals to it (round robin over every
/// unit of the manifest).
pub fn choose(planned: &[PlannedAsset], only: &[String], shard: Option<Shard>) -> Vec<Unit> {
    parts::units(planned).into_iter().enumerate().filter(|(k, u)| (only.is_empty() || only.contains(&planned[u.asset].name)) && shard.is_none_or(|s| s.takes(*k))).map(|(_, u)| u).collect()
}

/// The assets with `parts` whose every part is among `units`: this run joins them.
pub fn complete(planned: &[PlannedAsset], units: &[Unit]) -> Vec<usize> {
    planned.iter().enumerate().filter(|(i, a)| a.parts.is_some_and(|n| units.iter().filter(|u| u.asset == *i && u.part.is_some()).count() == n as usize)).map(|(i, _)| i).collect()
}

/// "smoke" or "smoke (part 1/2)".
pub fn label(name: &str, part: Option<PartNo>) -> String {
    match part {
        Some(p) => format!("{name} (part {p})"),
        None => name.to_string(),
    }
}

/// In a merged report, joins each asset's parts (their files' paths already
/// made relative to the report that listed each) into `out_dir`. Every part of every asset
/// must be listed, and every listed part that was baked must be there:
/// otherwise one line naming the asset and the part, and nothing is written.
/// An asset with a failed part fails (not joined).
pub fn join_merged(report: &mut Report, out_dir: &Path, allow_outside: bool, force: bool, gpu: &GpuArgs) -> Result<()> {
    let mut groups: Vec<Vec<AssetReport>> = Vec::new();
    let mut rest = Vec::new();
    for a in std::mem::take(&mut report.assets) {
        match (&a.part, groups.iter_mut().find(|g| g[0].index == a.index)) {
            (None, _) => rest.push(a),
            (Some(_), Some(g)) => g.push(a),
            (Some(_), None) => groups.push(vec![a]),
        }
    }
    // First every check, so that a missing part writes nothing.
    for g in &groups {
        let count = g.iter().filter_map(|a| a.part.as_ref()).map(|p| p.count).max().unwrap_or(0);
        for i in 1..=count {
            if !g.iter().any(|a| a.part.as_ref().is_some_and(|p| p.index == i)) {
                return Err(anyhow!("asset {}: part {i}/{count} is in none of the reports (expected the reports of every shard)", g[0].name));
            }
        }
        if g.iter().any(|a| a.part.as_ref().is_some_and(|p| p.count != count)) {
            return Err(anyhow!("asset {}: its parts are of cooks in different numbers of parts (expected the reports of one bake)", g[0].name));
        }
        if g.iter().all(|a| matches!(a.status, Status::Baked | Status::Cached)) {
            for a in g {
                let p = a.part.as_ref().map_or(PathBuf::new(), |p| PathBuf::from(&p.file));
                if !p.is_file() {
                    let n = a.part.as_ref().map_or(String::new(), |p| format!("{}/{}", p.index, p.count));
                    return Err(anyhow!("asset {}: part {n} is missing ({}: no such file)", a.name, p.display()));
                }
            }
            if !allow_outside {
                if let Some(why) = place::outside(out_dir, &g[0].output) {
                    return Err(crate::Usage(format!("asset {}: {why}", g[0].name)).into());
                }
            }
        }
    }
    let renderer = std::cell::OnceCell::new();
    let thumb = |asset: &vdbcook_vpak::Asset| renderer.get_or_init(|| gpu.renderer().ok()).as_ref().and_then(|r| vdbcook_bake::preview(r, asset));
    for g in groups {
        let mut r = g[0].clone();
        r.part = None;
        r.seconds = g.iter().map(|a| a.seconds).sum();
        r.record = Default::default();
        r.bytes = None;
        if let Some(bad) = g.iter().find(|a| !matches!(a.status, Status::Baked | Status::Cached)) {
            r.status = if bad.status == Status::Skipped { Status::Skipped } else { Status::Failed };
            let p = bad.part.as_ref().map_or(String::new(), |p| format!("{}/{}", p.index, p.count));
            r.message = Some(format!("part {p}: {}", bad.message.as_deref().unwrap_or("failed")));
        } else {
            let files: Vec<PathBuf> = g.iter().filter_map(|a| a.part.as_ref()).map(|p| PathBuf::from(&p.file)).collect();
            match parts::join(&r.name, &files, &vdbcook_bake::manifest::resolve(out_dir, &r.output), force, &thumb) {
                Ok(j) => {
                    r.status = if g.iter().any(|a| a.status == Status::Baked) { Status::Baked } else { Status::Cached };
                    r.message = None;
                    r.record = j.record;
                    r.bytes = Some(j.bytes);
                    r.cache_key = j.key;
                }
                Err(e) => {
                    r.status = Status::Failed;
                    r.message = Some(vdbcook_pipeline::one_line(&e));
                }
            }
        }
        rest.push(r);
    }
    rest.sort_by_key(AssetReport::order);
    report.summary = Summary::of(&rest);
    report.assets = rest;
    Ok(())
}
