//! `parts = N` in a bake manifest: an asset cooked as N part units dealt out
//! over shards like assets and joined by `bake --merge` (or by a bake that
//! baked every part), to the unsplit bake's asset; missing parts and
//! manifest errors.

mod common;
use common::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use vdbcook_vpak::segments::rewrite_metadata;
use vdbcook_vpak::Asset;

/// A project of two assets (a still and a 4-frame sequence, supercompressed:
/// the still's small body is wrapped) in `dir`; the sequence's table gets
/// `extra` (e.g. "parts = 2").
fn project(dir: &Path, file: &str, extra: &str) -> PathBuf {
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    std::fs::copy(root().join("fixtures/fog_none.vdb"), src.join("fog.vdb")).unwrap();
    for i in 1..=4 {
        let f = format!("smoke_{i:04}.vdb");
        std::fs::copy(root().join("fixtures/smoke_seq").join(&f), src.join(&f)).unwrap();
    }
    let manifest = dir.join(file);
    let text = format!(
        "[defaults]\nformat = \"bc4\"\nquality = \"ultra-fast\"\nsupercompress = \"zstd\"\n\n[[asset]]\nname = \"fog\"\noutput = \"fog.vpak\"\ninputs = [\"src/fog.vdb\"]\n\n[[asset]]\nname = \"smoke\"\noutput = \"seq/smoke.vpak\"\ninputs = [\"src/smoke_####.vdb\"]\nframes = \"1-4\"\nsegment_frames = 1\n{extra}\n"
    );
    std::fs::write(&manifest, text).unwrap();
    manifest
}

