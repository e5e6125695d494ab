//! The C ABI: `include/vpak.h` declares exactly the functions the crate
//! exports, the C example compiles against it with every warning an error,
//! and bad input is an error code and a message, never a crash. (Cooked
//! assets of every format through the C example: `cli/tests/runtime.rs`.)

use std::collections::BTreeSet;
use std::ffi::{CStr, CString};
use vdbcook_testkit::workspace_root;

/// Names of the functions `src/lib.rs` exports (`#[no_mangle] … extern "C" fn NAME`).
fn exported() -> BTreeSet<String> {
    let src = std::fs::read_to_string(workspace_root().join("crates/vpak-c/src/lib.rs")).unwrap();
    let lines: Vec<&str> = src.lines().collect();
    let mut names = BTreeSet::new();
    for (i, l) in lines.iter().enumerate() {
        if l.trim() != "#[no_mangle]" {
            continue;
        }
        let f = lines.get(i + 1).copied().unwrap_or_default();
        let name = f.split("extern \"C\" fn ").nth(1).and_then(|r| r.split('(').next()).unwrap_or_else(|| panic!("#[no_mangle] on something other than an extern \"C\" fn: {f}"));
        names.insert(name.to_string());
    }
    names
}

/// Names of the functions the header declares (a `vpak_…(` after a return type, outside comments).
fn declared() -> BTreeSet<String> {
    let h = std::fs::read_to_string(workspace_root().join("include/vpak.h")).unwrap();
    let mut code = String::new();
    let mut rest = h.as_str();
    while let Some(start) = rest.find("/*") {
        code.push_str(&rest[..start]);
        rest = rest[start..].split_once("*/").map_or("", |(_, after)| after);
    }
    code.push_str(rest);
    let mut names = BTreeSet::new();
    for decl in code.split(';') {
        let decl = decl.trim();
        if decl.starts_with('#') || decl.starts_with("typedef") || !decl.contains('(') {
            continue;
        }
        let head = decl.split('(').next().unwrap_or_default();
        if let Some(name) = head.split(|c: char| c.is_whitespace() || c == '*').rfind(|w| !w.is_empty()) {
            names.insert(name.to_string());
        }
    }
    names
}

#[test]
fn the_header_declares_exactly_the_exports() {
    let (exported, declared) = (exported(), declared());
    assert!(exported.len() >= 12, "found only {exported:?}");
    assert_eq!(exported, declared, "include/vpak.h and crates/vpak-c/src/lib.rs disagree");
}

#[test]
fn the_header_codes_are_the_crates() {
    let h = std::fs::read_to_string(workspace_root().join("include/vpak.h")).unwrap();
    for (name, code) in [
        ("VPAK_OK", vpak::VPAK_OK),
        ("VPAK_ERROR_IO", vpak::VPAK_ERROR_IO),
        ("VPAK_ERROR_FORMAT", vpak::VPAK_ERROR_FORMAT),
        ("VPAK_ERROR_ARGUMENT", vpak::VPAK_ERROR_ARGUMENT),
        ("VPAK_ERROR_PANIC", vpak::VPAK_ERROR_PANIC),
    ] {
        assert!(h.contains(&format!("#define {name} {code}\n")), "{name} is not {code} in the header");
    }
    for k in 1..=12 {
        let name = vdbcook_vpak::kind::name(k).to_uppercase().replace(' ', "_").replace("BRICK_ATLAS", "ATLAS");
        assert!(h.contains(&format!("#define VPAK_KIND_{name} {k}\n")), "kind {k} ({name}) is not in the header");
    }
}

fn scratch(tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("vpak-c-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn the_c_example_compiles_and_reports_bad_files() {
    let dir = scratch("example");
    let exe = vdbcook_testkit::c_example("vpak_dump", &dir).unwrap();
    let run = |file: &std::path::Path| std::process::Command::new(&exe).arg(file).output().unwrap();
    let missing = run(&dir.join("missing.vpak"));
    let err = String::from_utf8_lossy(&missing.stderr);
    assert_eq!(missing.status.code(), Some(1));
    assert!(err.starts_with("vpak_dump: error: open: ") && err.contains("missing.vpak") && err.contains("No such file"), "{err}");
    let junk = dir.join("junk.vpak");
    std::fs::write(&junk, b"VPAK\r\n\x1a\n and then nothing of the sort, long enough for a header: 64 bytes..").unwrap();
    let out = run(&junk);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1));
    assert!(err.contains("truncated: the header says"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_calls_are_error_codes_with_messages() {
    use vpak::*;
    let dir = scratch("calls");
    let path = CString::new(dir.join("short.vpak").to_str().unwrap()).unwrap();
    std::fs::write(dir.join("short.vpak"), b"VPAK").unwrap();
    let mut r = std::ptr::dangling_mut::<VpakReader>();
    // SAFETY: valid pointers throughout; null readers are part of the contract.
    unsafe {
        assert_eq!(vpak_open(path.as_ptr(), &mut r), VPAK_ERROR_FORMAT);
        assert!(r.is_null());
        let msg = CStr::from_ptr(vpak_last_error()).to_str().unwrap();
        assert!(msg.contains("short.vpak: not a .vpak file"), "{msg}");
        assert_eq!(vpak_open(std::ptr::null(), &mut r), VPAK_ERROR_ARGUMENT);
        assert_eq!((vpak_frame_count(r), vpak_segment_count(r), vpak_bytes_read(r)), (0, 0, 0));
        assert_eq!(vpak_locate(r, 0, std::ptr::null_mut(), std::ptr::null_mut()), VPAK_ERROR_ARGUMENT);
        assert_eq!(CStr::from_ptr(vpak_last_error()).to_str().unwrap(), "the reader is null");
        assert_eq!(vpak_check(r), VPAK_ERROR_ARGUMENT);
        vpak_close(r);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
