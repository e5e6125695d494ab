//! Truncated and bit-flipped files: the reader must return an error (or, for
//! a flip that happens to keep the file valid, a result), never panic, and
//! never make an allocation that the file's size cannot justify.
//!
//! The allocation high-water mark is global to the test binary: the other
//! test here allocates far less than the budget.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Tracking;
static LARGEST: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        LARGEST.fetch_max(l.size(), Ordering::Relaxed);
        System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        System.dealloc(p, l)
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        LARGEST.fetch_max(l.size(), Ordering::Relaxed);
        System.alloc_zeroed(l)
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        LARGEST.fetch_max(n, Ordering::Relaxed);
        System.realloc(p, l, n)
    }
}

#[global_allocator]
static A: Tracking = Tracking;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Reads everything the reader can read; `Ok` carries a checksum of the result.
fn read_all(bytes: Vec<u8>) -> Result<f64, vdbcook_vdb::Error> {
    let file = vdbcook_vdb::VdbFile::parse(bytes)?;
    let mut acc = 0.0;
    for i in 0..file.grids.len() {
        if file.grids[i].is_readable() {
            for g in file.read_channels(i)? {
                acc += g.stats().sum;
            }
        }
    }
    Ok(acc)
}

/// A small deterministic generator (xorshift64*).
use vdbcook_testkit::Rng;

fn inputs() -> Vec<PathBuf> {
    let mut v = Vec::new();
    for name in [
        "fog_blosc.vdb",
        "fog_zip.vdb",
        "fog_none.vdb",
        "fog_activemask.vdb",
        "fog_half_blosc.vdb",
        "fog_half_zip.vdb",
        "multi_grid.vdb",
        "tiles.vdb",
        "instanced.vdb",
        "levelset_half.vdb",
        "empty.vdb",
    ] {
        let p = root().join("fixtures").join(name);
        assert!(p.exists(), "fixture {} is missing (run `just fixtures`)", p.display());
        v.push(p);
    }
    // vec3 grids written by OpenVDB (cli/tests/vec3_sources.py; see tests/data/README.md).
    for name in ["vec3s_half_active.vdb", "vec3d_blosc.vdb"] {
        v.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name));
    }
    // Small files written by other tools, when the shared corpus is present.
    let shared = root().join("../shared/vdb-samples");
    for name in ["bwproject/cloud.vdb", "hsim/test.vdb", "vfx-toolkit-embergen/embergen_fire_a_0.vdb", "elyg-visualizer/fogTommy.vdb", "arnold-usd/torus01.vdb", "plasmadxr/fluid_data_0001.vdb"] {
        let p = shared.join(name);
        if p.exists() {
            v.push(p);
        }
    }
    v
}

/// A float grid and a vec3s grid with tiles at every level, written by our
/// writer at file versions 224 and 221 (the legacy layout).
fn written_vec3_files() -> Vec<(String, Vec<u8>)> {
    use vdbcook_grid::{Coord, Grid, GridClass, Leaf, LeafMask, Tile, Transform, LEAF_VOXELS};
    use vdbcook_vdb::{write_vdb_grids, WriteGrid, WriteOptions};
    let mut rng = Rng::new(3);
    let mut mask = LeafMask::default();
    for i in 0..LEAF_VOXELS {
        mask.set(i, rng.below(4) == 0);
    }
    let comps: Vec<Grid> = (0..3)
        .map(|c| {
            // One root child: its 32³ node's 32768 tile values dominate the decoding time.
            let leaves = [Coord::new(8, 0, 0), Coord::new(0, 8, 16), Coord::new(1024, 0, 0)]
                .into_iter()
                .map(|origin| Leaf { origin, mask, values: std::array::from_fn(|i| (i * (c + 1)) as f32 * 0.25) })
                .collect();
            let tiles = vec![
                Tile { origin: Coord::new(0, 0, 0), dim: 8, value: 1.0 + c as f32, active: true },
                Tile { origin: Coord::new(128, 0, 0), dim: 128, value: 2.0, active: false },
                Tile { origin: Coord::new(-8192, 0, 0), dim: 4096, value: -(c as f32), active: true },
            ];
            Grid { name: String::new(), class: GridClass::Staggered, background: 0.5 * c as f32, transform: Transform::identity(), leaves, tiles }
        })
        .collect();
    let density = Grid { name: "density".into(), class: GridClass::FogVolume, background: 0.0, transform: Transform::identity(), leaves: comps[0].leaves.clone(), tiles: vec![] };
    let grids = [WriteGrid::Float(&density), WriteGrid::Vec3 { name: "vel", class: GridClass::Staggered, components: [&comps[0], &comps[1], &comps[2]] }];
    [(224, true), (221, true)].into_iter().map(|(version, zip)| (format!("written vec3 v{version}"), write_vdb_grids(&grids, WriteOptions { version, zip }).unwrap())).collect()
}