/// `vdbcook bake ARGS --json`: exit code, report, stderr.
fn bake(args: &[&str]) -> (Option<i32>, Value, String) {
    let mut a = vec!["bake", "--json"];
    a.extend(args);
    let o = vdbcook(&a);
    (o.status.code(), serde_json::from_slice(&o.stdout).unwrap_or(Value::Null), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn entries(v: &Value) -> Vec<(String, String, Option<String>)> {
    v["assets"]
        .as_array()
        .unwrap_or(&Vec::new())
        .iter()
        .map(|a| (a["name"].as_str().unwrap().into(), a["status"].as_str().unwrap().into(), a["part"]["index"].as_u64().map(|i| format!("{i}/{}", a["part"]["count"]))))
        .collect()
}

/// The asset with the bake's own settings taken out of every segment's metadata.
fn without_bake_settings(path: &Path) -> Vec<u8> {
    let asset = Asset::open(path).unwrap();
    rewrite_metadata(&asset, |m| m.settings.retain(|(k, _)| k != "cache_key" && k != "bake_record")).unwrap()
}

fn record(path: &Path) -> Value {
    let meta = Asset::open(path).unwrap().check().unwrap();
    let text = &meta.settings.iter().find(|(k, _)| k == "bake_record").unwrap().1;
    serde_json::from_str(text).unwrap()
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).map(|r| r.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect()).unwrap_or_default();
    v.sort();
    v
}

#[test]
fn parts_on_two_shards_merge_into_the_unsplit_asset() {
    let dir = scratch_dir("bake-parts", "shards");
    let parted = project(&dir, "parts.toml", "parts = 2");
    let whole = project(&dir, "whole.toml", "");
    let out = |d: &str| dir.join(d);

    // The plan deals units round robin: fog, smoke 1/2, smoke 2/2.
    let o = ok(vdbcook(&["bake", s(&parted), "--plan", "--json", "--shard", "1/2"]));
    let plan: Value = serde_json::from_slice(&o.stdout).unwrap();
    let names: Vec<&str> = plan["assets"].as_array().unwrap().iter().map(|a| a["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["fog", "smoke"]);
    let smoke = &plan["assets"][1]["parts"];
    assert_eq!(smoke.as_array().unwrap().len(), 1, "{smoke}");
    assert_eq!((smoke[0]["part"].as_str(), smoke[0]["output"].as_str()), (Some("2/2"), Some("seq/smoke.vpak.part2of2")));
    assert_eq!(plan["assets"][0]["parts"], Value::Null);

    // The unsplit bake, and the parted one in one process.
    let (code, _, err) = bake(&[s(&whole), "--out-dir", s(&out("whole"))]);
    assert_eq!(code, Some(0), "{err}");
    let (code, v, err) = bake(&[s(&parted), "--out-dir", s(&out("one"))]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(entries(&v), [("fog".into(), "baked".into(), None), ("smoke".into(), "baked".into(), None)]);
    assert_eq!(files_in(&out("one/seq")), ["smoke.vpak"], "the part files go once joined");

    // Two shards, then the merge joins.
    let (code, v, err) = bake(&[s(&parted), "--shard", "1/2", "--out-dir", s(&out("s1"))]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(entries(&v), [("fog".into(), "baked".into(), None), ("smoke".into(), "baked".into(), Some("2/2".into()))]);
    let (code, v, err) = bake(&[s(&parted), "--shard", "2/2", "--out-dir", s(&out("s2"))]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(entries(&v), [("smoke".into(), "baked".into(), Some("1/2".into()))]);
    assert_eq!(files_in(&out("s2/seq")), ["smoke.vpak.part1of2"]);
    let junit = std::fs::read_to_string(out("s2/report.xml")).unwrap();
    assert!(junit.contains("<testcase name=\"smoke (part 1/2)\""), "{junit}");
    let (code, v, err) = bake(&["--merge", s(&out("s1/report.json")), s(&out("s2/report.json")), "--report-dir", s(&out("merged"))]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(entries(&v), [("fog".into(), "baked".into(), None), ("smoke".into(), "baked".into(), None)]);
    let merged = out("merged/seq/smoke.vpak");
    assert!(std::fs::read(&merged).unwrap() == std::fs::read(out("one/seq/smoke.vpak")).unwrap(), "the shards' joined asset differs from one process's");
    assert_eq!(v["assets"][1]["bytes"].as_u64(), Some(std::fs::metadata(&merged).unwrap().len()));

    // The unsplit bake's asset, byte for byte: key and record (voxel error from the segments' sums) included.
    let unsplit = out("whole/seq/smoke.vpak");
    let (a, b) = (record(&merged), record(&unsplit));
    assert!(a["voxel_rmse"].as_f64() > Some(0.0) && a["voxel_rmse"] == b["voxel_rmse"] && a["voxel_psnr"] == b["voxel_psnr"], "{:?} vs {:?}", a["voxel_rmse"], b["voxel_rmse"]);
    assert!(std::fs::read(&merged).unwrap() == std::fs::read(&unsplit).unwrap(), "the joined asset differs from the unsplit bake's");
    assert!(without_bake_settings(&merged) == without_bake_settings(&unsplit));
    // Supercompressed as the manifest says, parts and all; the still's small body wrapped in one zstd frame.
    let joined = Asset::open(&merged).unwrap();
    assert!((0..joined.segment_count()).all(|s| joined.stored_segment(s).unwrap().is_coded()));
    assert!(Asset::open(&out("whole/fog.vpak")).unwrap().is_wrapped(0));

    // Baked again: the joined asset is in place, so no part is cooked.
    let (code, v, err) = bake(&[s(&parted), "--out-dir", s(&out("one"))]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(entries(&v), [("fog".into(), "cached".into(), None), ("smoke".into(), "cached".into(), None)]);
    // A shard again: its part is in place, and a cache serves the next one.
    let cache = out("cache");
    let (code, v, err) = bake(&[s(&parted), "--shard", "2/2", "--out-dir", s(&out("s2")), "--cache", s(&cache)]);
    assert_eq!((code, entries(&v)[0].1.as_str()), (Some(0), "cached"), "{err}");
    let (code, v, err) = bake(&[s(&parted), "--shard", "2/2", "--out-dir", s(&out("s2b")), "--cache", s(&cache)]);
    assert_eq!((code, entries(&v)[0].1.as_str()), (Some(0), "baked"), "{err}");
    let (code, v, err) = bake(&[s(&parted), "--shard", "2/2", "--out-dir", s(&out("s2c")), "--cache", s(&cache)]);
    assert_eq!((code, entries(&v)[0].1.as_str()), (Some(0), "cached"), "{err}");
    assert!(std::fs::read(out("s2c/seq/smoke.vpak.part1of2")).unwrap() == std::fs::read(out("s2/seq/smoke.vpak.part1of2")).unwrap());

    // Missing parts: one line naming the asset and the part, exit 1, nothing written.
    let report_dir = out("bad");
    let o = vdbcook(&["bake", "--merge", s(&out("s1/report.json")), "--report-dir", s(&report_dir)]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && e.lines().count() == 1 && e.contains("asset smoke: part 1/2 is in none of the reports"), "{:?}: {e}", o.status);
    assert!(!report_dir.exists(), "{:?}", files_in(&report_dir));
    std::fs::remove_file(out("s2/seq/smoke.vpak.part1of2")).unwrap();
    let o = vdbcook(&["bake", "--merge", s(&out("s1/report.json")), s(&out("s2/report.json")), "--report-dir", s(&report_dir)]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && e.lines().count() == 1 && e.contains("asset smoke: part 1/2 is missing") && e.contains("smoke.vpak.part1of2"), "{:?}: {e}", o.status);
    assert!(!report_dir.exists(), "{:?}", files_in(&report_dir));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn parts_errors_in_the_manifest_write_nothing() {
    let dir = scratch_dir("bake-parts", "errors");
    let cases = [
        ("parts = 2", "segment_frames = 1\n", "segment_frames = 2\n", ""),
        ("parts = 2\nvalidate = true", "", "", "validate: decides over the whole asset"),
        ("parts = 2", "segment_frames = 1\n", "", "parts: needs segment_frames"),
        ("parts = 8", "", "", "parts: 8 parts of 4 segment(s)"),
        ("parts = 0", "", "", "parts: 0 is not in 2..=1024"),
        ("parts = \"2\"", "", "", "parts: invalid type"),
    ];
    for (k, (extra, from, to, want)) in cases.into_iter().enumerate() {
        let m = project(&dir, &format!("m{k}.toml"), extra);
        let text = std::fs::read_to_string(&m).unwrap().replace(from, to);
        std::fs::write(&m, text).unwrap();
        let o = vdbcook(&["bake", s(&m), "--out-dir", s(&dir.join("out"))]);
        let e = String::from_utf8_lossy(&o.stderr);
        if want.is_empty() {
            // segment_frames = 2: two segments, two parts; fine.
            let plan = ok(vdbcook(&["bake", s(&m), "--plan"]));
            assert!(String::from_utf8_lossy(&plan.stdout).contains("part 2/2"), "{}", String::from_utf8_lossy(&plan.stdout));
            assert!(o.status.success(), "{e}");
            let _ = std::fs::remove_dir_all(dir.join("out"));
            continue;
        }
        assert_eq!(o.status.code(), Some(2), "{extra}: {e}");
        assert!(e.lines().count() == 1 && e.contains(&format!("m{k}.toml:")) && e.contains(want), "{extra}: expected {want:?}, got {e}");
        assert!(!dir.join("out").exists(), "{extra}: something was written");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
