//! Reader and writer agree: every fixture grid written as a .vdb (file
//! versions 224 and 221, zip or raw) reads back identical.  That OpenVDB reads
//! the same files is checked in cli/tests/voxels.rs.

use std::path::Path;
use vdbcook_grid::Grid;
use vdbcook_vdb::{write_vdb, VdbFile, WriteOptions};

fn sorted_tiles(g: &Grid) -> Vec<String> {
    let mut t: Vec<String> = g.tiles.iter().map(|t| format!("{t:?}")).collect();
    t.sort();
    t
}

#[test]
fn written_grids_read_back_identical() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
    let mut n = 0;
    for name in [
        "fog_blosc.vdb",
        "fog_half_blosc.vdb",
        "tiles.vdb",
        "tiles_root.vdb",
        "levelset_half.vdb",
        "inactive_modes_blosc.vdb",
        "map_AffineMap.vdb",
        "map_ScaleTranslateMap.vdb",
        "map_TranslationMap.vdb",
        "map_UnitaryMap.vdb",
        "map_ScaleMap.vdb",
        "empty.vdb",
    ] {
        let file = vdbcook_vdb::open(&root.join(name)).unwrap();
        let idx = file.select(None).unwrap();
        let grid = file.read_grid(idx).unwrap();
        for version in [224, 221] {
            for zip in [true, false] {
                let bytes = write_vdb(&grid, WriteOptions { version, zip }).unwrap();
                let back = VdbFile::parse(bytes).unwrap();
                assert_eq!(back.file_version, version);
                let g = back.read_grid(0).unwrap_or_else(|e| panic!("{name} v{version} zip={zip}: {e}"));
                assert_eq!((&g.name, g.class, g.background, g.transform), (&grid.name, grid.class, grid.background, grid.transform), "{name}");
                assert!(g.leaves == grid.leaves, "{name} v{version} zip={zip}: leaves differ");
                assert_eq!(sorted_tiles(&g), sorted_tiles(&grid), "{name} v{version} zip={zip}");
                n += 1;
            }
        }
    }
    assert_eq!(n, 48);
}

#[test]
fn unknown_versions_are_refused() {
    let file = vdbcook_vdb::open(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/empty.vdb")).unwrap();
    let grid = file.read_grid(0).unwrap();
    assert!(write_vdb(&grid, WriteOptions { version: 223, zip: true }).is_err());
}
