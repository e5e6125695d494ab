//! Several files per frame (`cook --with`, `NAME@N`, manifest `with`), end to
//! end on a Blender-style sequence that OpenVDB writes (cli/tests/with_sources.py):
//! noise/fluid_noise_####.vdb (density, flame) and data/fluid_data_####.vdb
//! (vel, and another density), frames 1 to 3, one voxel size.

mod common;
use common::*;
use std::collections::HashMap;
use std::path::Path;
use std::process::{Command, Output};

const NOISE: &str = "noise/fluid_noise_####.vdb";
const DATA: &str = "data/fluid_data_####.vdb";

/// A scratch directory holding the sequence, written by OpenVDB (`None` without pyopenvdb).
fn sequence(tag: &str) -> Option<Scratch> {
    if !oracle_available() {
        return None;
    }
    let dir = scratch_dir("with", tag);
    let out = Command::new("/usr/bin/python3").arg(root().join("cli/tests/with_sources.py")).arg(&dir).output().expect("run with_sources.py");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    Some(dir)
}

/// vdbcook run in `dir`, with relative inputs as a user types them.
fn run_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(args).current_dir(dir).output().expect("run vdbcook")
}

fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `cook -q --frames 1-3 NOISE --with DATA -o OUT` and `extra`, in `dir`.
fn cook(dir: &Path, out: &str, extra: &[&str]) -> Output {
    let mut args = vec!["cook", "-q", "--frames", "1-3", NOISE, "--with", DATA, "-o", out];
    args.extend(extra);
    run_in(dir, &args)
}

/// An error of exit code `code`, one line, that says each of `words`.
fn assert_error(o: &Output, code: i32, words: &[&str]) {
    let e = err(o);
    assert_eq!(o.status.code(), Some(code), "{e}");
    assert_eq!(e.trim_end().lines().count(), 1, "one line: {e}");
    for w in words {
        assert!(e.contains(w), "{w:?} missing from: {e}");
    }
    assert!(!e.contains("panicked"), "{e}");
}

/// Every grid of a .vdb as OpenVDB reads it: values by coordinate (scalars and vec3s).
fn openvdb_grids(file: &Path, dir: &Path) -> HashMap<String, HashMap<[i32; 3], Vec<f64>>> {
    let (d1, d3) = (dir.join("d1.bin"), dir.join("d3.bin"));
    let json = run_oracle(file, &["--voxels", s(&d1), "--vec3-voxels", s(&d3)]).expect("OpenVDB reads the unpacked file");
    let names: Vec<String> = json["grids"].as_array().unwrap().iter().map(|g| g["name"].as_str().unwrap().to_string()).collect();
    let mut out: HashMap<String, HashMap<[i32; 3], Vec<f64>>> = names.iter().map(|n| (n.clone(), HashMap::new())).collect();
    for (g, c, v) in read_dump::<1>(&d1).voxels {
        out.entry(names[g as usize].clone()).or_default().insert(c, v.to_vec());
    }
    for (g, c, v) in read_dump::<3>(&d3).voxels {
        out.entry(names[g as usize].clone()).or_default().insert(c, v.to_vec());
    }
    out
}

/// The sources every segment of `asset` records, by path.
fn recorded_sources(asset: &Path) -> Vec<String> {
    let a = vdbcook_vpak::Asset::open(asset).unwrap();
    let mut paths: Vec<String> = (0..a.segment_count()).flat_map(|s| a.stored_segment(s).unwrap().metadata().unwrap().sources).map(|s| s.path).collect();
    paths.sort();
    paths.dedup();
    paths
}

