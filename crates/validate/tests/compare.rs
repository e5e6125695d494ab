//! The comparison as a library: two tiny assets cooked in the test (an asset
//! and its lossless reference), compared without the executable. GPU tests
//! need an adapter (Mesa's lavapipe is enough); with CI=true a missing adapter
//! fails the test instead of skipping it.

use std::path::Path;
use vdbcook_cook::{CookOptions, Cooker, Format, NoProgress};
use vdbcook_validate::options::RmseBudget;
use vdbcook_validate::{compare_assets, CompareError, CompareOptions, Gate, Levels, Renderer, Size, Viewing, Views};
use vdbcook_vpak::Asset;

fn cook(format: Format, levels: u32) -> Asset {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/smoke_seq");
    let mut files: Vec<_> = std::fs::read_dir(&root).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    let mut c = Cooker::new(CookOptions { format, levels: vdbcook_vpak::LevelCount::new(levels).unwrap(), clustering: None, ..CookOptions::default() });
    for f in files.iter().take(2) {
        let v = vdbcook_vdb::open(f).unwrap();
        c.push(&v.read_grid(v.select(None).unwrap()).unwrap(), None).unwrap();
    }
    Asset::from_bytes(&vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)).unwrap()
}

fn renderer() -> Option<Renderer> {
    vdbcook_testkit::or_skip(Renderer::new(None), "GPU adapter")
}

fn options() -> CompareOptions {
    CompareOptions { viewing: Viewing { views: Views::new(2).unwrap(), size: Size::new(32, 24).unwrap(), ..Viewing::default() }, ..CompareOptions::default() }
}

#[test]
fn an_exact_asset_passes_any_gate_and_a_lossy_one_fails_a_strict_one() {
    let Some(r) = renderer() else { return };
    let reference = cook(Format::F32, 1);
    let strict = CompareOptions { gate: Gate { max_rmse: Some(RmseBudget::new(0.0).unwrap()), ..Gate::default() }, ..options() };
    let same = compare_assets(&reference, "f32", &reference, &strict, || Ok::<_, CompareError>(&r), &NoProgress).unwrap();
    assert!(same.passed(), "{:?}", same.gate_failure);
    assert_eq!(same.levels.len(), 1);
    assert_eq!(same.levels[0].shots.len(), 2 * 2, "2 frames x 2 views");
    assert_eq!(same.worst.unwrap().rmse, 0.0);
    assert_eq!(same.doc["images"].as_array().unwrap().len(), 4);

    let lossy = cook(Format::Bc4, 1);
    let c = compare_assets(&lossy, "bc4", &reference, &strict, || Ok::<_, CompareError>(&r), &NoProgress).unwrap();
    assert!(!c.passed());
    assert!(c.gate_failure.as_deref().unwrap().contains("over budget"), "{:?}", c.gate_failure);
    assert!(c.worst.unwrap().rmse > 0.0);
    // The document is built from the typed figures.
    assert_eq!(c.doc["worst"]["rmse"].as_f64(), c.levels[0].worst_shot.map(|s| s.metrics.rmse));
}

#[test]
fn every_level_is_compared_and_bad_options_are_usage_errors() {
    let Some(r) = renderer() else { return };
    let reference = cook(Format::F32, 2);
    let asset = cook(Format::Unorm8, 2);
    let every = CompareOptions { levels: Levels::Every, ..options() };
    let c = compare_assets(&asset, "unorm8", &reference, &every, || Ok::<_, CompareError>(&r), &NoProgress).unwrap();
    assert_eq!(c.levels.iter().map(|l| l.lod).collect::<Vec<_>>(), [0, 1]);
    assert_eq!(c.doc["levels"].as_array().unwrap().len(), 2);

    let frames = CompareOptions { frames: Some(vec![5]), ..options() };
    let e = compare_assets(&asset, "unorm8", &reference, &frames, || Ok::<_, CompareError>(&r), &NoProgress).unwrap_err();
    assert!(e.is_usage() && e.to_string().starts_with("--frames: frame 5 is out of range"), "{e}");
    let mut ext = options();
    ext.viewing.extinction = Some("nothing".into());
    let e = compare_assets(&asset, "unorm8", &reference, &ext, || Ok::<_, CompareError>(&r), &NoProgress).unwrap_err();
    assert!(e.is_usage() && e.to_string().starts_with("--extinction:"), "{e}");
    // A level neither asset stores is not the options' fault.
    let one = CompareOptions { levels: Levels::At(vdbcook_vpak::Level::new(3).unwrap()), ..options() };
    let e = compare_assets(&asset, "unorm8", &reference, &one, || Ok::<_, CompareError>(&r), &NoProgress).unwrap_err();
    assert!(!e.is_usage() && e.to_string().contains("level 3 is out of range"), "{e}");
}

#[test]
fn the_report_is_written_where_asked() {
    let Some(r) = renderer() else { return };
    let reference = cook(Format::F32, 1);
    let asset = cook(Format::F16, 1);
    let dir = std::env::temp_dir().join(format!("vdbcook-compare-report-{}", std::process::id()));
    let opts = CompareOptions { report: Some(dir.clone()), ..options() };
    let c = compare_assets(&asset, "f16", &reference, &opts, || Ok::<_, CompareError>(&r), &NoProgress).unwrap();
    assert!(c.text.contains("report.html"));
    for f in ["report.json", "report.html"] {
        assert!(dir.join(f).is_file(), "{f}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
