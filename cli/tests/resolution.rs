//! Channels at their own voxel size (issue 26, format version 10), through the
//! commands: a pyro-style sequence whose `vel` is on voxels twice (or four
//! times) the density's cooks in every configuration, its usage errors are
//! one line with exit 2, segments and parts join byte for byte, the asset
//! validates (vel in the voxel domain) and plays.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

fn python_ok() -> bool {
    let ok = Command::new("/usr/bin/python3").args(["-c", "import numpy, pyopenvdb"]).output().is_ok_and(|o| o.status.success());
    assert!(ok || !in_ci(), "CI=true but /usr/bin/python3 lacks numpy or pyopenvdb");
    ok
}

/// `scripts/make_pyro_sequence.py` into `dir`: frames 1 to `frames`.
fn pyro(dir: &Path, frames: u32, extra: &[&str]) -> String {
    let script = root().join("scripts/make_pyro_sequence.py");
    let mut args = vec![s(&script).to_string(), s(dir).to_string(), "--frames".into(), frames.to_string(), "--size".into(), "32".into()];
    args.extend(extra.iter().map(|a| a.to_string()));
    ok(Command::new("/usr/bin/python3").args(&args).output().expect("python3"));
    dir.display().to_string()
}

const GRIDS: &[&str] = &["--grids", "density,temperature,vel"];

fn with_grids<'a>(flags: &[&'a str]) -> Vec<&'a str> {
    let mut v = GRIDS.to_vec();
    v.extend(flags);
    v
}