#[test]
fn every_channel_of_two_files_per_frame_round_trips_through_openvdb() {
    let Some(dir) = sequence("roundtrip") else { return };
    let asset = dir.join("fire.vpak");
    ok(cook(&dir, s(&asset), &["--grids", "density@0,flame,vel", "--format", "f32"]));
    let meta = inspect(&asset);
    let names: Vec<&str> = meta["channels"].as_array().unwrap().iter().map(|c| c["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["density", "flame", "vel.x", "vel.y", "vel.z"], "channels keep their grids' names");
    // Every file of every frame is recorded; each frame's own source is its main file.
    let mut want: Vec<String> = (1..=3).flat_map(|n| [format!("data/fluid_data_{n:04}.vdb"), format!("noise/fluid_noise_{n:04}.vdb")]).collect();
    want.sort();
    assert_eq!(recorded_sources(&asset), want);
    let frame_sources: Vec<u64> = meta["frame_info"].as_array().unwrap().iter().map(|f| f["source"].as_u64().unwrap()).collect();
    for (f, i) in frame_sources.iter().enumerate() {
        assert_eq!(meta["sources"][*i as usize]["path"], format!("noise/fluid_noise_{:04}.vdb", f + 1));
    }
    let mut compared = 0;
    for frame in 0..3 {
        let out = dir.join(format!("f{frame}.vdb"));
        ok(vdbcook(&["unpack", "-q", s(&asset), "--frame", &frame.to_string(), "-o", s(&out)]));
        let back = openvdb_grids(&out, &dir);
        let n = frame + 1;
        // (grid, the file it comes from, its components)
        for (grid, file, components) in
            [("density", format!("noise/fluid_noise_{n:04}.vdb"), 1), ("flame", format!("noise/fluid_noise_{n:04}.vdb"), 1), ("vel", format!("data/fluid_data_{n:04}.vdb"), 3)]
        {
            let src = vdbcook_vdb::open(&dir.join(&file)).unwrap();
            let gi = src.grids.iter().position(|g| g.name == grid).unwrap();
            let parts = src.read_channels(gi).unwrap();
            assert_eq!(parts.len(), components);
            let theirs = &back[grid];
            for (k, g) in parts.iter().enumerate() {
                assert!(g.tiles.is_empty(), "the generator writes voxels only");
                for l in &g.leaves {
                    for i in l.mask.iter_on() {
                        let (x, y, z) = vdbcook_grid::leaf_local(i);
                        let c = [l.origin.x + x, l.origin.y + y, l.origin.z + z];
                        let v = theirs.get(&c).unwrap_or_else(|| panic!("frame {frame} {grid}: voxel {c:?} of {file} is not active in the unpacked grid"))[k];
                        assert_eq!(v, f64::from(l.values[i]), "frame {frame} {grid}[{k}] at {c:?}: OpenVDB reads {v}, {file} holds {}", l.values[i]);
                        compared += 1;
                    }
                }
            }
        }
    }
    assert!(compared > 20_000, "{compared} values compared");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_grid_in_two_files_needs_its_sequence() {
    let Some(dir) = sequence("ambiguous") else { return };
    let out = dir.join("a.vpak");
    // "density" is in both files of every frame.
    for grids in ["density,flame,vel", "all"] {
        let r = cook(&dir, s(&out), &["--grids", grids]);
        assert_error(&r, 2, &["\"density\"", "noise/fluid_noise_0001.vdb", "data/fluid_data_0001.vdb", "density@0", "density@1"]);
        assert!(!out.exists());
    }
    // @1 takes the data file's density (its values are 2 to 2.5; the noise file's at most 1.01;
    // a voxel active in vel alone reads the background, 0).
    ok(cook(&dir, s(&out), &["--grids", "density@1,vel", "--format", "f32"]));
    let ch = &inspect(&out)["channels"];
    assert_eq!((ch[0]["name"].as_str(), ch[0]["grid"].as_str()), (Some("density"), Some("density")), "the channel is the grid's, without @1");
    assert!(ch[0]["value_range"][1].as_f64().unwrap() > 2.0, "{}", ch[0]);
    assert_eq!(recorded_sources(&out).len(), 6);
    let _ = std::fs::remove_file(&out);
    ok(cook(&dir, s(&out), &["--grids", "density@0", "--format", "f32"]));
    assert!(inspect(&out)["channels"][0]["value_range"][1].as_f64().unwrap() < 1.5);
    let _ = std::fs::remove_file(&out);
    // --grid finds a grid in whichever file has it.
    ok(cook(&dir, s(&out), &["--grid", "vel"]));
    assert_eq!(inspect(&out)["channels"].as_array().unwrap().len(), 3);
    let _ = std::fs::remove_file(&out);
    // A sequence that does not exist, or that lacks the grid.
    assert_error(&cook(&dir, s(&out), &["--grids", "density@2,vel"]), 2, &["density@2", "no sequence 2"]);
    assert_error(&cook(&dir, s(&out), &["--grids", "flame@1"]), 2, &["data/fluid_data_0001.vdb", "no grid named \"flame\""]);
    assert_error(&run_in(&dir, &["cook", "-q", "--frames", "1-3", NOISE, "--grids", "density@1", "-o", s(&out)]), 2, &["density@1", "no sequence 1"]);
    assert!(!out.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_frame_missing_from_a_with_sequence_is_an_error_or_empty_channels() {
    let Some(dir) = sequence("missing") else { return };
    let out = dir.join("a.vpak");
    let frame2 = std::fs::read(dir.join("data/fluid_data_0002.vdb")).unwrap();
    std::fs::remove_file(dir.join("data/fluid_data_0002.vdb")).unwrap();
    assert_error(&cook(&dir, s(&out), &["--grids", "density@0,vel"]), 1, &["frame 2", DATA, "data/fluid_data_0002.vdb", "--allow-missing"]);
    // A directory (or glob) without a file numbered 2.
    let r = run_in(&dir, &["cook", "-q", "noise", "--with", "data", "--grids", "density@0,vel", "-o", s(&out)]);
    assert_error(&r, 1, &["frame 2", "--with data", "number 2"]);
    assert!(!out.exists());
    // --allow-missing: frame 2 has the noise file's channels, and an empty vel (its voxels,
    // active for density, read vel's background).
    ok(cook(&dir, s(&out), &["--grids", "density@0,vel", "--format", "f32", "--allow-missing"]));
    assert_eq!(recorded_sources(&out).len(), 5);
    for frame in 0..3 {
        let file = dir.join(format!("u{frame}.vdb"));
        ok(vdbcook(&["unpack", "-q", s(&out), "--frame", &frame.to_string(), "-o", s(&file)]));
        let back = openvdb_grids(&file, &dir);
        let moving = back.get("vel").map_or(0, |v| v.values().filter(|x| x.iter().any(|&c| c != 0.0)).count());
        assert!(back["density"].len() >= 2000, "frame {frame}: {} density voxels", back["density"].len());
        assert_eq!(moving == 0, frame == 1, "frame {frame}: {moving} vel voxels not 0");
    }
    // Names without numbers are matched by position: the counts must agree.
    std::fs::write(dir.join("data/fluid_data_0002.vdb"), frame2).unwrap();
    for (sub, from) in [("m", "noise/fluid_noise"), ("w", "data/fluid_data")] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
        for (n, name) in ["a", "b", "c"].iter().enumerate() {
            std::fs::copy(dir.join(format!("{from}_{:04}.vdb", n + 1)), dir.join(sub).join(format!("{name}.vdb"))).unwrap();
        }
    }
    std::fs::remove_file(dir.join("w/c.vdb")).unwrap();
    let positional = dir.join("p.vpak");
    let r = run_in(&dir, &["cook", "-q", "m", "--with", "w", "--grids", "density@0,vel", "-o", s(&positional)]);
    assert_error(&r, 1, &["--with w", "2 file(s)", "3 frame(s)", "position"]);
    std::fs::copy(dir.join("data/fluid_data_0003.vdb"), dir.join("w/c.vdb")).unwrap();
    ok(run_in(&dir, &["cook", "-q", "m", "--with", "w", "--grids", "density@0,vel", "--format", "f32", "-o", s(&positional)]));
    let whole = dir.join("whole.vpak");
    ok(cook(&dir, s(&whole), &["--grids", "density@0,vel", "--format", "f32"]));
    let (a, b) = (inspect(&positional), inspect(&whole));
    assert_eq!(
        a["frame_info"].as_array().map(|f| f.iter().map(|x| x["active_voxels"].clone()).collect::<Vec<_>>()),
        b["frame_info"].as_array().map(|f| f.iter().map(|x| x["active_voxels"].clone()).collect::<Vec<_>>())
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn parts_and_segments_of_a_two_file_cook_join_into_the_whole() {
    let Some(dir) = sequence("parts") else { return };
    let whole = dir.join("whole.vpak");
    let grids = ["--grids", "density@0,flame,vel", "--segment-frames", "1"];
    ok(cook(&dir, s(&whole), &grids));
    let mut parts = Vec::new();
    for i in 1..=3 {
        let p = dir.join(format!("p{i}.part"));
        let mut extra = grids.to_vec();
        let part = format!("{i}/3");
        extra.extend(["--part", &part]);
        ok(cook(&dir, s(&p), &extra));
        parts.push(p);
    }
    let joined = dir.join("joined.vpak");
    let mut args = vec!["join", "-q"];
    args.extend(parts.iter().map(|p| s(p)));
    args.extend(["-o", s(&joined)]);
    ok(run_in(&dir, &args));
    assert_eq!(std::fs::read(&joined).unwrap(), std::fs::read(&whole).unwrap(), "the parts join into the one cook's bytes");
    assert_eq!(recorded_sources(&whole).len(), 6, "each segment records its frame's files");
    // A part of a cook with other --with files does not join with these.
    std::fs::create_dir_all(dir.join("other")).unwrap();
    for n in 1..=3 {
        std::fs::copy(dir.join(format!("data/fluid_data_{n:04}.vdb")), dir.join(format!("other/vel_{n:04}.vdb"))).unwrap();
    }
    let stranger = dir.join("s2.part");
    ok(run_in(&dir, &["cook", "-q", "--frames", "1-3", NOISE, "--with", "other/vel_####.vdb", "--grids", "density@0,flame,vel", "--segment-frames", "1", "--part", "2/3", "-o", s(&stranger)]));
    let r = run_in(&dir, &["join", "-q", s(&parts[0]), s(&stranger), s(&parts[2]), "-o", s(&dir.join("bad.vpak"))]);
    assert_ne!(r.status.code(), Some(0), "parts of two cooks are refused");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cook_validate_and_validate_pass_on_a_two_file_asset() {
    let Some(dir) = sequence("validate") else { return };
    if !gpu_available() {
        return;
    }
    let asset = dir.join("fire.vpak");
    let view = ["--views", "2", "--size", "48x48", "--max-rmse", "0"];
    let mut extra = vec!["--grids", "density@0,flame,vel", "--format", "f32", "--validate"];
    extra.extend(view);
    ok(cook(&dir, s(&asset), &extra));
    // From the files the asset records (the --with ones found again and checked) ...
    let mut args = vec!["validate", s(&asset)];
    args.extend(view);
    let r = ok(run_in(&dir, &args));
    assert!(String::from_utf8_lossy(&r.stdout).contains("the 6 file(s) the asset records"), "{}", String::from_utf8_lossy(&r.stdout));
    // ... from another directory (they are looked up beside the asset) ...
    ok(vdbcook(&args));
    // ... and from --source and --with.
    let mut given = vec!["validate", s(&asset), "--source", NOISE, "--source-frames", "1-3", "--with", DATA];
    given.extend(view);
    ok(run_in(&dir, &given));
    // Without the --with files, the asset's vel has no source.
    let mut without = vec!["validate", s(&asset), "--source", NOISE, "--source-frames", "1-3"];
    without.extend(view);
    assert_ne!(run_in(&dir, &without).status.code(), Some(0));
    // A segmented asset (its sources recorded per segment) and --auto's choice validate too.
    let segmented = dir.join("seg.vpak");
    ok(cook(&dir, s(&segmented), &["--grids", "density@0,flame,vel", "--format", "f32", "--segment-frames", "2"]));
    let mut args2 = vec!["validate", s(&segmented)];
    args2.extend(view);
    ok(run_in(&dir, &args2));
    let auto = dir.join("auto.vpak");
    ok(cook(&dir, s(&auto), &["--grids", "density@0,flame,vel", "--auto", "--min-psnr", "30", "--views", "1", "--size", "32x32"]));
    assert_eq!(recorded_sources(&auto).len(), 6);
    let mut args3 = vec!["validate", s(&auto), "--min-psnr", "30"];
    args3.extend(&view[..4]);
    ok(run_in(&dir, &args3));
    // A --with file that changed since the cook is named.
    std::fs::copy(dir.join("data/fluid_data_0003.vdb"), dir.join("data/fluid_data_0002.vdb")).unwrap();
    assert_error(&run_in(&dir, &args), 1, &["data/fluid_data_0002.vdb", "changed"]);
    let _ = std::fs::remove_dir_all(&dir);
}

const MANIFEST: &str = r#"[[asset]]
name = "fire"
output = "fire.vpak"
inputs = ["noise/fluid_noise_####.vdb"]
with = ["data/fluid_data_####.vdb"]
frames = "1-3"
grids = "density@0,flame,vel"
format = "f16"
"#;

/// The key `bake --plan` gives the manifest's one asset.
fn planned_key(manifest: &Path) -> String {
    let o = ok(vdbcook(&["bake", s(manifest), "--plan", "--json"]));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // A build system's action reads every file the plan lists: the with files too.
    let files: Vec<&str> = v["assets"][0]["files"].as_array().unwrap().iter().map(|f| f.as_str().unwrap()).collect();
    assert_eq!(files.len(), 6, "{files:?}");
    assert!(files[3..].iter().all(|f| f.contains("fluid_data_")), "{files:?}");
    v["assets"][0]["cache_key"].as_str().unwrap().to_string()
}

#[test]
fn a_manifest_with_with_cooks_the_cli_bytes_and_keys_the_with_files() {
    let Some(dir) = sequence("bake") else { return };
    let manifest = dir.join("bake.toml");
    std::fs::write(&manifest, MANIFEST).unwrap();
    let out = dir.join("out");
    let r = ok(vdbcook(&["bake", "--json", s(&manifest), "--out-dir", s(&out)]));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(v["assets"][0]["status"], "baked", "{v}");
    // The bake's asset, without what a bake adds to its settings, is the command line's.
    let baked = vdbcook_vpak::Asset::open(&out.join("fire.vpak")).unwrap();
    let stripped = vdbcook_vpak::segments::rewrite_metadata(&baked, |m| m.settings.retain(|(k, _)| k != "cache_key" && k != "bake_record")).unwrap();
    let cli = dir.join("cli.vpak");
    ok(cook(&dir, s(&cli), &["--grids", "density@0,flame,vel", "--format", "f16"]));
    assert!(stripped == std::fs::read(&cli).unwrap(), "bake and cook write the same bytes");
    // The key follows the with files' bytes and the with inputs.
    let key = planned_key(&manifest);
    assert_eq!(key, v["assets"][0]["cache_key"].as_str().unwrap());
    let kept = std::fs::read(dir.join("data/fluid_data_0003.vdb")).unwrap();
    std::fs::copy(dir.join("data/fluid_data_0002.vdb"), dir.join("data/fluid_data_0003.vdb")).unwrap();
    let changed = planned_key(&manifest);
    assert_ne!(changed, key, "a changed with file changes the key");
    std::fs::write(dir.join("data/fluid_data_0003.vdb"), &kept).unwrap();
    assert_eq!(planned_key(&manifest), key);
    std::fs::create_dir_all(dir.join("moved")).unwrap();
    for n in 1..=3 {
        std::fs::copy(dir.join(format!("data/fluid_data_{n:04}.vdb")), dir.join(format!("moved/fluid_data_{n:04}.vdb"))).unwrap();
    }
    let elsewhere = dir.join("elsewhere.toml");
    std::fs::write(&elsewhere, MANIFEST.replace("data/fluid_data", "moved/fluid_data")).unwrap();
    assert_ne!(planned_key(&elsewhere), key, "other with inputs, another key");
    // Unchanged: the bake finds it in place.
    let again: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["bake", "--json", s(&manifest), "--out-dir", s(&out)])).stdout).unwrap();
    assert_eq!(again["assets"][0]["status"], "cached");
    // A with file missing: a manifest error naming the frame and the key, unless allow_missing.
    std::fs::remove_file(dir.join("data/fluid_data_0002.vdb")).unwrap();
    let r = vdbcook(&["bake", s(&manifest), "--out-dir", s(&dir.join("out2"))]);
    assert_error(&r, 2, &["frame 2", "with data/fluid_data_####.vdb", "allow_missing = true"]);
    std::fs::write(&manifest, MANIFEST.replace("format", "allow_missing = true\nformat")).unwrap();
    let r = ok(vdbcook(&["bake", "--json", s(&manifest), "--out-dir", s(&dir.join("out2"))]));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(v["assets"][0]["status"], "baked", "{v}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn help_explains_with_and_picking_a_sequence() {
    let help = String::from_utf8_lossy(&ok(vdbcook(&["cook", "--help"])).stdout).into_owned();
    for want in ["--with <INPUT>", "@N", "--with data/fluid_data_####.vdb"] {
        assert!(help.contains(want), "cook --help lacks {want:?}");
    }
    let bake = String::from_utf8_lossy(&ok(vdbcook(&["bake", "--help"])).stdout).into_owned();
    assert!(bake.contains("with = ["), "bake --help shows the with key");
    let validate = String::from_utf8_lossy(&ok(vdbcook(&["validate", "--help"])).stdout).into_owned();
    assert!(validate.contains("--with <INPUT>"));
}
