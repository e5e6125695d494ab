use super::*;
use crate::leaf_local;
use std::collections::HashMap;
use vdbcook_testkit::Rng;

fn grid(background: f32, leaves: Vec<Leaf>, tiles: Vec<Tile>) -> Grid {
    let mut leaves = leaves;
    leaves.sort_by_key(|l| l.origin);
    Grid { name: "density".into(), class: GridClass::FogVolume, background, transform: Transform::identity(), leaves, tiles }
}

fn floor2(c: Coord) -> Coord {
    Coord::new(c.x >> 1, c.y >> 1, c.z >> 1)
}

/// A random grid: leaves with random masks and values around the origin
/// (negative coordinates too), some 8³ tiles where no leaf is, and (every
/// other seed) a 128³ tile away from them.
fn random_grid(rng: &mut Rng, background: f32) -> Grid {
    let mut used = std::collections::HashSet::new();
    let mut leaves = Vec::new();
    let mut tiles = Vec::new();
    let n = 1 + rng.below(24) as usize;
    let density = rng.unit();
    for _ in 0..n {
        let o = Coord::new((rng.below(10) as i32 - 5) * 8, (rng.below(10) as i32 - 5) * 8, (rng.below(10) as i32 - 5) * 8);
        if !used.insert(o) {
            continue;
        }
        if rng.below(5) == 0 {
            tiles.push(Tile { origin: o, dim: 8, value: rng.unit() * 4.0 - 1.0, active: true });
            continue;
        }
        let mut leaf = Leaf { origin: o, mask: LeafMask::default(), values: [0.0; LEAF_VOXELS] };
        for i in 0..LEAF_VOXELS {
            // Inactive voxels hold junk: the filter must read the background there.
            leaf.values[i] = rng.unit() * 100.0 - 50.0;
            if rng.unit() < density {
                leaf.mask.set(i, true);
                leaf.values[i] = rng.unit() * 2.0;
            }
        }
        leaves.push(leaf);
    }
    if rng.below(2) == 0 {
        tiles.push(Tile { origin: Coord::new(256, -128, 0), dim: 128, value: 0.75, active: true });
    }
    grid(background, leaves, tiles)
}

/// Active fine voxels of leaves and 8³ tiles (128³ tiles are checked on their own).
fn small_active(g: &Grid) -> Vec<(Coord, f32)> {
    let mut out = Vec::new();
    for l in &g.leaves {
        for i in l.mask.iter_on() {
            let (x, y, z) = leaf_local(i);
            out.push((l.origin.offset(x, y, z), l.values[i]));
        }
    }
    for t in g.tiles.iter().filter(|t| t.active && t.dim == 8) {
        for i in 0..LEAF_VOXELS {
            let (x, y, z) = leaf_local(i);
            out.push((t.origin.offset(x, y, z), t.value));
        }
    }
    out
}

/// The coarse grid as the definition says, voxel by voxel, over the leaves and 8³ tiles.
fn reference(g: &Grid, filter: Filter) -> HashMap<Coord, f32> {
    let mut out = HashMap::new();
    for (c, _) in small_active(g) {
        let p = floor2(c);
        if out.contains_key(&p) {
            continue;
        }
        let (mut sum, mut n) = (0.0f64, 0u32);
        for d in 0..8 {
            let child = Coord::new(2 * p.x + (d >> 2), 2 * p.y + ((d >> 1) & 1), 2 * p.z + (d & 1));
            match g.probe(child) {
                (v, true) => {
                    sum += f64::from(v);
                    n += 1;
                }
                _ if filter == Filter::Mean => sum += f64::from(g.background),
                _ => {}
            }
        }
        let v = if filter == Filter::Mean { sum / 8.0 } else { sum / f64::from(n) };
        out.insert(p, v as f32);
    }
    out
}

#[test]
fn random_grids_match_the_definition_voxel_by_voxel() {
    let mut rng = Rng::new(14);
    for case in 0..60 {
        let bg = if case % 3 == 0 { 0.0 } else { rng.unit() - 0.5 };
        let g = random_grid(&mut rng, bg);
        for filter in [Filter::Mean, Filter::ActiveMean] {
            let c = coarsen(&g, filter);
            let want = reference(&g, filter);
            let big_tiles: u64 = g.tiles.iter().filter(|t| t.dim == 128).map(|_| 64 * 64 * 64).sum();
            assert_eq!(c.stats().active_voxels, want.len() as u64 + big_tiles, "case {case} {filter:?}: active voxels");
            for (&p, &v) in &want {
                let (got, active) = c.probe(p);
                assert!(active, "case {case} {filter:?}: {p:?} inactive");
                assert!((got - v).abs() <= 1e-6 * v.abs().max(1.0), "case {case} {filter:?}: {p:?} is {got}, want {v}");
            }
            assert!(c.leaves.windows(2).all(|w| w[0].origin < w[1].origin), "leaves sorted and distinct");
            assert!(c.leaves.iter().all(|l| l.origin.is_aligned(8)) && c.tiles.iter().all(|t| t.origin.is_aligned(t.dim as i32)));
        }
    }
}

