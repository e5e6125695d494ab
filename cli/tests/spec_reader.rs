//! The specification is complete: `scripts/vpak_read.py`, written from
//! docs/format.md alone (numpy, Pillow, xxhash, zstandard; nothing shared with the Rust),
//! decodes every channel of every frame of assets in each format and packing,
//! and gives the values `vdbcook unpack` writes (read back by OpenVDB), voxel
//! by voxel, over the same active voxels; version-8 assets with supercompressed
//! sections included (the reader restores them from the page's "Supercompression"),
//! and version-10 assets whose channels have voxels of their own ("Channel
//! resolutions"), each channel on its own transform.

mod common;
use common::*;
use std::process::Command;

fn python(args: &[&str]) -> std::process::Output {
    Command::new("/usr/bin/python3").args(args).current_dir(root()).output().expect("run /usr/bin/python3")
}

/// The reader's Python modules are there (CI: they must be).
fn reader_available() -> bool {
    let ok = python(&["-c", "import numpy, PIL, xxhash, zstandard, pyopenvdb"]).status.success();
    assert!(ok || !in_ci(), "CI=true but /usr/bin/python3 lacks numpy, PIL, xxhash, zstandard or pyopenvdb (scripts/test.sh installs them)");
    ok
}

#[test]
fn the_spec_only_reader_decodes_what_unpack_writes() {
    let Some(samples) = shared_samples() else { return };
    if !reader_available() {
        return;
    }
    let w = samples.join("waveletturbulence").to_string_lossy().into_owned();
    let e: Vec<String> = (0..4).map(|k| samples.join(format!("vfx-toolkit-embergen/embergen_fire_a_{k}.vdb")).to_string_lossy().into_owned()).collect();
    let smoke = "fixtures/smoke_seq".to_string();
    let tiles = "fixtures/tiles.vdb".to_string();
    // Frames whose trees need L1 nodes of 8³, 16³ and 32³ slots (content out to x = 700, 1600 and 4000).
    let dir = scratch_dir("spec", "unpack");
    let wide_dir = dir.join("wide");
    std::fs::create_dir_all(&wide_dir).unwrap();
    let make = r#"
import pyopenvdb as vdb, sys
for k, far in enumerate([(700, 5, 5), (1600, 9, 3), (4000, 1, 1)]):
    g = vdb.FloatGrid(); g.name = 'density'; a = g.getAccessor()
    for i, (x, y, z) in enumerate([(k, k, k), far, (900, 900, 900)]):
        for d in range(27): a.setValueOn((x + d % 3, y + d // 3 % 3, z + d // 9), 0.1 * (i + 1) + 0.01 * d)
    vdb.write('%s/wide_%04d.vdb' % (sys.argv[1], k + 1), grids=[g])
"#;
    let out = python(&["-c", make, s(&wide_dir)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let wide = wide_dir.display().to_string();
    let probe = wide_dir.join("probe.vpak");
    assert!(vdbcook(&["cook", "-q", "--force", "-o", s(&probe), &wide]).status.success());
    let sizes = python(&[
        "-c",
        "import sys; sys.path.insert(0, 'scripts'); import vpak_read as v; m, s = v.open_asset(sys.argv[1]); f = s.u32(v.K_FRAMES); l1 = s.u32(v.K_L1); print(sorted(int(l1[int(x)]) for x in f))",
        s(&probe),
    ]);
    assert_eq!(String::from_utf8_lossy(&sizes.stdout).trim(), "[3, 4, 5]", "the wide frames' L1 nodes: {}", String::from_utf8_lossy(&sizes.stderr));
    // (inputs, cook flags): every format, every packing (R/RG/RGBA, BC4 per
    // channel, BC7 with 4, 2 and 1 z-slices per texel), vec3, mixed groups,
    // split atlases, tiles and an empty frame; per-brick formats (constant,
    // bc7, bc4, unorm8, unorm16, f16 planes of one channel, split atlases, several channels).
    let cases: Vec<(Vec<String>, Vec<&str>)> = vec![
        (vec![smoke.clone()], vec!["--format", "f32"]),
        (vec![smoke.clone()], vec!["--format", "bc4", "--max-texture-dim", "24"]),
        (vec![smoke.clone()], vec!["--format", "bc7"]),
        (vec![smoke.clone()], vec!["--max-error", "0.001"]),
        // Segments (version 7): each frame read from its own segment's body.
        (vec![smoke.clone()], vec!["--max-error", "0.004", "--segment-frames", "3"]),
        (vec![smoke.clone()], vec!["--max-error", "0.004", "--max-texture-dim", "16"]),
        (vec![w.clone()], vec!["--grids", "density,velocity", "--format", "unorm16"]),
        (vec![w.clone()], vec!["--grids", "all", "--format", "f16"]),
        (vec![w.clone()], vec!["--grids", "all", "--format", "unorm8", "--max-texture-dim", "16"]),
        (vec![w.clone()], vec!["--grids", "density,temperature,flame,shadow", "--format", "bc7"]),
        (vec![w.clone()], vec!["--grids", "density,temperature,velocity", "--format", "bc4", "--group", "velocity=f32", "--group", "density,temperature=bc7"]),
        (vec![w.clone()], vec!["--grids", "density,shadow,temperature,flame", "--format", "f16", "--group", "density,shadow,temperature,flame=bc7"]),
        (e.clone(), vec!["--grids", "all", "--format", "bc7"]),
        (e.clone(), vec!["--grids", "all", "--format", "unorm8", "--group", "flames=bc4"]),
        (e.clone(), vec!["--grids", "all", "--format", "bc7", "--segment-frames", "2"]),
        (e.clone(), vec!["--grids", "all", "--max-error", "0.02"]),
        (vec![tiles.clone()], vec!["--format", "f16"]),
        (vec![tiles], vec!["--max-error", "0.002"]),
        (vec![wide.clone()], vec!["--format", "f16"]),
        (vec![wide.clone()], vec!["--format", "bc4", "--lods", "3"]),
        (vec![wide.clone()], vec!["--format", "f16", "--lods", "2", "--segment-frames", "1"]),
        // Supercompressed sections (version 8): every format, packings and groups,
        // per-brick formats, levels of detail, several segments, a high zstd level.
        (vec![smoke.clone()], vec!["--format", "f32", "--supercompress", "zstd", "--segment-frames", "3"]),
        (vec![smoke.clone()], vec!["--format", "f16", "--supercompress", "zstd:19"]),
        // One small segment: its body wrapped whole in one zstd frame (version 13).
        (vec![format!("{smoke}/smoke_0001.vdb")], vec!["--format", "unorm8", "--supercompress", "zstd"]),
        (vec![smoke], vec!["--max-error", "0.004", "--supercompress", "zstd", "--segment-frames", "2", "--lods", "2"]),
        (vec![w.clone()], vec!["--grids", "density,velocity", "--format", "unorm16", "--supercompress", "zstd"]),
        (vec![w], vec!["--grids", "density,temperature,velocity", "--format", "bc4", "--group", "velocity=f32", "--group", "density,temperature=bc7", "--supercompress", "zstd"]),
        (e.clone(), vec!["--grids", "all", "--format", "unorm8", "--group", "flames=bc4", "--supercompress", "zstd:19", "--segment-frames", "2"]),
        (e.clone(), vec!["--grids", "all", "--max-error", "0.02", "--supercompress", "zstd", "--segment-frames", "2"]),
        // Atlases context-coded over their shown voxels (scheme 4): per-brick formats, several channels, segments.
        (e, vec!["--grids", "all", "--max-error", "0.004", "--supercompress", "zstd", "--optimize", "disk", "--segment-frames", "2"]),
        (vec![wide], vec!["--format", "bc4", "--lods", "3", "--supercompress", "zstd"]),
    ];
    let results = par_map(&cases.iter().enumerate().collect::<Vec<_>>(), |(k, (inputs, flags))| compare_case(&dir, &format!("a{k}"), inputs, flags, None));
    let mut total = 0;
    for r in results {
        total += r.unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(total > 500_000, "{total} values compared");
    assert!(WRAPPED.load(std::sync::atomic::Ordering::Relaxed) > 0, "no case made a wrapped body");
    assert!(MASKED.load(std::sync::atomic::Ordering::Relaxed) > 0, "no case made a mask-coded L3 array");
    assert!(SHOWN.load(std::sync::atomic::Ordering::Relaxed) > 0, "no case made an atlas coded over its shown voxels");
}

/// Bodies the spec-only reader found wrapped (version 13), over every case.
static WRAPPED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
/// Mask-coded sections (scheme 3, version 14) the spec-only reader restored, over every case.
static MASKED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
/// Atlases context-coded over their shown voxels (scheme 4, version 15) the spec-only reader restored.
static SHOWN: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Cooks `inputs` with `flags` into `dir/TAG.vpak`, then per frame decodes it with the
/// spec-only reader and with `vdbcook unpack` (at `lod`, when given) and compares them
/// voxel by voxel, each channel's transform too. The values compared, or what differed.
fn compare_case(dir: &std::path::Path, tag: &str, inputs: &[String], flags: &[&str], lod: Option<u32>) -> Result<usize, String> {
    let asset = dir.join(format!("{tag}.vpak"));
    let mut args = vec!["cook", "-q", "--force", "-o", s(&asset)];
    args.extend(flags.iter().copied());
    args.extend(inputs.iter().map(String::as_str));
    let r = vdbcook(&args);
    if !r.status.success() {
        return Err(format!("{flags:?}: cook failed: {}", String::from_utf8_lossy(&r.stderr)));
    }
    let mut wrapped_by_reader = None;
    if flags.contains(&"--supercompress") {
        // The reader restored sections in every segment (not a file stored as it is),
        // context-coded ones (scheme 2 or 4) among them when the cook optimised for the disk; and
        // how many L3 arrays it found mask-coded (scheme 3) and atlases coded over their shown voxels (4).
        let coded = python(&[
            "-c",
            "import sys; sys.path.insert(0, 'scripts'); import vpak_read as v; a = v.open_segments(sys.argv[1]); \
             print(a.version, min(len(s.coding) + w for (_, s), w in zip(a.bodies, a.wrapped)), sum(r[0] in (2, 4) for _, s in a.bodies for r in s.coding.values()), sum(a.wrapped), \
             sum(r[0] == 3 for _, s in a.bodies for r in s.coding.values()), sum(r[0] == 4 for _, s in a.bodies for r in s.coding.values()))",
            s(&asset),
        ]);
        let said = String::from_utf8_lossy(&coded.stdout);
        let fields: Vec<&str> = said.split_whitespace().collect();
        let context = flags.contains(&"disk");
        if fields.len() != 6 || fields[0] != vdbcook_vpak::VERSION.to_string() || fields[1] == "0" || (fields[2] == "0") == context {
            return Err(format!(
                "{flags:?}: not supercompressed in every segment, or context coding not as expected (version, fewest records or wrapped, context-coded, wrapped: {said}) {}",
                String::from_utf8_lossy(&coded.stderr)
            ));
        }
        wrapped_by_reader = fields[3].parse::<usize>().ok();
        MASKED.fetch_add(fields[4].parse::<usize>().unwrap_or(0), std::sync::atomic::Ordering::Relaxed);
        SHOWN.fetch_add(fields[5].parse::<usize>().unwrap_or(0), std::sync::atomic::Ordering::Relaxed);
    }
    let meta: serde_json::Value = serde_json::from_slice(&vdbcook(&["inspect", "--json", s(&asset)]).stdout).unwrap();
    let meta = &meta["files"][0];
    // Both readers find the same bodies wrapped in one zstd frame (version 13).
    if let Some(w) = wrapped_by_reader {
        let said = meta["segments"].as_array().map(|a| a.iter().filter(|s| s["wrapped"] == true).count());
        if said != Some(w) {
            return Err(format!("{flags:?}: the reader found {w} wrapped bodies, inspect {said:?}"));
        }
        WRAPPED.fetch_add(w, std::sync::atomic::Ordering::Relaxed);
    }
    let lod_args: Vec<String> = lod.map(|k| vec!["--lod".to_string(), k.to_string()]).unwrap_or_default();
    let lod_args: Vec<&str> = lod_args.iter().map(String::as_str).collect();
    let mut compared = 0;
    for frame in 0..meta["frames"].as_u64().unwrap() {
        let (npz, vdb) = (dir.join(format!("{tag}-{frame}.npz")), dir.join(format!("{tag}-{frame}.vdb")));
        let out = python(&[&["scripts/vpak_read.py", s(&asset), "--frame", &frame.to_string(), "--out", s(&npz)], &lod_args[..]].concat());
        if !out.status.success() {
            return Err(format!("{flags:?} frame {frame}: vpak_read.py failed: {}", String::from_utf8_lossy(&out.stderr)));
        }
        let r = vdbcook(&[&["unpack", "-q", "--force", s(&asset), "--frame", &frame.to_string(), "-o", s(&vdb)], &lod_args[..]].concat());
        if !r.status.success() {
            return Err(format!("{flags:?} frame {frame}: unpack failed: {}", String::from_utf8_lossy(&r.stderr)));
        }
        let out = python(&["cli/tests/spec_reader_check.py", s(&npz), s(&vdb)]);
        if !out.status.success() {
            return Err(format!("{flags:?} frame {frame}: the comparison failed: {}", String::from_utf8_lossy(&out.stderr)));
        }
        let cmp: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        for ch in meta["channels"].as_array().unwrap() {
            let name = ch["name"].as_str().unwrap();
            let c = &cmp[name];
            let n = c["voxels"].as_u64().ok_or(format!("{flags:?} frame {frame}: the reader gave no channel {name}"))?;
            // The same active voxels: every voxel the reader gives is active in
            // the unpacked grid, and the unpacked grid has no others.
            if c["active_in_unpacked"].as_u64() != Some(n) || c["unpacked_active_voxels"].as_u64() != Some(n) {
                return Err(format!("{flags:?} frame {frame} {name}: reader {n} voxels, unpacked {} active of them, {} in all", c["active_in_unpacked"], c["unpacked_active_voxels"]));
            }
            // The same voxels in the world: the reader's transform of the channel (its level and offset) is the unpacked grid's.
            if c["transform_diff"].as_f64().is_none_or(|d| d > 1e-9) {
                return Err(format!("{flags:?} frame {frame} {name}: the reader's transform (level {}) differs from the unpacked grid's by {}", c["level"], c["transform_diff"]));
            }
            // BC4 may be decoded to 8 bits by the reader's library (half a level of
            // the brick's range, at most the channel's); everything else exactly,
            // up to float rounding.
            let range = ch["value_range"][1].as_f64().unwrap() - ch["value_range"][0].as_f64().unwrap();
            let top = ch["value_range"][0].as_f64().unwrap().abs().max(ch["value_range"][1].as_f64().unwrap().abs());
            let tol = if ch["format"].as_str().is_some_and(|f| f.split('+').any(|f| f == "bc4")) { range / 255.0 * 0.5 + 1e-6 } else { top * 1e-6 + 1e-7 };
            let diff = c["max_diff"].as_f64().unwrap();
            if diff > tol {
                return Err(format!("{flags:?} frame {frame} {name} ({}): values differ by {diff} (tolerance {tol})", ch["format"]));
            }
            compared += n as usize;
        }
    }
    Ok(compared)
}

/// A pyro-style sequence of three frames (scripts/make_pyro_sequence.py): density and
/// temperature at voxel size 0.1, `vel` at its own, coarser voxels.
fn pyro(dir: &std::path::Path, tag: &str, flags: &[&str]) -> String {
    let out = dir.join(tag);
    let r = python(&[&["scripts/make_pyro_sequence.py", s(&out), "--frames", "3", "--size", "32"], flags].concat());
    assert!(r.status.success(), "make_pyro_sequence.py {flags:?}: {}", String::from_utf8_lossy(&r.stderr));
    out.display().to_string()
}

#[test]
fn the_spec_only_reader_decodes_channels_at_their_own_voxels() {
    if !reader_available() {
        return;
    }
    let dir = scratch_dir("spec", "multi");
    // vel at twice the voxels of density, sharing its origin; four times, half a
    // density voxel off; twice, a whole density voxel off the other way.
    let (p2, p4, p2o) = (pyro(&dir, "p2", &[]), pyro(&dir, "p4", &["--vel-scale", "4", "--offset", "1"]), pyro(&dir, "p2o", &["--offset", "-2"]));
    let g = ["--grids", "density,temperature,vel"];
    let cases: Vec<(&String, Vec<&str>, Option<u32>)> = vec![
        (&p2, vec!["--format", "f32"], None),
        (&p2, vec!["--format", "f16"], None),
        (&p2, vec!["--format", "unorm8"], None),
        (&p2, vec!["--format", "unorm16"], None),
        (&p2, vec!["--format", "bc4"], None),
        (&p2, vec!["--format", "bc7"], None),
        (&p2, vec!["--max-error", "0.01"], None),
        (&p2, vec!["--format", "unorm8", "--group", "density,vel=bc7"], None),
        // Levels of detail: each channel at its first stored level, and at its stored level nearest K.
        (&p2, vec!["--format", "f16", "--lods", "2"], None),
        (&p2, vec!["--format", "f16", "--lods", "2"], Some(1)),
        (&p2, vec!["--format", "f16", "--lods", "2"], Some(2)),
        // Finer levels left out to fit a byte budget (first_level 1).
        (&p2o, vec!["--format", "f16", "--lods", "3", "--max-bytes", "300000"], None),
        (&p2, vec!["--format", "bc7", "--segment-frames", "2", "--supercompress", "zstd"], None),
        (&p4, vec!["--format", "f32", "--segment-frames", "1"], None),
        (&p4, vec!["--format", "bc4", "--lods", "2", "--supercompress", "zstd"], Some(1)),
        (&p2o, vec!["--format", "f32"], None),
        (&p2o, vec!["--max-error", "0.004", "--lods", "2", "--segment-frames", "2", "--supercompress", "zstd:19"], Some(1)),
        (&p2o, vec!["--max-error", "0.004", "--lods", "2", "--segment-frames", "2", "--supercompress", "zstd", "--optimize", "disk"], Some(1)),
    ];
    let results = par_map(&cases.iter().enumerate().collect::<Vec<_>>(), |(k, (input, flags, lod))| {
        let flags = [&g[..], flags].concat();
        compare_case(&dir, &format!("m{k}"), &[(*input).clone()], &flags, *lod)
    });
    let mut total = 0;
    for r in results {
        total += r.unwrap();
    }
    assert!(total > 100_000, "{total} values compared");
    // The f32 round trip through unpack and OpenVDB: every grid exact at its own
    // voxels (active where the source is, the source's value wherever it is active),
    // on the source grid's transform.
    // Cases 0, 13 and 15 are the f32 assets; their unpacked frames are still there.
    for (input, tag) in [(&p2, "m0"), (&p4, "m13"), (&p2o, "m15")] {
        for frame in 0..3 {
            let vdb = dir.join(format!("{tag}-{frame}.vdb"));
            let source = format!("{input}/pyro_{:04}.vdb", frame + 1);
            let out = python(&["cli/tests/spec_reader_check.py", "--source", &source, s(&vdb)]);
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
            let cmp: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            for grid in ["density", "temperature", "vel"] {
                let c = &cmp[grid];
                assert!(c["source_active"].as_u64().unwrap() > 0, "{source} {grid}: {c}");
                assert_eq!((c["not_active"].as_u64(), c["max_diff"].as_f64(), c["other_values"].as_u64()), (Some(0), Some(0.0), Some(0)), "{source} {grid}: {c}");
                assert!(c["transform_diff"].as_f64().unwrap() <= 1e-9, "{source} {grid}: {c}");
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Files built and damaged in Python from what vdbcook cooks: segmented files
/// (scripts/test_vpak_segments.py), and supercompressed ones
/// (scripts/test_vpak_coding.py: restored sections equal `recompress
/// --supercompress none`'s, every filter the page allows decodes, corrupt coding
/// (truncated or bit-flipped frames, a restored size that lies, broken records)
/// refused in one line).
fn python_check(script: &str) {
    if !reader_available() {
        return;
    }
    let out = python(&[script, "--vdbcook", env!("CARGO_BIN_EXE_vdbcook")]);
    assert!(out.status.success(), "{script}: {}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
}

#[test]
fn the_spec_only_reader_reads_segmented_files_and_refuses_damaged_ones() {
    python_check("scripts/test_vpak_segments.py");
}

#[test]
fn the_spec_only_reader_restores_supercompressed_sections_and_refuses_corrupt_ones() {
    python_check("scripts/test_vpak_coding.py");
}
