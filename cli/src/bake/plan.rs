//! `bake --plan` and `bake --dry-run`: what a bake would do, per asset and per part.

use super::{parts, BakeArgs};
use crate::exit;
use anyhow::Result;
use serde_json::json;
use std::path::Path;
use vdbcook_bake::manifest::resolve;
use vdbcook_bake::parts::{cached_part, part_key, part_output, Unit};
use vdbcook_bake::{cached, place, PlannedAsset};

pub fn print_plan(args: &BakeArgs, manifest: &str, out_dir: &Path, planned: &[PlannedAsset], units: &[Unit], quiet: bool) -> Result<u8> {
    if quiet {
        return Ok(exit::SUCCESS);
    }
    let assets: Vec<&PlannedAsset> = planned.iter().enumerate().filter(|(i, _)| units.iter().any(|u| u.asset == *i)).map(|(_, a)| a).collect();
    // An asset's parts in this plan (with --shard, those of this shard).
    let parts_of = |a: &PlannedAsset| -> Vec<(String, String, String)> {
        units.iter().filter(|u| planned[u.asset].index == a.index).filter_map(|u| u.part).map(|p| (p.to_string(), part_output(&a.output, p), part_key(&a.key, p))).collect()
    };
    let text = if args.json {
        let doc = json!({
            "version": 1,
            "manifest": manifest,
            "out_dir": out_dir.display().to_string(),
            "shard": args.shard,
            "assets": assets.iter().map(|a| json!({
                "index": a.index,
                "name": a.name,
                "output": a.output,
                "output_path": resolve(out_dir, &a.output).display().to_string(),
                "inputs": a.inputs,
                "files": a.files.iter().chain(&a.with_files).map(|f| f.display().to_string()).collect::<Vec<_>>(),
                "cache_key": a.key,
                "settings": a.settings.pairs().into_iter().map(|(k, v)| (k.to_string(), json!(v))).collect::<serde_json::Map<_, _>>(),
                "parts": a.parts.map(|_| parts_of(a).into_iter().map(|(p, o, k)| json!({
                    "part": p,
                    "output": o,
                    "output_path": resolve(out_dir, &o).display().to_string(),
                    "cache_key": k,
                })).collect::<Vec<_>>()),
            })).collect::<Vec<_>>(),
        });
        format!("{}\n", serde_json::to_string_pretty(&doc).unwrap_or_default())
    } else {
        let mut t = String::new();
        for a in assets {
            let n = a.files.len() + a.with_files.len();
            t += &format!("{}  {}  {} <- {n} file{}\n", a.name, a.key, resolve(out_dir, &a.output).display(), if n == 1 { "" } else { "s" });
            for (p, o, k) in parts_of(a) {
                t += &format!("  part {p}  {k}  {}\n", resolve(out_dir, &o).display());
            }
        }
        t
    };
    crate::emit_final(&text)?;
    Ok(exit::SUCCESS)
}

pub fn dry_run(args: &BakeArgs, out_dir: &Path, planned: &[PlannedAsset], units: &[Unit], joins: &[usize], quiet: bool) -> Result<u8> {
    let mut rows = Vec::new();
    let in_cache = |file: String, check: &dyn Fn(&Path) -> bool| args.cache.as_ref().is_some_and(|c| check(&c.join(file)));
    for u in units {
        let a = &planned[u.asset];
        // An asset this run would join: one row when it is already made.
        let whole = joins.contains(&u.asset) && (cached(&resolve(out_dir, &a.output), &a.key).is_some() || in_cache(format!("{}.vpak", a.key), &|p| cached(p, &a.key).is_some()));
        if whole && u.part.is_some_and(|p| p.index > 1) {
            continue;
        }
        let (output, key, part) = match u.part.filter(|_| !whole) {
            Some(p) => (part_output(&a.output, p), part_key(&a.key, p), Some(p)),
            None => (a.output.clone(), a.key.clone(), None),
        };
        let out = resolve(out_dir, &output);
        let found = |p: &Path| if part.is_some() { cached_part(p, &key).is_some() } else { cached(p, &key).is_some() };
        let action = if found(&out) {
            "cached"
        } else if place::may_replace(&out, args.force).is_err() {
            "refused"
        } else if in_cache(format!("{key}.{}", if part.is_some() { "vpakpart" } else { "vpak" }), &found) {
            "from-cache"
        } else {
            "bake"
        };
        rows.push((parts::label(&a.name, part), output, out, key, part, action));
    }
    if quiet {
        return Ok(exit::SUCCESS);
    }
    let text = if args.json {
        let doc = json!({ "assets": rows.iter().map(|(name, output, out, key, part, action)| {
            let mut v = json!({"name": name, "action": action, "output": output, "output_path": out.display().to_string(), "cache_key": key});
            if let Some(p) = part {
                v["part"] = json!(p.to_string());
            }
            v
        }).collect::<Vec<_>>() });
        format!("{}\n", serde_json::to_string_pretty(&doc).unwrap_or_default())
    } else {
        rows.iter().map(|(name, _, out, _, _, action)| format!("{action:<10} {name}  {}\n", out.display())).collect()
    };
    crate::emit_final(&text)?;
    Ok(exit::SUCCESS)
}
