//! `vdbcook cook --auto`: the format search against the quality gate, on the
//! GPU (Mesa's lavapipe in CI).

mod common;
use common::*;
use serde_json::Value;
use std::path::Path;

fn scratch(tag: &str) -> Scratch {
    scratch_dir("auto", tag)
}

/// `cook --auto` on the bundled sequence with two small views; exit code, JSON, stderr.
fn auto(out: &Path, gate: &[&str]) -> (Option<i32>, Value, String) {
    let mut args = vec!["cook", "--json", "--auto", "-o", s(out), "fixtures/smoke_seq", "--views", "2", "--size", "64x48"];
    args.extend(gate);
    let r = vdbcook(&args);
    let err = String::from_utf8_lossy(&r.stderr).into_owned();
    (r.status.code(), serde_json::from_slice(&r.stdout).unwrap_or_else(|e| panic!("{e}: {err}")), err)
}

/// The asset `cook --format FORMAT` writes with the same other settings.
fn direct(dir: &Path, format: &str, extra: &[&str]) -> Vec<u8> {
    let out = dir.join(format!("direct-{format}.vpak"));
    let mut args = vec!["cook", "-q", "--force", "--format", format, "-o", s(&out), "fixtures/smoke_seq"];
    args.extend(extra);
    ok(vdbcook(&args));
    std::fs::read(out).unwrap()
}

fn candidates(v: &Value) -> &Vec<Value> {
    v["auto"]["candidates"].as_array().unwrap()
}

