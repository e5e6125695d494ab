//! Clustering (`--clusters`): similar bricks merged with variance-gated
//! k-means before encoding, strays held to a maximum error, and what
//! clustering cost in error.

use crate::encode::union_masks;
use crate::errors::{frame_errors, scanned_bricks};
use crate::{ClusterReport, Progress};
use rayon::prelude::*;
use vdbcook_encode::{Brick, Bricks, Encoded, ErrorStats, PlaneSpec, Quality};
use vdbcook_flipbook::Built;
use vdbcook_grid::spill::{trim_now, SpillPolicy, Store, StoreError};

/// The clustered pool, `channels` [`Brick`]s per brick.
pub(crate) struct Clustered {
    /// The work bricks: centroids and bricks kept as they are (then strays),
    /// under the cook's spill policy (they are nearly as many as the pool's).
    pub(crate) bricks: Store<Brick>,
    /// Pool brick -> work brick.
    pub(crate) remap: Vec<u32>,
    /// Per pool brick: merged into a centroid.
    pub(crate) merged: Vec<bool>,
    stats: vdbcook_cluster::Stats,
}

/// Clusters the pool (`channels` bricks per brick), each channel weighing
/// alike: its values divided by its own value range (`ranges`); the work
/// bricks and the copy k-means reads are stores under `spill`.
pub(crate) fn cluster(pool: Bricks, ranges: &[[f32; 2]], opts: &vdbcook_cluster::Options, spill: Option<&SpillPolicy>, progress: &dyn Progress) -> Result<Clustered, StoreError> {
    progress.start("clustering", opts.iterations as u64 + 1);
    let scales: Vec<f32> = ranges.iter().map(|r| r[1] - r[0]).map(|s| if s > 0.0 && s.is_finite() { s } else { 1.0 }).collect();
    let c = cluster_channels(pool, &scales, opts, spill, &|_, _| progress.advance(1));
    progress.finish();
    c
}

/// Variance-gated k-means over bricks of `scales.len()` channels: each brick
/// is one item of its channels' values, each divided by its channel's
/// `scale` (so distances weigh every channel alike; `max_brick_error` stays
/// in the channels' units), and the centroids are scaled back.
fn cluster_channels(pool: Bricks, scales: &[f32], opts: &vdbcook_cluster::Options, spill: Option<&SpillPolicy>, progress: &(dyn Fn(usize, usize) + Sync)) -> Result<Clustered, StoreError> {
    fn run<const N: usize>(pool: Bricks, scales: &[f32], opts: &vdbcook_cluster::Options, spill: Option<&SpillPolicy>, progress: &(dyn Fn(usize, usize) + Sync)) -> Result<Clustered, StoreError> {
        let mut flat = Store::<f32>::with_policy(spill.cloned());
        flat.par_extend((0..pool.len() * N).into_par_iter().map(|j| pool.get(j / N, j % N / 512)[j % 512] / scales[j % N / 512]), "the bricks to cluster")?;
        let items: Vec<&[f32; N]> = flat.chunks_exact(N).filter_map(|item| item.try_into().ok()).collect();
        let out = vdbcook_cluster::cluster_scaled(&items, opts, scales, progress, &trim_now);
        work_bricks(out, pool, |centroid, k| std::array::from_fn(|v| centroid[k * 512 + v] * scales[k]), spill)
    }
    match (scales.len(), pool.as_dense()) {
        (1, Some(dense)) => {
            // One channel: the values as they are (same results as before channels existed).
            let items: Vec<&Brick> = dense.iter().collect();
            let out = vdbcook_cluster::cluster(&items, opts, progress, &trim_now);
            work_bricks(out, pool, |centroid, _| *centroid, spill)
        }
        (1, None) => run::<512>(pool, scales, opts, spill, progress),
        (2, _) => run::<1024>(pool, scales, opts, spill, progress),
        (3, _) => run::<1536>(pool, scales, opts, spill, progress),
        (4, _) => run::<2048>(pool, scales, opts, spill, progress),
        (5, _) => run::<2560>(pool, scales, opts, spill, progress),
        (6, _) => run::<3072>(pool, scales, opts, spill, progress),
        (7, _) => run::<3584>(pool, scales, opts, spill, progress),
        _ => run::<4096>(pool, scales, opts, spill, progress),
    }
}

