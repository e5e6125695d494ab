//! Time in the asset (source frame numbers and frame rate, format version 9)
//! and `vdbcook play`: streamed segments, frames identical to `render`.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

fn numbers(doc: &serde_json::Value, key: &str) -> Vec<i64> {
    doc[key].as_array().unwrap_or_else(|| panic!("no {key}: {doc}")).iter().map(|v| v.as_i64().unwrap()).collect()
}

fn json(out: std::process::Output) -> serde_json::Value {
    serde_json::from_slice(&ok(out).stdout).unwrap()
}

#[test]
fn frames_keep_their_source_numbers_and_rate() {
    let dir = scratch_dir("play", "numbers");
    numbered_copies(&dir, "fire", 1001..=1010);
    let pattern = dir.join("fire_####.vdb");
    let asset = cook_into(&dir, "fire.vpak", &[s(&pattern)], &["--frames", "1001-1010:3", "--fps", "30", "--segment-frames", "2", "--supercompress", "zstd"]);
    let doc = inspect(&asset);
    assert_eq!((doc["fps"].as_f64(), doc["time_recorded"].as_bool()), (Some(30.0), Some(true)));
    assert_eq!(numbers(&doc, "frame_numbers"), [1001, 1004, 1007, 1010]);
    assert_eq!(doc["segments"].as_array().unwrap().iter().map(|s| s["first_number"].as_i64().unwrap()).collect::<Vec<_>>(), [1001, 1007]);
    assert_eq!(doc["settings"]["fps"], "30");
    // The spec-only reader finds the same.
    let spec = Command::new("/usr/bin/python3").args([s(&root().join("scripts/vpak_read.py")), s(&asset), "--json"]).output().unwrap();
    let spec = json(spec);
    assert_eq!((spec["fps"].as_f64(), numbers(&spec, "frame_numbers")), (Some(30.0), vec![1001, 1004, 1007, 1010]));
    // The cook report too (a second cook, into JSON).
    let out = dir.join("again.vpak");
    let report = json(vdbcook(&["cook", "--json", "-o", s(&out), s(&pattern), "--frames", "1001-1010:3", "--fps", "30", "--segment-frames", "2", "--supercompress", "zstd"]));
    assert_eq!((report["fps"].as_f64(), numbers(&report, "frame_numbers")), (Some(30.0), vec![1001, 1004, 1007, 1010]));
    assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(&asset).unwrap(), "the same cook gives the same bytes");

    // play reports them (and holds to no rate unless asked).
    if gpu_available() {
        let played = json(vdbcook(&["play", "--headless", "--json", s(&asset), "--size", "16x16"]));
        let played_numbers: Vec<i64> = played["frames"].as_array().unwrap().iter().map(|f| f["number"].as_i64().unwrap()).collect();
        assert_eq!((played["asset_fps"].as_f64(), played_numbers, played["fps_held"].is_null()), (Some(30.0), vec![1001, 1004, 1007, 1010], true));
        // validate --source-frame renders that frame alone.
        let checked = json(vdbcook(&["validate", s(&asset), "--source-frame", "1007", "--size", "16x16", "--views", "1", "--json"]));
        let images: Vec<(u64, i64)> = checked["images"].as_array().unwrap().iter().map(|i| (i["frame"].as_u64().unwrap(), i["number"].as_i64().unwrap())).collect();
        assert_eq!((images, checked["worst"]["number"].as_i64()), (vec![(2, 1007)], Some(1007)));
    }
    // A frame chosen by its source number is the frame at its index.
    let (by_number, by_index) = (dir.join("n.vdb"), dir.join("i.vdb"));
    ok(vdbcook(&["unpack", s(&asset), "--source-frame", "1007", "-o", s(&by_number)]));
    ok(vdbcook(&["unpack", s(&asset), "--frame", "2", "-o", s(&by_index)]));
    assert_eq!(std::fs::read(&by_number).unwrap(), std::fs::read(&by_index).unwrap());
    let missing = vdbcook(&["unpack", s(&asset), "--source-frame", "1005", "-o", s(&dir.join("x.vdb"))]);
    let err = String::from_utf8_lossy(&missing.stderr);
    assert_eq!((missing.status.code(), err.lines().count()), (Some(1), 1), "{err}");
    assert!(err.contains("no frame has source number 1005") && err.contains("1001-1010 step 3"), "{err}");
    assert!(!dir.join("x.vdb").exists());

    // Files given as a directory: numbers from their names, gaps kept.
    let gappy = dir.join("gappy");
    std::fs::create_dir_all(&gappy).unwrap();
    numbered_copies(&gappy, "smoke", [7, 8, 12].into_iter());
    assert_eq!(numbers(&inspect(&cook_into(&dir, "gappy.vpak", &[s(&gappy)], &[])), "frame_numbers"), [7, 8, 12]);
    // Names whose numbers do not increase (two sequences given together): numbered from 0, at 24 fps.
    let twice = cook_into(&dir, "twice.vpak", &[s(&gappy.join("smoke_0007.vdb")), s(&dir.join("fire_1001.vdb")), s(&gappy.join("smoke_0008.vdb"))], &[]);
    let doc = inspect(&twice);
    assert_eq!((numbers(&doc, "frame_numbers"), doc["fps"].as_f64()), (vec![0, 1, 2], Some(24.0)));
}

