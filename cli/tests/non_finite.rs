//! Real data holds NaN and ±inf voxels (Blender's empty obstacle level sets,
//! the odd bad voxel of a simulation): `cook` reports honest figures over the
//! finite voxels and says what it did with the others, no format lets them
//! damage their neighbours, `inspect` tells a non-finite figure from a
//! missing one, and both JSON outputs follow their documented schemas.

mod common;
use common::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use vdbcook_grid::{Coord, Grid, GridClass, Leaf, LeafMask, Transform};

fn scratch(name: &str) -> Scratch {
    scratch_dir("non-finite", name)
}

/// Voxels made NaN and +inf in [`dirty`], both inside one brick.
const NAN_AT: (usize, usize) = (5, 3 * 64 + 4 * 8 + 5);
const INF_AT: (usize, usize) = (5, 4 * 64 + 4 * 8 + 4);

/// A smooth 24³ block of density in [0, 1.6] (27 full leaves).
fn clean() -> Grid {
    let mut leaves = Vec::new();
    for (bx, by, bz) in (0..27).map(|k| (k / 9, (k / 3) % 3, k % 3)) {
        let origin = Coord::new(bx * 8, by * 8, bz * 8);
        let values = std::array::from_fn(|i| {
            let (x, y, z) = ((bx * 8) as f32 + (i / 64) as f32, (by * 8) as f32 + ((i / 8) % 8) as f32, (bz * 8) as f32 + (i % 8) as f32);
            0.8 + 0.8 * (x * 0.21).sin() * (y * 0.17 + z * 0.13).cos()
        });
        leaves.push(Leaf { origin, mask: LeafMask([u64::MAX; 8]), values });
    }
    Grid { name: "density".into(), class: GridClass::FogVolume, background: 0.0, transform: Transform::identity(), leaves, tiles: vec![] }
}

fn dirty() -> Grid {
    let mut g = clean();
    g.leaves[NAN_AT.0].values[NAN_AT.1] = f32::NAN;
    g.leaves[INF_AT.0].values[INF_AT.1] = f32::INFINITY;
    g
}

fn write(dir: &Path, name: &str, g: &Grid) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, vdbcook_vdb::write_vdb(g, vdbcook_vdb::WriteOptions::default()).unwrap()).unwrap();
    p
}

fn cook_json(input: &Path, out: &Path, args: &[&str]) -> Value {
    let mut a = vec!["cook", s(input), "-o", s(out), "--force", "--json"];
    a.extend_from_slice(args);
    serde_json::from_slice(&ok(vdbcook(&a)).stdout).unwrap()
}

/// The one grid of a .vdb, read back.
fn read(p: &Path) -> Grid {
    vdbcook_vdb::open(p).unwrap().read_grid(0).unwrap()
}