#[test]
fn the_mean_filter_keeps_a_region_integral() {
    // Over every active coarse voxel, 8 · Σ coarse = Σ fine active + bg · (inactive children):
    // with background 0 the integral (optical depth) is kept exactly, at every level.
    let mut rng = Rng::new(7);
    for case in 0..60 {
        let bg = if case % 2 == 0 { 0.0 } else { rng.unit() };
        let mut g = random_grid(&mut rng, bg);
        g.tiles.retain(|t| t.dim == 8);
        let (s0, n0) = {
            let s = g.stats();
            (s.sum, s.active_voxels)
        };
        let mut level = g.clone();
        let mut scale = 1.0f64;
        for k in 1..=4 {
            let next = coarsen(&level, Filter::Mean);
            let (s, sn) = (level.stats(), next.stats());
            let want = s.sum + f64::from(bg) * (8 * sn.active_voxels - s.active_voxels) as f64;
            assert!((8.0 * sn.sum - want).abs() <= 1e-5 * want.abs().max(1.0), "case {case} level {k}: 8·{} vs {want}", sn.sum);
            scale *= 8.0;
            if bg == 0.0 {
                assert!((scale * sn.sum - s0).abs() <= 1e-4 * s0.abs().max(1.0), "case {case} level {k}: the integral moved: {} vs {s0}", scale * sn.sum);
            }
            assert!(sn.active_voxels * 8 >= s.active_voxels && sn.active_voxels <= s.active_voxels.max(1));
            level = next;
        }
        assert!(n0 == 0 || level.stats().active_voxels > 0, "case {case}: something survives");
    }
}

#[test]
fn a_constant_region_stays_the_same_constant() {
    let v = 0.3125f32;
    // 32³ voxels aligned to the coarsest voxel (level 4: 16³), negative coordinates included.
    let leaves: Vec<Leaf> =
        (0..64).map(|i| Leaf { origin: Coord::new(-32 + (i >> 4) * 8, (i >> 2 & 3) * 8 - 64, (i & 3) * 8 + 32), mask: LeafMask([u64::MAX; 8]), values: [v; LEAF_VOXELS] }).collect();
    let mut level = grid(0.0, leaves, vec![]);
    for k in 1..=4 {
        for filter in [Filter::Mean, Filter::ActiveMean] {
            let c = coarsen(&level, filter);
            let s = c.stats();
            assert_eq!(s.active_voxels, (32u64 >> k).pow(3), "level {k}");
            assert_eq!((s.min, s.max), (Some(f64::from(v)), Some(f64::from(v))), "level {k} {filter:?}");
        }
        level = coarsen(&level, Filter::Mean);
    }
}

#[test]
fn a_single_active_voxel_survives_diluted_at_every_level() {
    let p = Coord::new(-13, 22, 5);
    let mut leaf = Leaf { origin: p.leaf_origin(), mask: LeafMask::default(), values: [9.0; LEAF_VOXELS] };
    leaf.mask.set(crate::leaf_offset(p.x, p.y, p.z), true);
    leaf.values[crate::leaf_offset(p.x, p.y, p.z)] = 1.0;
    let mut mean = grid(0.0, vec![leaf.clone()], vec![]);
    let mut active = mean.clone();
    for k in 1..=6 {
        mean = coarsen(&mean, Filter::Mean);
        active = coarsen(&active, Filter::ActiveMean);
        let at = Coord::new(p.x >> k, p.y >> k, p.z >> k);
        assert_eq!(mean.stats().active_voxels, 1, "level {k}");
        assert_eq!(mean.probe(at), (0.125f32.powi(k), true), "level {k}: diluted by 8 per level");
        assert_eq!(active.probe(at), (1.0, true), "level {k}: the active mean keeps it");
    }
}