#[test]
fn a_bad_frame_rate_is_a_usage_error() {
    let smoke = root().join("fixtures/smoke_seq");
    for bad in ["0", "-24", "nan", "5000", "fast"] {
        let out = vdbcook(&["cook", s(&smoke), "-o", "/nonexistent/x.vpak", "--fps", bad]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "--fps {bad}: {err}");
        assert!(err.contains("--fps"), "{err}");
    }
}

/// An asset of `frames` copies of one fixture frame, `per` frames a
/// segment, supercompressed: every segment the same size on the GPU.
fn same_segments(dir: &Path, frames: i64, per: u32) -> PathBuf {
    let src = dir.join("same");
    std::fs::create_dir_all(&src).unwrap();
    let one = root().join("fixtures/smoke_seq/smoke_0003.vdb");
    for n in 1..=frames {
        std::fs::copy(&one, src.join(format!("still_{n:04}.vdb"))).unwrap();
    }
    cook_into(dir, "same.vpak", &[s(&src)], &["--segment-frames", &per.to_string(), "--supercompress", "zstd", "--format", "bc7"])
}

#[test]
fn play_streams_segments_and_draws_what_render_draws() {
    if !gpu_available() {
        return;
    }
    let dir = scratch_dir("play", "stream");
    let asset = same_segments(&dir, 8, 2);
    let frames = dir.join("frames");
    let played = json(vdbcook(&["play", "--headless", s(&asset), "--json", "--size", "64x48", "--out", s(&frames)]));
    let per_frame = played["frames"].as_array().unwrap();
    assert_eq!(per_frame.len(), 8);
    // Every key is documented, and every documented key is there.
    let doc = std::fs::read_to_string(root().join("docs/play-json.md")).unwrap();
    assert_documented(&played, &doc_section(&doc, "Top level"), "play");
    assert_documented(&per_frame[0], &doc_section(&doc, "Frame objects"), "play frame");
    assert_documented(&played["summary"], &doc_section(&doc, "Summary"), "play summary");
    let summary = &played["summary"];
    assert_eq!((summary["frames"].as_u64(), summary["segments_loaded"].as_u64(), played["segments"].as_u64()), (Some(8), Some(4), Some(4)));
    for (i, f) in per_frame.iter().enumerate() {
        assert_eq!((f["index"].as_u64(), f["frame"].as_u64(), f["number"].as_i64(), f["segment"].as_u64()), (Some(i as u64), Some(i as u64), Some(i as i64 + 1), Some(i as u64 / 2)));
        for k in ["decode_ms", "upload_ms", "render_ms", "wait_ms"] {
            assert!(f[k].as_f64().is_some_and(|v| v >= 0.0), "{k}: {f}");
        }
        // A segment's decode and upload are counted at the frame it became resident for.
        assert_eq!(f["upload_ms"].as_f64().unwrap() > 0.0, i % 2 == 0, "{f}");
    }
    // At most two segments on the GPU: what one segment alone takes, twice.
    let one = json(vdbcook(&["play", "--headless", s(&asset), "--json", "--size", "64x48", "--frames", "0-1"]));
    let single = one["summary"]["peak_resident_bytes"].as_u64().unwrap();
    let peak = summary["peak_resident_bytes"].as_u64().unwrap();
    assert_eq!(one["summary"]["segments_loaded"].as_u64(), Some(1));
    assert!(single > 0 && peak >= single && peak <= 2 * single, "peak {peak} with segments of {single} bytes");
    // Streamed, not loaded whole: playing one segment of four reads that
    // segment and every segment's head (checked at open: header, section
    // table, metadata: about a kilobyte each here), under half the file.
    let file = std::fs::metadata(&asset).unwrap().len();
    let (all_read, one_read) = (summary["bytes_read"].as_u64().unwrap(), one["summary"]["bytes_read"].as_u64().unwrap());
    assert!(one_read < file / 2 && all_read > file * 9 / 10 && all_read < file * 3 / 2, "read {one_read} and {all_read} of a {file}-byte file");
    // Each frame's PNG is what `render` draws of it.
    for f in [0, 3, 7] {
        let png = dir.join(format!("render_{f}.png"));
        ok(vdbcook(&["render", s(&asset), "--frame", &f.to_string(), "--size", "64x48", "-o", s(&png)]));
        assert_eq!(std::fs::read(&png).unwrap(), std::fs::read(frames.join(format!("{f:05}.png"))).unwrap(), "frame {f}");
    }
    // A loop plays the frames again, loading the segments again.
    let twice = json(vdbcook(&["play", "--headless", s(&asset), "--json", "--size", "32x32", "--frames", "2-5", "--loop", "2"]));
    assert_eq!(twice["frames"].as_array().unwrap().iter().map(|f| f["frame"].as_u64().unwrap()).collect::<Vec<_>>(), [2, 3, 4, 5, 2, 3, 4, 5]);
    assert_eq!(twice["summary"]["segments_loaded"].as_u64(), Some(4));
}