#[test]
fn every_format_reports_the_finite_voxels_and_spares_their_neighbours() {
    let dir = scratch("formats");
    let (clean_vdb, dirty_vdb) = (write(&dir, "clean.vdb", &clean()), write(&dir, "dirty.vdb", &dirty()));
    for format in ["f32", "f16", "unorm8", "bc4", "bc7"] {
        let want = cook_json(&clean_vdb, &dir.join("clean.vpak"), &["--format", format]);
        let got = cook_json(&dirty_vdb, &dir.join("dirty.vpak"), &["--format", format]);
        // The figures are numbers, about those of the grid without the two voxels.
        let (g, w) = (got["voxel_rmse"].as_f64().unwrap_or(f64::NAN), want["voxel_rmse"].as_f64().unwrap());
        assert!((g - w).abs() <= w * 0.02, "{format}: rmse {} against {w} without them", got["voxel_rmse"]);
        let (g, w) = (got["voxel_max_error"].as_f64().unwrap_or(f64::NAN), want["voxel_max_error"].as_f64().unwrap());
        assert!(g <= w * 1.1, "{format}: max error {} against {w} without them", got["voxel_max_error"]);
        if format == "f32" {
            assert_eq!(got["voxel_psnr"], "Infinity");
        } else {
            assert!((got["voxel_psnr"].as_f64().unwrap() - want["voxel_psnr"].as_f64().unwrap()).abs() < 0.1, "{format}: psnr {}", got["voxel_psnr"]);
        }
        assert_eq!(got["non_finite_voxels"], 2);
        assert_eq!(got["channels"][0]["non_finite"], serde_json::json!({"nan": 1, "pos_inf": 1, "neg_inf": 0}));
        assert_eq!(got["value_range"][1], "Infinity");
        // Text: what happened, in one line.
        let text = String::from_utf8(ok(vdbcook(&["cook", s(&dirty_vdb), "-o", s(&dir.join("dirty.vpak")), "--force", "--format", format])).stdout).unwrap();
        let line = text.lines().find(|l| l.trim_start().starts_with("non-finite")).unwrap_or_else(|| panic!("{format}: {text}"));
        assert!(line.contains("2 source voxels (1 NaN, 1 +inf) left out of the error figures"), "{line}");
        assert!(!text.contains("NaN dB"), "{text}");
        // Voxel by voxel: the brick holding both decodes its finite voxels
        // exactly as the clean grid's brick does, and the two voxels as documented.
        let unpacked = |vpak: &str, vdb: &str| {
            ok(vdbcook(&["unpack", s(&dir.join(vpak)), "--frame", "0", "-o", s(&dir.join(vdb)), "--force"]));
            read(&dir.join(vdb))
        };
        let (gd, wd) = (unpacked("dirty.vpak", "dirty_out.vdb"), unpacked("clean.vpak", "clean_out.vdb"));
        let (src, a, b) = (&clean().leaves[NAN_AT.0], &gd.leaves[NAN_AT.0], &wd.leaves[NAN_AT.0]);
        let step = 1.6 / 255.0;
        for i in (0..512).filter(|&i| i != NAN_AT.1 && i != INF_AT.1) {
            let tol = if format.starts_with("bc") { step } else { 1e-6 };
            assert!((a.values[i] - b.values[i]).abs() <= tol, "{format}: voxel {i} decodes to {} against {} without the non-finite ones", a.values[i], b.values[i]);
        }
        for (i, v) in [(NAN_AT.1, f32::NAN), (INF_AT.1, f32::INFINITY)] {
            let d = a.values[i];
            match format {
                "f32" | "f16" => assert!(d == v || d.is_nan() && v.is_nan(), "{format}: {v} became {d}"),
                // The mean of its finite neighbours: close to the smooth field there.
                _ => assert!((d - src.values[i]).abs() < 0.05, "{format}: {v} became {d}, the field there is {}", src.values[i]),
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn inspect_tells_non_finite_figures_from_missing_ones() {
    let dir = scratch("inspect");
    let p = write(&dir, "dirty.vdb", &dirty());
    let v: Value = serde_json::from_slice(&ok(vdbcook(&["inspect", "--json", s(&p), "fixtures/empty.vdb"])).stdout).unwrap();
    let g = &v["files"][0]["grids"][0];
    assert_eq!(g["non_finite"], 2);
    assert_eq!(g["max"], "Infinity");
    assert_eq!(g["sum"], "NaN");
    assert!(g["min"].as_f64().is_some_and(|m| m > 0.0 && m < 0.01), "{g}");
    for g in v["files"][1]["grids"].as_array().unwrap() {
        assert!(g["min"].is_null() && g["max"].is_null() && g["sum"].is_null(), "{g}");
        assert_eq!(g["non_finite"], 0);
    }
    let text = String::from_utf8(ok(vdbcook(&["inspect", s(&p)])).stdout).unwrap();
    assert!(text.contains("non-finite     2 active values"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_transform_mismatch_names_both_files() {
    // Given last, the odd file sorts first (natural order) and sets the transform.
    let dir = scratch("transform");
    let mut odd = clean();
    odd.transform = Transform::scale_translate(vdbcook_grid::MapType::UniformScale, [0.5; 3], [0.0; 3]);
    let files = [write(&dir, "smoke_2.vdb", &clean()), write(&dir, "smoke_3.vdb", &clean()), write(&dir, "smoke_1.vdb", &odd)];
    let out = vdbcook(&["cook", s(&files[0]), s(&files[1]), s(&files[2]), "-o", s(&dir.join("x.vpak"))]);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert_eq!(err.matches("frame 1").count(), 1, "{err}");
    let here = format!("{}: frame 1: grid \"density\" has transform UniformScaleMap [[1.0", files[0].display());
    let there = format!("but the channel's transform, set by grid \"density\" of frame 0 ({}), is UniformScaleMap [[0.5", files[2].display());
    assert!(err.contains(&here) && err.contains(&there), "{err}");
    assert!(!dir.join("x.vpak").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cook_json_follows_the_documented_schema() {
    let dir = scratch("cook-schema");
    let p = write(&dir, "dirty.vdb", &dirty());
    let doc = std::fs::read_to_string(root().join("docs/cook-json.md")).unwrap();
    let mut top = doc_section(&doc, "Top level");
    top.retain(|k| k != "validation" && k != "auto"); // only with --validate or --auto (a GPU)
    let v = cook_json(&p, &dir.join("x.vpak"), &["--format", "bc4", "--clusters", "4"]);
    assert_documented(&v, &top, "top level");
    assert_documented(&v["channels"][0], &doc_section(&doc, "Channel objects"), "channel");
    assert_documented(&v["clustering"], &doc_section(&doc, "Clustering"), "clustering");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn inspect_json_follows_the_documented_schema() {
    let doc = std::fs::read_to_string(root().join("docs/inspect-json.md")).unwrap();
    let keys = doc_section(&doc, "Grid objects");
    let v: Value = serde_json::from_slice(&ok(vdbcook(&["inspect", "--json", "fixtures/multi_grid.vdb", "fixtures/tiles.vdb"])).stdout).unwrap();
    for f in v["files"].as_array().unwrap() {
        for g in f["grids"].as_array().unwrap() {
            assert_documented(g, &keys, "grid");
        }
    }
}
