//! Several grids in one asset (`cook --grids`, `--group`), end to end: the
//! command line, inspect, validate and the fire render.

mod common;
use common::*;
use std::path::{Path, PathBuf};

fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vdbcook-channels-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ok(out: std::process::Output) -> std::process::Output {
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    out
}

fn sample(rel: &str) -> Option<String> {
    shared_samples().map(|p| p.join(rel).to_string_lossy().into_owned())
}

fn inspect(asset: &Path) -> serde_json::Value {
    let v: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["inspect", "--json", s(asset)])).stdout).unwrap();
    v["files"][0].clone()
}

#[test]
fn a_missing_grid_or_a_bad_group_is_a_usage_error_that_says_what_there_is() {
    let Some(w) = sample("waveletturbulence") else { return };
    let dir = scratch("usage");
    let out = dir.join("x.vpak");
    let r = vdbcook(&["cook", "-q", "--grids", "density,smoke", "-o", s(&out), &w]);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("\"smoke\"") && err.contains("density") && err.contains("temperature") && err.contains("fluid_data_0150.vdb"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(!out.exists());
    for (group, want) in [("flames=bc7", "not a channel"), ("density=bc9", "CHANNELS=FORMAT"), ("=bc7", "CHANNELS=FORMAT")] {
        let r = vdbcook(&["cook", "-q", "--grids", "density,temperature", "--group", group, "-o", s(&out), &w]);
        assert_eq!(r.status.code(), Some(2), "{group}");
        assert!(String::from_utf8_lossy(&r.stderr).contains(want), "{group}: {}", String::from_utf8_lossy(&r.stderr));
    }
    let r = vdbcook(&["cook", "-q", "--grid", "density", "--grids", "density", "-o", s(&out), &w]);
    assert_eq!(r.status.code(), Some(2), "--grid and --grids conflict");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn grids_all_cooks_every_float_grid_into_one_tree() {
    let Some(w) = sample("waveletturbulence") else { return };
    let dir = scratch("all");
    let out = dir.join("w.vpak");
    let cooked: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["cook", "--json", "--grids", "all", "--format", "unorm8", "-o", s(&out), &w])).stdout).unwrap();
    let f = inspect(&out);
    let names: Vec<&str> = f["channels"].as_array().unwrap().iter().map(|c| c["name"].as_str().unwrap()).collect();
    for want in ["density", "shadow", "temperature", "flame"] {
        assert!(names.contains(&want), "{names:?}");
    }
    assert_eq!(cooked["channels"].as_array().unwrap().len(), names.len());
    // unorm8: one RGBA plane holds four scalar channels.
    assert!(f["planes"].as_array().unwrap().iter().any(|p| p["lanes"] == 4));
    // One tree: the same L3 count as the density alone (every grid shares its leaves here).
    let one = dir.join("d.vpak");
    let d: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["cook", "--json", "--format", "unorm8", "-o", s(&one), &w])).stdout).unwrap();
    assert_eq!(cooked["l3_nodes"], d["l3_nodes"]);
    assert!(cooked["file_bytes"].as_u64().unwrap() < 4 * d["file_bytes"].as_u64().unwrap());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn embergen_fire_has_an_empty_first_frame_and_renders_as_fire() {
    let Some(e) = sample("vfx-toolkit-embergen") else { return };
    let dir = scratch("fire");
    let out = dir.join("fire.vpak");
    let files: Vec<String> = (0..4).map(|k| format!("{e}/embergen_fire_a_{k}.vdb")).collect();
    let mut args = vec!["cook", "-q", "--grids", "temperature,flames", "--format", "bc7", "-o", s(&out)];
    args.extend(files.iter().map(String::as_str));
    ok(vdbcook(&args));
    let f = inspect(&out);
    assert_eq!(f["frame_info"][0]["active_voxels"], 0, "frame 0 of the EmberGen pack is empty");
    assert!(f["frame_info"][3]["active_voxels"].as_u64().unwrap() > 40_000);
    if !gpu_available() {
        return;
    }
    // validate: per-channel voxel figures, and an RGB report whose images glow.
    let report = dir.join("report");
    let mut args = vec!["validate", s(&out), "--views", "2", "--size", "96x96", "--json", "--report", s(&report), "--source"];
    args.extend(files.iter().map(String::as_str));
    let r = vdbcook(&args);
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let ch = v["voxel_channels"].as_array().unwrap();
    assert_eq!(ch.iter().map(|c| c["name"].as_str().unwrap()).collect::<Vec<_>>(), ["temperature", "flames"]);
    assert!(ch.iter().all(|c| c["rmse"].as_f64().unwrap() > 0.0 && c["format"] == "bc7"));
    assert_eq!(v["shown"], "flames", "without density, flames give extinction");
    // The rendered fire is orange: red above green above blue where it glows.
    let png = dir.join("fire.png");
    ok(vdbcook(&["render", s(&out), "--frame", "3", "--size", "96x96", "-o", s(&png)]));
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    let lit: Vec<&[u8]> = buf[..info.buffer_size()].chunks(3).filter(|p| p[0] > 40).collect();
    assert!(lit.len() > 50, "the fire shows ({} lit pixels)", lit.len());
    let (r, g, b) = lit.iter().fold((0u64, 0u64, 0u64), |a, p| (a.0 + u64::from(p[0]), a.1 + u64::from(p[1]), a.2 + u64::from(p[2])));
    assert!(r > g && g > b, "fire is red > green > blue on average: {r} {g} {b}");
    let _ = std::fs::remove_dir_all(&dir);
}
