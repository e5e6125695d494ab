//! Bad input and bad usage: one-line errors that name the file (and the grid),
//! documented exit codes, never a panic.

mod common;
use common::*;

fn stderr_of(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn scratch(name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("vdbcook-errors-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
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
    let p = scratch("notes.vdb", b"this is not a volume at all, just text\n");
    let out = vdbcook(&["inspect", p.to_str().unwrap()]);
    assert_one_line_error(&out, &["notes.vdb", "not an OpenVDB file"]);
}

#[test]
fn truncated_file_names_file_and_grid() {
    let full = std::fs::read(root().join("fixtures/fog_blosc.vdb")).unwrap();
    let p = scratch("cut.vdb", &full[..full.len() * 2 / 3]);
    let out = vdbcook(&["inspect", p.to_str().unwrap()]);
    assert_one_line_error(&out, &["cut.vdb", "grid \"density\"", "truncated"]);
}

#[test]
fn flipped_count_is_refused_without_a_huge_allocation() {
    // The file metadata count sits right after the 8+4+8+1+36-byte header.
    let mut bytes = std::fs::read(root().join("fixtures/fog_blosc.vdb")).unwrap();
    bytes[57 + 3] ^= 0x40;
    let p = scratch("flipped.vdb", &bytes);
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
