//! `vdbcook validate`, `render` and `cook --validate` end to end on the GPU
//! (Mesa's lavapipe in CI).

mod common;
use common::*;
use std::path::{Path, PathBuf};

fn scratch(tag: &str) -> Scratch {
    scratch_dir("validate", tag)
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
        for k in ["frame", "view", "rmse", "psnr", "max_error", "flip"] {
            assert!(img.get(k).is_some(), "{img}");
        }
        assert!(img["rmse"].as_f64().unwrap() < 1e-6, "{img}");
        assert_eq!(img["flip"], 0.0, "the same 8-bit pixels: {img}");
    }
    assert_eq!(v["worst_flip"]["flip"], 0.0);
    assert_eq!(v["flip_ppd"], 67.0);
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
fn the_flip_gate_exits_3_over_budget_and_0_within() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("flipgate");
    let bc4 = cook(&dir, "bc4");
    let (code, v, err) = validate_json(&bc4, &[]);
    assert_eq!(code, Some(0), "{err}");
    let flips: Vec<f64> = v["images"].as_array().unwrap().iter().map(|i| i["flip"].as_f64().unwrap()).collect();
    let worst = v["worst_flip"]["flip"].as_f64().unwrap();
    assert!(worst > 0.0 && worst < 1.0, "a lossy asset shows some FLIP error: {worst}");
    assert_eq!(worst, flips.iter().copied().fold(0.0, f64::max), "worst_flip is the largest image FLIP");
    assert_eq!(v["gate"]["max_flip"], serde_json::Value::Null);
    let (code, v, err) = validate_json(&bc4, &["--max-flip", &format!("{}", worst * 0.5)]);
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("quality gate failed") && err.contains("flip"), "{err}");
    assert_eq!(v["gate"]["max_flip"].as_f64(), Some(worst * 0.5));
    let (code, _, err) = validate_json(&bc4, &["--max-flip", &format!("{worst}")]);
    assert_eq!(code, Some(0), "the budget is inclusive: {err}");
    // The other gates alone still pass: only FLIP decides here.
    let (code, _, err) = validate_json(&bc4, &["--max-flip", "0", "--max-rmse", "1"]);
    assert_eq!(code, Some(3), "{err}");

    // cook --validate takes the same gate.
    let out = dir.join("again.vpak");
    let cook_gate =
        |budget: f64| vdbcook(&["cook", "-q", "--format", "bc4", "--force", "-o", s(&out), "fixtures/smoke_seq", "--validate", "--views", "2", "--size", "64x48", "--max-flip", &format!("{budget}")]);
    assert_eq!(cook_gate(worst * 0.5).status.code(), Some(3));
    let r = cook_gate(1.0);
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn max_flip_must_be_a_finite_budget() {
    // `--max-flip -0.1` reads as a number too; `-inf` needs `--max-flip=-inf`.
    let r = vdbcook(&["validate", "x.vpak", "--source", "fixtures/smoke_seq", "--max-flip", "-0.1"]);
    assert!(r.status.code() == Some(2) && String::from_utf8_lossy(&r.stderr).contains("must be a finite number >= 0, not -0.1"), "{}", String::from_utf8_lossy(&r.stderr));
    for bad in ["-0.1", "nan", "inf", "-inf", "lots"] {
        let bad = &format!("--max-flip={bad}");
        let r = vdbcook(&["validate", "x.vpak", "--source", "fixtures/smoke_seq", bad]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{bad}: {err}");
        assert!(err.contains("--max-flip"), "{bad}: {err}");
        let r = vdbcook(&["cook", "-o", "/nonexistent/x.vpak", "fixtures/tiles.vdb", "--validate", bad]);
        assert_eq!(r.status.code(), Some(2), "cook {bad}: {}", String::from_utf8_lossy(&r.stderr));
    }
    let r = vdbcook(&["cook", "-o", "/nonexistent/x.vpak", "fixtures/tiles.vdb", "--max-flip", "0.1"]);
    assert_eq!(r.status.code(), Some(2), "--max-flip needs --validate: {}", String::from_utf8_lossy(&r.stderr));
}

#[test]
fn rmse_and_psnr_gates_must_be_numbers_that_can_gate() {
    // A negative RMSE budget fails every image, a NaN one none: both are
    // usage errors, in validate and in cook --validate alike.
    for (flag, want) in [("--max-rmse=-1", "must be a number >= 0, not -1"), ("--max-rmse=nan", "must be a number >= 0, not NaN"), ("--min-psnr=nan", "must be a number, not NaN")] {
        for args in [vec!["validate", "x.vpak", "--source", "fixtures/smoke_seq", flag], vec!["cook", "-o", "/nonexistent/x.vpak", "fixtures/tiles.vdb", "--validate", flag]] {
            let r = vdbcook(&args);
            let err = String::from_utf8_lossy(&r.stderr);
            assert!(r.status.code() == Some(2) && err.contains(want), "{args:?}: {err}");
        }
    }
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
    assert_eq!(pngs, 12, "reference, asset, heat-map and FLIP map for the three worst views");
    assert!(html.contains("FLIP error map") && html.contains("worst FLIP"), "the FLIP map is next to the difference");
    // Figures as people read them: the worst RMSE with four significant digits.
    let wr = json["worst"]["rmse"].as_f64().unwrap();
    assert!(html.contains(&format!("<td>{wr:.4e}</td>")), "{html}");
    // The JSON's FLIP of a view is FLIP of the two PNGs the report shows.
    let worst = &json["worst"];
    let stem = rep.join(format!("frame{}_view{}", worst["frame"], worst["view"]));
    let pixels = |suffix: &str| {
        let mut dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(format!("{}_{suffix}.png", stem.display())).unwrap())).read_info().unwrap();
        let mut buf = vec![0; dec.output_buffer_size().unwrap()];
        let info = dec.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height, info.color_type), (32, 32, png::ColorType::Rgb));
        buf
    };
    let map = vdbcook_validate::flip::flip_srgb8(&pixels("reference"), &pixels("asset"), 32, 32, 67.0).unwrap();
    assert_eq!(Some(map.mean()), worst["flip"].as_f64());
    assert_eq!(pixels("flip"), map.magma_rgb8());

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
    assert!(v["validation"]["images"][0]["flip"].is_number() && v["validation"]["gate"]["max_flip"].is_null());
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
    let keys = |name: &str| doc_section(&doc, name);
    let top = keys("Top level");
    assert!(top.len() >= 12, "{top:?}");
    assert_documented(&v, &top, "top level");
    for img in v["images"].as_array().unwrap() {
        for k in keys("Image entries") {
            assert!(img.get(&k).is_some(), "{k} missing in {img}");
        }
    }
    for k in keys("Voxel figures") {
        assert!(v["voxel"].get(&k).is_some(), "{k} missing in {}", v["voxel"]);
    }
    for k in ["max_rmse", "min_psnr", "max_flip"] {
        assert!(v["gate"].get(k).is_some() && doc.contains(&format!("`{k}`")), "gate key {k}: {}", v["gate"]);
    }
    for k in ["frame", "view", "flip"] {
        assert!(v["worst_flip"].get(k).is_some(), "{k} missing in {}", v["worst_flip"]);
    }
    assert!(["texture", "shader"].contains(&v["bc_decode"].as_str().unwrap()));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The first Chromium on the PATH; none outside CI skips (in CI it fails).
