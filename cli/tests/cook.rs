//! `vdbcook cook` and `unpack` end to end, checked through OpenVDB itself.

mod common;
use common::*;
use std::path::{Path, PathBuf};

fn scratch() -> PathBuf {
    let d = std::env::temp_dir().join(format!("vdbcook-cook-{}-{}", std::process::id(), std::thread::current().name().unwrap_or("t").replace("::", "_")));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Active voxels as (coord, value), and active tiles as (min, max, value).
type OracleVoxels = (Vec<([i32; 3], f64)>, Vec<([i32; 3], [i32; 3], f64)>);

/// Active voxels of grid 0 in an oracle dump: (coord, value), sorted.
fn openvdb_voxels(file: &Path, dir: &Path) -> OracleVoxels {
    let dump = dir.join(format!("{}.bin", file.file_name().unwrap().to_string_lossy()));
    oracle(file, Some(&dump)).expect("OpenVDB reads it");
    let b = std::fs::read(&dump).unwrap();
    let nv = u64::from_le_bytes(b[16..24].try_into().unwrap()) as usize;
    let nt = u64::from_le_bytes(b[24..32].try_into().unwrap()) as usize;
    let i32_at = |o: usize| i32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let mut v = Vec::new();
    let mut o = 32;
    for _ in 0..nv {
        if i32_at(o) == 0 {
            v.push(([i32_at(o + 4), i32_at(o + 8), i32_at(o + 12)], f64_at(o + 16)));
        }
        o += 24;
    }
    let mut t = Vec::new();
    for _ in 0..nt {
        if i32_at(o) == 0 {
            t.push(([i32_at(o + 4), i32_at(o + 8), i32_at(o + 12)], [i32_at(o + 16), i32_at(o + 20), i32_at(o + 24)], f64_at(o + 28)));
        }
        o += 36;
    }
    (v, t)
}

/// Cooks `inputs` (one grid per frame, selected by default) and checks every
/// unpacked frame against its source through OpenVDB; `tol(source, unpacked)`.
fn round_trip(inputs: &[&str], format: &str, tol: impl Fn(f64, f64) -> bool) {
    let dir = scratch();
    let asset = dir.join(format!("rt-{format}.vpak"));
    let mut args = vec!["cook", "-q", "--format", format, "-o", s(&asset)];
    args.extend(inputs);
    ok(vdbcook(&args));
    for (frame, src) in inputs.iter().enumerate() {
        let out = dir.join(format!("frame{frame}-{format}.vdb"));
        ok(vdbcook(&["unpack", "-q", s(&asset), "--frame", &frame.to_string(), "-o", s(&out)]));
        let (sv, st) = openvdb_voxels(&root().join(src), &dir);
        let (uv, ut) = openvdb_voxels(&out, &dir);
        assert_eq!(sv.len(), uv.len(), "{src} {format}: active voxel count");
        for (a, b) in sv.iter().zip(&uv) {
            assert_eq!(a.0, b.0, "{src} {format}: active set");
            assert!(tol(a.1, b.1), "{src} {format}: voxel {:?}: source {} unpacked {}", a.0, a.1, b.1);
        }
        assert_eq!(st, ut, "{src} {format}: tiles");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

const SEQ: [&str; 4] = ["fixtures/smoke_seq/smoke_0001.vdb", "fixtures/smoke_seq/smoke_0002.vdb", "fixtures/smoke_seq/smoke_0003.vdb", "fixtures/smoke_seq/smoke_0004.vdb"];

#[test]
fn f32_round_trip_through_openvdb_is_exact() {
    if !oracle_available() {
        return;
    }
    round_trip(&SEQ, "f32", |a, b| a == b);
    round_trip(&["fixtures/tiles.vdb"], "f32", |a, b| a == b);
    round_trip(&["fixtures/levelset_half.vdb"], "f32", |a, b| a == b);
}

#[test]
fn f16_round_trip_is_within_half_precision() {
    if !oracle_available() {
        return;
    }
    round_trip(&SEQ, "f16", |a, b| a == b || (a - b).abs() <= a.abs() * 2f64.powi(-11) + 6e-8);
}

#[test]
fn unorm8_round_trip_is_within_half_a_step_of_each_brick() {
    if !oracle_available() {
        return;
    }
    // Each brick's range is the min and max of its active values (inactive
    // voxels are filled from them), and a step is range / 255.
    let file = vdbcook_vdb::open(&root().join("fixtures/fog_blosc.vdb")).unwrap();
    let grid = file.read_grid(file.select(None).unwrap()).unwrap();
    let step_of = |c: [i32; 3]| {
        let o = vdbcook_grid::Coord::new(c[0], c[1], c[2]).leaf_origin();
        let leaf = grid.leaves.iter().find(|l| l.origin == o).unwrap();
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for i in leaf.mask.iter_on() {
            lo = lo.min(f64::from(leaf.values[i]));
            hi = hi.max(f64::from(leaf.values[i]));
        }
        (hi - lo) / 255.0
    };
    let dir = scratch();
    let asset = dir.join("u8.vpak");
    ok(vdbcook(&["cook", "-q", "--format", "unorm8", "-o", s(&asset), "fixtures/fog_blosc.vdb"]));
    let out = dir.join("u8.vdb");
    ok(vdbcook(&["unpack", "-q", s(&asset), "--frame", "0", "-o", s(&out)]));
    let (sv, _) = openvdb_voxels(&root().join("fixtures/fog_blosc.vdb"), &dir);
    let (uv, _) = openvdb_voxels(&out, &dir);
    assert_eq!(sv.len(), uv.len());
    for (a, b) in sv.iter().zip(&uv) {
        assert_eq!(a.0, b.0);
        let half_step = step_of(a.0) * 0.5;
        assert!((a.1 - b.1).abs() <= half_step * (1.0 + 1e-5) + 1e-7, "voxel {:?}: {} vs {} (half step {half_step})", a.0, a.1, b.1);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn same_bytes_on_one_and_two_threads() {
    let dir = scratch();
    let (a, b) = (dir.join("a.vpak"), dir.join("b.vpak"));
    ok(vdbcook(&["-j", "1", "cook", "-q", "--format", "unorm8", "-o", s(&a), "fixtures/smoke_seq"]));
    ok(vdbcook(&["-j", "2", "cook", "-q", "--format", "unorm8", "-o", s(&b), "fixtures/smoke_seq"]));
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_hundred_unchanging_frames_cost_about_one() {
    let dir = scratch();
    let (one, hundred) = (dir.join("one.vpak"), dir.join("hundred.vpak"));
    ok(vdbcook(&["cook", "-q", "-o", s(&one), "fixtures/fog_blosc.vdb"]));
    let mut args = vec!["cook", "-q", "-o", s(&hundred)];
    args.extend(std::iter::repeat_n("fixtures/fog_blosc.vdb", 100));
    ok(vdbcook(&args));
    let (a, b) = (std::fs::metadata(&one).unwrap().len(), std::fs::metadata(&hundred).unwrap().len());
    assert!((b as f64) < a as f64 * 1.03, "one frame {a} bytes, a hundred {b}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn existing_output_needs_force_and_failures_leave_it_alone() {
    let dir = scratch();
    let out = dir.join("x.vpak");
    ok(vdbcook(&["cook", "-q", "-o", s(&out), "fixtures/fog_blosc.vdb"]));
    let before = std::fs::read(&out).unwrap();
    let r = vdbcook(&["cook", "-q", "-o", s(&out), "fixtures/tiles.vdb"]);
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("--force"));
    // A failing cook, even with --force, leaves the old asset and no temporary file.
    let bad = dir.join("cut.vdb");
    let src = std::fs::read(root().join("fixtures/fog_zip.vdb")).unwrap();
    std::fs::write(&bad, &src[..src.len() / 2]).unwrap();
    let r = vdbcook(&["cook", "-q", "--force", "-o", s(&out), "fixtures/fog_blosc.vdb", s(&bad)]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("cut.vdb") && err.lines().count() == 1, "{err}");
    assert!(std::fs::read(&out).unwrap() == before);
    let names: Vec<String> = std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    assert!(names.iter().all(|n| !n.ends_with(".tmp")), "{names:?}");
    ok(vdbcook(&["cook", "-q", "--force", "-o", s(&out), "fixtures/tiles.vdb"]));
    assert!(std::fs::read(&out).unwrap() != before);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn missing_grids_and_files() {
    let dir = scratch();
    let out = dir.join("m.vpak");
    let r = vdbcook(&["cook", "-q", "--grid", "temperature", "-o", s(&out), "fixtures/smoke_seq/smoke_0001.vdb", "fixtures/fog_blosc.vdb"]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("fog_blosc.vdb") && err.contains("temperature"), "{err}");
    assert!(!out.exists());
    ok(vdbcook(&["cook", "-q", "--allow-missing", "--grid", "temperature", "-o", s(&out), "fixtures/smoke_seq/smoke_0001.vdb", "fixtures/fog_blosc.vdb"]));
    let v: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["inspect", "--json", s(&out)])).stdout).unwrap();
    let f = &v["files"][0];
    assert_eq!(f["frames"], 2);
    // Natural order puts fixtures/fog_blosc.vdb (no temperature grid) first.
    assert_eq!(f["frame_info"][0]["active_voxels"], 0);
    assert!(f["frame_info"][1]["active_voxels"].as_u64().unwrap() > 0);
    // Frame patterns: a missing frame is an error unless allowed.
    let pat = "fixtures/smoke_seq/smoke_####.vdb";
    let r = vdbcook(&["cook", "-q", "--force", "--frames", "1-5", "-o", s(&out), pat]);
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("smoke_0005.vdb"));
    ok(vdbcook(&["cook", "-q", "--force", "--allow-missing", "--frames", "1-5", "-o", s(&out), pat]));
    assert_eq!(vdbcook(&["cook", "-q", "--force", "-o", s(&out), pat]).status.code(), Some(2));
    assert_eq!(vdbcook(&["cook", "-q", "--force", "--frames", "1-2", "-o", s(&out), "fixtures/fog_blosc.vdb"]).status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn inspect_reports_sections_and_refuses_corruption() {
    let dir = scratch();
    let out = dir.join("i.vpak");
    let r = ok(vdbcook(&["cook", "--json", "--format", "f32", "-o", s(&out), "fixtures/smoke_seq"]));
    let cooked: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(cooked["frames"], 4);
    assert!(cooked["unique_bricks"].as_u64().unwrap() <= cooked["bricks"].as_u64().unwrap());
    assert_eq!(cooked["voxel_rmse"], 0.0);
    let v: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["inspect", "--json", s(&out)])).stdout).unwrap();
    let f = &v["files"][0];
    assert_eq!(f["kind"], "vpak");
    assert_eq!(f["format"], "f32");
    assert_eq!(f["nodes"]["l3"]["count"], cooked["l3_nodes"]);
    assert_eq!(f["file_bytes"], cooked["file_bytes"]);
    assert_eq!(f["sources"].as_array().unwrap().len(), 4);
    // Flip one byte of the brick atlas: inspect and unpack both refuse the asset.
    let atlas = f["sections"].as_array().unwrap().iter().find(|s| s["name"] == "brick atlas").unwrap();
    let mut bytes = std::fs::read(&out).unwrap();
    bytes[atlas["offset"].as_u64().unwrap() as usize + 100] ^= 0x55;
    let bad = dir.join("bad.vpak");
    std::fs::write(&bad, bytes).unwrap();
    let r = vdbcook(&["inspect", s(&bad)]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("bad.vpak") && err.contains("checksum"), "{err}");
    let r = vdbcook(&["unpack", s(&bad), "--frame", "0", "-o", s(&dir.join("u.vdb"))]);
    assert_eq!(r.status.code(), Some(1));
    assert!(!dir.join("u.vdb").exists());
    let r = vdbcook(&["unpack", s(&out), "--frame", "4", "-o", s(&dir.join("u.vdb"))]);
    assert!(String::from_utf8_lossy(&r.stderr).contains("out of range"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn real_samples_cook() {
    // Files written by other tools: half floats, tiles, an AffineMap, a double grid,
    // an EmberGen sequence whose first frame is empty.
    let Some(samples) = shared_samples() else { return };
    let dir = scratch();
    for (i, (input, grid)) in
        [("elyg-visualizer/test.vdb", None), ("vfx-toolkit-embergen", Some("flames")), ("waveletturbulence", None), ("hsim/writer.vdb", None), ("vscode-cmaketemplate/smoke.vdb", None)]
            .into_iter()
            .enumerate()
    {
        let out = dir.join(format!("{i}.vpak"));
        let mut args = vec!["cook", "-q", "-o", s(&out)];
        if let Some(g) = grid {
            args.extend(["--grid", g]);
        }
        let path = samples.join(input);
        args.push(s(&path));
        let r = vdbcook(&args);
        assert!(r.status.success(), "{input}: {}", String::from_utf8_lossy(&r.stderr));
        ok(vdbcook(&["inspect", s(&out)]));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bc7_unpack_read_by_openvdb_matches_the_reported_rmse() {
    if !oracle_available() {
        return;
    }
    let dir = scratch();
    let asset = dir.join("bc7.vpak");
    let r = ok(vdbcook(&["cook", "--json", "--format", "bc7", "-o", s(&asset), "fixtures/fog_blosc.vdb"]));
    let report: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let reported = report["voxel_rmse"].as_f64().unwrap();
    let out = dir.join("bc7.vdb");
    ok(vdbcook(&["unpack", "-q", s(&asset), "--frame", "0", "-o", s(&out)]));
    let (sv, _) = openvdb_voxels(&root().join("fixtures/fog_blosc.vdb"), &dir);
    let (uv, _) = openvdb_voxels(&out, &dir);
    assert_eq!(sv.len(), uv.len());
    let mut sum = 0.0;
    for (a, b) in sv.iter().zip(&uv) {
        assert_eq!(a.0, b.0);
        sum += (a.1 - b.1).powi(2);
    }
    let rmse = (sum / sv.len() as f64).sqrt();
    assert!(reported > 0.0 && (rmse - reported).abs() <= reported * 1e-4, "OpenVDB sees {rmse}, the report says {reported}");
    // `vdbcook diff` agrees too.
    let d: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["diff", "--json", "fixtures/fog_blosc.vdb", s(&out)])).stdout).unwrap();
    assert!((d["rmse"].as_f64().unwrap() - reported).abs() <= reported * 1e-4);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn clustering_report_and_bound() {
    let dir = scratch();
    let asset = dir.join("cl.vpak");
    let r = ok(vdbcook(&["cook", "--json", "--format", "f32", "--clusters", "16", "--variance-threshold", "1", "--max-brick-error", "0.05", "-o", s(&asset), "fixtures/fog_blosc.vdb"]));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let c = &v["clustering"];
    assert!(c["bricks_out"].as_u64().unwrap() < c["bricks_in"].as_u64().unwrap(), "{c}");
    assert_eq!(c["rmse_without"], 0.0);
    assert!(c["rmse_with"].as_f64().unwrap() > 0.0);
    assert!(v["voxel_max_error"].as_f64().unwrap() <= 0.05 + 1e-6);
    let _ = std::fs::remove_dir_all(&dir);
}