#[test]
fn tiles_stay_tiles() {
    let g = grid(0.0, vec![], vec![Tile { origin: Coord::new(-128, 0, 128), dim: 128, value: 2.0, active: true }, Tile { origin: Coord::new(0, 0, 4096), dim: 4096, value: 1.0, active: true }]);
    let l1 = coarsen(&g, Filter::Mean);
    assert!(l1.leaves.is_empty());
    assert_eq!(l1.tiles.iter().filter(|t| t.dim == 8 && t.value == 2.0).count(), 512, "a 64³ cube is 8³ tiles of 8");
    assert_eq!(l1.tiles.iter().filter(|t| t.dim == 128 && t.value == 1.0).count(), 16 * 16 * 16, "a 2048³ cube is 16³ tiles of 128");
    let l2 = coarsen(&l1, Filter::Mean);
    assert!(l2.leaves.is_empty(), "eight 4³ blocks of one value are a tile");
    assert_eq!(l2.tiles.iter().filter(|t| t.dim == 8 && t.value == 2.0).count(), 64);
    assert_eq!(l2.tiles.iter().filter(|t| t.dim == 128 && t.value == 1.0).count(), 8 * 8 * 8, "eight 64³ cubes of one value fill a 128³ tile");
    assert_eq!(l2.stats().active_voxels, 32 * 32 * 32 + 1024 * 1024 * 1024);
    // An 8³ tile beside a leaf: a 4³ block of the coarse leaf.
    let mut leaf = Leaf { origin: Coord::new(8, 0, 0), mask: LeafMask::default(), values: [0.0; LEAF_VOXELS] };
    leaf.mask.set(0, true);
    leaf.values[0] = 8.0;
    let c = coarsen(&grid(0.0, vec![leaf], vec![Tile { origin: Coord::new(0, 0, 0), dim: 8, value: 3.0, active: true }]), Filter::Mean);
    assert_eq!((c.leaves.len(), c.tiles.len()), (1, 0));
    assert_eq!(c.probe(Coord::new(3, 3, 3)), (3.0, true));
    assert_eq!(c.probe(Coord::new(4, 0, 0)), (1.0, true));
    assert_eq!(c.stats().active_voxels, 64 + 1);
}

#[test]
fn a_coarse_voxel_centre_is_its_childrens_centre() {
    for t in [
        Transform::identity(),
        Transform::scale_translate(MapType::ScaleTranslate, [0.5, 0.25, 2.0], [1.0, -3.0, 7.5]),
        Transform { map_type: MapType::Affine, matrix: [[0.0, 0.5, 0.0, 0.0], [-0.5, 0.0, 0.0, 0.0], [0.0, 0.0, 0.5, 0.0], [3.0, 2.0, 1.0, 1.0]] },
    ] {
        let mut fine = t;
        for k in 1..=4 {
            let coarse = coarsen_transform(&fine);
            assert_eq!(coarse.map_type, if t.map_type == MapType::Affine { MapType::Affine } else { coarsen_transform(&t).map_type });
            for c in [[0.0, 0.0, 0.0], [3.0, -5.0, 11.0]] {
                let centre = coarse.index_to_world(c);
                let mut mean = [0.0; 3];
                for d in 0..8 {
                    let child = [2.0 * c[0] + f64::from(d >> 2), 2.0 * c[1] + f64::from((d >> 1) & 1), 2.0 * c[2] + f64::from(d & 1)];
                    let w = fine.index_to_world(child);
                    (0..3).for_each(|a| mean[a] += w[a] / 8.0);
                }
                assert!((0..3).all(|a| (centre[a] - mean[a]).abs() < 1e-9), "level {k}: {centre:?} vs {mean:?}");
                // Chained: level k index i sits at level-0 index 2^k·i + (2^k − 1)/2.
                let s = f64::from(1 << k);
                let direct = t.index_to_world([s * c[0] + (s - 1.0) / 2.0, s * c[1] + (s - 1.0) / 2.0, s * c[2] + (s - 1.0) / 2.0]);
                assert!((0..3).all(|a| (centre[a] - direct[a]).abs() < 1e-9), "level {k}");
            }
            let vs = coarse.voxel_size();
            let fs = fine.voxel_size();
            assert!((0..3).all(|a| (vs[a] - 2.0 * fs[a]).abs() < 1e-12));
            fine = coarse;
        }
    }
}

#[test]
fn the_result_does_not_depend_on_the_thread_count() {
    let mut rng = Rng::new(3);
    let g = random_grid(&mut rng, 0.0);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| coarsen(&g, Filter::Mean));
    let many = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap().install(|| coarsen(&g, Filter::Mean));
    assert_eq!(one, many);
}
