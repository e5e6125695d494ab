//! Supercompression (`cook --supercompress`, format version 8) and
//! `recompress`: a supercompressed asset restores exactly the GPU bytes of
//! the same asset stored plainly, for every format, channel packing, level
//! and segment; damaged compressed sections are refused in one line; the
//! reports give bytes on disk and on the GPU.

mod common;
use common::*;
use std::path::Path;

use common::cook_into as cook;

fn recompress(asset: &Path, out: &Path, to: &str) {
    ok(vdbcook(&["recompress", "-q", "--force", s(asset), "-o", s(out), "--supercompress", to]));
}

fn smoke() -> String {
    s(&root().join("fixtures/smoke_seq")).to_string()
}

#[test]
fn supercompressed_assets_restore_the_plain_assets_bytes() {
    let dir = scratch_dir("supercompress", "same");
    let multi = s(&root().join("fixtures/multi_grid.vdb")).to_string();
    let smoke = smoke();
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (vec![&smoke], vec!["--format", "f32"]),
        (vec![&smoke], vec!["--format", "f16", "--lods", "3"]),
        (vec![&smoke], vec!["--format", "unorm8", "--segment-frames", "3"]),
        (vec![&smoke], vec!["--format", "unorm16"]),
        (vec![&smoke], vec!["--format", "bc4", "--segment-frames", "2", "--lods", "2"]),
        (vec![&smoke], vec!["--format", "bc7", "--clusters", "40"]),
        (vec![&multi], vec!["--grids", "all", "--format", "unorm8"]),
        (vec![&multi], vec!["--grids", "all", "--group", "density,temperature=bc7"]),
    ];
    let results = par_map(&cases.iter().enumerate().collect::<Vec<_>>(), |&(k, (inputs, flags))| {
        let plain = cook(&dir, &format!("p{k}.vpak"), inputs, flags);
        let level = if k % 2 == 0 { "zstd" } else { "zstd:19" };
        let coded = cook(&dir, &format!("z{k}.vpak"), inputs, &[flags.as_slice(), &["--supercompress", level]].concat());
        // The GPU bytes are the plain cook's: stored plainly again, the file is the plain one byte for byte.
        let back = dir.join(format!("b{k}.vpak"));
        recompress(&coded, &back, "none");
        let (p, c, b) = (std::fs::read(&plain).unwrap(), std::fs::read(&coded).unwrap(), std::fs::read(&back).unwrap());
        assert!(b == p, "{flags:?}: recompressed to none differs from the plain cook");
        // And the plain asset supercompressed is the supercompressed cook byte for byte.
        let again = dir.join(format!("a{k}.vpak"));
        recompress(&plain, &again, level);
        assert!(std::fs::read(&again).unwrap() == c, "{flags:?}: recompressing the plain asset differs from the supercompressed cook");
        assert!(c.len() < p.len(), "{flags:?}: {} bytes supercompressed, {} plain", c.len(), p.len());
        (p.len(), c.len())
    });
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(results.len(), cases.len());
}

