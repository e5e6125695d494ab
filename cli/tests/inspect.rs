//! `vdbcook inspect` on every fixture and every real-world sample, checked
//! figure by figure against what OpenVDB itself reports.

mod common;
use common::*;
use serde_json::Value;
use std::path::PathBuf;

fn all_inputs() -> Vec<PathBuf> {
    let mut files = vdb_files(&root().join("fixtures"));
    assert!(files.len() >= 20, "fixtures missing");
    if let Some(s) = shared_samples() {
        files.extend(vdb_files(&s));
    }
    files
}

fn ours(file: &std::path::Path) -> Value {
    let out = vdbcook(&["inspect", "--json", file.to_str().unwrap()]);
    assert!(out.status.success(), "{}: {}", file.display(), String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    v["files"][0].clone()
}

fn close(a: &Value, b: &Value, rel: f64) -> bool {
    match (a.as_f64(), b.as_f64()) {
        (Some(x), Some(y)) => x == y || (x - y).abs() <= rel * x.abs().max(y.abs()),
        _ => a == b,
    }
}

fn close_vec(a: &Value, b: &Value, rel: f64) -> bool {
    match (a.as_array(), b.as_array()) {
        (Some(x), Some(y)) => x.len() == y.len() && x.iter().zip(y).all(|(p, q)| close(p, q, rel)),
        _ => a == b,
    }
}

#[test]
fn every_file_reads_and_matches_openvdb() {
    let files = all_inputs();
    let have_oracle = oracle_available();
    let results = par_map(&files, |f| (ours(f), if have_oracle { oracle(f, None) } else { None }));
    let mut compared = 0;
    let mut failures = Vec::new();
    for (file, (mine, theirs)) in files.iter().zip(results) {
        let name = file.display();
        assert!(mine["grids"].as_array().map(Vec::len).is_some(), "{name}: no grids array");
        let Some(theirs) = theirs else { continue };
        compared += 1;
        let mut fail = |what: String| failures.push(format!("{name}: {what}"));
        for k in ["file_version", "library_version"] {
            if mine[k] != theirs[k] {
                fail(format!("{k}: ours {} openvdb {}", mine[k], theirs[k]));
            }
        }
        let (mg, tg) = (mine["grids"].as_array().unwrap(), theirs["grids"].as_array().unwrap());
        if mg.len() != tg.len() {
            fail(format!("grid count: ours {} openvdb {}", mg.len(), tg.len()));
            continue;
        }
        for (m, t) in mg.iter().zip(tg) {
            let gname = t["name"].as_str().unwrap_or("?").to_string();
            for k in ["name", "value_type", "class", "half_float"] {
                if m[k] != t[k] {
                    fail(format!("grid {gname}: {k}: ours {} openvdb {}", m[k], t[k]));
                }
            }
            if t["map_type"] != "NonlinearFrustumMap" {
                if m["transform"]["map_type"] != t["map_type"] {
                    fail(format!("grid {gname}: map_type: ours {} openvdb {}", m["transform"]["map_type"], t["map_type"]));
                }
                if !close_vec(&m["voxel_size"], &t["voxel_size"], 1e-9) {
                    fail(format!("grid {gname}: voxel_size: ours {} openvdb {}", m["voxel_size"], t["voxel_size"]));
                }
            }
            if !m["skipped"].is_null() {
                continue;
            }
            // Double grids are read as f32: their values match to f32 precision.
            let rel = if t["value_type"] == "double" { 1e-6 } else { 0.0 };
            for k in ["active_voxels", "bbox_min", "bbox_max", "leaf_count", "active_tiles"] {
                if m[k] != t[k] {
                    fail(format!("grid {gname}: {k}: ours {} openvdb {}", m[k], t[k]));
                }
            }
            for k in ["min", "max", "background"] {
                if !close(&m[k], &t[k], rel) {
                    fail(format!("grid {gname}: {k}: ours {} openvdb {}", m[k], t[k]));
                }
            }
            if !close(&m["sum"], &t["sum"], rel.max(1e-9)) {
                fail(format!("grid {gname}: sum: ours {} openvdb {}", m["sum"], t["sum"]));
            }
        }
    }
    assert!(failures.is_empty(), "{} differences:\n{}", failures.len(), failures.join("\n"));
    if have_oracle {
        assert!(compared >= 20, "only {compared} files compared with OpenVDB");
    }
}

#[test]
fn skipped_grids_are_explained_and_the_rest_still_read() {
    let v = ours(&root().join("fixtures/multi_grid.vdb"));
    let grids = v["grids"].as_array().unwrap();
    let skipped: Vec<&Value> = grids.iter().filter(|g| !g["skipped"].is_null()).collect();
    let read: Vec<&Value> = grids.iter().filter(|g| g["skipped"].is_null()).collect();
    assert!(!skipped.is_empty() && !read.is_empty(), "{v}");
    for g in skipped {
        let why = g["skipped"].as_str().unwrap();
        assert!(why.contains(g["value_type"].as_str().unwrap()), "{why}");
        assert!(g["active_voxels"].is_null());
    }
    for g in read {
        assert!(g["active_voxels"].as_u64().unwrap() > 0, "{g}");
    }
}

#[test]
fn human_output_names_each_grid() {
    let out = vdbcook(&["inspect", "fixtures/fog_blosc.vdb"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("grid \"density\": float fog volume"), "{text}");
    assert!(text.contains("active voxels"), "{text}");
    assert!(text.contains("OpenVDB file version 224"), "{text}");
}

/// Channels at their own voxel size (format v10): each channel's level, voxel
/// size, offset and stored levels, in JSON and in text, and which channels each
/// level of detail holds; an asset of one voxel size has every channel at level 0.
#[test]
fn an_asset_shows_each_channels_level_and_voxel_size() {
    if !oracle_available() {
        return;
    }
    let dir = scratch_dir("inspect", "resolutions");
    let seq = dir.join("pyro");
    // vel at four times the density's voxels, its origin half a density voxel off.
    let made = std::process::Command::new("/usr/bin/python3")
        .args(["scripts/make_pyro_sequence.py", s(&seq), "--frames", "2", "--size", "32", "--vel-scale", "4", "--offset", "1"])
        .current_dir(root())
        .output()
        .unwrap();
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    let asset = cook_into(&dir, "p.vpak", &[s(&seq)], &["--grids", "density,temperature,vel", "--format", "f16", "--lods", "2"]);
    let v = inspect(&asset);
    let ch = |name: &str| v["channels"].as_array().unwrap().iter().find(|c| c["name"] == name).unwrap().clone();
    for (name, level, size, half, levels) in [("density", 0, 0.1, 0, [0, 1]), ("temperature", 0, 0.1, 0, [0, 1]), ("vel.y", 2, 0.4, -2, [2, 3])] {
        let c = ch(name);
        assert_eq!(c["level"], level, "{c}");
        assert!(c["voxel_size"].as_array().unwrap().iter().all(|x| (x.as_f64().unwrap() - size).abs() < 1e-12), "{c}");
        // vel's voxel j is centred at 0.4·j + 0.05, level 2's at 0.4·j + 0.15: one density voxel (two halves) before.
        assert_eq!(c["half_offset"], serde_json::json!([half, half, half]), "{c}");
        assert_eq!(c["levels"], serde_json::json!(levels), "{c}");
    }
    let held: Vec<(u64, Vec<&str>)> =
        v["levels"].as_array().unwrap().iter().map(|l| (l["level"].as_u64().unwrap(), l["channels"].as_array().unwrap().iter().map(|n| n.as_str().unwrap()).collect())).collect();
    let (fine, vel) = (vec!["density", "temperature"], vec!["vel.x", "vel.y", "vel.z"]);
    assert_eq!(held, [(0, fine.clone()), (1, fine), (2, vel.clone()), (3, vel)]);
    let text = String::from_utf8(ok(vdbcook(&["inspect", s(&asset)])).stdout).unwrap();
    // Channel rows: name, format, lod, voxel, ...
    let row = |name: &str| text.lines().map(|l| l.split_whitespace().collect::<Vec<_>>()).find(|w| w.first() == Some(&name)).unwrap_or_else(|| panic!("no row {name}: {text}"));
    assert_eq!(row("density")[1..4], ["f16", "0", "0.1"], "{text}");
    assert_eq!(row("vel.z")[1..4], ["f16", "2", "0.4"], "{text}");
    assert!(text.contains("\n  offset         vel.x, vel.y, vel.z: centres [-1.0, -1.0, -1.0] voxels from level 2's\n"), "{text}");
    // The levels of detail say which channels each level holds (a vec3 grid by its name).
    let lods: Vec<&str> = text.lines().skip_while(|l| !l.trim_start().starts_with("lod ")).skip(1).take(4).collect();
    assert_eq!(lods.len(), 4, "{text}");
    for (l, want) in lods.iter().zip(["density, temperature", "density, temperature", "vel", "vel"]) {
        assert!(l.ends_with(&format!("%  {want}")), "{l}\n{text}");
    }
    // One voxel size: every channel at level 0, each level holding every channel.
    let plain = cook_into(&dir, "plain.vpak", &[s(&root().join("fixtures/smoke_seq"))], &["--lods", "2"]);
    let v = inspect(&plain);
    for c in v["channels"].as_array().unwrap() {
        assert_eq!((c["level"].as_u64(), &c["half_offset"], &c["levels"]), (Some(0), &serde_json::json!([0, 0, 0]), &serde_json::json!([0, 1])), "{c}");
        assert_eq!(c["voxel_size"][0].as_f64().unwrap(), v["transform"][0][0].as_f64().unwrap().abs(), "{c}");
    }
    assert!(v["levels"].as_array().unwrap().iter().all(|l| l["channels"].as_array().unwrap().len() == v["channels"].as_array().unwrap().len()), "{v}");
    let _ = std::fs::remove_dir_all(&dir);
}