#[test]
fn transforms_that_cannot_be_combined_are_usage_errors() {
    if !python_ok() {
        return;
    }
    let dir = scratch_dir("resolution", "usage");
    for (extra, what) in [(&["--vel-scale", "3"][..], "voxel size 0.3"), (&["--vel-scale", "2", "--offset", "1"][..], "")] {
        let input = pyro(&dir.join(extra.join("_")), 1, extra);
        let out = vdbcook(&["cook", "-q", "--force", "-o", s(&dir.join("a.vpak")), "--grids", "density,vel", &input]);
        if what.is_empty() {
            // Half a density voxel off: it combines.
            ok(out);
            continue;
        }
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains("grid \"vel.x\"") && err.contains("grid \"density\"") && err.contains(what) && err.contains("voxel size 0.1"), "{err}");
        assert!(!dir.join("a.vpak").exists());
    }
    // Eight times coarser and four levels of detail from its own: more than five levels.
    let input = pyro(&dir.join("eight"), 1, &["--vel-scale", "8"]);
    let out = vdbcook(&["cook", "-q", "--force", "-o", s(&dir.join("b.vpak")), "--grids", "density,vel", "--lods", "4", &input]);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!((out.status.code(), err.trim().lines().count()), (Some(2), 1), "{err}");
    assert!(err.contains("--lods"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn every_configuration_cooks_and_the_coarse_channel_costs_its_own_voxels() {
    if !python_ok() {
        return;
    }
    let dir = scratch_dir("resolution", "configs");
    let input = pyro(&dir.join("in"), 3, &[]);
    let report = |flags: &[&str]| -> serde_json::Value {
        let out = dir.join("r.vpak");
        let mut args = vec!["cook", "--force", "--json", "-o", s(&out)];
        args.extend(flags);
        args.push(&input);
        serde_json::from_slice(&ok(vdbcook(&args)).stdout).unwrap()
    };
    for flags in [&["--format", "f16"][..], &["--format", "bc7"], &["--max-error", "0.01"], &["--lods", "2"], &["--format", "unorm8", "--clusters", "16"], &["--group", "vel=bc4", "--format", "f16"]] {
        let both = report(&with_grids(flags));
        let fine_flags: Vec<&str> = flags.iter().copied().filter(|f| !f.starts_with("vel") && *f != "--group").collect();
        let fine = report(&[&["--grids", "density,temperature"][..], &fine_flags].concat());
        let levels: Vec<u64> = both["channels"].as_array().unwrap().iter().map(|c| c["level"].as_u64().unwrap()).collect();
        assert_eq!(levels, vec![0, 0, 1, 1, 1], "{flags:?}");
        // vel on its own voxels: an eighth of a full-resolution channel each, far from 2.5× the fine asset.
        let ratio = both["file_bytes"].as_f64().unwrap() / fine["file_bytes"].as_f64().unwrap();
        assert!(ratio > 1.01 && ratio < 1.6, "{flags:?}: {ratio}");
        for c in both["channels"].as_array().unwrap() {
            assert!(c["voxel_psnr"].as_f64().unwrap() > 25.0, "{flags:?}: {c}");
            if flags.contains(&"--max-error") {
                assert!(c["voxel_max_error"].as_f64().unwrap() <= 0.01, "{flags:?}: {c}");
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn segments_parts_and_supercompression_keep_the_resolutions() {
    if !python_ok() {
        return;
    }
    let dir = scratch_dir("resolution", "parts");
    let input = pyro(&dir.join("in"), 4, &["--vel-scale", "4", "--offset", "1"]);
    let seg = ["--segment-frames", "2", "--supercompress", "zstd"];
    let whole = cook_into(&dir, "whole.vpak", &[&input], &with_grids(&seg));
    let mut parts: Vec<PathBuf> = Vec::new();
    for i in 1..=2 {
        let part = format!("{i}/2");
        parts.push(cook_into(&dir, &format!("p{i}.part"), &[&input], &with_grids(&[&seg[..], &["--part", &part]].concat())));
    }
    let joined = dir.join("joined.vpak");
    ok(vdbcook(&["join", "-q", s(&parts[0]), s(&parts[1]), "-o", s(&joined)]));
    assert_eq!(std::fs::read(&whole).unwrap(), std::fs::read(&joined).unwrap(), "parts joined differ from one process");
    // One thread cooks the same bytes.
    let one = dir.join("one.vpak");
    let mut args = vec!["cook", "-q", "--force", "-o", s(&one)];
    args.extend(with_grids(&seg));
    args.push(&input);
    ok(Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(&args).env("RAYON_NUM_THREADS", "1").current_dir(root()).output().unwrap());
    assert_eq!(std::fs::read(&whole).unwrap(), std::fs::read(&one).unwrap(), "one thread cooked other bytes");
    let doc = inspect(&whole);
    assert_eq!(doc["levels"].as_array().map(Vec::len), Some(3), "{}", doc["levels"]);
    // The plain asset, recompressed, is the supercompressed one's bytes restored.
    let plain = cook_into(&dir, "plain.vpak", &[&input], &with_grids(&seg[..2]));
    let back = dir.join("back.vpak");
    ok(vdbcook(&["recompress", "-q", s(&whole), "-o", s(&back), "--supercompress", "none"]));
    assert_eq!(std::fs::read(&plain).unwrap(), std::fs::read(&back).unwrap());
    // Every frame unpacks, each channel at its own voxels.
    for f in 0..4 {
        ok(vdbcook(&["unpack", "-q", "--force", s(&whole), "--frame", &f.to_string(), "-o", s(&dir.join(format!("f{f}.vdb")))]));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_asset_validates_with_vel_in_the_voxel_domain_and_plays() {
    if !python_ok() || !gpu_available() {
        return;
    }
    let dir = scratch_dir("resolution", "validate");
    let input = pyro(&dir.join("in"), 2, &[]);
    let out = dir.join("a.vpak");
    let cooked = ok(vdbcook(&[
        "cook",
        "--force",
        "--json",
        "--validate",
        "--views",
        "2",
        "--size",
        "48x48",
        "--max-rmse",
        "0.01",
        "-o",
        s(&out),
        "--grids",
        "density,temperature,vel",
        "--format",
        "bc7",
        &input,
    ]));
    let doc: serde_json::Value = serde_json::from_slice(&cooked.stdout).unwrap();
    let voxel = &doc["validation"]["voxel_channels"];
    let names: Vec<&str> = voxel.as_array().map(|a| a.iter().filter_map(|c| c["name"].as_str()).collect()).unwrap_or_default();
    assert_eq!(names, ["density", "temperature", "vel.x", "vel.y", "vel.z"], "{}", doc["validation"]);
    // bc7 loses something in every channel: each was compared over voxels of its own.
    for c in voxel.as_array().unwrap() {
        assert!(c["rmse"].as_f64().unwrap() > 0.0 && c["psnr"].as_f64().unwrap() > 25.0, "{c}");
    }
    // The coarse channel drawn on its own: at its level, it shows.
    let png = dir.join("vel.png");
    ok(vdbcook(&["render", "-q", "--force", s(&out), "--extinction", "vel.y", "--size", "48x48", "-o", s(&png)]));
    // Played headless, every frame draws.
    let played = ok(vdbcook(&["play", s(&out), "--headless", "--json", "--size", "32x32"]));
    let p: serde_json::Value = serde_json::from_slice(&played.stdout).unwrap();
    assert_eq!(p["frames"].as_array().map(Vec::len), Some(2), "{p}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Checks with OpenVDB that each grid of `unpacked` holds, at every active
/// voxel of the same grid in `sources`, the same value, active, and that its
/// transform maps index to world as the source's does. Prints the values compared.
const SAME_AS_SOURCES: &str = r#"
import sys, pyopenvdb as vdb
unpacked, sources = sys.argv[1], sys.argv[2:]
back = {g.name: g for g in vdb.readAll(unpacked)[0]}
n = 0
for f in sources:
    for src in vdb.readAll(f)[0]:
        got = back[src.name]
        for p in [(0, 0, 0), (1, 2, 3), (-7, 5, 11)]:
            a, b = src.transform.indexToWorld(p), got.transform.indexToWorld(p)
            assert max(abs(x - y) for x, y in zip(a, b)) < 1e-9, (src.name, p, a, b)
        acc = got.getConstAccessor()
        for item in src.iterOnValues():
            assert item["min"] == item["max"], "voxels only"
            v, on = acc.probeValue(item["min"])
            assert on and v == item["value"], (src.name, item["min"], v, item["value"])
            n += 1
print(n)
"#;

#[test]
fn two_files_per_frame_at_two_voxel_sizes_round_trip_through_openvdb() {
    if !python_ok() {
        return;
    }
    let dir = scratch_dir("resolution", "split");
    pyro(&dir.join("in"), 2, &["--split"]);
    let (noise, data) = (dir.join("in/noise"), dir.join("in/data"));
    let asset = cook_into(&dir, "a.vpak", &[s(&noise)], &["--format", "f32", "--grids", "density,temperature,vel", "--with", s(&data)]);
    let doc = inspect(&asset);
    let levels: Vec<u64> = doc["channels"].as_array().unwrap().iter().map(|c| c["level"].as_u64().unwrap()).collect();
    assert_eq!(levels, [0, 0, 1, 1, 1]);
    assert_eq!(doc["sources"].as_array().map(Vec::len), Some(4), "both files of both frames: {}", doc["sources"]);
    for frame in 0..2 {
        let out = dir.join(format!("f{frame}.vdb"));
        ok(vdbcook(&["unpack", "-q", "--force", s(&asset), "--frame", &frame.to_string(), "-o", s(&out)]));
        let n = frame + 1;
        let sources = [noise.join(format!("pyro_noise_{n:04}.vdb")), data.join(format!("pyro_data_{n:04}.vdb"))];
        let r = Command::new("/usr/bin/python3").args(["-c", SAME_AS_SOURCES, s(&out), s(&sources[0]), s(&sources[1])]).output().unwrap();
        assert!(r.status.success(), "frame {frame}: {}", String::from_utf8_lossy(&r.stderr));
        let compared: u64 = String::from_utf8_lossy(&r.stdout).trim().parse().unwrap();
        assert!(compared > 10_000, "frame {frame}: {compared} values compared");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
