//! vec3 grids against OpenVDB itself: every active value of every vec3 grid
//! the reader produces (as three component grids) equals OpenVDB's, on the
//! real samples and on files OpenVDB writes with every codec (none, zip,
//! blosc, active-mask with each inactive-value code, half floats, vec3d);
//! and files holding several float and vec3s grids, written by our writer,
//! are read back by OpenVDB (pyopenvdb `readAll` and the oracle) with the
//! same values, active voxels, classes, transforms and backgrounds.

mod common;
use common::*;
use serde_json::Value;
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use vdbcook_grid::{Coord, Grid, GridClass};
use vdbcook_vdb::{ScalarType, ValueType, VdbFile, WriteGrid, WriteOptions};

/// Ours equals OpenVDB's value: exactly for float and half data, after
/// rounding to f32 for double data (the reader's one conversion).
fn same(ours: f32, theirs: f64, double: bool) -> bool {
    if double {
        ours.to_bits() == (theirs as f32).to_bits()
    } else {
        f64::from(ours).to_bits() == theirs.to_bits()
    }
}

type TileKey<const N: usize> = ([i32; 3], [i32; 3], [u64; N]);

/// Checks `comps` (one grid per component, one topology) against grid `gi`
/// of an oracle dump and JSON; returns the number of values compared.
fn compare<const N: usize>(comps: &[Grid; N], gi: u32, dump: &Dump<N>, json: &Value, double: bool) -> Result<usize, String> {
    let name = &comps[0].name;
    let fail = |what: String| Err(format!("grid {name}: {what}"));
    if json["class"] != comps[0].class.vdb_name() {
        return fail(format!("class: ours {} openvdb {}", comps[0].class.vdb_name(), json["class"]));
    }
    let bg: Vec<f64> =
        if N == 1 { vec![json["background"].as_f64().unwrap_or(f64::NAN)] } else { json["background"].as_array().map(|a| a.iter().filter_map(Value::as_f64).collect()).unwrap_or_default() };
    if bg.len() != N || comps.iter().zip(&bg).any(|(g, &b)| !same(g.background, b, double)) {
        return fail(format!("background: ours {:?} openvdb {}", comps.iter().map(|g| g.background).collect::<Vec<_>>(), json["background"]));
    }
    for g in &comps[1..] {
        let topo = |g: &Grid| (g.leaves.iter().map(|l| (l.origin, l.mask)).collect::<Vec<_>>(), g.tiles.iter().map(|t| (t.origin, t.dim, t.active)).collect::<Vec<_>>());
        if topo(g) != topo(&comps[0]) || g.transform != comps[0].transform || g.class != comps[0].class {
            return fail(format!("component {} does not share the x component's topology", g.name));
        }
    }
    let mut n = 0usize;
    for (_, c, v) in dump.voxels.iter().filter(|r| r.0 == gi) {
        for (g, &theirs) in comps.iter().zip(v) {
            let (val, on) = g.probe(Coord::new(c[0], c[1], c[2]));
            if !on || !same(val, theirs, double) {
                return fail(format!("{}: voxel {c:?}: ours {val} (active {on}), openvdb {theirs}", g.name));
            }
        }
        n += 1;
    }
    let leaf_active: usize = comps[0].leaves.iter().map(|l| l.mask.count_on() as usize).sum();
    if leaf_active != n {
        return fail(format!("{leaf_active} active leaf voxels, openvdb has {n}"));
    }
    let bits = |v: f64| if double { f64::from(v as f32).to_bits() } else { v.to_bits() };
    let theirs: HashSet<TileKey<N>> = dump.tiles.iter().filter(|t| t.0 == gi).map(|t| (t.1, t.2, t.3.map(bits))).collect();
    let ours: HashSet<TileKey<N>> = (0..comps[0].tiles.len())
        .filter(|&i| comps[0].tiles[i].active)
        .map(|i| (comps[0].tiles[i].bbox().min.to_array(), comps[0].tiles[i].bbox().max.to_array(), std::array::from_fn(|c| f64::from(comps[c].tiles[i].value).to_bits())))
        .collect();
    if ours != theirs {
        return fail(format!("active tiles differ ({} ours, {} openvdb)", ours.len(), theirs.len()));
    }
    let st = comps[0].stats();
    for (k, v) in [("active_voxels", st.active_voxels), ("leaf_count", st.leaf_count), ("active_tiles", st.active_tiles)] {
        if json[k] != v {
            return fail(format!("{k}: ours {v} openvdb {}", json[k]));
        }
    }
    Ok(n * N + ours.len())
}