fn chromium() -> Option<&'static str> {
    let found = ["chromium", "chromium-browser", "google-chrome"].into_iter().find(|c| std::process::Command::new(c).arg("--version").output().is_ok_and(|o| o.status.success()));
    if found.is_none() {
        assert!(!in_ci(), "CI=true but there is no chromium (scripts/test.sh installs it)");
        eprintln!("note: no chromium; skipping the HTML check");
    }
    found
}

/// Screenshots `html` into `shot` with headless Chromium: it loads without a script error.
fn screenshot(chromium: &str, html: &Path, shot: &Path, size: &str) {
    let o = std::process::Command::new(chromium)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--enable-logging=stderr", "--v=0", &format!("--window-size={size}")])
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", html.display()))
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    assert!(!log.contains("Uncaught"), "{log}");
    assert!(std::fs::read(shot).unwrap().starts_with(&[0x89, b'P', b'N', b'G']));
}

/// Loads a copy of `html` (in `dir`) in headless Chromium with a probe that logs
/// "probe images OK/ALL" (images decoded) and "probe rows" (the first word of
/// each caption of each `.row`, `|` between captions, `;` between rows); the log.
fn probe(chromium: &str, html: &Path, dir: &Path) -> String {
    let probe = "<script>window.addEventListener('load', function () {\
var imgs = Array.prototype.slice.call(document.images);\
var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;\
console.log('probe images ' + ok + '/' + imgs.length);\
var rows = Array.prototype.map.call(document.querySelectorAll('.row'), function (r) { return Array.prototype.map.call(r.querySelectorAll('figcaption'), function (c) { return c.textContent.replace(/[^A-Za-z ]/g, '').split(' ')[0]; }).join('|'); });\
console.log('probe rows ' + rows.join(';'));});</script>";
    let text = std::fs::read_to_string(html).unwrap();
    let probed = dir.join("probed.html");
    std::fs::write(&probed, text.replace("</body>", &format!("{probe}</body>"))).unwrap();
    let o = std::process::Command::new(chromium)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--v=0", "--virtual-time-budget=3000", "--dump-dom"])
        .arg(format!("file://{}", probed.display()))
        .output()
        .unwrap();
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn the_validation_report_shows_the_flip_map_in_headless_chromium() {
    if !gpu_available() {
        return;
    }
    let Some(chromium) = chromium() else { return };
    let dir = scratch("chromium");
    let asset = cook(&dir, "bc4");
    // Kept after the test: the screenshot is for people to look at.
    let keep = Path::new(env!("CARGO_TARGET_TMPDIR")).join("validate-html");
    let _ = std::fs::remove_dir_all(&keep);
    let r = vdbcook(&["validate", "-q", s(&asset), "--source", "fixtures/smoke_seq", "--frames", "3-3", "--views", "2", "--size", "128x128", "--report", s(&keep)]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    screenshot(chromium, &keep.join("report.html"), &keep.join("report.png"), "1200,900");
    // Every image decodes, and each view's row has its FLIP map after the difference.
    let log = probe(chromium, &keep.join("report.html"), &dir);
    assert!(log.contains("probe images 8/8"), "two views, four images each: {log}");
    assert!(log.contains("probe rows reference|asset|difference|FLIP;reference|asset|difference|FLIP"), "{log}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Decoded RGB pixels of a report PNG.
fn png_pixels(path: &Path) -> Vec<u8> {
    let mut dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))).read_info().unwrap();
    let mut buf = vec![0; dec.output_buffer_size().unwrap()];
    dec.next_frame(&mut buf).unwrap();
    buf
}

#[test]
fn every_lod_report_shows_the_levels_side_by_side() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("every-lod-report");
    let asset = dir.join("bc7.vpak");
    let r = vdbcook(&["cook", "-q", "--force", "--lods", "3", "--format", "bc7", "-o", s(&asset), "fixtures/smoke_seq"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    // Kept after the test: the screenshot is for people to look at.
    let rep = Path::new(env!("CARGO_TARGET_TMPDIR")).join("validate-levels-html");
    let _ = std::fs::remove_dir_all(&rep);
    let r = vdbcook(&["validate", s(&asset), "--source", "fixtures/smoke_seq", "--every-lod", "--views", "2", "--size", "64x64", "--report", s(&rep)]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(String::from_utf8_lossy(&r.stdout).contains(&format!("report   {}", rep.join("report.html").display())));

    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(rep.join("report.json")).unwrap()).unwrap();
    let levels = json["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 3, "{json}");
    for (k, l) in levels.iter().enumerate() {
        assert_eq!(l["level"], k as u64);
        for fig in [&l["worst"]["rmse"], &l["worst"]["psnr"], &l["worst"]["flip"], &l["worst_flip"]["flip"], &l["voxel"]["rmse"], &l["voxel"]["psnr"]] {
            assert!(fig.as_f64().is_some_and(f64::is_finite), "level {k}: {l}");
        }
        assert!(l["worst"]["rmse"].as_f64().unwrap() > 0.0, "bc7 is lossy at level {k}: {l}");
    }

    let html = std::fs::read_to_string(rep.join("report.html")).unwrap();
    assert!(html.contains("Levels side by side"), "{html}");
    // The summary table: a row per level with its voxel size and worst RMSE.
    for (k, l) in levels.iter().enumerate() {
        let row = format!("<tr><td>{k}</td><td>{}×</td>", 1 << k);
        assert!(html.contains(&row), "{row} missing");
        assert!(html.contains(&format!("<td>{:.4e}</td>", l["worst"]["rmse"].as_f64().unwrap())), "level {k}'s worst RMSE");
    }
    // A column per level, captioned with the level and its figures: level 0's worst view at every level.
    let (f, v) = (&json["worst"]["frame"], &json["worst"]["view"]);
    for (k, l) in levels.iter().enumerate() {
        assert!(html.contains(&format!("<b>level {k}</b> (voxels {}×)", 1 << k)), "level {k}'s column");
        let w = &l["worst"];
        assert!(html.contains(&format!("level's worst image: rmse {:.3e}, FLIP {:.4}", w["rmse"].as_f64().unwrap(), l["worst_flip"]["flip"].as_f64().unwrap())), "level {k}'s caption");
        for kind in ["reference", "asset", "error", "flip"] {
            assert!(rep.join(format!("level{k}_frame{f}_view{v}_{kind}.png")).is_file(), "level {k} {kind}");
        }
    }
    let files: Vec<String> = std::fs::read_dir(&rep).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(files.iter().filter(|n| n.starts_with("level") && n.ends_with(".png")).count(), 3 * 4, "{files:?}");
    assert_eq!(files.iter().filter(|n| n.starts_with("frame") && n.ends_with(".png")).count(), 3 * 4, "level 0's three worst views: {files:?}");
    assert_eq!(html.matches("data:image/png;base64,").count(), 3 * 4 + 3 * 4, "every PNG is inline");
    // Level 0's column is the worst view itself; a coarser level draws another image.
    let level_png = |k: usize, kind: &str| png_pixels(&rep.join(format!("level{k}_frame{f}_view{v}_{kind}.png")));
    assert_eq!(level_png(0, "asset"), png_pixels(&rep.join(format!("frame{f}_view{v}_asset.png"))));
    assert_ne!(level_png(0, "reference"), level_png(2, "reference"), "level 2's reference is the filtered source");

    if let Some(chromium) = chromium() {
        screenshot(chromium, &rep.join("report.html"), &rep.join("report.png"), "1400,2000");
        let log = probe(chromium, &rep.join("report.html"), &dir);
        assert!(log.contains("probe images 24/24"), "three worst views and three levels, four images each: {log}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cook_validate_with_levels_gates_every_level() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("cook-lods-gate");
    let out = dir.join("s.vpak");
    let cook = |extra: &[&str]| {
        let mut args = vec!["cook", "--force", "--lods", "3", "--format", "bc7", "-o", s(&out), "fixtures/smoke_seq", "--validate", "--views", "2", "--size", "64x64"];
        args.extend(extra);
        vdbcook(&args)
    };
    let r = cook(&["--json"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let levels = v["validation"]["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 3, "every level is checked: {v}");
    let rmse: Vec<f64> = levels.iter().map(|l| l["worst"]["rmse"].as_f64().unwrap()).collect();
    assert!(rmse.iter().all(|x| x.is_finite() && *x > 0.0), "{rmse:?}");
    assert_eq!(rmse[0], v["validation"]["worst"]["rmse"].as_f64().unwrap(), "the rest is level 0's");
    // A budget level 0 meets and a coarser level does not.
    let (coarse, worst) = rmse.iter().enumerate().skip(1).max_by(|a, b| a.1.total_cmp(b.1)).map(|(k, x)| (k, *x)).unwrap();
    assert!(worst > rmse[0], "this fixture's coarse levels render worse than level 0: {rmse:?}");
    let budget = format!("{}", (rmse[0] + worst) / 2.0);
    let r = vdbcook(&["validate", s(&out), "--source", "fixtures/smoke_seq", "--views", "2", "--size", "64x64", "--max-rmse", &budget]);
    assert_eq!(r.status.code(), Some(0), "level 0 alone is within the budget: {}", String::from_utf8_lossy(&r.stderr));
    let r = cook(&["--max-rmse", &budget]);
    let (text, err) = (String::from_utf8_lossy(&r.stdout), String::from_utf8_lossy(&r.stderr));
    assert_eq!(r.status.code(), Some(3), "{text}{err}");
    let failing: Vec<usize> = (1..3).filter(|&k| rmse[k] > (rmse[0] + worst) / 2.0).collect();
    assert!(failing.contains(&coarse));
    assert!(err.contains(&format!("quality gate failed: level {}: ", failing[0])), "{err}");
    assert!(text.contains("levels") && text.lines().filter(|l| l.trim_end().ends_with("FAIL")).count() == failing.len(), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn validate_without_source_uses_the_recorded_files() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("recorded");
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    for f in vdb_files(&root().join("fixtures/smoke_seq")) {
        std::fs::copy(&f, src.join(f.file_name().unwrap())).unwrap();
    }
    let asset = dir.join("a.vpak");
    ok(vdbcook(&["cook", "-q", "--format", "bc7", "-o", s(&asset), s(&src)]));
    let small = ["--views", "1", "--size", "32x32", "--json"];
    let run = |args: &[&str]| {
        let r = vdbcook(&[&["validate"], args, &small[..]].concat());
        (r.status.code(), serde_json::from_slice::<serde_json::Value>(&r.stdout).unwrap_or_default(), String::from_utf8_lossy(&r.stderr).into_owned())
    };
    // The recorded sources give the same figures as the sources named.
    let (code, recorded, err) = run(&[s(&asset)]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(recorded["sources"]["recorded"], true, "{recorded}");
    assert_eq!(recorded["sources"]["files"], 4);
    // The order a user types: --source SRC ASSET.
    let (code, named, err) = run(&["--source", s(&src), s(&asset)]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(named["sources"]["recorded"], false, "{named}");
    assert_eq!(recorded["worst"], named["worst"]);
    assert_eq!(recorded["voxel"], named["voxel"]);
    // A source changed since the cook (same size, other bytes; then another size): named, exit 1.
    let first = vdb_files(&src)[0].clone();
    let bytes = std::fs::read(&first).unwrap();
    let mut flipped = bytes.clone();
    *flipped.last_mut().unwrap() ^= 1;
    for changed in [flipped, [&bytes[..], b"x"].concat()] {
        std::fs::write(&first, &changed).unwrap();
        let (code, _, err) = run(&[s(&asset)]);
        assert_eq!(code, Some(1), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains(s(&first)) && err.contains("changed since the cook") && err.contains("--source"), "{err}");
    }
    std::fs::write(&first, &bytes).unwrap();
    // A recorded file that does not exist here (an asset cooked on another machine).
    let moved = dir.join("moved");
    std::fs::rename(&src, &moved).unwrap();
    let (code, _, err) = run(&[s(&asset)]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains(s(&first)) && err.contains("does not exist here") && err.contains("--source"), "{err}");
    let (code, _, err) = run(&["--source", s(&moved), s(&asset)]);
    assert_eq!(code, Some(0), "{err}");
    // No asset at all: a usage error.
    let (code, _, err) = run(&["--source", s(&moved)]);
    assert_eq!(code, Some(2), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn render_of_a_missing_asset_and_unpack_of_one_frame() {
    let dir = scratch("missing");
    let r = vdbcook(&["render", s(&dir.join("nothere.vpak")), "-o", s(&dir.join("x.png"))]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("nothere.vpak: no such file") && !err.contains("allow-missing"), "{err}");
    // One frame: no --frame needed; several: a usage error that says how many.
    let one = dir.join("one.vpak");
    ok(vdbcook(&["cook", "-q", "--format", "f16", "-o", s(&one), "fixtures/smoke_seq/smoke_0001.vdb"]));
    ok(vdbcook(&["unpack", s(&one), "-o", s(&dir.join("one.vdb"))]));
    assert!(dir.join("one.vdb").is_file());
    let four = dir.join("four.vpak");
    ok(vdbcook(&["cook", "-q", "--format", "f16", "-o", s(&four), "fixtures/smoke_seq"]));
    let r = vdbcook(&["unpack", s(&four), "-o", s(&dir.join("four.vdb"))]);
    assert_eq!(r.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&r.stderr).contains("4 frames"));
    assert!(!dir.join("four.vdb").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn frames_out_of_range_are_refused_before_the_sources_are_read() {
    let dir = scratch("frames-first");
    let asset = cook(&dir, "f16");
    // The sources do not exist: the frame is refused first, as a usage error.
    let missing = dir.join("no-such-sources");
    let r = vdbcook(&["validate", "-q", s(&asset), "--source", s(&missing), "--frames", "99"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("--frames: frame 99 is out of range") && !err.contains("no-such-sources"), "{err}");
    let r = vdbcook(&["validate", "-q", s(&asset), "--source", s(&missing), "--source-frame", "1234"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.code() == Some(1) && err.contains("no frame has source number 1234"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
