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

/// Three component grids with one topology: leaves on both sides of the
/// origin, inactive values, tiles at every level (active and inactive).
fn synthetic_vec3() -> [Grid; 3] {
    use vdbcook_grid::{Coord, GridClass, Leaf, LeafMask, Tile, Transform, LEAF_VOXELS};
    let mut rng = vdbcook_testkit::Rng::new(7);
    let origins = [Coord::new(-4096, 0, 8), Coord::new(-8, -8, -8), Coord::new(0, 0, 0), Coord::new(120, 64, 4088)];
    let masks: Vec<LeafMask> = origins
        .iter()
        .map(|_| {
            let mut m = LeafMask::default();
            for i in 0..LEAF_VOXELS {
                m.set(i, rng.below(3) == 0);
            }
            m
        })
        .collect();
    let transform = Transform::scale_translate(vdbcook_grid::MapType::ScaleTranslate, [0.5, 0.25, 2.0], [1.0, -2.0, 3.0]);
    std::array::from_fn(|c| {
        let leaves = origins
            .iter()
            .zip(&masks)
            .map(|(&origin, &mask)| {
                let mut values = [0.0f32; LEAF_VOXELS];
                for v in values.iter_mut() {
                    *v = (rng.below(2000) as f32 - 1000.0) / 7.0 + c as f32;
                }
                Leaf { origin, mask, values }
            })
            .collect();
        let tiles = vec![
            Tile { origin: Coord::new(8192, 0, 0), dim: 4096, value: 1.0 + c as f32, active: true },
            Tile { origin: Coord::new(-8192, 0, 0), dim: 4096, value: -3.0 * c as f32, active: false },
            Tile { origin: Coord::new(256, 0, 0), dim: 128, value: 0.25, active: true },
            Tile { origin: Coord::new(16, 0, 0), dim: 8, value: c as f32 * 0.5, active: true },
            Tile { origin: Coord::new(24, 8, 0), dim: 8, value: 9.0, active: false },
        ];
        Grid { name: format!("ignored{c}"), class: GridClass::Unknown, background: [0.5, -1.0, 2.0][c], transform, leaves, tiles }
    })
}

#[test]
fn several_float_and_vec3_grids_read_back_identical() {
    use vdbcook_grid::GridClass;
    use vdbcook_vdb::{ValueType, WriteGrid};
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
    let float_of = |name: &str| {
        let f = vdbcook_vdb::open(&root.join(name)).unwrap();
        f.read_grid(f.select(None).unwrap()).unwrap()
    };
    let (density, tiles) = (float_of("fog_blosc.vdb"), float_of("tiles_root.vdb"));
    let vel = synthetic_vec3();
    let [x, y, z] = &vel;
    let grids = [
        WriteGrid::Vec3 { name: "vel", class: GridClass::Staggered, components: [x, y, z] },
        WriteGrid::Float(&density),
        WriteGrid::Vec3 { name: "vel", class: GridClass::Unknown, components: [x, y, z] },
        WriteGrid::Float(&tiles),
    ];
    for version in [224, 221] {
        for zip in [true, false] {
            let bytes = vdbcook_vdb::write_vdb_grids(&grids, WriteOptions { version, zip }).unwrap();
            let file = VdbFile::parse(bytes).unwrap();
            let names: Vec<(&str, &str, &str)> = file.grids.iter().map(|g| (g.name.as_str(), g.unique_name.as_str(), g.value_type.name())).collect();
            assert_eq!(names, [("vel", "vel\u{1e}0", "vec3s"), ("density", "density\u{1e}0", "float"), ("vel", "vel\u{1e}1", "vec3s"), ("density", "density\u{1e}1", "float")], "v{version} zip={zip}");
            assert_eq!(file.grids[0].value_type, ValueType::Vec3(vdbcook_vdb::ScalarType::Float));
            assert!(file.grids[0].is_readable_vec3() && !file.grids[0].is_readable_scalar() && file.grids[0].is_readable());
            assert_eq!(file.grids[0].channel_names(), ["vel.x", "vel.y", "vel.z"]);
            assert_eq!((file.grids[0].class, file.grids[2].class), (GridClass::Staggered, GridClass::Unknown));
            for gi in [0, 2] {
                let back = file.read_vec3(gi).unwrap();
                for (c, (b, src)) in back.iter().zip(&vel).enumerate() {
                    assert_eq!(b.name, format!("vel{}", vdbcook_vdb::VEC3_SUFFIXES[c]));
                    assert_eq!((b.class, b.background, b.transform), (file.grids[gi].class, src.background, src.transform));
                    assert!(b.leaves == src.leaves, "v{version} zip={zip}: component {c} leaves differ");
                    assert_eq!(sorted_tiles(b), sorted_tiles(src), "v{version} zip={zip}: component {c}");
                }
                assert_eq!(file.read_channels(gi).unwrap(), back.to_vec());
                let e = file.read_grid(gi).unwrap_err().to_string();
                assert!(e.contains("vec3s") && e.contains("read_vec3"), "{e}");
            }
            assert!(file.read_grid(1).unwrap() == density);
            assert!(file.read_grid(3).unwrap() == tiles);
            assert_eq!(file.read_channels(1).unwrap(), vec![density.clone()]);
            assert!(file.read_vec3(1).is_err());
        }
    }
}

#[test]
fn vec3_components_must_share_one_topology() {
    use vdbcook_grid::GridClass;
    use vdbcook_vdb::WriteGrid;
    let vel = synthetic_vec3();
    let write = |c: &[Grid; 3]| vdbcook_vdb::write_vdb_grids(&[WriteGrid::Vec3 { name: "vel", class: GridClass::Staggered, components: [&c[0], &c[1], &c[2]] }], WriteOptions::default());
    assert!(write(&vel).is_ok());
    let mut mask = vel.clone();
    let on = mask[1].leaves[2].mask.is_on(5);
    mask[1].leaves[2].mask.set(5, !on);
    let mut leaves = vel.clone();
    leaves[2].leaves.pop();
    let mut transform = vel.clone();
    transform[2].transform.matrix[3][0] += 1.0;
    let mut active_tile = vel.clone();
    active_tile[1].tiles[0].active = false;
    let mut missing_tile = vel.clone();
    missing_tile[2].tiles.remove(0);
    let mut misaligned = vel.clone();
    misaligned[0].tiles[2].origin.x += 8;
    let mut over_leaf = vel.clone();
    for g in over_leaf.iter_mut() {
        g.tiles[3].origin = g.leaves[2].origin;
    }
    let mut over_root_child = vel.clone();
    for g in over_root_child.iter_mut() {
        g.tiles[1].origin = vdbcook_grid::Coord::new(-4096, 0, 0);
    }
    for (what, c) in [
        ("mask", mask),
        ("leaves", leaves),
        ("transform", transform),
        ("active tile", active_tile),
        ("missing tile", missing_tile),
        ("misaligned tile", misaligned),
        ("tile over a leaf", over_leaf),
        ("root tile over a child", over_root_child),
    ] {
        let e = write(&c).expect_err(what);
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput, "{what}: {e}");
        assert!(e.to_string().contains("vel"), "{what}: {e}");
    }
    // A component without an inactive tile the others have reads it as its background.
    let mut fewer = vel.clone();
    fewer[1].tiles.remove(4);
    let back = VdbFile::parse(write(&fewer).unwrap()).unwrap().read_vec3(0).unwrap();
    let t = back[1].tiles.iter().find(|t| t.dim == 8 && !t.active).unwrap();
    assert_eq!(t.value, fewer[1].background);
}
