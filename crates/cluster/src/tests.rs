use super::*;

/// A smooth, positive, low-variance brick shaped by `p`.
fn prototype(p: usize) -> Brick {
    std::array::from_fn(|i| {
        let (x, y, z) = ((i / 64) as f32, ((i / 8) % 8) as f32, (i % 8) as f32);
        0.5 + 0.05 * ((x + p as f32 * 1.7) * 0.4).sin() * ((y * 0.3 + z * 0.2) + p as f32).cos()
    })
}

fn jitter(b: &Brick, seed: u64, amp: f32) -> Brick {
    let mut r = Rng(seed);
    b.map(|v| v + amp * (r.unit() as f32 - 0.5))
}

/// Clusters `bricks`: the result and its output bricks, copied.
fn clustered(bricks: &[Brick], opts: &Options) -> (Clustered, Vec<Brick>) {
    let refs: Vec<&Brick> = bricks.iter().collect();
    let c = cluster(&refs, opts, &|_, _| {}, &|| {});
    let out = (0..c.len()).map(|w| *c.brick(&refs, w).unwrap()).collect();
    (c, out)
}

fn planted() -> (Vec<Brick>, Vec<usize>) {
    let mut bricks = Vec::new();
    let mut group = Vec::new();
    for p in 0..6 {
        let base = prototype(p);
        for c in 0..40 {
            bricks.push(jitter(&base, (p * 1000 + c) as u64, 1e-3));
            group.push(p);
        }
    }
    (bricks, group)
}

#[test]
fn planted_near_duplicates_collapse_to_the_planted_count() {
    let (bricks, group) = planted();
    for seed in 0..20 {
        let opts = Options { clusters: 6, iterations: 5, variance_threshold: 0.05, max_brick_error: None, seed };
        let (c, _) = clustered(&bricks, &opts);
        assert_eq!(c.stats.bricks_out, 6, "seed {seed}: {:?}", c.stats);
        for i in 0..bricks.len() {
            for j in 0..bricks.len() {
                assert_eq!(c.remap[i] == c.remap[j], group[i] == group[j], "seed {seed}: bricks {i} and {j}");
            }
        }
        assert!(c.merged.iter().all(|&m| m));
    }
}

#[test]
fn high_variance_and_constant_bricks_are_never_merged() {
    let (mut bricks, _) = planted();
    let spiky: Brick = std::array::from_fn(|i| if i % 7 == 0 { 1.0 } else { 0.001 });
    let constant = [0.25f32; BRICK];
    bricks.push(spiky);
    bricks.push(constant);
    let n = bricks.len();
    assert!(normalized_variance(&spiky) > 0.05);
    let opts = Options { clusters: 6, iterations: 5, variance_threshold: 0.05, max_brick_error: None, seed: 1 };
    let (c, out) = clustered(&bricks, &opts);
    assert!(!c.merged[n - 2] && !c.merged[n - 1]);
    assert_eq!(out[c.remap[n - 2] as usize], spiky);
    assert_eq!(out[c.remap[n - 1] as usize], constant);
    assert_eq!((c.stats.high_variance, c.stats.constant), (1, 1));
    assert_eq!(c.stats.bricks_out, 8);
}

#[test]
fn max_brick_error_is_honoured_brick_by_brick() {
    let (mut bricks, _) = planted();
    // Outliers: near a prototype, but off by more than the bound somewhere.
    for k in 0..5 {
        let mut b = jitter(&prototype(k), 99 + k as u64, 1e-3);
        b[k * 50] += 0.02;
        bricks.push(b);
    }
    let e = 0.01f32;
    let opts = Options { clusters: 6, iterations: 5, variance_threshold: 0.05, max_brick_error: Some(e), seed: 3 };
    let (c, out) = clustered(&bricks, &opts);
    for (i, b) in bricks.iter().enumerate() {
        let out = &out[c.remap[i] as usize];
        let worst = b.iter().zip(out).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(worst <= e, "brick {i}: {worst}");
    }
    assert_eq!(c.stats.over_error, 5, "{:?}", c.stats);
    let (loose, _) = clustered(&bricks, &Options { max_brick_error: None, ..opts });
    assert_eq!(loose.stats.over_error, 0);
    assert!(loose.stats.bricks_out < c.stats.bricks_out);
}

#[test]
fn same_result_on_any_thread_count() {
    let (bricks, _) = planted();
    let opts = Options { clusters: 4, iterations: 3, variance_threshold: 0.05, max_brick_error: None, seed: 9 };
    let run = |t| rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap().install(|| clustered(&bricks, &opts));
    let ((a, a_out), (b, b_out)) = (run(1), run(3));
    assert_eq!(a.remap, b.remap);
    assert!(a_out == b_out);
}

