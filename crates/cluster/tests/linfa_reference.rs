//! Our k-means against linfa-clustering's (the reference implementation) on
//! planted data: from the same initial centroids, with the L1 distance, both
//! group the bricks the same way.

use linfa::prelude::*;
use linfa_clustering::{KMeans, KMeansInit};
use linfa_nn::distance::L1Dist;
use ndarray::Array2;
use rand_xoshiro::rand_core::SeedableRng;
use vdbcook_cluster::{assign, seed_centroids, update, Brick, BRICK};

fn planted(groups: usize, per: usize) -> Vec<Brick> {
    let mut out = Vec::new();
    let mut state = 12345u64;
    let mut noise = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((state >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 2e-3
    };
    for g in 0..groups {
        for _ in 0..per {
            out.push(std::array::from_fn(|i| 0.4 + 0.1 * (((i as f32) * 0.05 + g as f32 * 0.9).sin()) + noise()));
        }
    }
    out
}

/// True when two labelings induce the same partition.
fn same_partition(a: &[usize], b: &[usize]) -> bool {
    let mut map = std::collections::HashMap::new();
    let mut back = std::collections::HashMap::new();
    a.iter().zip(b).all(|(x, y)| *map.entry(x).or_insert(y) == y && *back.entry(y).or_insert(x) == x)
}

#[test]
fn same_clusters_as_linfa() {
    let bricks = planted(8, 50);
    let data: Vec<&Brick> = bricks.iter().collect();
    let init = seed_centroids(&data, 8, 42);

    let mut centroids = init.clone();
    let mut labels = assign(&data, &centroids, None);
    for _ in 0..5 {
        centroids = update(&data, &labels, &centroids);
        labels = assign(&data, &centroids, Some(&labels));
    }
    let ours: Vec<usize> = labels.iter().map(|l| l.0 as usize).collect();

    let records = Array2::from_shape_fn((bricks.len(), BRICK), |(r, c)| f64::from(bricks[r][c]));
    let init_arr = Array2::from_shape_fn((init.len(), BRICK), |(r, c)| f64::from(init[r][c]));
    let dataset = DatasetBase::from(records.clone());
    let model = KMeans::params_with(8, rand_xoshiro::Xoshiro256Plus::seed_from_u64(42), L1Dist)
        .init_method(KMeansInit::Precomputed(init_arr))
        .n_runs(1)
        .max_n_iterations(5)
        .tolerance(1e-12)
        .fit(&dataset)
        .expect("linfa k-means");
    let theirs: Vec<usize> = model.predict(&records).to_vec();
    assert!(same_partition(&ours, &theirs), "ours {ours:?}\nlinfa {theirs:?}");
    // And both recover the planted groups.
    let planted_labels: Vec<usize> = (0..bricks.len()).map(|i| i / 50).collect();
    assert!(same_partition(&ours, &planted_labels));
}
