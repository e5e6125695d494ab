//! Levels of detail (`cook --lods`, `unpack --lod`, `inspect`): every level of
//! real samples and fixtures, unpacked to a .vdb, is read by OpenVDB and
//! compared with the level computed independently in numpy from the source as
//! OpenVDB reads it (cli/tests/lod_check.py: active set, values, voxel size,
//! and the world position of a level voxel against the centre of its source
//! voxels); the spec-only reader decodes every level as `unpack --lod` writes
//! it; errors and determinism.

mod common;
use common::*;
use std::process::Command;

fn python(args: &[&str]) -> std::process::Output {
    Command::new("/usr/bin/python3").args(args).current_dir(root()).output().expect("run /usr/bin/python3")
}

fn json(out: std::process::Output) -> serde_json::Value {
    serde_json::from_slice(&ok(out).stdout).expect("JSON")
}

#[test]
fn every_level_is_the_filtered_source_as_openvdb_reads_it() {
    if !oracle_available() {
        return;
    }
    let samples = shared_samples();
    // (source, cook flags, grid checked, filter, tolerance relative to the largest value).
    let mut cases: Vec<(String, Vec<&str>, &str, &str, f64)> = vec![(root().join("fixtures/smoke_seq/smoke_0002.vdb").display().to_string(), vec!["--format", "f32"], "density", "mean", 1e-6)];
    if let Some(sm) = &samples {
        let p = |f: &str| sm.join(f).display().to_string();
        cases.extend([
            // An affine map and active tiles.
            (p("elyg-visualizer/test.vdb"), vec!["--format", "f32"], "density", "mean", 1e-6),
            // A half-float level set: the active mean.
            (p("mjurczyk-openvdb/sphere.vdb"), vec!["--format", "f32"], "ls_sphere", "active", 1e-6),
            // A constant region of tiles and leaves, in half precision.
            (p("hsim/writer.vdb"), vec!["--format", "f16"], "temperature", "mean", 1e-3),
            // Two channels of one tree (translated transform), lossy.
            (p("vfx-toolkit-embergen/embergen_fire_a_2.vdb"), vec!["--grids", "all", "--format", "f32"], "flames", "mean", 1e-6),
            (p("vfx-toolkit-embergen/embergen_fire_a_2.vdb"), vec!["--grids", "all", "--format", "unorm8"], "temperature", "mean", 0.5 / 255.0 + 1e-6),
        ]);
    }
    let dir = scratch_dir("lod", "oracle");
    let results = par_map(&cases.iter().enumerate().collect::<Vec<_>>(), |(n, (source, flags, grid, filter, tol))| -> Result<usize, String> {
        let asset = dir.join(format!("a{n}.vpak"));
        let mut args = vec!["cook", "-q", "-o", s(&asset), "--lods", "5"];
        args.extend(flags.iter().copied());
        args.push(source);
        let r = vdbcook(&args);
        if !r.status.success() {
            return Err(format!("{source}: cook failed: {}", String::from_utf8_lossy(&r.stderr)));
        }
        let meta = json(vdbcook(&["inspect", "--json", s(&asset)]));
        let levels = meta["files"][0]["levels"].as_array().unwrap().clone();
        assert_eq!(levels.len(), 5, "{source}");
        let mut compared = 0;
        for k in 0..5u32 {
            let vdb = dir.join(format!("a{n}-{k}.vdb"));
            let r = vdbcook(&["unpack", "-q", s(&asset), "--frame", "0", "--lod", &k.to_string(), "-o", s(&vdb)]);
            if !r.status.success() {
                return Err(format!("{source} level {k}: unpack failed: {}", String::from_utf8_lossy(&r.stderr)));
            }
            let out = python(&["cli/tests/lod_check.py", source, grid, &k.to_string(), filter, s(&vdb)]);
            if !out.status.success() {
                return Err(format!("{source} level {k}: lod_check.py failed: {}", String::from_utf8_lossy(&out.stderr)));
            }
            let c: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            let what = format!("{source} {grid} level {k}: {c}");
            let n = c["reference_voxels"].as_u64().unwrap();
            if n == 0 || c["missing"] != 0 || c["extra_not_background"] != 0 {
                return Err(format!("{what}: not the same active voxels"));
            }
            // With several channels a voxel active in another channel's level is active here too, at the background.
            let multi = flags.contains(&"all");
            if !multi && c["extra"] != 0 {
                return Err(format!("{what}: extra active voxels"));
            }
            let max = c["max_value"].as_f64().unwrap().max(1e-30);
            if c["max_diff"].as_f64().unwrap() > tol * max {
                return Err(format!("{what}: values differ"));
            }
            // OpenVDB reads the level with voxels 2^k times as large, centred on their source voxels.
            let (vs, src) = (c["voxel_size"].as_array().unwrap(), c["source_voxel_size"].as_array().unwrap());
            for a in 0..3 {
                let (v, w) = (vs[a].as_f64().unwrap(), src[a].as_f64().unwrap() * f64::from(1u32 << k));
                if (v - w).abs() > 1e-9 * w {
                    return Err(format!("{what}: voxel size {v}, want {w}"));
                }
            }
            if c["world_error"].as_f64().unwrap() > 1e-9 {
                return Err(format!("{what}: a level voxel is not at the centre of its source voxels"));
            }
            // inspect's level figures agree with what OpenVDB counts (the checked channel is the whole tree with one channel).
            if !multi && levels[k as usize]["active_voxels"].as_u64() != Some(n) {
                return Err(format!("{what}: inspect says {} active voxels", levels[k as usize]["active_voxels"]));
            }
            compared += n as usize;
        }
        Ok(compared)
    });
    let total: usize = results.into_iter().map(|r| r.unwrap()).sum();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(total > 10_000, "{total} level voxels compared");
}