#[test]
fn truncated_and_bit_flipped_files_fail_cleanly() {
    let mut rng = Rng::new(0x9E37_79B9_7F4A_7C15);
    let mut runs = 0usize;
    let files = inputs().into_iter().map(|p| (p.display().to_string(), std::fs::read(&p).unwrap()));
    for (path, original) in files.chain(written_vec3_files()) {
        let len = original.len();
        read_all(original.clone()).unwrap_or_else(|e| panic!("{}: the intact file must read: {e}", path));
        // Anything above this is an allocation sized by the file's contents
        // rather than its size.  The floor is what one 32³ node justifies: its
        // 32768 values (vec3d: 768 KiB), or, when a flipped background makes
        // every slot a tile, 32768 + 4096 per child tiles of up to 32 bytes in
        // a vector that grows by doubling (2 MiB).
        let budget = 8 * len + (2 << 20);
        LARGEST.store(0, Ordering::Relaxed);

        // Truncations: every length for small files, a spread for larger ones.
        let step = (len / 400).max(1);
        let mut cuts: Vec<usize> = (0..len.min(600)).chain((600..len).step_by(step)).collect();
        cuts.push(len - 1);
        for cut in cuts {
            let data = original[..cut].to_vec();
            let r = std::panic::catch_unwind(|| read_all(data));
            match r {
                Err(_) => panic!("{}: panic reading the first {cut} bytes", path),
                Ok(Ok(_)) => panic!("{}: the first {cut} of {len} bytes read without error", path),
                Ok(Err(e)) => assert!(!e.to_string().contains('\n'), "multi-line error: {e}"),
            }
            runs += 1;
        }
        // Single bit flips anywhere in the file.
        for _ in 0..1500 {
            let mut data = original.clone();
            let bit = rng.below(len as u64 * 8) as usize;
            data[bit / 8] ^= 1 << (bit % 8);
            if std::panic::catch_unwind(|| read_all(data)).is_err() {
                panic!("{}: panic after flipping bit {bit}", path);
            }
            runs += 1;
        }
        let largest = LARGEST.load(Ordering::Relaxed);
        assert!(largest <= budget, "{}: an allocation of {largest} bytes for a {len}-byte file", path);
    }
    assert!(runs > 5000, "only {runs} corrupted reads");
}

/// Found by reading the code (fuzz/regressions): many descriptors pointing at
/// one shared grid block made reading quadratic in the file size. Grid data
/// must now lie after its own descriptor, so such a file is refused.
#[test]
fn descriptors_cannot_share_grid_data() {
    let p = root().join("fuzz/regressions/read_vdb-timeout-shared-grid-block.bin");
    let bytes = std::fs::read(&p).unwrap();
    let e = vdbcook_vdb::VdbFile::parse(bytes).err().expect("refused");
    assert!(e.to_string().contains("starts before its descriptor ends"), "{e}");
}