/// The work bricks of `out`: a kept brick's channels as the pool holds them
/// (exactly: v / s · s need not be v), a centroid's channel `k` as
/// `centroid(values, k)` makes it.
fn work_bricks<const N: usize>(out: vdbcook_cluster::Clustered<N>, pool: Bricks, centroid: impl Fn(&[f32; N], usize) -> Brick + Sync, spill: Option<&SpillPolicy>) -> Result<Clustered, StoreError> {
    let c = pool.channels();
    let mut bricks = Store::with_policy(spill.cloned());
    let made = (0..out.len() * c).into_par_iter().map(|j| {
        scanned_bricks(1);
        match out.kept.get(j / c) {
            Some(&i) => *pool.get(i as usize, j % c),
            None => centroid(&out.centroids[j / c - out.kept.len()], j % c),
        }
    });
    bricks.par_extend(made, "the clustered bricks")?;
    Ok(Clustered { bricks, remap: out.remap, merged: out.merged, stats: out.stats })
}

impl Clustered {
    /// Per work brick, the union of its pool bricks' masks.
    pub(crate) fn work_masks(&self, pool_masks: &[[u64; 8]], channels: usize, spill: Option<&SpillPolicy>) -> Result<Store<[u64; 8]>, StoreError> {
        union_masks(self.bricks.len() / channels, self.remap.iter().zip(pool_masks).map(|(&w, &mask)| (w as usize, mask)), spill)
    }

    /// Splits off the merged bricks that their work brick's choice
    /// (`choices`, per work brick and channel) leaves past `bound`: each
    /// becomes a work brick of its own, appended; returns their masks.
    /// Centroids all of whose bricks strayed are no longer counted.
    pub(crate) fn split_strays(&mut self, pool: Bricks, channels: usize, masks: &[[u64; 8]], choices: &vdbcook_encode::Choices, bound: f32) -> Result<Vec<[u64; 8]>, StoreError> {
        let strays: Vec<usize> = (0..self.merged.len())
            .into_par_iter()
            .filter(|&i| {
                let w = self.remap[i] as usize;
                self.merged[i]
                    && !(0..channels).all(|ch| {
                        let j = w * channels + ch;
                        choices.pick(j).is_some_and(|pick| vdbcook_encode::within(pool.get(i, ch), &vdbcook_encode::decode_one(pick.format, choices.bytes(j), pick.range), &masks[i], bound))
                    })
            })
            .collect();
        let first = self.bricks.len();
        for (k, &i) in strays.iter().enumerate() {
            self.remap[i] = (first / channels + k) as u32;
            self.merged[i] = false;
            let own: Vec<Brick> = pool.channels_of(i).copied().collect();
            self.bricks.extend_from_slice(&own, "the clustered bricks")?;
        }
        self.stats.over_error += strays.len();
        self.stats.clustered -= strays.len();
        // Centroids all of whose bricks strayed are not stored.
        let merged_into: std::collections::BTreeSet<u32> = self.remap.iter().zip(&self.merged).filter(|(_, &m)| m).map(|(&w, _)| w).collect();
        self.stats.centroids = merged_into.len();
        self.stats.bricks_out = self.merged.iter().filter(|&&m| !m).count() + merged_into.len();
        Ok(strays.iter().map(|&i| masks[i]).collect())
    }
}

