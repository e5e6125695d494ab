//! `cook --max-error E`: per-brick formats, checked from the outside: every
//! active voxel of the source, read by OpenVDB, and of the unpacked asset,
//! read by OpenVDB, within E; bad bounds are usage errors.

mod common;
use common::*;
use std::collections::HashMap;
use std::path::Path;

/// Every active value of grid `grid` of `file` as OpenVDB reads it, tiles expanded.
fn active_values(file: &Path, grid: &str, dump: &Path) -> HashMap<[i32; 3], f64> {
    let json = oracle(file, Some(dump)).unwrap_or_else(|| panic!("OpenVDB cannot read {}", file.display()));
    let index = json["grids"].as_array().unwrap().iter().position(|g| g["name"] == grid).unwrap_or_else(|| panic!("{}: no grid {grid}", file.display())) as u32;
    let d = read_dump::<1>(dump);
    let mut out: HashMap<[i32; 3], f64> = d.voxels.iter().filter(|v| v.0 == index).map(|&(_, c, [v])| (c, v)).collect();
    for &(_, lo, hi, [v]) in d.tiles.iter().filter(|t| t.0 == index) {
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    out.insert([x, y, z], v);
                }
            }
        }
    }
    out
}

/// Inputs, the grid, E.
type Case<'a> = (Vec<String>, &'a str, f32);

#[test]
fn unpacked_voxels_are_within_the_bound_through_openvdb() {
    if !oracle_available() {
        return;
    }
    let dir = scratch_dir("max_error", "openvdb");
    let mut cases: Vec<Case> = vec![
        (vec![s(&root().join("fixtures/smoke_seq/smoke_0002.vdb")).into(), s(&root().join("fixtures/smoke_seq/smoke_0003.vdb")).into()], "density", 0.003),
        (vec![s(&root().join("fixtures/tiles.vdb")).into()], "density", 0.0005),
    ];
    if let Some(samples) = shared_samples() {
        cases.push((vec![s(&samples.join("vfx-toolkit-embergen/embergen_fire_a_2.vdb")).into()], "flames", 0.01));
    }
    // Each case as GPU texels and as texels for the disk (supercompressed: on the coarsest grid within the bound).
    let runs: Vec<_> = cases.iter().enumerate().flat_map(|(k, c)| [(k, c, false), (k, c, true)]).collect::<Vec<(usize, &Case, bool)>>();
    let results = par_map(&runs, |&(k, (inputs, grid, e), disk)| -> Result<usize, String> {
        let k = format!("{k}{}", if disk { "z" } else { "" });
        let asset = dir.join(format!("m{k}.vpak"));
        let bound = e.to_string();
        let mut args = vec!["cook", "-q", "--force", "--grid", grid, "--max-error", &bound, "-o", s(&asset)];
        if disk {
            args.extend(["--supercompress", "zstd"]);
        }
        args.extend(inputs.iter().map(String::as_str));
        let r = vdbcook(&args);
        if !r.status.success() {
            return Err(format!("cook: {}", String::from_utf8_lossy(&r.stderr)));
        }
        let mut compared = 0;
        for (frame, input) in inputs.iter().enumerate() {
            let vdb = dir.join(format!("m{k}-{frame}.vdb"));
            let r = vdbcook(&["unpack", "-q", "--force", s(&asset), "--frame", &frame.to_string(), "-o", s(&vdb)]);
            if !r.status.success() {
                return Err(format!("unpack: {}", String::from_utf8_lossy(&r.stderr)));
            }
            let source = active_values(Path::new(input), grid, &dir.join(format!("m{k}-{frame}-src.bin")));
            let back = active_values(&vdb, grid, &dir.join(format!("m{k}-{frame}-back.bin")));
            if source.len() != back.len() {
                return Err(format!("frame {frame}: {} active voxels in the source, {} unpacked", source.len(), back.len()));
            }
            for (c, v) in &source {
                let b = back.get(c).ok_or(format!("frame {frame}: voxel {c:?} is not active unpacked"))?;
                // OpenVDB hands both as f32 widened to f64: the difference is exact.
                if (b - v).abs() > f64::from(*e) {
                    return Err(format!("frame {frame}: voxel {c:?} is {b}, the source {v}: off by more than {e}"));
                }
            }
            compared += source.len();
        }
        Ok(compared)
    });
    let _ = std::fs::remove_dir_all(&dir);
    let mut total = 0;
    for ((_, case, disk), r) in runs.iter().zip(results) {
        total += r.unwrap_or_else(|e| panic!("{:?} E = {} (supercompressed: {disk}): {e}", case.0, case.2));
    }
    assert!(total > 100_000, "{total} voxels compared");
}

