//! Every active value the reader produces, compared one by one with the
//! values OpenVDB itself decodes from the same file.

mod common;
use common::*;
use std::collections::HashSet;
use std::path::Path;
use vdbcook_grid::Coord;

struct Dump {
    voxels: Vec<(u32, [i32; 3], f64)>,
    tiles: Vec<(u32, [i32; 3], [i32; 3], f64)>,
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().unwrap())
}
fn i32_at(b: &[u8], o: usize) -> i32 {
    i32::from_le_bytes(b[o..o + 4].try_into().unwrap())
}
fn f64_at(b: &[u8], o: usize) -> f64 {
    f64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}

/// Parses the oracle's binary dump (layout documented in scripts/openvdb_oracle.py).
fn read_dump(path: &Path) -> Dump {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[..8], b"VDBORC01");
    let nv = u64::from_le_bytes(b[16..24].try_into().unwrap()) as usize;
    let nt = u64::from_le_bytes(b[24..32].try_into().unwrap()) as usize;
    let mut o = 32;
    let mut voxels = Vec::with_capacity(nv);
    for _ in 0..nv {
        voxels.push((u32_at(&b, o), [i32_at(&b, o + 4), i32_at(&b, o + 8), i32_at(&b, o + 12)], f64_at(&b, o + 16)));
        o += 24;
    }
    let mut tiles = Vec::with_capacity(nt);
    for _ in 0..nt {
        let min = [i32_at(&b, o + 4), i32_at(&b, o + 8), i32_at(&b, o + 12)];
        let max = [i32_at(&b, o + 16), i32_at(&b, o + 20), i32_at(&b, o + 24)];
        tiles.push((u32_at(&b, o), min, max, f64_at(&b, o + 28)));
        o += 36;
    }
    assert_eq!(o, b.len());
    Dump { voxels, tiles }
}

fn check_file(file: &Path, dump_path: &Path) -> Result<usize, String> {
    if oracle(file, Some(dump_path)).is_none() {
        return Ok(0);
    }
    let dump = read_dump(dump_path);
    let vdb = vdbcook_vdb::open(file).map_err(|e| e.to_string())?;
    let mut checked = 0;
    for (gi, info) in vdb.grids.iter().enumerate() {
        if !info.is_readable_scalar() {
            continue;
        }
        let grid = vdb.read_grid(gi).map_err(|e| e.to_string())?;
        let double = info.value_type.name() == "double";
        let same = |ours: f32, theirs: f64| if double { ours == theirs as f32 } else { f64::from(ours) == theirs };
        let gi = gi as u32;
        let mut n = 0u64;
        for &(_, c, v) in dump.voxels.iter().filter(|r| r.0 == gi) {
            let (val, on) = grid.probe(Coord::new(c[0], c[1], c[2]));
            if !on || !same(val, v) {
                return Err(format!("grid {}: voxel {c:?}: ours {val} (active {on}), openvdb {v}", info.name));
            }
            n += 1;
        }
        let leaf_active: u64 = grid.leaves.iter().map(|l| u64::from(l.mask.count_on())).sum();
        if leaf_active != n {
            return Err(format!("grid {}: {leaf_active} active leaf voxels, openvdb has {n}", info.name));
        }
        let theirs: HashSet<([i32; 3], [i32; 3], u64)> = dump.tiles.iter().filter(|t| t.0 == gi).map(|t| (t.1, t.2, if double { f64::from(t.3 as f32).to_bits() } else { t.3.to_bits() })).collect();
        let ours: HashSet<([i32; 3], [i32; 3], u64)> = grid.tiles.iter().filter(|t| t.active).map(|t| (t.bbox().min.to_array(), t.bbox().max.to_array(), f64::from(t.value).to_bits())).collect();
        if ours != theirs {
            return Err(format!("grid {}: active tiles differ ({} ours, {} openvdb)", info.name, ours.len(), theirs.len()));
        }
        checked += n as usize + ours.len();
    }
    Ok(checked)
}

#[test]
fn every_active_value_matches_openvdb() {
    if !oracle_available() {
        return;
    }
    let mut files = vdb_files(&root().join("fixtures"));
    if let Some(s) = shared_samples() {
        files.extend(vdb_files(&s));
    }
    let scratch = std::env::temp_dir().join(format!("vdbcook-voxels-{}", std::process::id()));
    std::fs::create_dir_all(&scratch).unwrap();
    // Several samples share a file name: number the dumps.
    let jobs: Vec<(usize, &std::path::PathBuf)> = files.iter().enumerate().collect();
    let results = par_map(&jobs, |(i, f)| check_file(f, &scratch.join(format!("{i}.bin"))));
    let _ = std::fs::remove_dir_all(&scratch);
    let mut total = 0;
    let mut failures = Vec::new();
    for (f, r) in files.iter().zip(results) {
        match r {
            Ok(n) => total += n,
            Err(e) => failures.push(format!("{}: {e}", f.display())),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(total > 5_000_000, "only {total} values compared");
}

/// Grids written by our writer (file versions 224 and 221) are read by
/// OpenVDB with the same active values as the source: checks the writer and,
/// through the 221 files, the reader's legacy path.
#[test]
fn openvdb_reads_what_we_write() {
    if !oracle_available() {
        return;
    }
    let scratch = std::env::temp_dir().join(format!("vdbcook-written-{}", std::process::id()));
    std::fs::create_dir_all(&scratch).unwrap();
    let mut jobs = Vec::new();
    for name in ["fog_blosc.vdb", "tiles.vdb", "levelset_half.vdb", "map_UnitaryMap.vdb", "map_TranslationMap.vdb", "inactive_modes_blosc.vdb"] {
        let src = vdbcook_vdb::open(&root().join("fixtures").join(name)).unwrap();
        let grid = src.read_grid(src.select(None).unwrap()).unwrap();
        for (version, zip) in [(224, true), (224, false), (221, true), (221, false)] {
            let bytes = vdbcook_vdb::write_vdb(&grid, vdbcook_vdb::WriteOptions { version, zip }).unwrap();
            let path = scratch.join(format!("{}-{version}-{zip}.vdb", name.trim_end_matches(".vdb")));
            std::fs::write(&path, bytes).unwrap();
            jobs.push((path, grid.clone()));
        }
    }
    let results = par_map(&jobs, |(path, grid)| -> Result<(), String> {
        let dump = path.with_extension("bin");
        let json = oracle(path, Some(&dump)).ok_or("OpenVDB cannot read it")?;
        let g = &json["grids"][0];
        if g["map_type"] != grid.transform.map_type.vdb_name() {
            return Err(format!("map type {} ", g["map_type"]));
        }
        let st = grid.stats();
        if g["active_voxels"] != st.active_voxels || g["leaf_count"] != st.leaf_count || g["active_tiles"] != st.active_tiles {
            return Err(format!("figures differ: {g}"));
        }
        let d = read_dump(&dump);
        for &(_, c, v) in &d.voxels {
            let (val, on) = grid.probe(Coord::new(c[0], c[1], c[2]));
            if !on || f64::from(val) != v {
                return Err(format!("voxel {c:?}: source {val} ({on}), openvdb {v}"));
            }
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&scratch);
    let failures: Vec<String> = jobs.iter().zip(results).filter_map(|((p, _), r)| r.err().map(|e| format!("{}: {e}", p.display()))).collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