/// Per work brick (`n` of them), whether some pool brick uses it: with
/// per-brick formats, a centroid all of whose bricks strayed past the bound
/// is not stored.
pub(crate) fn used_work(clustered: Option<&Clustered>, n: usize) -> Vec<bool> {
    match clustered {
        Some(c) => {
            let mut used = vec![false; n];
            for &w in &c.remap {
                if let Some(u) = used.get_mut(w as usize) {
                    *u = true;
                }
            }
            used
        }
        None => vec![true; n],
    }
}

/// How the cook would have encoded without clustering, for its report.
pub(crate) struct Unclustered<'a> {
    pub(crate) built: &'a Built,
    /// The first stored level, and each channel's.
    pub(crate) first: u32,
    pub(crate) own: &'a [u32],
    pub(crate) channels: usize,
    /// The planes of a cook without per-brick formats.
    pub(crate) specs: &'a [PlaneSpec],
    pub(crate) quality: Quality,
    pub(crate) max_error: Option<f32>,
    /// Texels for a supercompressed file (as the stored bricks' are).
    pub(crate) disk: Option<vdbcook_encode::Optimize>,
    /// The pool's shown voxels, when encoding used them.
    pub(crate) masks: Option<&'a [[u64; 8]]>,
    /// The cook's spill policy, for the merged bricks and their encoding.
    pub(crate) spill: Option<&'a SpillPolicy>,
}

/// The thesis's Figure 19 table: the first channel's voxel RMSE as stored
/// (`rmse_with`) and with every merged brick encoded on its own instead
/// (other bricks decode as stored, `decode_stored`).
pub(crate) fn report(
    c: &Clustered,
    co: &vdbcook_cluster::Options,
    u: &Unclustered,
    decode_stored: &crate::errors::Decode,
    rmse_with: f64,
    advance: &crate::errors::Advance,
) -> Result<ClusterReport, crate::Error> {
    let channels = u.channels;
    let merged: Vec<usize> = (0..c.merged.len()).filter(|&i| c.merged[i]).collect();
    let pool = u.built.pool.bricks();
    let mut own = Store::<Brick>::with_policy(u.spill.cloned());
    let copy = |j: usize| {
        scanned_bricks(1);
        *pool.get(merged[j / channels], j % channels)
    };
    own.par_extend((0..merged.len() * channels).into_par_iter().map(copy), "the merged bricks")?;
    let own_masks: Option<Vec<[u64; 8]>> = u.masks.map(|m| merged.iter().map(|&i| m[i]).collect());
    let own = Bricks::dense(&own, channels);
    let own_enc = match u.max_error {
        None => Encoded::with_absent(u.specs.to_vec(), u.quality, own, own_masks.as_deref(), None, u.spill, &|_| {})?,
        Some(e) => {
            let mut choices = vdbcook_encode::Choices::new(channels, u.spill.cloned());
            choices.choose(own, own_masks.as_deref().unwrap_or(&[]), e, u.quality, u.disk, &|_| {})?;
            Encoded::from_choices(own, choices, &vec![true; merged.len()])
        }
    };
    let mut slot = vec![u32::MAX; c.merged.len()];
    for (k, &i) in merged.iter().enumerate() {
        slot[i] = k as u32;
    }
    let decode_unclustered = |b: u32, want: &[bool]| match slot.get(b as usize) {
        Some(&k) if k != u32::MAX => own_enc.decode_wanted(k as usize, want),
        _ => decode_stored(b, want),
    };
    let mut without = ErrorStats::default();
    for e in frame_errors(u.built, u.first, u.own, &decode_unclustered, advance)? {
        without.merge(&e[0]);
    }
    Ok(ClusterReport {
        clusters: co.clusters,
        iterations: co.iterations,
        variance_threshold: co.variance_threshold,
        max_brick_error: co.max_brick_error,
        stats: c.stats.clone(),
        ratio: c.stats.bricks_in as f64 / c.stats.bricks_out.max(1) as f64,
        rmse_without: without.rmse(),
        rmse_with,
        without,
    })
}
