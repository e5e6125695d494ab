//! Segments (`cook --segment-frames N`, format version 7), parts (`cook
//! --part I/N`) and `join`: a segmented asset decodes as the one-segment
//! asset does, frame by frame; parts joined are the one-process asset byte
//! for byte; bad parts are refused; and the cook's memory follows the
//! segment, not the sequence.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

/// `frames` frames of a dense `size`³ block of distinct values (every brick
/// unique) that moves `step` voxels along x per frame.
fn moving_sequence(dir: &Path, frames: usize, size: usize, step: usize) -> String {
    let make = r#"
import sys, numpy as np, pyopenvdb as vdb
d, n, size, step = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
rng = np.random.default_rng(7)
for f in range(n):
    a = (0.05 + rng.random((size, size, size))).astype(np.float32)
    g = vdb.FloatGrid(); g.name = 'density'
    g.copyFromArray(a, ijk=(f * step, 0, 0))
    vdb.write('%s/plume_%04d.vdb' % (d, f + 1), grids=[g])
"#;
    let out = Command::new("/usr/bin/python3").args(["-c", make, s(dir), &frames.to_string(), &size.to_string(), &step.to_string()]).output().expect("python3");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    dir.display().to_string()
}

fn python_ok() -> bool {
    let ok = Command::new("/usr/bin/python3").args(["-c", "import numpy, pyopenvdb"]).output().is_ok_and(|o| o.status.success());
    assert!(ok || !in_ci(), "CI=true but /usr/bin/python3 lacks numpy or pyopenvdb");
    ok
}

fn cook(dir: &Path, name: &str, input: &str, flags: &[&str]) -> PathBuf {
    cook_into(dir, name, &[input], flags)
}

fn unpacked(dir: &Path, asset: &Path, frame: usize, lod: Option<u32>) -> Vec<u8> {
    let out = dir.join(format!("{}-{frame}.vdb", asset.file_stem().unwrap().to_string_lossy()));
    let f = frame.to_string();
    let mut args = vec!["unpack", "-q", "--force", s(asset), "--frame", &f, "-o", s(&out)];
    let l = lod.map(|l| l.to_string());
    if let Some(l) = &l {
        args.extend(["--lod", l]);
    }
    ok(vdbcook(&args));
    std::fs::read(&out).unwrap()
}