/// Every vec3 grid of `file` read by us against OpenVDB; returns the values compared.
fn check_vec3_file(file: &Path, dump_path: &Path) -> Result<usize, String> {
    let json = run_oracle(file, &["--skip-unreadable", "--vec3-voxels", dump_path.to_str().unwrap()])?;
    let dump = read_dump::<3>(dump_path);
    let vdb = vdbcook_vdb::open(file).map_err(|e| e.to_string())?;
    let mut checked = 0;
    for (gi, info) in vdb.grids.iter().enumerate() {
        let ValueType::Vec3(st) = info.value_type else { continue };
        if !info.is_readable_vec3() || info.is_readable_scalar() {
            return Err(format!("grid {}: not readable as vec3: {:?}", info.name, info.unsupported));
        }
        let comps = vdb.read_vec3(gi).map_err(|e| e.to_string())?;
        let names: Vec<&str> = comps.iter().map(|g| g.name.as_str()).collect();
        if names != info.channel_names() || vdb.read_channels(gi).map_err(|e| e.to_string())? != comps.to_vec() {
            return Err(format!("grid {}: channel names {names:?}", info.name));
        }
        if vdb.read_grid(gi).is_ok() {
            return Err(format!("grid {}: read_grid accepted a vec3 grid", info.name));
        }
        let jg = &json["grids"][gi];
        if jg["value_type"] != info.value_type.name() {
            return Err(format!("grid {}: value type ours {} openvdb {}", info.name, info.value_type.name(), jg["value_type"]));
        }
        checked += compare(&comps, gi as u32, &dump, jg, st == ScalarType::Double)?;
    }
    Ok(checked)
}

/// Files OpenVDB writes with every codec (cli/tests/vec3_sources.py).
fn generate(dir: &Path) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let out = Command::new("/usr/bin/python3").arg(root().join("cli/tests/vec3_sources.py")).arg(dir).output().expect("run vec3_sources.py");
    assert!(out.status.success(), "vec3_sources.py: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap().lines().map(|l| dir.join(l)).collect()
}

fn has_vec3(file: &Path) -> bool {
    vdbcook_vdb::open(file).is_ok_and(|f| f.grids.iter().any(|g| matches!(g.value_type, ValueType::Vec3(_))))
}

