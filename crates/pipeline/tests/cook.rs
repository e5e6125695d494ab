//! The pipeline as a library: inputs expanded, frames fed from files to the
//! Cooker, the lossless reference, and typed errors (usage or not).

use std::path::{Path, PathBuf};
use vdbcook_cook::{Format, NoProgress};
use vdbcook_pipeline::options::CookSettings;
use vdbcook_pipeline::{cook_asset, cook_formats, cook_lossless_levels, inputs, selection_of, CookJob, GridSelection};

fn fixture(p: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures").join(p).display().to_string()
}

fn files() -> Vec<PathBuf> {
    inputs::expand(&[fixture("smoke_seq")], None).unwrap()
}

#[test]
fn a_fixture_cooks_with_its_reference_from_one_read() {
    let s = CookSettings { format: Format::Unorm8, ..CookSettings::default() };
    let cooked = cook_asset(CookJob { settings: &s, files: files(), inputs: &[fixture("smoke_seq")], base: None, reference: true, output: None, part: None }, &NoProgress).unwrap();
    assert_eq!(cooked.report.frames, 4);
    assert_eq!(cooked.report.format, "unorm8");
    assert_eq!(cooked.grid.as_deref(), Some("density"));
    let asset = &cooked.asset;
    let meta = asset.metadata().unwrap();
    assert_eq!(meta.frame_count, 4);
    // The reference is the lossless cook of the same frames: what cook_lossless_levels makes alone.
    let reference = cooked.reference.unwrap();
    let numbered = vdbcook_pipeline::FrameFile::numbered(files(), vdbcook_pipeline::inputs::frame_numbers(&files()), false);
    let alone = cook_lossless_levels(numbered, selection_of(&meta), vdbcook_vpak::LevelCount::ONE, None, &NoProgress).unwrap();
    assert_eq!(reference.bytes(), alone.bytes());
    assert_eq!(reference.metadata().unwrap().format_names(), "f32");
}

#[test]
fn formats_cook_from_one_read_in_the_order_given() {
    let s = CookSettings::default();
    let all = cook_formats(CookJob { settings: &s, files: files(), inputs: &[], base: None, reference: false, output: None, part: None }, &[Format::Bc7, Format::F32], &NoProgress).unwrap();
    assert_eq!(all.iter().map(|c| c.report.format.as_str()).collect::<Vec<_>>(), ["bc7", "f32"]);
    assert!(all.iter().all(|c| c.reference.is_none()));
    // Each is what a cook of that format alone writes.
    let f32 = CookSettings { format: Format::F32, ..CookSettings::default() };
    let alone = cook_asset(CookJob { settings: &f32, files: files(), inputs: &[], base: None, reference: false, output: None, part: None }, &NoProgress).unwrap();
    assert_eq!(alone.asset.bytes(), all[1].asset.bytes());
}

#[test]
fn errors_say_whose_fault_they_are() {
    let bad_grid = CookSettings { grid: Some("nothing".into()), ..CookSettings::default() };
    let e = cook_asset(CookJob { settings: &bad_grid, files: files(), inputs: &[], base: None, reference: false, output: None, part: None }, &NoProgress).err().unwrap();
    assert!(!e.is_usage(), "a grid missing from a frame is that frame's problem: {e}");
    assert!(e.to_string().contains("no grid named \"nothing\""), "{e}");
    let twice = CookSettings { grids: Some("density,density".into()), ..CookSettings::default() };
    let e = cook_asset(CookJob { settings: &twice, files: files(), inputs: &[], base: None, reference: false, output: None, part: None }, &NoProgress).err().unwrap();
    assert!(e.is_usage(), "{e}");
    assert!(inputs::expand(&["s_####.vdb".into()], None).unwrap_err().is_usage());
    let e = inputs::expand(&[fixture("no_such_dir/")], None).unwrap_err();
    assert!(!e.is_usage() && e.to_string().ends_with("no such file or directory"), "{e}");
    assert_eq!(GridSelection::from_flags(None, Some("all")), GridSelection::All);
}
