//! The `--auto` search and validating a file, as library calls. GPU tests
//! need an adapter (Mesa's lavapipe is enough); with CI=true a missing adapter
//! fails the test instead of skipping it.

use std::path::{Path, PathBuf};
use vdbcook_cook::NoProgress;
use vdbcook_pipeline::auto::search;
use vdbcook_pipeline::options::CookSettings;
use vdbcook_pipeline::{cook_asset, inputs, validate_file, CookJob, Sources};
use vdbcook_validate::options::RmseBudget;
use vdbcook_validate::{Gate, Renderer, Size, Viewing, Views};

/// An image RMSE of 0: only an exact asset passes.
fn lossless_gate() -> Gate {
    Gate { max_rmse: Some(RmseBudget::new(0.0).unwrap()), ..Gate::default() }
}

fn renderer() -> Option<Renderer> {
    vdbcook_testkit::or_skip(Renderer::new(None), "GPU adapter")
}

fn smoke() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/smoke_seq").display().to_string()
}

fn settings(gate: Gate) -> CookSettings {
    CookSettings { viewing: Viewing { views: Views::new(2).unwrap(), size: Size::new(32, 24).unwrap(), ..Viewing::default() }, gate, ..CookSettings::default() }
}

#[test]
fn the_search_picks_the_smallest_format_that_meets_the_gate() {
    let Some(r) = renderer() else { return };
    let files = inputs::expand(&[smoke()], None).unwrap();
    // An exact gate: f32 renders exactly (no clustering), so the search ends by f32 at the latest.
    let s = settings(lossless_gate());
    let found =
        search(CookJob { settings: &s, files: files.clone(), inputs: &[], base: None, reference: false, output: None, part: None }, &s.compare_options(None), "smoke", &r, &NoProgress).unwrap();
    let chosen = found.chosen.expect("f32 meets an exact gate");
    assert_eq!(found.candidates[chosen].worst().unwrap().rmse, 0.0);
    assert!(found.failure().is_none());
    let bytes: Vec<u64> = found.candidates.iter().map(|c| c.bytes).collect();
    assert!(bytes.windows(2).all(|w| w[0] <= w[1]), "smallest file first: {bytes:?}");
    assert!(found.candidates[..chosen].iter().all(|c| c.result() == "fail"));
    let format = found.candidates[chosen].format;
    assert_eq!(found.doc()["chosen"], format.name());
    // The chosen asset is byte for byte what a cook of that format writes.
    let f32 = CookSettings { format, ..s.clone() };
    let alone = cook_asset(CookJob { settings: &f32, files, inputs: &[], base: None, reference: false, output: None, part: None }, &NoProgress).unwrap();
    assert_eq!(alone.asset.bytes(), found.candidates[chosen].cooked.asset.bytes());
}

#[test]
fn a_gate_nothing_meets_names_the_best_reached() {
    let Some(r) = renderer() else { return };
    let files = inputs::expand(&[smoke()], None).unwrap();
    // With clustering into one brick, even f32 is lossy.
    let s = CookSettings { clusters: Some("1".parse().unwrap()), ..settings(lossless_gate()) };
    let found = search(CookJob { settings: &s, files, inputs: &[], base: None, reference: false, output: None, part: None }, &s.compare_options(None), "smoke", &r, &NoProgress).unwrap();
    assert!(found.chosen.is_none());
    assert!(found.best.is_some());
    let why = found.failure().unwrap();
    assert!(why.starts_with("--auto: no format meets the gate (rmse <= 0)") && why.contains("the best reached"), "{why}");
}

#[test]
fn a_written_asset_validates_against_its_recorded_sources() {
    let Some(r) = renderer() else { return };
    let dir = std::env::temp_dir().join(format!("vdbcook-pipeline-validate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out: PathBuf = dir.join("smoke.vpak");
    let s = settings(Gate::default());
    let cooked =
        cook_asset(CookJob { settings: &s, files: inputs::expand(&[smoke()], None).unwrap(), inputs: &[smoke()], base: None, reference: false, output: None, part: None }, &NoProgress).unwrap();
    vdbcook_vpak::write_atomic(&out, cooked.asset.bytes(), true).unwrap();
    let c = validate_file(&out, Sources::Recorded, &s.compare_options(None), || Ok::<_, std::convert::Infallible>(&r), &NoProgress).unwrap();
    assert_eq!(c.doc["sources"]["recorded"], true);
    assert_eq!(c.levels[0].shots.len(), 4 * 2);
    let e = validate_file(&dir.join("none.vpak"), Sources::Recorded, &s.compare_options(None), || Ok::<_, std::convert::Infallible>(&r), &NoProgress).err().unwrap();
    assert!(!e.is_usage());
    let _ = std::fs::remove_dir_all(&dir);
}