#[test]
fn every_vec3_value_matches_openvdb() {
    if !oracle_available() {
        return;
    }
    let scratch = std::env::temp_dir().join(format!("vdbcook-vec3-{}", std::process::id()));
    let generated = generate(&scratch.join("src"));
    assert_eq!(generated.len(), 12, "{generated:?}");
    let mut files = generated.clone();
    files.push(root().join("fixtures/multi_grid.vdb"));
    let shared = shared_samples();
    if let Some(s) = &shared {
        files.extend(vdb_files(s).into_iter().filter(|f| has_vec3(f)));
    }
    let jobs: Vec<(usize, &PathBuf)> = files.iter().enumerate().collect();
    let results = par_map(&jobs, |(i, f)| check_vec3_file(f, &scratch.join(format!("{i}.bin"))));
    let _ = std::fs::remove_dir_all(&scratch);
    let mut total = 0;
    let mut failures = Vec::new();
    let mut checked = Vec::new();
    for (f, r) in files.iter().zip(results) {
        match r {
            Ok(0) => failures.push(format!("{}: no vec3 value compared", f.display())),
            Ok(n) => {
                total += n;
                checked.push(f.clone());
            }
            Err(e) => failures.push(format!("{}: {e}", f.display())),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    if let Some(s) = &shared {
        for name in [
            "zeno/vel_VDB_bound_v02.vdb",
            "waveletturbulence/fluid_data_0150.vdb",
            "waveletturbulence/fluid_data_0153.vdb",
            "plasmadxr/fluid_data_0001.vdb",
            "c42/fluid_data_0001.vdb",
            "csc415-blender/fluid_data_0001.vdb",
            "csc415-blender/fluid_data_0002.vdb",
        ] {
            assert!(checked.contains(&s.join(name)), "{name} was not compared");
        }
        assert!(total > 700_000, "only {total} values compared");
    }
    assert!(total > 100_000, "only {total} values compared");
}

fn grid_of(file: &str) -> Grid {
    let f = vdbcook_vdb::open(&root().join("fixtures").join(file)).unwrap();
    f.read_grid(f.select(None).unwrap()).unwrap()
}

/// The written grids: what OpenVDB must read back.
enum Expect {
    Float(Grid),
    Vec3(&'static str, GridClass, Box<[Grid; 3]>),
}

/// Our writer's multi-grid files (float and vec3s grids, every class,
/// duplicate names, tiles at every level, inactive values) read by OpenVDB.
#[test]
fn openvdb_reads_several_float_and_vec3_grids_we_write() {
    if !oracle_available() {
        return;
    }
    let scratch = std::env::temp_dir().join(format!("vdbcook-vec3-written-{}", std::process::id()));
    let generated = generate(&scratch.join("src"));
    let vec3_of = |name: &str| -> [Grid; 3] {
        let p = generated.iter().find(|p| p.ends_with(name)).unwrap();
        let f = vdbcook_vdb::open(p).unwrap();
        f.read_vec3(0).unwrap()
    };
    let vel = vec3_of("vec3s_blosc.vdb");
    let mut vel_d = vec3_of("vec3d_zip.vdb");
    for g in vel_d.iter_mut() {
        g.transform = grid_of("map_AffineMap.vdb").transform;
    }
    // Every class, and two grids named "vel" (told apart as OpenVDB does).
    let expected = [
        Expect::Float(grid_of("fog_blosc.vdb")),
        Expect::Vec3("vel", GridClass::Staggered, Box::new(vel)),
        Expect::Float(grid_of("levelset_half.vdb")),
        Expect::Vec3("vel", GridClass::Unknown, Box::new(vel_d)),
        Expect::Float(grid_of("tiles_root.vdb")),
    ];
    let info = |e: &Expect| -> (String, GridClass) {
        match e {
            Expect::Float(g) => (g.name.clone(), g.class),
            Expect::Vec3(name, class, _) => (name.to_string(), *class),
        }
    };
    assert_eq!(expected.iter().map(|e| info(e).1.vdb_name()).collect::<HashSet<_>>().len(), 4, "every class");
    let grids: Vec<WriteGrid<'_>> = expected
        .iter()
        .map(|e| match e {
            Expect::Float(g) => WriteGrid::Float(g),
            Expect::Vec3(name, class, c) => WriteGrid::Vec3 { name, class: *class, components: [&c[0], &c[1], &c[2]] },
        })
        .collect();
    let mut jobs = Vec::new();
    for (version, zip) in [(224, true), (224, false), (221, true)] {
        let bytes = vdbcook_vdb::write_vdb_grids(&grids, WriteOptions { version, zip }).unwrap();
        // Our reader reads it back identically.
        let back = VdbFile::parse(bytes.clone()).unwrap();
        assert_eq!(back.grids.len(), expected.len());
        for (i, e) in expected.iter().enumerate() {
            let (name, class) = info(e);
            assert_eq!(back.grids[i].name, name);
            assert_eq!(back.grids[i].class, class);
            match e {
                Expect::Float(g) => assert!(back.read_grid(i).unwrap() == *g, "{name}: float grid differs"),
                Expect::Vec3(_, _, c) => {
                    let r = back.read_vec3(i).unwrap();
                    for (a, b) in r.iter().zip(c.iter()) {
                        assert!(a.leaves == b.leaves && a.tiles == b.tiles && a.background == b.background && a.transform == b.transform, "{name}: component {} differs", a.name);
                    }
                }
            }
        }
        let path = scratch.join(format!("multi-{version}-{zip}.vdb"));
        std::fs::write(&path, bytes).unwrap();
        jobs.push(path);
    }
    let results = par_map(&jobs, |path| -> Result<(), String> {
        let (d1, d3) = (path.with_extension("1.bin"), path.with_extension("3.bin"));
        let json = run_oracle(path, &["--voxels", d1.to_str().unwrap(), "--vec3-voxels", d3.to_str().unwrap()])?;
        let (dump1, dump3) = (read_dump::<1>(&d1), read_dump::<3>(&d3));
        let jgrids = json["grids"].as_array().ok_or("no grids")?;
        if jgrids.len() != expected.len() {
            return Err(format!("openvdb reads {} grids", jgrids.len()));
        }
        // pyopenvdb.readAll: every grid, its type, class, active voxels and transform.
        let script = "import sys, json, pyopenvdb as vdb\n\
            grids, _ = vdb.readAll(sys.argv[1])\n\
            print(json.dumps([[g.name, g.valueTypeName, g.gridClass, g.activeVoxelCount(), list(g.transform.indexToWorld((1.0, -2.0, 3.0)))] for g in grids]))";
        let out = Command::new("/usr/bin/python3").args(["-c", script]).arg(path).output().expect("run python");
        if !out.status.success() {
            return Err(format!("readAll: {}", String::from_utf8_lossy(&out.stderr)));
        }
        let all: Value = serde_json::from_slice(&out.stdout).map_err(|e| e.to_string())?;
        // readAll lists grids by unique name ("vel\x1e0" before "vel\x1e1"), not in file order.
        let mut order: Vec<usize> = (0..expected.len()).collect();
        order.sort_by_key(|&i| info(&expected[i]).0);
        let all: Vec<&Value> = (0..expected.len()).map(|i| &all[order.iter().position(|&o| o == i).unwrap_or(usize::MAX)]).collect();
        for (i, (e, jg)) in expected.iter().zip(jgrids).enumerate() {
            let (name, class) = info(e);
            let (first, n) = match e {
                Expect::Float(g) => (g, 1),
                Expect::Vec3(_, _, c) => (&c[0], 3),
            };
            let ra = all[i];
            let world = first.transform.index_to_world([1.0, -2.0, 3.0]);
            let world_ok = (0..3).all(|k| ra[4][k].as_f64().is_some_and(|w| (w - world[k]).abs() <= 1e-9 * w.abs().max(1.0)));
            let st = first.stats();
            let want_type = if n == 1 { "float" } else { "vec3s" };
            if ra[0] != name.as_str() || ra[1] != want_type || ra[2] != class.vdb_name() || ra[3] != st.active_voxels || !world_ok {
                return Err(format!("grid {i} ({name}): readAll gives {ra}"));
            }
            if jg["map_type"] != first.transform.map_type.vdb_name() {
                return Err(format!("grid {name}: map type {}", jg["map_type"]));
            }
            match e {
                Expect::Float(g) => {
                    compare(std::slice::from_ref(g).try_into().unwrap(), i as u32, &dump1, jg, false)?;
                }
                Expect::Vec3(_, _, c) => {
                    let mut c = c.clone();
                    for g in c.iter_mut() {
                        g.class = class;
                    }
                    compare(&c, i as u32, &dump3, jg, false)?;
                }
            }
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&scratch);
    let failures: Vec<String> = jobs.iter().zip(results).filter_map(|(p, r)| r.err().map(|e| format!("{}: {e}", p.display()))).collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