#[test]
fn the_spec_only_reader_decodes_every_level_as_unpack_writes_it() {
    let ok_py = python(&["-c", "import numpy, PIL, xxhash, pyopenvdb"]).status.success();
    assert!(ok_py || !in_ci(), "CI=true but /usr/bin/python3 lacks numpy, PIL, xxhash or pyopenvdb");
    if !ok_py {
        return;
    }
    let dir = scratch_dir("lod", "spec");
    let asset = dir.join("s.vpak");
    let mut compared = 0;
    // Levels with one format, and with per-brick formats (coarse bricks choose theirs too).
    for format in [&["--format", "bc7"][..], &["--max-error", "0.002"]] {
        let mut args = vec!["cook", "-q", "--force", "-o", s(&asset), "--lods", "4", "fixtures/smoke_seq"];
        args.extend(format);
        ok(vdbcook(&args));
        for frame in [0, 3] {
            for k in 0..4 {
                let (npz, vdb) = (dir.join(format!("{frame}-{k}.npz")), dir.join(format!("{frame}-{k}.vdb")));
                let out = python(&["scripts/vpak_read.py", s(&asset), "--frame", &frame.to_string(), "--lod", &k.to_string(), "--out", s(&npz)]);
                assert!(out.status.success(), "{format:?} vpak_read.py: {}", String::from_utf8_lossy(&out.stderr));
                ok(vdbcook(&["unpack", "-q", "--force", s(&asset), "--frame", &frame.to_string(), "--lod", &k.to_string(), "-o", s(&vdb)]));
                let c: serde_json::Value = serde_json::from_slice(&ok(python(&["cli/tests/spec_reader_check.py", s(&npz), s(&vdb)])).stdout).unwrap();
                let d = &c["density"];
                let n = d["voxels"].as_u64().unwrap();
                assert!(n > 0 && d["active_in_unpacked"] == n && d["unpacked_active_voxels"] == n, "frame {frame} level {k}: {c}");
                assert!(d["max_diff"].as_f64().unwrap() <= 1e-6, "{format:?} frame {frame} level {k}: {c}");
                compared += n;
            }
        }
    }
    let out = python(&["scripts/vpak_read.py", s(&asset), "--frame", "0", "--lod", "4", "--out", s(&dir.join("x.npz"))]);
    assert_eq!(out.status.code(), Some(1), "a level past the asset's is refused");
    let _ = std::fs::remove_dir_all(&dir);
    assert!(compared > 1000);
}