#[test]
fn a_segmented_asset_decodes_as_the_whole_one_frame_by_frame() {
    if !python_ok() {
        return;
    }
    let dir = scratch_dir("segments", "decode");
    // Content 150 voxels further each frame: the segments have index offsets of their own.
    let seq = moving_sequence(&dir.join("src").tap_mkdir(), 5, 40, 150);
    for flags in [vec!["--format", "f16"], vec!["--format", "bc7", "--lods", "2"], vec!["--max-error", "0.01"]] {
        let whole = cook(&dir, "whole.vpak", &seq, &flags);
        let seg = cook(&dir, "seg.vpak", &seq, &[flags.as_slice(), &["--segment-frames", "2"]].concat());
        let (w, g) = (inspect(&whole), inspect(&seg));
        assert_eq!(g["segments"].as_array().unwrap().len(), 3, "{flags:?}");
        let offsets: Vec<i64> = g["segments"].as_array().unwrap().iter().map(|e| e["index_offset"][0].as_i64().unwrap()).collect();
        assert!(offsets.windows(2).all(|p| p[0] < p[1]), "{flags:?}: the segments' offsets {offsets:?}");
        for key in ["frames", "index_bbox", "frame_info", "active_voxels"] {
            assert_eq!(w[key], g[key], "{flags:?}: {key}");
        }
        assert_eq!(w["channels"][0]["value_range"], g["channels"][0]["value_range"], "{flags:?}");
        for frame in 0..5 {
            for lod in if flags.contains(&"--lods") { vec![None, Some(1)] } else { vec![None] } {
                assert!(unpacked(&dir, &whole, frame, lod) == unpacked(&dir, &seg, frame, lod), "{flags:?}: frame {frame} level {lod:?} unpacks differently");
            }
        }
    }
    // The same images: validation draws each segment in its own index space.
    if gpu_available() {
        let seg = cook(&dir, "seg32.vpak", &seq, &["--format", "f32", "--segment-frames", "2"]);
        let out = ok(vdbcook(&["validate", "--json", "--size", "48x48", "--views", "2", "--source", &seq, s(&seg)]));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["images"].as_array().unwrap().len(), 10);
        assert!(v["worst"]["rmse"].as_f64().unwrap() < 1e-6, "{}", v["worst"]);
        let a = dir.join("a.png");
        let b = dir.join("b.png");
        let whole = cook(&dir, "whole32.vpak", &seq, &["--format", "f32"]);
        ok(vdbcook(&["render", "--force", "-q", s(&seg), "--frame", "4", "--size", "160x160", "-o", s(&a)]));
        ok(vdbcook(&["render", "--force", "-q", s(&whole), "--frame", "4", "--size", "160x160", "-o", s(&b)]));
        // The segment's box sits 512 voxels further along x in its own index
        // space: float rounding may move a pixel by a level, no more.
        let cmp = "import sys, numpy as np; from PIL import Image; a, b = (np.asarray(Image.open(p), dtype=int) for p in sys.argv[1:]); print(int(abs(a - b).max()), int((a > 8).sum()))";
        let out = Command::new("/usr/bin/python3").args(["-c", cmp, s(&a), s(&b)]).output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        let figures: Vec<u64> = text.split_whitespace().filter_map(|w| w.parse().ok()).collect();
        assert!(
            figures.len() == 2 && figures[0] <= 1 && figures[1] > 200,
            "frame 4 of the segmented asset against the whole one: max difference, lit pixels: {text} {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

trait Mkdir {
    fn tap_mkdir(self) -> PathBuf;
}
impl Mkdir for PathBuf {
    fn tap_mkdir(self) -> PathBuf {
        std::fs::create_dir_all(&self).unwrap();
        self
    }
}

#[test]
fn parts_join_to_what_one_process_writes_and_bad_parts_are_refused() {
    let dir = scratch_dir("segments", "parts");
    let seq = "fixtures/smoke_seq";
    let flags = ["--format", "bc7", "--segment-frames", "1", "--lods", "2"];
    let whole = cook(&dir, "whole.vpak", seq, &flags);
    let part = |i: &str, name: &str, extra: &[&str]| cook(&dir, name, seq, &[flags.as_slice(), extra, &["--part", i]].concat());
    let (a, b, c) = (part("1/3", "a.part", &[]), part("2/3", "b.part", &[]), part("3/3", "c.part", &[]));
    let joined = dir.join("joined.vpak");
    ok(vdbcook(&["join", "-q", s(&a), s(&b), s(&c), "-o", s(&joined)]));
    assert!(std::fs::read(&joined).unwrap() == std::fs::read(&whole).unwrap(), "the joined asset differs from one process's");
    // Determinism at another thread count, segments and all.
    let one_thread = dir.join("one-thread.vpak");
    let mut args = vec!["cook", "-q", "-o", s(&one_thread)];
    args.extend(flags);
    args.push(seq);
    ok(Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(&args).env("RAYON_NUM_THREADS", "1").current_dir(root()).output().unwrap());
    assert!(std::fs::read(&one_thread).unwrap() == std::fs::read(&whole).unwrap(), "one thread cooks another asset");

    let other = part("3/3", "other.part", &["--quality", "slow"]);
    let truncated = dir.join("truncated.part");
    let bytes = std::fs::read(&c).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() - 100]).unwrap();
    let out = dir.join("bad.vpak");
    let cases: [(&[&PathBuf], &str); 5] = [
        (&[&a, &b], "cooked in 3 parts; 2 given"),
        (&[&a, &a, &c], "a.part: is part 1 of 3, but part 2 belongs here"),
        (&[&b, &a, &c], "b.part: is part 2 of 3, but part 1 belongs here"),
        (&[&a, &b, &other], "other.part: is a part of another cook"),
        (&[&a, &b, &truncated], "truncated.part: truncated"),
    ];
    for (parts, want) in cases {
        let mut args = vec!["join", "-o", s(&out)];
        args.extend(parts.iter().map(|p| s(p)));
        let r = vdbcook(&args);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{want}: {err}");
        assert!(err.contains(want) && err.lines().count() == 1, "expected \"{want}\", got: {err}");
        assert!(!out.exists(), "{want}: an output was left");
    }
    // A full disk (a file-size limit of 8 KiB here) while joining: one line, nothing left.
    let o = Command::new("sh").args(["-c", "ulimit -f 8 && exec \"$0\" join \"$1\" \"$2\" \"$3\" -o \"$4\"", env!("CARGO_BIN_EXE_vdbcook"), s(&a), s(&b), s(&c), s(&out)]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.lines().count() == 1 && err.contains("bad.vpak"), "{:?}: {err}", o.status);
    assert!(!out.exists());
    let leftovers: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().filter(|e| e.file_name().to_string_lossy().ends_with(".tmp")).collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    // A part is not an asset, and parts need segments.
    let r = vdbcook(&["inspect", s(&a)]);
    assert!(String::from_utf8_lossy(&r.stderr).contains("join the parts"), "{}", String::from_utf8_lossy(&r.stderr));
    let r = vdbcook(&["cook", "-o", s(&dir.join("x.part")), "--part", "1/2", seq]);
    assert_eq!(r.status.code(), Some(2));
    let r = vdbcook(&["cook", "-o", s(&dir.join("x.part")), "--segment-frames", "4", "--part", "1/2", seq]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(String::from_utf8_lossy(&r.stderr).contains("1 segment(s) to share among 2 parts"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Peak resident memory (KiB) of a cook, as `/usr/bin/time -f %M` reports it.
fn peak_kib(args: &[&str]) -> u64 {
    let out = Command::new("/usr/bin/time").args(["-f", "%M", env!("CARGO_BIN_EXE_vdbcook")]).args(args).current_dir(root()).output().expect("/usr/bin/time (Debian package time)");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stderr).lines().last().and_then(|l| l.trim().parse().ok()).expect("a peak from /usr/bin/time")
}

#[test]
fn memory_follows_the_segment_not_the_sequence() {
    if !python_ok() || !Path::new("/usr/bin/time").exists() {
        assert!(!in_ci(), "CI=true but /usr/bin/time is missing (Debian package time)");
        return;
    }
    let dir = scratch_dir("segments", "memory");
    // 32 frames of 2,744 distinct bricks each (5.6 MB of f32 values a frame).
    let seq = moving_sequence(&dir.join("src").tap_mkdir(), 32, 112, 0);
    let files: Vec<String> = (1..=32).map(|f| format!("{seq}/plume_{f:04}.vdb")).collect();
    let run = |frames: usize, segment: Option<&str>, spill: &str| {
        let out = dir.join(format!("out-{frames}-{}-{spill}.vpak", segment.unwrap_or("one")));
        let mut args = vec!["cook", "-q", "--force", "--format", "f16", "--spill-above", spill, "-o", s(&out)];
        if let Some(n) = segment {
            args.extend(["--segment-frames", n]);
        }
        args.extend(files[..frames].iter().map(String::as_str));
        (peak_kib(&args), out)
    };
    let ((eight, _), (thirty_two, _)) = (run(8, Some("8"), "never"), run(32, Some("8"), "never"));
    let ((whole, in_memory), (spilled, from_file)) = (run(32, None, "never"), run(32, None, "8MiB"));
    eprintln!("peak RSS: 8 frames {eight} KiB, 32 frames in segments of 8 {thirty_two} KiB, 32 frames in one segment {whole} KiB, the same spilled past 8 MiB {spilled} KiB");
    // Flat in the sequence's length: the target is 1.25 (docs/benchmarks.md measures it on a
    // production-size sequence); here the frame read during a segment's encoding and the
    // allocator's pieces weigh more against a small segment, hence the margin...
    assert!(thirty_two as f64 <= 1.4 * eight as f64, "32 frames took {thirty_two} KiB, 8 frames {eight} KiB");
    // ... where one segment grows with it in memory (so the figure above can fail) ...
    assert!(whole as f64 >= 2.0 * thirty_two as f64, "one segment of 32 frames took {whole} KiB, segments of 8 {thirty_two} KiB");
    // ... and not once its pool and atlas are in a spill file, which writes the same asset.
    assert!(spilled as f64 <= 1.4 * eight as f64, "one segment of 32 frames spilled took {spilled} KiB, 8 frames {eight} KiB");
    assert!(std::fs::read(&in_memory).unwrap() == std::fs::read(&from_file).unwrap(), "the spilled cook wrote another asset");
    // Segments spilled: the reader waits at each segment's end (no frame read
    // beside its last stages), and the asset is the in-memory segments' one.
    let (segments_spilled, segments_file) = run(32, Some("8"), "8MiB");
    assert!(segments_spilled as f64 <= 1.4 * eight as f64, "segments of 8 spilled took {segments_spilled} KiB, 8 frames {eight} KiB");
    assert!(std::fs::read(dir.join("out-32-8-never.vpak")).unwrap() == std::fs::read(&segments_file).unwrap(), "the spilled segments wrote another asset");
    // Clustering a spilled segment: k-means++ copies a sample of bricks
    // scattered over the pool, and the system maps a large piece of the file
    // around each one read; dropped every few of them, not every 512 (which
    // took 2.2 times the 8 frames' peak here, 2.6 times on 96 frames of 224³).
    // How many of the file's pages a read maps in depends on what the page
    // cache holds, so the peak moves from run to run (1.15 to 1.43 times the
    // 8 frames' in four pairs of runs): the lower of two runs each,
    // against a bound that still catches the 2.2 times.
    let clustered = |frames: usize| {
        let out = dir.join("clustered.vpak");
        let mut args = vec!["cook", "-q", "--force", "--format", "unorm8", "--clusters", "16", "--variance-threshold", "1", "--spill-above", "8MiB", "-o", s(&out)];
        args.extend(files[..frames].iter().map(String::as_str));
        let peak = peak_kib(&args).min(peak_kib(&args));
        std::fs::remove_file(&out).unwrap();
        peak
    };
    let (clustered_eight, clustered_all) = (clustered(8), clustered(32));
    assert!(clustered_all as f64 <= 1.5 * clustered_eight as f64, "32 frames clustered in one spilled segment took {clustered_all} KiB, 8 frames {clustered_eight} KiB");
    // The report says how much went to the files, and nothing when nothing did.
    let spilled = |spill: &str| {
        let out = dir.join("report.vpak");
        let mut args = vec!["cook", "--json", "--force", "--format", "f16", "--spill-above", spill, "-o", s(&out)];
        args.extend(files[..8].iter().map(String::as_str));
        let v: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&args)).stdout).expect("cook --json");
        std::fs::remove_file(&out).unwrap();
        v["spilled_bytes"].as_u64().expect("spilled_bytes")
    };
    // 8 frames of 2,744 distinct bricks: a 45 MB pool, most of it past 8 MiB.
    let (none, some) = (spilled("never"), spilled("8MiB"));
    assert_eq!(none, 0);
    assert!(some >= 30_000_000, "{some} bytes spilled");
    // The spill files had no names: nothing is left beside the outputs.
    let mut left: Vec<String> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    left.sort();
    assert_eq!(left, ["out-32-8-8MiB.vpak", "out-32-8-never.vpak", "out-32-one-8MiB.vpak", "out-32-one-never.vpak", "out-8-8-never.vpak", "src"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_multi_channel_segment_holds_a_few_bytes_per_leaf_of_each_frame() {
    if !python_ok() || !Path::new("/usr/bin/time").exists() {
        assert!(!in_ci(), "CI=true but /usr/bin/time is missing (Debian package time)");
        return;
    }
    let dir = scratch_dir("segments", "channel-masks");
    // One fire frame, three grids of 8,192 leaves with one active voxel each
    // (one brick, one L3 node), as every frame: all that grows with the
    // frames is what is kept per leaf of each frame. Each channel's own mask
    // there used to be kept whole, 64 bytes a channel: 8 frames to 64 then
    // took 1.5 times the memory.
    let make = r#"
import sys, os, pyopenvdb as vdb
d, n = sys.argv[1], int(sys.argv[2])
grids = []
for name, v in (('density', 0.5), ('temperature', 2.0), ('flame', 0.25)):
    g = vdb.FloatGrid(); g.name = name
    acc = g.getAccessor()
    for i in range(32):
        for j in range(16):
            for k in range(16):
                acc.setValueOn((i * 8 + 3, j * 8 + 3, k * 8 + 3), v)
    grids.append(g)
vdb.write('%s/fire_0001.vdb' % d, grids=grids)
for f in range(2, n + 1):
    os.link('%s/fire_0001.vdb' % d, '%s/fire_%04d.vdb' % (d, f))
"#;
    let src = dir.join("src").tap_mkdir();
    let out = Command::new("/usr/bin/python3").args(["-c", make, s(&src), "64"]).output().expect("python3");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let pattern = format!("{}/fire_####.vdb", s(&src));
    let asset = dir.join("fire.vpak");
    let peak = |frames: &str| peak_kib(&["cook", "-q", "--force", "--format", "f16", "--grids", "density,temperature,flame", "--frames", frames, "-o", s(&asset), &pattern]);
    let (eight, sixty_four) = (peak("1-8"), peak("1-64"));
    eprintln!("peak RSS: 8 frames {eight} KiB, 64 frames {sixty_four} KiB");
    assert!(sixty_four as f64 <= 1.25 * eight as f64, "64 frames took {sixty_four} KiB, 8 frames {eight} KiB");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Unmounts a scratch file system when the test ends, however it ends.
struct Mounted(PathBuf);

impl Drop for Mounted {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

#[test]
fn a_full_disk_under_the_spill_file_is_one_line_and_leaves_nothing() {
    if !python_ok() {
        return;
    }
    let dir = scratch_dir("segments", "full-disk");
    // 8 frames of 512 distinct bricks: an 8 MiB pool, on a 4 MiB file system.
    let seq = moving_sequence(&dir.join("src").tap_mkdir(), 8, 64, 0);
    let small = dir.join("small").tap_mkdir();
    let mounted = Command::new("mount").args(["-t", "tmpfs", "-o", "size=4m", "tmpfs", s(&small)]).output().is_ok_and(|o| o.status.success());
    if !mounted {
        eprintln!("skipped: mounting a 4 MiB tmpfs needs root");
        std::fs::remove_dir_all(&dir).unwrap();
        return;
    }
    let guard = Mounted(small.clone());
    let out = small.join("out.vpak");
    let r = vdbcook(&["cook", "-q", "--format", "f16", "--spill-above", "1MiB", "-o", s(&out), &seq]);
    let err = String::from_utf8_lossy(&r.stderr).into_owned();
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("the brick pool: could not spill") && err.contains("No space left on device"), "{err}");
    assert_eq!(std::fs::read_dir(&small).unwrap().count(), 0, "left behind on the full disk");
    // With room, the same cook spills and succeeds.
    drop(guard);
    ok(vdbcook(&["cook", "-q", "--format", "f16", "--spill-above", "1MiB", "-o", s(&out), &seq]));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A segment is written while the next one cooks: a write that fails there
/// (a file-size limit, as a full disk would) is still one line naming the
/// output, exit 1, and nothing left in the output's directory.
#[test]
fn a_segment_written_beside_the_next_that_fails_is_one_line_and_leaves_nothing() {
    if !python_ok() || !cfg!(unix) {
        return;
    }
    let dir = scratch_dir("segments", "write-fails");
    // 8 frames of 64 distinct bricks: about 64 KiB of f16 texels a frame.
    let seq = moving_sequence(&dir.join("src").tap_mkdir(), 8, 32, 0);
    let out_dir = dir.join("out").tap_mkdir();
    let out = out_dir.join("out.vpak");
    let o = Command::new("sh").args(["-c", "ulimit -f 96 && exec \"$0\" cook \"$1\" --format f16 --segment-frames 2 -o \"$2\" -q", env!("CARGO_BIN_EXE_vdbcook"), &seq, s(&out)]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("out.vpak") && err.contains("too large"), "{err}");
    assert_eq!(std::fs::read_dir(&out_dir).unwrap().count(), 0, "left behind");
    // Without the limit, the same cook succeeds.
    ok(vdbcook(&["cook", "-q", "--format", "f16", "--segment-frames", "2", "-o", s(&out), &seq]));
    std::fs::remove_dir_all(&dir).unwrap();
}
