//! Bad input and bad usage: one-line errors that name the file (and the grid),
//! documented exit codes, never a panic.

mod common;
use common::*;

fn stderr_of(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A scratch directory holding `bytes` as the file `name`, and that file.
fn scratch(name: &str, bytes: &[u8]) -> (Scratch, std::path::PathBuf) {
    let dir = scratch_dir("errors", name);
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    (dir, p)
}

fn assert_one_line_error(out: &std::process::Output, needles: &[&str]) {
    let err = stderr_of(out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "not one line: {err}");
    assert!(err.starts_with("vdbcook: error: "), "{err}");
    for n in needles {
        assert!(err.contains(n), "{err:?} lacks {n:?}");
    }
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn missing_file_is_a_failure_naming_it() {
    let out = vdbcook(&["inspect", "no/such/file.vdb"]);
    assert_one_line_error(&out, &["no/such/file.vdb"]);
}

#[test]
fn not_a_vdb_file() {
    let (_dir, p) = scratch("notes.vdb", b"this is not a volume at all, just text\n");
    let out = vdbcook(&["inspect", p.to_str().unwrap()]);
    assert_one_line_error(&out, &["notes.vdb", "not an OpenVDB file"]);
}

#[test]
fn truncated_file_names_file_and_grid() {
    let full = std::fs::read(root().join("fixtures/fog_blosc.vdb")).unwrap();
    let (_dir, p) = scratch("cut.vdb", &full[..full.len() * 2 / 3]);
    let out = vdbcook(&["inspect", p.to_str().unwrap()]);
    assert_one_line_error(&out, &["cut.vdb", "grid \"density\"", "truncated"]);
}

#[test]
fn flipped_count_is_refused_without_a_huge_allocation() {
    // The file metadata count sits right after the 8+4+8+1+36-byte header.
    let mut bytes = std::fs::read(root().join("fixtures/fog_blosc.vdb")).unwrap();
    bytes[57 + 3] ^= 0x40;
    let (_dir, p) = scratch("flipped.vdb", &bytes);
    let out = vdbcook(&["inspect", p.to_str().unwrap()]);
    assert_one_line_error(&out, &["flipped.vdb", "implausible metadata count"]);
}

#[test]
fn good_files_are_still_described_when_one_fails() {
    let out = vdbcook(&["inspect", "--json", "fixtures/fog_zip.vdb", "nope.vdb", "fixtures/tiles.vdb"]);
    assert_eq!(out.status.code(), Some(1));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let paths: Vec<&str> = v["files"].as_array().unwrap().iter().map(|f| f["path"].as_str().unwrap()).collect();
    assert_eq!(paths, ["fixtures/fog_zip.vdb", "fixtures/tiles.vdb"]);
    assert!(stderr_of(&out).contains("nope.vdb"));
}

#[test]
fn frustum_grid_is_skipped_with_a_reason() {
    let out = vdbcook(&["inspect", "--json", "fixtures/map_NonlinearFrustumMap.vdb"]);
    assert!(out.status.success(), "{}", stderr_of(&out));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let why = v["files"][0]["grids"][0]["skipped"].as_str().unwrap();
    assert!(why.contains("NonlinearFrustumMap"), "{why}");
}

#[test]
fn usage_errors_exit_2() {
    assert_eq!(vdbcook(&["inspect"]).status.code(), Some(2));
    assert_eq!(vdbcook(&["inspect", "--bogus", "x.vdb"]).status.code(), Some(2));
    assert_eq!(vdbcook(&["frobnicate"]).status.code(), Some(2));
    assert_eq!(vdbcook(&["--threads", "0", "inspect", "fixtures/empty.vdb"]).status.code(), Some(2));
}

#[test]
fn help_documents_exit_codes() {
    let out = vdbcook(&["--help"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for line in ["0  success", "1  failure", "2  usage error", "3  quality gate"] {
        assert!(text.contains(line), "{text}");
    }
}

#[test]
fn output_does_not_depend_on_thread_count() {
    let one = vdbcook(&["-j", "1", "inspect", "--json", "fixtures/fog_half_blosc.vdb", "fixtures/tiles.vdb"]);
    let two = vdbcook(&["-j", "2", "inspect", "--json", "fixtures/fog_half_blosc.vdb", "fixtures/tiles.vdb"]);
    assert!(one.status.success());
    assert_eq!(one.stdout, two.stdout);
}

/// The smallest address-space limit (KiB, `ulimit -v`) under which the
/// binary starts at all, found by bisection: the floor the test builds on.
fn start_limit_kib() -> u64 {
    let starts =
        |kib: u64| std::process::Command::new("sh").args(["-c", &format!("ulimit -v {kib} && exec \"$0\" --version"), env!("CARGO_BIN_EXE_vdbcook")]).output().is_ok_and(|o| o.status.success());
    let (mut lo, mut hi) = (1u64 << 10, 1u64 << 22);
    assert!(starts(hi), "vdbcook does not start under a 4 GiB limit");
    while hi - lo > 512 {
        let mid = (lo + hi) / 2;
        if starts(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// Eight frames of a dense 96³ fog whose bricks all differ (a 28 MB brick pool).
fn dense_frames(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    use vdbcook_grid::{Coord, Grid, GridClass, Leaf, LeafMask, Transform};
    (0..8)
        .map(|f| {
            let mut leaves = Vec::new();
            for (x, y, z) in (0..12).flat_map(|x| (0..12).flat_map(move |y| (0..12).map(move |z| (x, y, z)))) {
                let mut values = [0f32; 512];
                for (i, v) in values.iter_mut().enumerate() {
                    *v = ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(((x * 144 + y * 12 + z + 1728 * f) as u32).wrapping_mul(40_503)) >> 8) as f32 / (1u32 << 24) as f32;
                }
                leaves.push(Leaf { origin: Coord::new(x * 8, y * 8, z * 8), mask: LeafMask([u64::MAX; 8]), values });
            }
            let g = Grid { name: "density".into(), class: GridClass::FogVolume, background: 0.0, transform: Transform::identity(), leaves, tiles: Vec::new() };
            let bytes = vdbcook_vdb::write_vdb_grids(&[vdbcook_vdb::WriteGrid::Float(&g)], vdbcook_vdb::WriteOptions { version: 224, zip: false }).unwrap();
            let p = dir.join(format!("dense_{f}.vdb"));
            std::fs::write(&p, bytes).unwrap();
            p
        })
        .collect()
}

/// Out of memory is a failure like any other: one line, exit 1, nothing written.
#[test]
fn running_out_of_memory_is_one_line_and_leaves_nothing() {
    if !cfg!(target_os = "linux") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("vdbcook-oom-{}", std::process::id()));
    let out_dir = dir.join("out");
    std::fs::create_dir_all(&out_dir).unwrap();
    let frames = dense_frames(&dir);
    let out = out_dir.join("dense.vpak");
    let cook = |kib: u64| {
        let mut args = vec![format!("ulimit -v {kib} && exec \"$0\" cook \"$@\""), env!("CARGO_BIN_EXE_vdbcook").to_string()];
        args.extend(frames.iter().map(|p| p.display().to_string()));
        args.extend(["-o".into(), out.display().to_string(), "-q".into(), "-j".into(), "1".into()]);
        std::process::Command::new("sh").arg("-c").args(&args).output().unwrap()
    };
    // Below its need: 16 MB above what starting takes (threads' stacks included), where
    // the brick pool alone is 28 MB.
    let o = cook(start_limit_kib() + (16 << 10));
    assert_one_line_error(&o, &["memory"]);
    let left: Vec<_> = std::fs::read_dir(&out_dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    // With room, the same cook succeeds: the failure was the memory.
    let o = cook(4 << 20);
    assert_eq!(o.status.code(), Some(0), "{}", stderr_of(&o));
    assert!(out.is_file());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A file-size limit (a full disk as a test can make one) is a one-line error
/// naming the output, exit 1, and nothing left in the output's directory.
#[test]
fn a_write_past_the_file_size_limit_is_one_line_and_leaves_nothing() {
    if !cfg!(unix) {
        return;
    }
    let dir = std::env::temp_dir().join(format!("vdbcook-fsize-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("fog.vpak");
    let input = root().join("fixtures").join("fog_none.vdb");
    let o = std::process::Command::new("sh").args(["-c", "ulimit -f 8 && exec \"$0\" cook \"$1\" --format f32 -o \"$2\" -q", env!("CARGO_BIN_EXE_vdbcook"), s(&input), s(&out)]).output().unwrap();
    assert_one_line_error(&o, &["fog.vpak", "too large"]);
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "nothing is left behind");
    std::fs::remove_dir_all(&dir).unwrap();
}