#[test]
fn level_counts_out_of_range_are_usage_errors_and_levels_are_deterministic() {
    let dir = scratch_dir("lod", "errors");
    let out = dir.join("x.vpak");
    for (n, says) in [("0", "0 is not a level count"), ("6", "at most 5"), ("x", "invalid level count")] {
        let r = vdbcook(&["cook", "-o", s(&out), "--lods", n, "fixtures/smoke_seq"]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "--lods {n}: {err}");
        assert!(err.contains(says), "--lods {n}: {err}");
        assert!(!out.exists(), "nothing written");
    }
    let bake = dir.join("bake.toml");
    std::fs::write(&bake, format!("[[asset]]\nname = \"a\"\noutput = \"a.vpak\"\ninputs = [\"{}\"]\nlods = 9\n", root().join("fixtures/smoke_seq").display())).unwrap();
    let r = vdbcook(&["bake", s(&bake)]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(String::from_utf8_lossy(&r.stderr).contains("lods"), "{}", String::from_utf8_lossy(&r.stderr));
    // The same bytes on one thread and two; level 0 of a cook with levels is level 0 of one without.
    let (a, b, plain) = (dir.join("a.vpak"), dir.join("b.vpak"), dir.join("p.vpak"));
    ok(vdbcook(&["cook", "-q", "-j", "1", "-o", s(&a), "--lods", "5", "--format", "bc4", "fixtures/smoke_seq"]));
    ok(vdbcook(&["cook", "-q", "-j", "2", "-o", s(&b), "--lods", "5", "--format", "bc4", "fixtures/smoke_seq"]));
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(), "thread count changed the asset");
    ok(vdbcook(&["cook", "-q", "-o", s(&plain), "--format", "bc4", "fixtures/smoke_seq"]));
    let (u, v) = (dir.join("u.vdb"), dir.join("v.vdb"));
    ok(vdbcook(&["unpack", "-q", s(&a), "--frame", "2", "-o", s(&u)]));
    ok(vdbcook(&["unpack", "-q", s(&plain), "--frame", "2", "-o", s(&v)]));
    assert!(std::fs::read(&u).unwrap() == std::fs::read(&v).unwrap(), "level 0 is the frame itself");
    // A level past the asset's: one line naming the file, exit 1, nothing written.
    let w = dir.join("w.vdb");
    let r = vdbcook(&["unpack", s(&plain), "--frame", "0", "--lod", "1", "-o", s(&w)]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.starts_with("vdbcook: error: ") && err.contains("p.vpak") && err.contains("level 1 is out of range") && err.lines().count() == 1, "{err}");
    assert!(!w.exists());
    // The cook report gives the levels (JSON as docs/cook-json.md says).
    let j = json(vdbcook(&["cook", "--json", "--force", "-o", s(&a), "--lods", "3", "--format", "f32", "fixtures/smoke_seq"]));
    let levels = j["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 2);
    let doc = std::fs::read_to_string(root().join("docs/cook-json.md")).unwrap();
    for l in levels {
        assert_documented(l, &doc_section(&doc, "Level objects"), "level");
        assert_eq!(l["voxel_rmse"], 0.0, "f32 stores each level exactly");
    }
    assert!(j["timings"]["levels"].as_f64().unwrap() > 0.0);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn render_draws_a_level() {
    if !gpu_available() {
        return;
    }
    let dir = scratch_dir("lod", "render");
    let asset = dir.join("s.vpak");
    ok(vdbcook(&["cook", "-q", "-o", s(&asset), "--lods", "3", "fixtures/smoke_seq"]));
    let (a, b) = (dir.join("l0.png"), dir.join("l2.png"));
    ok(vdbcook(&["render", "-q", s(&asset), "--frame", "1", "--size", "64x64", "-o", s(&a)]));
    ok(vdbcook(&["render", "-q", s(&asset), "--frame", "1", "--lod", "2", "--size", "64x64", "-o", s(&b)]));
    assert!(std::fs::read(&a).unwrap() != std::fs::read(&b).unwrap(), "level 2 draws another image");
    // A .vdb is filtered to the level asked for, as cook --lods does.
    let c = dir.join("vdb_l2.png");
    ok(vdbcook(&["render", "-q", "fixtures/smoke_seq/smoke_0002.vdb", "--lod", "2", "--size", "64x64", "-o", s(&c)]));
    assert!(std::fs::metadata(&c).unwrap().len() > 0);
    let r = vdbcook(&["render", s(&asset), "--lod", "3", "-o", s(&dir.join("x.png"))]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("level 3 is out of range") && err.contains("--lods 4") && err.lines().count() == 1, "{err}");
    let r = vdbcook(&["render", s(&asset), "--lod", "7", "-o", s(&dir.join("x.png"))]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(!dir.join("x.png").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn validate_checks_a_level_against_the_filtered_source() {
    if !gpu_available() {
        return;
    }
    let dir = scratch_dir("lod", "validate");
    let (exact, lossy) = (dir.join("f32.vpak"), dir.join("bc7.vpak"));
    ok(vdbcook(&["cook", "-q", "-o", s(&exact), "--lods", "3", "--format", "f32", "fixtures/smoke_seq"]));
    ok(vdbcook(&["cook", "-q", "-o", s(&lossy), "--lods", "3", "--format", "bc7", "fixtures/smoke_seq"]));
    let doc = std::fs::read_to_string(root().join("docs/validate-json.md")).unwrap();
    for level in ["1", "2"] {
        let v = json(vdbcook(&["validate", s(&exact), "--source", "fixtures/smoke_seq", "--lod", level, "--views", "2", "--size", "48x48", "--json"]));
        assert_documented(&v, &doc_section(&doc, "Top level"), "validate --lod");
        assert_eq!(v["level"].to_string(), level);
        assert!(v["images"].as_array().unwrap().iter().all(|i| i["rmse"] == 0.0), "f32 level {level} renders exactly: {v}");
        assert_eq!(v["voxel"]["rmse"], 0.0);
        let v = json(vdbcook(&["validate", s(&lossy), "--source", "fixtures/smoke_seq", "--lod", level, "--views", "2", "--size", "48x48", "--json"]));
        let worst = v["worst"]["rmse"].as_f64().unwrap();
        assert!(worst > 0.0 && worst < 0.05, "bc7 level {level}: {v}");
        assert!(v["voxel"]["rmse"].as_f64().unwrap() > 0.0);
    }
    // Every level at once, side by side: f32 exact at every level, bc7 not, each level's figures its own.
    let v = json(vdbcook(&["validate", s(&exact), "--source", "fixtures/smoke_seq", "--every-lod", "--views", "2", "--size", "48x48", "--json"]));
    assert_documented(&v, &doc_section(&doc, "Top level"), "validate --every-lod");
    let rows = v["levels"].as_array().unwrap();
    assert_eq!(rows.len(), 3);
    assert!(rows.iter().enumerate().all(|(k, r)| r["level"] == k as u64 && r["worst"]["rmse"] == 0.0 && r["voxel"]["rmse"] == 0.0), "{v}");
    let r = vdbcook(&["validate", s(&lossy), "--source", "fixtures/smoke_seq", "--every-lod", "--views", "2", "--size", "48x48"]);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success() && text.contains("levels") && text.lines().filter(|l| l.trim_start().starts_with(['0', '1', '2'])).count() >= 3, "{text}");
    let v = json(vdbcook(&["validate", s(&lossy), "--source", "fixtures/smoke_seq", "--every-lod", "--views", "2", "--size", "48x48", "--json"]));
    let rmse: Vec<f64> = v["levels"].as_array().unwrap().iter().map(|r| r["worst"]["rmse"].as_f64().unwrap()).collect();
    assert!(rmse.iter().all(|&x| x > 0.0) && rmse[0] == v["worst"]["rmse"].as_f64().unwrap(), "{v}");
    let r = vdbcook(&["validate", s(&lossy), "--source", "fixtures/smoke_seq", "--every-lod", "--views", "1", "--size", "16x16", "--max-rmse", "1e-9"]);
    assert_eq!(r.status.code(), Some(3), "{}", String::from_utf8_lossy(&r.stderr));
    let r = vdbcook(&["validate", s(&lossy), "--source", "fixtures/smoke_seq", "--every-lod", "--lod", "1"]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    let r = vdbcook(&["validate", s(&exact), "--source", "fixtures/smoke_seq", "--lod", "3"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("level 3 is out of range") && err.lines().count() == 1, "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `cook --max-bytes`: the finest levels that fit stay, the asset starts at
/// its first kept level and every reader reads that one by default; a budget
/// below the coarsest level alone writes nothing and names the smallest size.
#[test]
fn a_byte_budget_leaves_out_the_finest_levels() {
    let dir = scratch_dir("lod", "budget");
    let (full, cut) = (dir.join("full.vpak"), dir.join("cut.vpak"));
    let cook = |out: &std::path::Path, extra: &[&str]| {
        let mut args = vec!["cook", "--force", "-o", s(out), "--lods", "4", "--format", "f32", "fixtures/smoke_seq"];
        args.extend(extra);
        vdbcook(&args)
    };
    let j = json(cook(&full, &["--json"]));
    let full_bytes = j["file_bytes"].as_u64().unwrap();
    assert!(j["budget"].is_null() && j["first_level"] == 0, "{j}");
    let budget = (full_bytes - 1).to_string();
    let j = json(cook(&cut, &["--json", "--max-bytes", &budget]));
    let doc = std::fs::read_to_string(root().join("docs/cook-json.md")).unwrap();
    let mut top = doc_section(&doc, "Top level");
    top.retain(|k| k != "validation" && k != "auto");
    assert_documented(&j, &top, "cook --max-bytes");
    let cut_bytes = std::fs::metadata(&cut).unwrap().len();
    assert!(cut_bytes < full_bytes && j["file_bytes"] == cut_bytes, "{j}");
    assert_eq!((j["first_level"].as_u64(), j["budget"]["dropped"].clone()), (Some(1), serde_json::json!([0])), "{j}");
    let tries = j["budget"]["tries"].as_array().unwrap();
    assert!(tries.len() == 2 && tries[0]["bytes"] == full_bytes && tries[1]["bytes"] == cut_bytes, "{j}");
    assert_eq!(j["levels"].as_array().unwrap().iter().map(|l| l["level"].as_u64().unwrap()).collect::<Vec<_>>(), [2, 3]);
    // The text summary says what was left out; the same settings in human units give the same asset.
    let r = cook(&dir.join("cut2.vpak"), &["--max-bytes", &format!("{}kB", (full_bytes - 1) as f64 / 1000.0)]);
    let text = String::from_utf8_lossy(&ok(r).stdout).to_string();
    assert!(text.contains("byte budget") && text.contains("levels 1 to 3 kept, level 0 left out"), "{text}");
    assert!(std::fs::read(dir.join("cut2.vpak")).unwrap() == std::fs::read(&cut).unwrap());
    // inspect: the stored levels.
    let i = json(vdbcook(&["inspect", "--json", s(&cut)]))["files"][0].clone();
    assert_eq!(i["first_level"], 1, "{i}");
    assert_eq!(i["levels"].as_array().unwrap().iter().map(|l| l["level"].as_u64().unwrap()).collect::<Vec<_>>(), [1, 2, 3]);
    // unpack reads level 1 by default, the same level as the full asset's; level 0 is refused in one line.
    let (a, b, c) = (dir.join("a.vdb"), dir.join("b.vdb"), dir.join("c.vdb"));
    let out = ok(vdbcook(&["unpack", s(&cut), "--frame", "2", "-o", s(&a)]));
    assert!(String::from_utf8_lossy(&out.stdout).contains("at level 1"));
    ok(vdbcook(&["unpack", "-q", s(&full), "--frame", "2", "--lod", "1", "-o", s(&b)]));
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(), "level 1 of the cut asset is the full asset's");
    let r = vdbcook(&["unpack", s(&cut), "--frame", "2", "--lod", "0", "-o", s(&c)]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("cut.vpak") && err.contains("level 0 is not in the asset") && err.contains("left out") && err.lines().count() == 1, "{err}");
    assert!(!c.exists());
    // The spec-only reader follows first_level too.
    if python(&["-c", "import numpy, xxhash"]).status.success() {
        let npz = dir.join("a.npz");
        let out = python(&["scripts/vpak_read.py", s(&cut), "--frame", "2", "--out", s(&npz)]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        if python(&["-c", "import pyopenvdb"]).status.success() {
            let c: serde_json::Value = serde_json::from_slice(&ok(python(&["cli/tests/spec_reader_check.py", s(&npz), s(&a)])).stdout).unwrap();
            assert!(c["density"]["voxels"].as_u64().unwrap() > 0 && c["density"]["max_diff"].as_f64().unwrap() == 0.0, "{c}");
        }
        let out = python(&["scripts/vpak_read.py", s(&cut), "--frame", "2", "--lod", "0", "--out", s(&npz)]);
        assert_eq!(out.status.code(), Some(1), "level 0 is refused by the spec reader");
    } else {
        assert!(!in_ci(), "CI=true but /usr/bin/python3 lacks numpy or xxhash");
    }
    // Too small for the coarsest level alone: exit 1, one line, nothing written.
    let none = dir.join("none.vpak");
    let r = cook(&none, &["--max-bytes", "1000"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("no asset fits in 1000 bytes") && err.contains("level 3 alone") && err.lines().count() == 1, "{err}");
    assert!(!none.exists());
    // Not a budget, or with --auto: usage errors.
    for bad in ["0", "-5", "abc", "1.5XB"] {
        let r = cook(&none, &["--max-bytes", bad]);
        assert_eq!(r.status.code(), Some(2), "--max-bytes {bad}: {}", String::from_utf8_lossy(&r.stderr));
    }
    let r = vdbcook(&["cook", "-o", s(&none), "--auto", "--min-psnr", "30", "--max-bytes", "1MB", "fixtures/smoke_seq"]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(!none.exists());
    // A bake manifest takes the same setting, as bytes or as text.
    let bake = dir.join("bake.toml");
    let src = root().join("fixtures/smoke_seq").display().to_string();
    std::fs::write(&bake, format!("[[asset]]\nname = \"a\"\noutput = \"a.vpak\"\ninputs = [\"{src}\"]\nlods = 4\nformat = \"f32\"\nmax_bytes = {}\n\n[[asset]]\nname = \"b\"\noutput = \"b.vpak\"\ninputs = [\"{src}\"]\nmax_bytes = \"0\"\n", full_bytes - 1)).unwrap();
    let r = vdbcook(&["bake", s(&bake)]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("bake.toml:13") && err.contains("byte budget \"0\""), "{err}");
    std::fs::write(&bake, format!("[[asset]]\nname = \"a\"\noutput = \"a.vpak\"\ninputs = [\"{src}\"]\nlods = 4\nformat = \"f32\"\nmax_bytes = {}\n", full_bytes - 1)).unwrap();
    let v: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["bake", "--json", s(&bake)])).stdout).unwrap();
    // Its thumbnail draws the first stored level (level 0 is not in the asset).
    assert!(v["assets"][0]["thumbnail"].is_string() || !gpu_available(), "{v}");
    let baked = json(vdbcook(&["inspect", "--json", s(&dir.join("a.vpak"))]))["files"][0].clone();
    assert!(baked["first_level"] == 1 && std::fs::metadata(dir.join("a.vpak")).unwrap().len() < full_bytes, "{baked}");
    // render and validate draw level 1 by default.
    if gpu_available() {
        let (p, q) = (dir.join("p.png"), dir.join("q.png"));
        ok(vdbcook(&["render", "-q", s(&cut), "--frame", "1", "--size", "48x48", "-o", s(&p)]));
        ok(vdbcook(&["render", "-q", s(&full), "--frame", "1", "--lod", "1", "--size", "48x48", "-o", s(&q)]));
        assert!(std::fs::read(&p).unwrap() == std::fs::read(&q).unwrap(), "render draws the first stored level");
        let v = json(vdbcook(&["validate", s(&cut), "--source", "fixtures/smoke_seq", "--views", "2", "--size", "48x48", "--json"]));
        assert!(v["level"] == 1 && v["voxel"]["rmse"] == 0.0 && v["images"].as_array().unwrap().iter().all(|i| i["rmse"] == 0.0), "{v}");
        let v = json(vdbcook(&["validate", s(&cut), "--source", "fixtures/smoke_seq", "--every-lod", "--views", "1", "--size", "32x32", "--json"]));
        assert_eq!(v["levels"].as_array().unwrap().iter().map(|l| l["level"].as_u64().unwrap()).collect::<Vec<_>>(), [1, 2, 3], "{v}");
        let r = vdbcook(&["render", s(&cut), "--lod", "0", "-o", s(&dir.join("x.png"))]);
        assert_eq!(r.status.code(), Some(1), "{}", String::from_utf8_lossy(&r.stderr));
    }
    let _ = std::fs::remove_dir_all(&dir);
}