#[test]
fn play_refuses_what_it_cannot_do() {
    let dir = scratch_dir("play", "refusals");
    let asset = cook_into(&dir, "smoke.vpak", &[s(&root().join("fixtures/smoke_seq"))], &[]);
    let missing = dir.join("missing.vpak");
    let cases: [(&[&str], i32, &str); 4] = [
        (&["play", s(&asset), "--json"], 2, "--json needs --headless"),
        (&["play", "--headless", s(&asset), "--frames", "2-9"], 1, "frame 4 is out of range"),
        (&["play", "--headless", s(&asset), "--loop", "0"], 2, "--loop"),
        (&["play", "--headless", s(&missing)], 1, "missing.vpak"),
    ];
    // Without --headless it plays in view's window, which needs a display.
    let windowless = Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(["play", s(&asset)]).env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY").output().unwrap();
    let err = String::from_utf8_lossy(&windowless.stderr);
    assert_eq!((windowless.status.code(), err.lines().count()), (Some(1), 1), "{err}");
    assert!(err.contains("no display"), "{err}");
    for (args, code, says) in cases {
        let out = vdbcook(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{args:?}: {err}");
        assert!(err.contains(says) && err.lines().count() == 1, "{args:?}: {err}");
    }
}

#[test]
fn what_the_sources_say_of_time_is_reported() {
    let Some(samples) = shared_samples() else { return };
    let dir = scratch_dir("play", "source-time");
    let fire: Vec<PathBuf> = (0..4).map(|i| samples.join(format!("vfx-toolkit-embergen/embergen_fire_a_{i}.vdb"))).collect();
    let out = dir.join("fire.vpak");
    let mut args = vec!["cook", "--json", "-o", s(&out), "--grids", "temperature,flames"];
    args.extend(fire.iter().map(|p| s(p)));
    let report = json(vdbcook(&args));
    // EmberGen writes each frame's simulation_time (1/60 s apart); the asset keeps --fps.
    let t = &report["source_time"];
    assert_eq!((t["key"].as_str(), t["frames"].as_u64(), t["stated_fps"].is_null()), (Some("simulation_time"), Some(4), true), "{t}");
    assert!((t["implied_fps"].as_f64().unwrap() - 60.0).abs() < 1e-3, "{t}");
    assert_eq!((report["fps"].as_f64(), numbers(&report, "frame_numbers")), (Some(24.0), vec![0, 1, 2, 3]));
    let text_out = dir.join("text.vpak");
    let text = ok(vdbcook(&["cook", "-o", s(&text_out), "--grids", "temperature,flames", s(&fire[0]), s(&fire[1])]));
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("simulation_time 0 to 0.016667 s over 2 frames, 60 frames per second of that time; the asset plays at 24 fps"), "{text}");
    // Files that say nothing of time: no such line, and null in the JSON.
    let (smoke_out, smoke) = (dir.join("smoke.vpak"), root().join("fixtures/smoke_seq"));
    let plain = json(vdbcook(&["cook", "--json", "-o", s(&smoke_out), s(&smoke)]));
    assert!(plain["source_time"].is_null());
}