#[test]
fn l1_early_exit_never_changes_the_minimum() {
    let a = prototype(0);
    let b = prototype(1);
    let full = l1(&a, &b, f32::INFINITY);
    assert!(l1(&a, &b, full * 0.5) >= full * 0.5);
    assert_eq!(l1(&a, &b, full * 2.0), full);
    assert_eq!(l1(&a, &a, 0.0), 0.0);
}

#[test]
fn fewer_candidates_than_clusters_changes_nothing() {
    let bricks = vec![prototype(0), prototype(1)];
    let (c, out) = clustered(&bricks, &Options { clusters: 8, ..Options::default() });
    assert_eq!(c.remap, vec![0, 1]);
    assert_eq!(c.kept, vec![0, 1]);
    assert!(out == bricks);
}

#[test]
fn hinted_search_finds_the_same_nearest_centroid() {
    let (bricks, _) = planted();
    let data: Vec<&Brick> = bricks.iter().collect();
    // Duplicate centroids make ties: the lower index must win either way.
    let mut cents = seed_centroids(&data, 6, 5);
    cents.push(cents[2]);
    cents.insert(0, cents[4]);
    let plain = assign(&data, &cents, None);
    for h in 0..cents.len() as u32 {
        let hints = vec![(h, 0.0); data.len()];
        assert_eq!(assign(&data, &cents, Some(&hints)), plain, "hint {h}");
    }
}

#[test]
fn bricks_with_non_finite_values_are_kept_as_they_are() {
    // A NaN or infinite voxel in a planted near-duplicate: its variance is
    // NaN or infinite, and no centroid may replace it (nor be dragged by it).
    let (mut bricks, _) = planted();
    for (k, x) in [(3, f32::NAN), (50, f32::INFINITY)] {
        bricks[k][100] = x;
    }
    let opts = Options { clusters: 6, iterations: 5, variance_threshold: 0.05, max_brick_error: None, seed: 1 };
    let (c, out) = clustered(&bricks, &opts);
    for k in [3, 50] {
        assert!(!c.merged[k], "brick {k}");
        let kept = &out[c.remap[k] as usize];
        assert!(kept.iter().zip(&bricks[k]).all(|(a, b)| a.to_bits() == b.to_bits()), "brick {k} is stored as it is");
    }
    assert_eq!(c.stats.high_variance, 2, "{:?}", c.stats);
    // Every centroid is finite.
    for (i, &m) in c.merged.iter().enumerate() {
        if m {
            assert!(out[c.remap[i] as usize].iter().all(|v| v.is_finite()), "centroid of brick {i}");
        }
    }
}

#[test]
fn every_pass_over_the_bricks_calls_the_scan_hook_and_changes_nothing() {
    let (bricks, _) = planted();
    let refs: Vec<&Brick> = bricks.iter().collect();
    let opts = Options { clusters: 6, iterations: 3, variance_threshold: 0.05, max_brick_error: Some(0.01), seed: 4 };
    let calls = std::sync::atomic::AtomicUsize::new(0);
    let plain = cluster(&refs, &opts, &|_, _| {}, &|| {});
    let hooked = cluster(&refs, &opts, &|_, _| {}, &|| {
        calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    });
    assert_eq!((plain.remap, plain.kept), (hooked.remap, hooked.kept));
    assert!(plain.centroids == hooked.centroids);
    // The variance gate, the seeding's copy, the first assignment, three
    // updates and assignments, and the error bound: at least once each.
    assert!(calls.into_inner() >= 10);
}

#[test]
fn passes_over_scattered_bricks_read_them_in_smaller_groups() {
    // Zeroed and never touched: only where the items lie matters.
    let pool = vec![[0f32; BRICK]; 8 * 8192];
    let dense: Vec<&Brick> = pool[..3 * 8192 + 100].iter().collect();
    let sparse: Vec<&Brick> = pool.iter().step_by(8).collect();
    let lens = |items: &[&Brick]| {
        let groups = super::scan_groups(items);
        // In order, every item once, whole chunks but the last.
        assert_eq!(groups.first().map(|g| g.start), Some(0));
        assert!(groups.windows(2).all(|w| w[0].end == w[1].start && w[0].len() % super::CHUNK == 0));
        assert_eq!(groups.last().map(|g| g.end), Some(items.len()));
        groups.iter().map(|g| g.len()).collect::<Vec<_>>()
    };
    // In order: 16 MiB of bricks a group.
    assert_eq!(lens(&dense), vec![8192, 8192, 8192, 100]);
    // Every 8th brick: one chunk of 1024 spans 16 MiB of the pool already.
    assert_eq!(lens(&sparse), vec![1024; 8]);
}