#[test]
fn texels_for_the_disk_stay_within_the_bound_and_compress_further() {
    let dir = scratch_dir("supercompress", "bound");
    let smoke = smoke();
    let plain = cook(&dir, "p.vpak", &[&smoke], &["--max-error", "0.01"]);
    let coded = cook(&dir, "z.vpak", &[&smoke], &["--max-error", "0.01", "--supercompress", "zstd"]);
    // The same plain asset, supercompressed without moving its texels: the snapped one is smaller still.
    let unsnapped = dir.join("u.vpak");
    recompress(&plain, &unsnapped, "zstd");
    let size = |p: &Path| std::fs::metadata(p).unwrap().len();
    assert!(size(&coded) < size(&unsnapped), "{} bytes with texels for the disk, {} without", size(&coded), size(&unsnapped));
    // The atlases of its 1-lane texels are stored as tiles (each brick over its step).
    let tiled = inspect(&coded)["sections"].as_array().unwrap().iter().filter(|x| x["coding"]["filter"].as_str().is_some_and(|f| f.starts_with("tiles"))).count();
    assert!(tiled > 0, "no atlas stored as tiles");
    // Every frame within E of its source, voxel by voxel (`diff`'s largest difference).
    for (frame, src) in vdb_files(&root().join("fixtures/smoke_seq")).iter().enumerate() {
        let vdb = dir.join(format!("z{frame}.vdb"));
        ok(vdbcook(&["unpack", "-q", "--force", s(&coded), "--frame", &frame.to_string(), "-o", s(&vdb)]));
        let d: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["diff", "--json", s(src), s(&vdb)])).stdout).unwrap();
        let max = d["max_error"].as_f64().unwrap_or(f64::MAX);
        assert!(max <= 0.01, "frame {frame}: max error {max}: {d}");
        assert_eq!(d["inactive_in_b"].as_u64(), Some(0), "{d}");
        assert!(d["voxels"].as_u64() > Some(1000), "{d}");
    }
    // Same bytes on one thread.
    let one = dir.join("z1.vpak");
    let r = std::process::Command::new(env!("CARGO_BIN_EXE_vdbcook"))
        .env("RAYON_NUM_THREADS", "1")
        .args(["cook", "-q", "--force", "--max-error", "0.01", "--supercompress", "zstd", "-o", s(&one), &smoke])
        .output()
        .unwrap();
    assert!(r.status.success());
    assert!(std::fs::read(&one).unwrap() == std::fs::read(&coded).unwrap(), "one thread wrote another asset");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--optimize disk` context-codes the atlases of level planes where that is smaller
/// (scheme 2, version 11; the smoke's over the voxels its nodes show, scheme 4, version 15):
/// the texels stay within the bound, the asset restores the bytes the cooker chose
/// (rewritten plainly and supercompressed again, it is the same file), any thread count
/// writes it alike, and a damaged stream is refused in one line.
#[test]
fn context_coded_atlases_restore_the_cookers_texels() {
    let dir = scratch_dir("supercompress", "context");
    let smoke = smoke();
    let flags = ["--max-error", "0.004", "--supercompress", "zstd", "--optimize", "disk", "--segment-frames", "2"];
    let coded = cook(&dir, "c.vpak", &[&smoke], &flags);
    let sections = inspect(&coded)["sections"].as_array().unwrap().clone();
    let context: Vec<&serde_json::Value> = sections.iter().filter(|x| x["coding"]["scheme"].as_str().is_some_and(|c| c.starts_with("context"))).collect();
    assert!(!context.is_empty() && context.iter().all(|x| x["coding"]["filter"].as_str().is_some_and(|f| f.starts_with("tiles unpredicted"))), "{sections:?}");
    assert!(context.iter().any(|x| x["coding"]["scheme"] == "context, shown"), "no atlas coded over its shown voxels: {sections:?}");
    let (plain, again) = (dir.join("p.vpak"), dir.join("a.vpak"));
    recompress(&coded, &plain, "none");
    recompress(&plain, &again, "zstd");
    assert!(std::fs::read(&again).unwrap() == std::fs::read(&coded).unwrap(), "supercompressed again, the asset differs");
    assert!(std::fs::metadata(&coded).unwrap().len() * 2 < std::fs::metadata(&plain).unwrap().len());
    for (frame, src) in vdb_files(&root().join("fixtures/smoke_seq")).iter().enumerate().step_by(3) {
        let vdb = dir.join(format!("c{frame}.vdb"));
        ok(vdbcook(&["unpack", "-q", "--force", s(&coded), "--frame", &frame.to_string(), "-o", s(&vdb)]));
        let d: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["diff", "--json", s(src), s(&vdb)])).stdout).unwrap();
        assert!(d["max_error"].as_f64().unwrap_or(f64::MAX) <= 0.004, "frame {frame}: {d}");
        assert_eq!(d["inactive_in_b"].as_u64(), Some(0), "{d}");
    }
    let one = dir.join("c1.vpak");
    let r = std::process::Command::new(env!("CARGO_BIN_EXE_vdbcook")).env("RAYON_NUM_THREADS", "1").args([&["cook", "-q", "--force", "-o", s(&one), &smoke][..], &flags].concat()).output().unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(std::fs::read(&one).unwrap() == std::fs::read(&coded).unwrap(), "one thread wrote another asset");
    // A byte of a context-coded stream flipped: the file is refused as it is opened.
    let mut bytes = std::fs::read(&coded).unwrap();
    bytes[context[0]["offset"].as_u64().unwrap() as usize + 40] ^= 0x08;
    let p = dir.join("flipped.vpak");
    std::fs::write(&p, bytes).unwrap();
    let r = vdbcook(&["unpack", "-q", "--force", s(&p), "-o", s(&dir.join("x.vdb"))]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!((r.status.code(), err.trim_end().lines().count()), (Some(1), 1), "{err}");
    assert!(err.contains("flipped.vpak") && err.contains("brick atlas"), "{err}");
    assert!(!dir.join("x.vdb").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn large_sections_compressed_by_workers_are_the_same_on_any_thread_count() {
    // A 128³ fog's f16 atlas (4 MiB) is above the size that zstd's workers
    // compress (as many as rayon has threads): one thread or two, the same bytes.
    let python = std::process::Command::new("/usr/bin/python3").args(["-c", "import numpy, pyopenvdb"]).output().is_ok_and(|o| o.status.success());
    assert!(python || !in_ci(), "CI=true but /usr/bin/python3 lacks numpy or pyopenvdb");
    if !python {
        return;
    }
    let dir = scratch_dir("supercompress", "threads");
    let fog = dir.join("fog.vdb");
    let made = std::process::Command::new("/usr/bin/python3").args(["scripts/make_bench_volume.py", s(&fog), "--size", "128"]).current_dir(root()).output().unwrap();
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    let cooked: Vec<Vec<u8>> = ["1", "2"]
        .iter()
        .map(|threads| {
            let out = dir.join(format!("z{threads}.vpak"));
            let r = std::process::Command::new(env!("CARGO_BIN_EXE_vdbcook"))
                .env("RAYON_NUM_THREADS", threads)
                .args(["cook", "-q", "--force", "--format", "f16", "--supercompress", "zstd", "-o", s(&out), s(&fog)])
                .output()
                .unwrap();
            assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
            std::fs::read(&out).unwrap()
        })
        .collect();
    let one = dir.join("z1.vpak");
    let atlas = inspect(&one)["sections"].as_array().unwrap().iter().find(|x| x["name"] == "brick atlas").cloned().unwrap();
    assert!(!atlas["coding"].is_null() && atlas["bytes"].as_u64() > Some(2 << 20), "not a large supercompressed atlas: {atlas}");
    assert!(cooked[0] == cooked[1], "one thread and two wrote different assets");
    // And its frame restores the plain cook's bytes.
    let plain = cook(&dir, "p.vpak", &[s(&fog)], &["--format", "f16"]);
    let back = dir.join("b.vpak");
    recompress(&one, &back, "none");
    assert!(std::fs::read(&back).unwrap() == std::fs::read(&plain).unwrap(), "restored bytes differ from the plain cook");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn damaged_compressed_sections_are_refused_in_one_line() {
    let dir = scratch_dir("supercompress", "damaged");
    let coded = cook(&dir, "z.vpak", &[&smoke()], &["--format", "unorm8", "--supercompress", "zstd"]);
    let bytes = std::fs::read(&coded).unwrap();
    let j = inspect(&coded);
    let atlas = j["sections"].as_array().unwrap().iter().find(|x| x["name"] == "brick atlas" && !x["coding"].is_null()).expect("a supercompressed atlas").clone();
    let at = atlas["offset"].as_u64().unwrap() as usize + 5;
    let mut flipped = bytes.clone();
    flipped[at] ^= 0x40;
    let cases = [("flipped.vpak", flipped), ("truncated.vpak", bytes[..at].to_vec())];
    for (name, b) in cases {
        let p = dir.join(name);
        std::fs::write(&p, b).unwrap();
        for cmd in [vec!["inspect", s(&p)], vec!["unpack", "-q", "--force", s(&p), "--frame", "0", "-o", s(&dir.join("x.vdb"))]] {
            let r = vdbcook(&cmd);
            let err = String::from_utf8_lossy(&r.stderr);
            assert_eq!(r.status.code(), Some(1), "{cmd:?}: {err}");
            assert_eq!(err.trim_end().lines().count(), 1, "{cmd:?}: {err}");
            assert!(err.contains(name), "{cmd:?}: {err}");
        }
        assert!(!dir.join("x.vdb").exists());
    }
    // A bad level is a usage error.
    let r = vdbcook(&["cook", "-q", "--supercompress", "zstd:30", "-o", s(&dir.join("y.vpak")), &smoke()]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(String::from_utf8_lossy(&r.stderr).contains("zstd:30"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn reports_give_bytes_on_disk_and_on_the_gpu() {
    let dir = scratch_dir("supercompress", "reports");
    let out = dir.join("z.vpak");
    let r = ok(vdbcook(&["cook", "--json", "--force", "--format", "f16", "--segment-frames", "2", "--supercompress", "zstd", "-o", s(&out), &smoke()]));
    let c: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let (file, gpu) = (c["file_bytes"].as_u64().unwrap(), c["gpu_bytes"].as_u64().unwrap());
    assert_eq!(file, std::fs::metadata(&out).unwrap().len());
    assert!(file < gpu, "{file} on disk, {gpu} on the GPU");
    let sections = c["sections"].as_array().unwrap();
    let sum = |k: &str| sections.iter().filter(|x| x["name"] != "metadata").map(|x| x[k].as_u64().unwrap()).sum::<u64>();
    assert_eq!(sum("bytes"), gpu);
    assert!(sum("disk_bytes") < gpu && sections.iter().any(|x| x["name"] == "coding" && x["disk_bytes"].as_u64() > Some(0)), "{sections:?}");
    let segs = c["segments"].as_array().unwrap();
    assert_eq!(segs.len(), 2);
    assert_eq!(segs.iter().map(|x| x["gpu_bytes"].as_u64().unwrap()).sum::<u64>(), gpu);
    // inspect agrees, per segment and per section.
    let i = inspect(&out);
    assert_eq!((i["file_bytes"].as_u64(), i["gpu_bytes"].as_u64(), i["version"].as_u64()), (Some(file), Some(gpu), Some(u64::from(vdbcook_vpak::VERSION))));
    for (a, b) in i["segments"].as_array().unwrap().iter().zip(segs) {
        assert_eq!((a["bytes"].as_u64(), a["gpu_bytes"].as_u64()), (b["bytes"].as_u64(), b["gpu_bytes"].as_u64()));
    }
    let coded: Vec<&serde_json::Value> = i["sections"].as_array().unwrap().iter().filter(|x| !x["coding"].is_null()).collect();
    assert!(!coded.is_empty() && coded.iter().all(|x| x["disk_bytes"].as_u64() < x["bytes"].as_u64()), "{coded:?}");
    // The text says both.
    let text = String::from_utf8_lossy(&ok(vdbcook(&["cook", "--force", "--format", "f16", "--supercompress", "zstd", "-o", s(&out), &smoke()])).stderr).into_owned()
        + &String::from_utf8_lossy(&ok(vdbcook(&["cook", "--force", "--format", "f16", "--supercompress", "zstd", "-o", s(&out), &smoke()])).stdout);
    assert!(text.contains("supercompressed") && text.contains("on the GPU"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_bake_records_both_sizes_and_a_cached_asset_reports_them_again() {
    let dir = scratch_dir("supercompress", "bake");
    let manifest = dir.join("bake.toml");
    let smoke = root().join("fixtures/smoke_seq").display().to_string();
    std::fs::write(&manifest, format!("[[asset]]\nname = \"smoke\"\noutput = \"smoke.vpak\"\ninputs = [\"{smoke}\"]\nmax_error = 0.01\nsupercompress = \"zstd:3\"\noptimize = \"disk\"\n")).unwrap();
    let out = dir.join("out");
    for run in 0..2 {
        let r = ok(vdbcook(&["bake", "--json", s(&manifest), "--out-dir", s(&out)]));
        let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
        let a = &v["assets"][0];
        assert_eq!(a["status"], if run == 0 { "baked" } else { "cached" }, "{a}");
        let (bytes, gpu) = (a["bytes"].as_u64().unwrap(), a["gpu_bytes"].as_u64().unwrap());
        assert_eq!(bytes, std::fs::metadata(out.join("smoke.vpak")).unwrap().len());
        assert!(bytes < gpu, "{bytes} on disk, {gpu} on the GPU");
    }
    let i = inspect(&out.join("smoke.vpak"));
    let set = &i["settings"];
    assert_eq!((set["supercompress"].as_str(), set["optimize"].as_str()), (Some("zstd:3"), Some("disk")), "{set}");
    let _ = std::fs::remove_dir_all(&dir);
}
