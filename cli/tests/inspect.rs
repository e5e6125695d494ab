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
