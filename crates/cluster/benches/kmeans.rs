//! k-means speed: our path on a million candidate bricks (K = 100, 5
//! iterations), and our path against linfa-clustering (the reference) on the
//! same subset, with the agreement of their partitions.
//!
//!     cargo bench -p vdbcook-cluster --bench kmeans
//!     VDBCOOK_BENCH_BRICKS=200000 VDBCOOK_BENCH_LINFA=20000 cargo bench -p vdbcook-cluster --bench kmeans
//!
//! Prints timings; never asserts them.

use linfa::prelude::*;
use linfa_clustering::{KMeans, KMeansInit};
use linfa_nn::distance::L1Dist;
use ndarray::Array2;
use rand_xoshiro::rand_core::SeedableRng;
use std::time::Instant;
use vdbcook_cluster::{assign, cluster, seed_centroids, update, Brick, Options, BRICK};

/// Smoke-like low-variance bricks around 300 smooth prototypes, with noise.
fn bricks(n: usize) -> Vec<Brick> {
    let mut state = 0x1234_5678u64;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..n)
        .map(|k| {
            let p = (k * 7919 % 300) as f32;
            let scale = 0.2 + 0.6 * rnd();
            std::array::from_fn(|i| {
                let (x, y, z) = ((i / 64) as f32, ((i / 8) % 8) as f32, (i % 8) as f32);
                scale * (0.5 + 0.1 * ((x * 0.3 + p).sin() * (y * 0.2 + z * 0.25 + p * 0.5).cos())) + 0.01 * rnd()
            })
        })
        .collect()
}

fn env(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn agreement(a: &[usize], b: &[usize], k: usize) -> f64 {
    // Fraction of points whose label matches under the best one-to-one-ish
    // mapping (each of our clusters to linfa's most common label in it).
    let mut table = vec![vec![0usize; k]; k];
    for (&x, &y) in a.iter().zip(b) {
        table[x][y] += 1;
    }
    table.iter().map(|row| row.iter().max().copied().unwrap_or(0)).sum::<usize>() as f64 / a.len() as f64
}

fn main() {
    let n = env("VDBCOOK_BENCH_BRICKS", 1_000_000);
    let m = env("VDBCOOK_BENCH_LINFA", 50_000).min(n);
    let (k, iters) = (100, 5);
    println!("k-means, K = {k}, {iters} iterations, {} threads", rayon::current_num_threads());
    let t0 = Instant::now();
    let all = bricks(n);
    println!("generated {n} bricks in {:.1} s", t0.elapsed().as_secs_f64());

    let opts = Options { clusters: k, iterations: iters, variance_threshold: f64::INFINITY, max_brick_error: None, seed: 7 };
    let t0 = Instant::now();
    let refs: Vec<&Brick> = all.iter().collect();
    let c = cluster(&refs, &opts, &|_, _| {}, &|| {});
    let ours_full = t0.elapsed().as_secs_f64();
    println!("vdbcook  {n:>9} bricks: {ours_full:7.2} s  ({} -> {} bricks)", c.stats.bricks_in, c.stats.bricks_out);

    // Same subset, same initial centroids, same iteration count.
    let sub: Vec<&Brick> = all[..m].iter().collect();
    let t0 = Instant::now();
    let init = seed_centroids(&sub, k, 7);
    let seeding = t0.elapsed().as_secs_f64();
    let mut cent = init.clone();
    let mut labels = assign(&sub, &cent, None);
    let first = t0.elapsed().as_secs_f64() - seeding;
    for _ in 0..iters {
        cent = update(&sub, &labels, &cent);
        labels = assign(&sub, &cent, Some(&labels));
    }
    let ours_sub = t0.elapsed().as_secs_f64();
    println!("vdbcook  {m:>9} bricks: seeding {seeding:.2} s, first assignment {first:.2} s, {iters} rounds {:.2} s", ours_sub - seeding - first);

    let records = Array2::from_shape_fn((m, BRICK), |(r, c)| all[r][c]);
    let init_arr = Array2::from_shape_fn((k, BRICK), |(r, c)| init[r][c]);
    let dataset = DatasetBase::from(records.clone());
    let t0 = Instant::now();
    let model = KMeans::params_with(k, rand_xoshiro::Xoshiro256Plus::seed_from_u64(7), L1Dist)
        .init_method(KMeansInit::Precomputed(init_arr))
        .n_runs(1)
        .max_n_iterations(iters as u64)
        .tolerance(1e-12)
        .fit(&dataset)
        .expect("linfa k-means");
    let theirs_labels = model.predict(&records);
    let linfa_sub = t0.elapsed().as_secs_f64();
    let ours_labels: Vec<usize> = labels.iter().map(|l| l.0 as usize).collect();
    println!("vdbcook  {m:>9} bricks: {ours_sub:7.2} s");
    println!("linfa    {m:>9} bricks: {linfa_sub:7.2} s  (linfa-clustering, L1Dist, m_k-means update)");
    println!("ratio    {:.1}x faster than linfa on the same subset; partitions agree on {:.1}% of bricks", linfa_sub / ours_sub, 100.0 * agreement(&ours_labels, &theirs_labels.to_vec(), k));
    println!("linfa extrapolated to {n} bricks: {:.0} s", linfa_sub * n as f64 / m as f64);
}