#[test]
fn a_loose_gate_writes_the_smallest_format() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("loose");
    let out = dir.join("a.vpak");
    let (code, v, err) = auto(&out, &["--max-rmse", "1"]);
    assert_eq!(code, Some(0), "{err}");
    let c = candidates(&v);
    assert_eq!(c.len(), 5);
    let bytes: Vec<u64> = c.iter().map(|c| c["bytes"].as_u64().unwrap()).collect();
    assert!(bytes.windows(2).all(|w| w[0] <= w[1]), "smallest file first: {bytes:?}");
    let mut formats: Vec<&str> = c.iter().map(|c| c["format"].as_str().unwrap()).collect();
    let smallest = formats[0];
    assert_eq!(c[0]["result"], "pass");
    assert!(c[1..].iter().all(|c| c["result"] == "not tried" && c["psnr"].is_null() && c["rmse"].is_null() && c["flip"].is_null()), "{c:?}");
    assert_eq!(v["auto"]["chosen"], smallest);
    assert_eq!(v["auto"]["best"], smallest);
    assert_eq!(v["auto"]["gate"]["max_rmse"], 1.0);
    // What was written is what `--format` writes for that format, and the report is its.
    let written = std::fs::read(&out).unwrap();
    assert_eq!(written, direct(&dir, smallest, &[]), "the {smallest} asset");
    assert_eq!(written.len() as u64, bytes[0]);
    assert_eq!(v["file_bytes"].as_u64(), Some(bytes[0]));
    assert_eq!(v["format"], smallest);
    assert_eq!(v["validation"]["worst"]["rmse"], c[0]["rmse"]);
    // Each format once; each candidate's bytes are its own cook's.
    formats.sort();
    assert_eq!(formats, ["bc4", "bc7", "f16", "f32", "unorm8"]);
    assert_eq!(direct(&dir, c[1]["format"].as_str().unwrap(), &[]).len() as u64, bytes[1]);

    // The text: the cook summary, the validation and the table.
    let r = ok(vdbcook(&["cook", "--auto", "--force", "-o", s(&out), "fixtures/smoke_seq", "--views", "2", "--size", "64x48", "--max-rmse", "1"]));
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(text.contains(&format!("({smallest}, ")) && text.contains("vs lossless reference"), "{text}");
    assert!(text.contains("auto: gate rmse <= 1; tried 1 of 5 formats"), "{text}");
    assert_eq!(text.lines().filter(|l| l.ends_with("not tried")).count(), 4, "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_gate_only_f32_meets_writes_f32() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("f32");
    let out = dir.join("a.vpak");
    let (code, v, err) = auto(&out, &["--min-psnr", "200"]);
    assert_eq!(code, Some(0), "{err}");
    let c = candidates(&v);
    let last = c.last().unwrap();
    assert_eq!((last["format"].as_str(), last["result"].as_str()), (Some("f32"), Some("pass")), "{c:?}");
    assert_eq!(last["psnr"], "Infinity", "f32 renders exactly");
    assert_eq!(last["rmse"], 0.0);
    for lossy in &c[..4] {
        assert_eq!(lossy["result"], "fail", "{lossy}");
        assert!(lossy["psnr"].as_f64().unwrap() < 200.0, "{lossy}");
    }
    assert_eq!(v["auto"]["chosen"], "f32");
    assert_eq!(std::fs::read(&out).unwrap(), direct(&dir, "f32", &[]));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_gate_no_format_meets_exits_3_and_writes_nothing() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("strict");
    let out = dir.join("a.vpak");
    // Clustering is lossy in every format, f32 too: nothing reaches 200 dB.
    let (code, v, err) = auto(&out, &["--min-psnr", "200", "--clusters", "2"]);
    assert_eq!(code, Some(3), "{err}");
    assert!(!out.exists(), "nothing written");
    assert!(std::fs::read_dir(&dir).unwrap().next().is_none(), "no temporary file left either");
    let c = candidates(&v);
    assert!(c.iter().all(|c| c["result"] == "fail"), "{c:?}");
    assert_eq!(v["auto"]["chosen"], Value::Null);
    // The best reached is the highest worst-image PSNR, and the error says so with its figures.
    let best = c.iter().max_by(|a, b| a["psnr"].as_f64().unwrap().total_cmp(&b["psnr"].as_f64().unwrap())).unwrap();
    assert_eq!(v["auto"]["best"], best["format"]);
    let line = err.lines().find(|l| l.contains("quality gate failed")).unwrap_or_else(|| panic!("{err}"));
    let named = format!("the best reached: {} ({} bytes): worst image psnr {:.1} dB", best["format"].as_str().unwrap(), best["bytes"], best["psnr"].as_f64().unwrap());
    assert!(line.contains("no format meets the gate (psnr >= 200 dB)") && line.contains(&named) && line.contains("nothing written"), "{line}");
    // An existing output is left as it was.
    std::fs::write(&out, b"old").unwrap();
    let (code, _, err) = auto(&out, &["--min-psnr", "200", "--clusters", "2", "--force"]);
    assert_eq!(code, Some(3), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), b"old");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_auto_json_follows_the_documented_schema() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("schema");
    let doc = std::fs::read_to_string(root().join("docs/cook-json.md")).unwrap();
    let section = |name: &str| doc_section(&doc, name);
    let (code, v, err) = auto(&dir.join("a.vpak"), &["--max-flip", "1"]);
    assert_eq!(code, Some(0), "{err}");
    assert_documented(&v, &section("Top level"), "top level");
    assert_documented(&v["auto"], &section("Auto search"), "auto");
    for c in candidates(&v) {
        assert_documented(c, &section("Auto candidates"), "candidate");
    }
    let (code, v, err) = auto(&dir.join("b.vpak"), &["--max-flip", "0", "--clusters", "2"]);
    assert_eq!(code, Some(3), "{err}");
    let keys: Vec<&String> = v.as_object().unwrap().keys().collect();
    assert_eq!(keys, ["auto", "output"], "only the search when nothing is written");
    assert_documented(&v["auto"], &section("Auto search"), "auto");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn auto_needs_a_gate_and_no_format() {
    let dir = scratch("usage");
    let out = dir.join("a.vpak");
    let r = vdbcook(&["cook", "--auto", "-o", s(&out), "fixtures/smoke_seq"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("--auto needs a quality gate") && err.lines().count() == 1, "{err}");
    let r = vdbcook(&["cook", "--auto", "--format", "bc7", "--min-psnr", "40", "-o", s(&out), "fixtures/smoke_seq"]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    // The gate flags take --auto in place of --validate, and still need one of them.
    let r = vdbcook(&["cook", "--min-psnr", "40", "-o", s(&out), "fixtures/smoke_seq"]);
    assert_eq!(r.status.code(), Some(2), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(!out.exists());
    let help = String::from_utf8_lossy(&ok(vdbcook(&["cook", "--help"])).stdout).into_owned();
    assert!(help.contains("--auto") && help.contains("smallest file first"), "{help}");
    let _ = std::fs::remove_dir_all(&dir);
}