#[test]
fn the_report_gives_bricks_and_bytes_per_format() {
    let dir = scratch_dir("max_error", "report");
    let asset = dir.join("a.vpak");
    let out = ok(vdbcook(&["cook", "--json", "--force", "--max-error", "0.001", "-o", s(&asset), s(&root().join("fixtures/smoke_seq"))]));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ch = &j["channels"][0];
    let formats = ch["formats"].as_array().unwrap();
    assert!(formats.len() >= 3, "{ch}");
    let names: Vec<&str> = formats.iter().map(|f| f["format"].as_str().unwrap()).collect();
    assert_eq!(ch["format"], names.join("+"));
    assert_eq!(j["format"], names.join("+"));
    let bricks: u64 = formats.iter().map(|f| f["bricks"].as_u64().unwrap()).sum();
    assert_eq!(ch["bricks"].as_u64(), Some(bricks));
    assert!(ch["bytes"].as_u64().unwrap() >= formats.iter().map(|f| f["bytes"].as_u64().unwrap()).sum::<u64>());
    assert!(j["voxel_max_error"].as_f64().unwrap() <= 0.001);
    // The text says the same, and inspect finds the channel's planes.
    let text = String::from_utf8_lossy(&ok(vdbcook(&["cook", "--force", "--max-error", "0.001", "-o", s(&asset), s(&root().join("fixtures/smoke_seq"))])).stdout).into_owned();
    let line = text.lines().find(|l| l.trim_start().starts_with("brick formats")).unwrap_or_else(|| panic!("{text}"));
    for f in formats {
        assert!(line.contains(&format!("{} {} (", f["format"].as_str().unwrap(), f["bricks"])), "{line}");
    }
    let meta: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["inspect", "--json", s(&asset)])).stdout).unwrap();
    let c = &meta["files"][0]["channels"][0];
    assert_eq!(c["format"], names.join("+"));
    assert_eq!(c["alternates"].as_array().unwrap().len(), names.len() - 1);
    assert_eq!(meta["files"][0]["settings"]["max_error"], "0.001");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_bounds_and_conflicting_flags_are_usage_errors() {
    let dir = scratch_dir("max_error", "usage");
    let asset = dir.join("a.vpak");
    let input = s(&root().join("fixtures/smoke_seq")).to_string();
    for (flags, want) in [
        (vec!["--max-error=-0.1"], "must be a finite number >= 0, not -0.1"),
        (vec!["--max-error", "nan"], "must be a finite number >= 0, not NaN"),
        (vec!["--max-error", "inf"], "must be a finite number >= 0, not inf"),
        (vec!["--max-error", "x"], "--max-error"),
        (vec!["--max-error", "0.01", "--format", "bc4"], "cannot be used with"),
        (vec!["--max-error", "0.01", "--group", "density=bc7"], "cannot be used with"),
        (vec!["--max-error", "0.01", "--auto", "--min-psnr", "40"], "cannot be used with"),
    ] {
        let mut args = vec!["cook", "--force", "-o", s(&asset), &input];
        args.extend(flags.iter().copied());
        let r = vdbcook(&args);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{flags:?}: {err}");
        assert!(err.contains(want), "{flags:?}: {err}");
        assert!(!asset.exists(), "{flags:?}: wrote an asset");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
