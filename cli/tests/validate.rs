//! `vdbcook validate`, `render` and `cook --validate` end to end on the GPU
//! (Mesa's lavapipe in CI).

mod common;
use common::*;
use std::path::{Path, PathBuf};

fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vdbcook-validate-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn cook(dir: &Path, format: &str) -> PathBuf {
    let out = dir.join(format!("{format}.vpak"));
    let r = vdbcook(&["cook", "-q", "--force", "--format", format, "-o", s(&out), "fixtures/smoke_seq"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    out
}

fn validate_json(asset: &Path, extra: &[&str]) -> (Option<i32>, serde_json::Value, String) {
    let mut args = vec!["validate", s(asset), "--source", "fixtures/smoke_seq", "--views", "2", "--size", "64x48", "--json"];
    args.extend(extra);
    let r = vdbcook(&args);
    let v = serde_json::from_slice(&r.stdout).unwrap_or(serde_json::Value::Null);
    (r.status.code(), v, String::from_utf8_lossy(&r.stderr).into_owned())
}

#[test]
fn f32_is_exact_and_the_json_lists_every_image() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("f32");
    let (code, v, err) = validate_json(&cook(&dir, "f32"), &[]);
    assert_eq!(code, Some(0), "{err}");
    let images = v["images"].as_array().unwrap();
    assert_eq!(images.len(), 4 * 2);
    for img in images {
        for k in ["frame", "view", "rmse", "psnr", "max_error"] {
            assert!(img.get(k).is_some(), "{img}");
        }
        assert!(img["rmse"].as_f64().unwrap() < 1e-6, "{img}");
    }
    assert_eq!(v["voxel"]["rmse"], 0.0);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_quality_gate_exits_3() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("gate");
    let bc7 = cook(&dir, "bc7");
    let (code, v, _) = validate_json(&bc7, &[]);
    assert_eq!(code, Some(0));
    let worst = v["worst"]["rmse"].as_f64().unwrap();
    assert!(worst > 0.0);
    let (code, _, err) = validate_json(&bc7, &["--max-rmse", &format!("{}", worst * 0.5)]);
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("quality gate failed"), "{err}");
    let (code, _, _) = validate_json(&bc7, &["--max-rmse", &format!("{}", worst * 2.0)]);
    assert_eq!(code, Some(0));
    let (code, _, _) = validate_json(&bc7, &["--min-psnr", "200"]);
    assert_eq!(code, Some(3));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bc_decoded_in_the_shader_reports_what_the_texture_unit_does() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("bc-decode");
    let bc7 = cook(&dir, "bc7");
    let (code, shader, err) = validate_json(&bc7, &["--bc-decode", "shader"]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(shader["bc_decode"], "shader");
    let (code, texture, err) = validate_json(&bc7, &["--bc-decode", "texture"]);
    if err.contains("TEXTURE_COMPRESSION_BC") {
        // An adapter without BC 3D textures: a clear error, and nothing to compare.
        assert_eq!(code, Some(1), "{err}");
    } else {
        assert_eq!(code, Some(0), "{err}");
        assert_eq!(texture["bc_decode"], "texture");
        for (a, b) in texture["images"].as_array().unwrap().iter().zip(shader["images"].as_array().unwrap()) {
            let (a, b) = (a["rmse"].as_f64().unwrap(), b["rmse"].as_f64().unwrap());
            assert!(a > 0.0 && (a - b).abs() <= 1e-6 * a.max(1e-3), "texture {a} vs shader {b}");
        }
    }
    let (code, _, err) = validate_json(&bc7, &["--bc-decode", "cpu"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("[possible values: auto, texture, shader]"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn report_and_render_write_their_files() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("report");
    let asset = cook(&dir, "unorm8");
    let rep = dir.join("rep");
    let r = vdbcook(&["validate", "-q", s(&asset), "--source", "fixtures/smoke_seq", "--views", "2", "--size", "32x32", "--report", s(&rep)]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let html = std::fs::read_to_string(rep.join("report.html")).unwrap();
    assert!(html.contains("<table") && html.contains("data:image/png;base64,") && html.contains("<svg"));
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(rep.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["images"].as_array().unwrap().len(), 8);
    let pngs = std::fs::read_dir(&rep).unwrap().flatten().filter(|e| e.file_name().to_string_lossy().ends_with(".png")).count();
    assert_eq!(pngs, 9, "reference, asset and heat-map for the three worst views");

    let png = dir.join("thumb.png");
    let r = vdbcook(&["render", "fixtures/fog_blosc.vdb", "-o", s(&png), "--size", "40x30"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(std::fs::read(&png).unwrap().starts_with(&[0x89, b'P', b'N', b'G']));
    assert_eq!(vdbcook(&["render", "fixtures/fog_blosc.vdb", "-o", s(&png)]).status.code(), Some(1), "no --force");
    let r = vdbcook(&["render", s(&asset), "--frame", "3", "-o", s(&png), "--force", "--size", "16x16"]);
    assert!(r.status.success());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_adapter_is_a_clear_error() {
    let dir = scratch("adapter");
    let asset = cook(&dir, "f16");
    let r = vdbcook(&["validate", s(&asset), "--source", "fixtures/smoke_seq", "--adapter", "no-such-gpu-anywhere"]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("no GPU adapter") && err.contains("mesa-vulkan-drivers") && err.lines().count() == 1, "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cook_validate_adds_the_validation() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("cookval");
    let out = dir.join("t.vpak");
    let r = vdbcook(&["cook", "--json", "--format", "f16", "--validate", "-o", s(&out), "fixtures/tiles.vdb"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(v["validation"]["images"].as_array().unwrap().len(), 8);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_json_follows_the_documented_schema() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("schema");
    let (code, v, err) = validate_json(&cook(&dir, "unorm8"), &[]);
    assert_eq!(code, Some(0), "{err}");
    let doc = std::fs::read_to_string(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/validate-json.md")).unwrap();
    let sections = documented_keys(&doc);
    let keys = |name: &str| sections.iter().find(|(h, _)| h.starts_with(name)).map(|(_, k)| k.clone()).unwrap_or_else(|| panic!("no section {name}"));
    let top = keys("Top level");
    assert!(top.len() >= 12, "{top:?}");
    for k in &top {
        assert!(v.get(k).is_some(), "documented key {k} is missing: {v}");
    }
    for k in v.as_object().unwrap().keys() {
        assert!(top.contains(k), "key {k} is not documented");
    }
    for img in v["images"].as_array().unwrap() {
        for k in keys("Image entries") {
            assert!(img.get(&k).is_some(), "{k} missing in {img}");
        }
    }
    for k in keys("Voxel figures") {
        assert!(v["voxel"].get(&k).is_some(), "{k} missing in {}", v["voxel"]);
    }
    assert!(["texture", "shader"].contains(&v["bc_decode"].as_str().unwrap()));
    let _ = std::fs::remove_dir_all(&dir);
}
