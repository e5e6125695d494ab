//! Variance-gated k-means over a brick pool (seed thesis §4.5 and §5.3).
//!
//! 1. Every brick is a row of 512 values. Its normalised variance is its
//!    variance divided by its mean. Constant bricks and bricks whose
//!    normalised variance exceeds the threshold are never clustered
//!    (constant bricks are already stored once by the exact deduplication).
//! 2. k-means over the remaining bricks with the normalised Manhattan
//!    distance (mean absolute difference over the 512 values): k-means++
//!    seeding from a fixed seed, then `iterations` rounds of assignment
//!    (nearest centroid, ties to the lower index) and update (the mean of
//!    each cluster; an empty cluster keeps its centroid), then a final
//!    assignment.
//! 3. Beyond the thesis, `max_brick_error`: a brick whose largest absolute
//!    difference from its centroid exceeds it is kept as it is, so no voxel
//!    moves further than the bound the artist sets.
//!
//! Everything is deterministic whatever the thread count: distances are
//! summed in a fixed order, and cluster sums are reduced over fixed-size
//! chunks in index order.

use rayon::prelude::*;

pub const BRICK: usize = 512;
pub type Brick = [f32; BRICK];

/// Bricks per chunk in reductions (fixed, so results do not depend on threads).
const CHUNK: usize = 1024;

/// Items of N values a pass over the bricks reads between two calls of the
/// caller's `scanned` (about 16 MiB; a whole number of [`CHUNK`]s, so that
/// reductions chunk alike): a caller whose bricks live in a mapped file
/// drops their pages there, where a thread of its own would lag a scan.
fn scan_items<const N: usize>() -> usize {
    ((16 << 20) / (N * 4) / CHUNK).max(1) * CHUNK
}

/// The groups a pass over `items` reads between two calls of `scanned`:
/// whole [`CHUNK`]s, at most [`scan_items`] items, and spanning at most
/// about as many bytes of the caller's memory, so that items scattered over
/// a larger pool (the k-means candidates among all bricks) make smaller
/// groups, since the system maps a file's pages around each one read.
fn scan_groups<const N: usize>(items: &[&[f32; N]]) -> Vec<std::ops::Range<usize>> {
    let scan = scan_items::<N>();
    let bytes = scan * N * 4;
    let span = |c: &[&[f32; N]]| c.iter().fold((usize::MAX, 0), |(lo, hi), &b| (lo.min(b.as_ptr() as usize), hi.max(b.as_ptr() as usize + N * 4)));
    let mut groups: Vec<std::ops::Range<usize>> = Vec::new();
    let mut current: Option<(std::ops::Range<usize>, usize, usize)> = None;
    for (k, chunk) in items.chunks(CHUNK).enumerate() {
        let (lo, hi) = span(chunk);
        let range = k * CHUNK..k * CHUNK + chunk.len();
        current = match current {
            Some((r, glo, ghi)) if r.len() + chunk.len() <= scan && ghi.max(hi) - glo.min(lo) <= bytes => Some((r.start..range.end, glo.min(lo), ghi.max(hi))),
            Some((r, _, _)) => {
                groups.push(r);
                Some((range, lo, hi))
            }
            None => Some((range, lo, hi)),
        };
    }
    groups.extend(current.map(|(r, _, _)| r));
    groups
}

/// `f(i, &items[i])` for every item, in parallel, a group of
/// [`scan_groups`] at a time, `scanned()` after each group.
fn map_scanned<const N: usize, R: Send>(items: &[&[f32; N]], scanned: &(dyn Fn() + Sync), f: impl Fn(usize, &[f32; N]) -> R + Sync + Send) -> Vec<R> {
    let mut out = Vec::with_capacity(items.len());
    for g in scan_groups(items) {
        let first = g.start;
        out.par_extend(items[g].par_iter().enumerate().map(|(j, item)| f(first + j, item)));
        scanned();
    }
    out
}

#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// Number of centroids (k).
    pub clusters: usize,
    pub iterations: usize,
    /// Bricks with variance / mean above this are never clustered (default 0.01,
    /// the default of `cook --variance-threshold` and of a bake manifest).
    pub variance_threshold: f64,
    /// A clustered brick whose largest absolute difference from its centroid exceeds this stays unique.
    pub max_brick_error: Option<f32>,
    pub seed: u64,
}

impl Default for Options {
    fn default() -> Self {
        Options { clusters: 256, iterations: 5, variance_threshold: 0.01, max_brick_error: None, seed: 0x5eed }
    }
}

/// Why each brick ended up where it did.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Stats {
    pub bricks_in: usize,
    pub constant: usize,
    pub high_variance: usize,
    pub candidates: usize,
    /// Candidates kept unique because their centroid was too far (`max_brick_error`).
    pub over_error: usize,
    pub clustered: usize,
    /// Centroids at least one brick uses.
    pub centroids: usize,
    pub bricks_out: usize,
}

/// The clustered pool: its output bricks are the unclustered input bricks
/// in input order (`kept`), then the used centroids.  The kept bricks are
/// named, not copied, so that the caller decides where the output lives (a
/// cook's may spill to a file).
pub struct Clustered<const N: usize = BRICK> {
    /// The input bricks kept as they are, in order: output bricks `0..kept.len()`.
    pub kept: Vec<u32>,
    /// The centroids in use, in order: the output bricks after the kept ones.
    pub centroids: Vec<[f32; N]>,
    /// For every input brick, its output brick.
    pub remap: Vec<u32>,
    /// For every input brick, whether it was replaced by a centroid.
    pub merged: Vec<bool>,
    pub stats: Stats,
}

impl<const N: usize> Clustered<N> {
    /// Output bricks.
    pub fn len(&self) -> usize {
        self.kept.len() + self.centroids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Output brick `w` (`None` past the end), the kept ones read from `input`.
    pub fn brick<'a>(&'a self, input: &'a [&'a [f32; N]], w: usize) -> Option<&'a [f32; N]> {
        match self.kept.get(w) {
            Some(&i) => input.get(i as usize).copied(),
            None => self.centroids.get(w - self.kept.len()),
        }
    }
}

/// Mean absolute difference, accumulated in eight fixed lanes (the result
/// does not depend on `bound`); stops early, returning a value above `bound`,
/// once the partial sum exceeds it (or reaches it, when `strict` is false).
#[inline]
fn l1_bounded<const N: usize>(a: &[f32; N], b: &[f32; N], bound: f32, strict: bool) -> f32 {
    let bound = bound * N as f32;
    let mut total = 0.0f32;
    for (ca, cb) in a.chunks_exact(64).zip(b.chunks_exact(64)) {
        let mut lanes = [0.0f32; 8];
        for (xa, xb) in ca.chunks_exact(8).zip(cb.chunks_exact(8)) {
            for k in 0..8 {
                lanes[k] += (xa[k] - xb[k]).abs();
            }
        }
        total += lanes.iter().sum::<f32>();
        if total > bound || (!strict && total == bound && bound.is_finite()) {
            return total / N as f32;
        }
    }
    total / N as f32
}

/// Mean absolute difference of two bricks (the normalised Manhattan distance);
/// stops early with a value >= `bound` once it is certain to reach it.
#[inline]
pub fn l1<const N: usize>(a: &[f32; N], b: &[f32; N], bound: f32) -> f32 {
    l1_bounded(a, b, bound, false)
}

/// Nearest centroid (ties to the lower index) and its distance. Starting
/// from `hint` (the previous assignment) gives a tight bound at once, so most
/// other centroids are abandoned after a few values; the result is the same
/// as a plain scan.
fn nearest<const N: usize>(b: &[f32; N], centroids: &[[f32; N]], hint: u32) -> (u32, f32) {
    let hint = if (hint as usize) < centroids.len() { hint } else { 0 };
    let mut best = (hint, l1(b, &centroids[hint as usize], f32::INFINITY));
    for (i, c) in centroids.iter().enumerate() {
        let i = i as u32;
        if i == hint {
            continue;
        }
        // A lower index wins a tie, so it must be computed in full when equal.
        let lower = i < best.0;
        let d = l1_bounded(b, c, best.1, lower);
        if d < best.1 || (lower && d == best.1) {
            best = (i, d);
        }
    }
    best
}

/// Mean, variance, and whether every value is equal.
fn moments<const N: usize>(b: &[f32; N]) -> (f64, f64, bool) {
    let mean = b.iter().map(|&v| f64::from(v)).sum::<f64>() / N as f64;
    let var = b.iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / N as f64;
    (mean, var, b.iter().all(|&v| v.to_bits() == b[0].to_bits()))
}

/// Normalised variance (variance / mean); infinite when the mean is not positive.
pub fn normalized_variance<const N: usize>(b: &[f32; N]) -> f64 {
    let (mean, var, _) = moments(b);
    if var == 0.0 {
        0.0
    } else if mean > 0.0 {
        var / mean
    } else {
        f64::INFINITY
    }
}

/// SplitMix64: a small, seeded, portable generator.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Bricks k-means++ looks at per centroid: seeding runs on a seeded random
/// sample of `SEED_SAMPLE_PER_CLUSTER · k` bricks (all of them when fewer), so
/// its cost does not grow with the pool.
pub const SEED_SAMPLE_PER_CLUSTER: usize = 64;

/// k-means++ seeding on a sample: the first centroid uniformly, each next
/// one with probability proportional to the squared distance to the nearest
/// chosen centroid.
pub fn seed_centroids<const N: usize>(data: &[&[f32; N]], k: usize, seed: u64) -> Vec<[f32; N]> {
    seed_centroids_scanned(data, k, seed, &|| {})
}

/// Items read scattered over a caller's memory between two calls of its `scanned`.
const SCATTERED_PER_SCAN: usize = 8;

/// [`seed_centroids`], calling `scanned` as it copies its sample (see [`scan_items`]).
fn seed_centroids_scanned<const N: usize>(data: &[&[f32; N]], k: usize, seed: u64, scanned: &(dyn Fn() + Sync)) -> Vec<[f32; N]> {
    let mut rng = Rng(seed);
    if data.is_empty() || k == 0 {
        return Vec::new();
    }
    let want = k.saturating_mul(SEED_SAMPLE_PER_CLUSTER);
    let sample: Vec<&[f32; N]> = if data.len() <= want {
        data.to_vec()
    } else {
        // Partial Fisher-Yates over indices, then back to input order.
        let mut idx: Vec<usize> = (0..data.len()).collect();
        for i in 0..want {
            let j = i + (rng.next() % (data.len() - i) as u64) as usize;
            idx.swap(i, j);
        }
        idx.truncate(want);
        idx.sort_unstable();
        idx.into_iter().map(|i| data[i]).collect()
    };
    // Seeding passes over the sample once per centroid: a copy of its own
    // (at most `want` bricks), so that those passes read memory, not bricks
    // scattered over a caller's spilled pool, whose pages the system would
    // map in and around each one again on every pass. The copy reads them
    // scattered too, so it calls `scanned` after a few of them: the system
    // may map a large folio of the file around each one read (512 kB and
    // more seen on ext4), so a group of 512 mapped 240 MB.
    let mut copy: Vec<[f32; N]> = Vec::with_capacity(sample.len());
    for group in sample.chunks(SCATTERED_PER_SCAN) {
        copy.extend(group.iter().map(|&b| *b));
        scanned();
    }
    let sample: Vec<&[f32; N]> = copy.iter().collect();
    kmeans_pp(&sample, k, &mut rng)
}

fn kmeans_pp<const N: usize>(data: &[&[f32; N]], k: usize, rng: &mut Rng) -> Vec<[f32; N]> {
    let mut centroids: Vec<[f32; N]> = Vec::with_capacity(k);
    centroids.push(*data[(rng.next() % data.len() as u64) as usize]);
    let mut dist: Vec<f32> = data.par_iter().map(|b| l1(b, &centroids[0], f32::INFINITY)).collect();
    while centroids.len() < k {
        // Sum in fixed chunks, in order.
        let partial: Vec<f64> = dist.par_chunks(CHUNK).map(|c| c.iter().map(|&d| f64::from(d) * f64::from(d)).sum()).collect();
        let total: f64 = partial.iter().sum();
        if total <= 0.0 {
            break; // every brick coincides with a centroid
        }
        let mut target = rng.unit() * total;
        let mut pick = dist.len() - 1;
        'find: for (ci, &p) in partial.iter().enumerate() {
            if target >= p {
                target -= p;
                continue;
            }
            for (j, &d) in dist[ci * CHUNK..].iter().enumerate().take(CHUNK) {
                target -= f64::from(d) * f64::from(d);
                if target < 0.0 {
                    pick = ci * CHUNK + j;
                    break 'find;
                }
            }
        }
        let c = *data[pick];
        dist.par_iter_mut().zip(data.par_iter()).for_each(|(d, b)| *d = d.min(l1(b, &c, *d)));
        centroids.push(c);
    }
    centroids
}

/// Labels every brick with its nearest centroid; `previous` labels, when
/// given, only speed the search up.
pub fn assign<const N: usize>(data: &[&[f32; N]], centroids: &[[f32; N]], previous: Option<&[(u32, f32)]>) -> Vec<(u32, f32)> {
    assign_scanned(data, centroids, previous, &|| {})
}

/// [`assign`], calling `scanned` as it goes (see [`scan_groups`]).
fn assign_scanned<const N: usize>(data: &[&[f32; N]], centroids: &[[f32; N]], previous: Option<&[(u32, f32)]>, scanned: &(dyn Fn() + Sync)) -> Vec<(u32, f32)> {
    map_scanned(data, scanned, |i, b| nearest(b, centroids, previous.and_then(|p| p.get(i)).map_or(0, |&(h, _)| h)))
}

/// New centroids: the mean of each cluster's bricks (an empty cluster keeps its centroid).
pub fn update<const N: usize>(data: &[&[f32; N]], labels: &[(u32, f32)], centroids: &[[f32; N]]) -> Vec<[f32; N]> {
    update_scanned(data, labels, centroids, &|| {})
}

/// [`update`], calling `scanned` as it goes (see [`scan_groups`]).
fn update_scanned<const N: usize>(data: &[&[f32; N]], labels: &[(u32, f32)], centroids: &[[f32; N]], scanned: &(dyn Fn() + Sync)) -> Vec<[f32; N]> {
    let k = centroids.len();
    let mut partial: Vec<(Vec<f64>, Vec<u64>)> = Vec::new();
    for g in scan_groups(data) {
        let (data, labels) = (&data[g.clone()], &labels[g]);
        partial.par_extend(data.par_chunks(CHUNK).zip(labels.par_chunks(CHUNK)).map(|(bs, ls)| {
            let mut sums = vec![0.0f64; k * N];
            let mut counts = vec![0u64; k];
            for (b, &(l, _)) in bs.iter().zip(ls) {
                let l = l as usize;
                counts[l] += 1;
                for (s, &v) in sums[l * N..(l + 1) * N].iter_mut().zip(b.iter()) {
                    *s += f64::from(v);
                }
            }
            (sums, counts)
        }));
        scanned();
    }
    let mut sums = vec![0.0f64; k * N];
    let mut counts = vec![0u64; k];
    for (s, c) in &partial {
        for (a, b) in sums.iter_mut().zip(s) {
            *a += b;
        }
        for (a, b) in counts.iter_mut().zip(c) {
            *a += b;
        }
    }
    (0..k).map(|i| if counts[i] == 0 { centroids[i] } else { std::array::from_fn(|v| (sums[i * N + v] / counts[i] as f64) as f32) }).collect()
}

/// Runs the whole procedure; `progress(step, steps)` after each k-means round.
pub fn cluster(bricks: &[&Brick], opts: &Options, progress: &(dyn Fn(usize, usize) + Sync), scanned: &(dyn Fn() + Sync)) -> Clustered {
    cluster_scaled(bricks, opts, &[1.0], progress, scanned)
}

/// [`cluster`] over items of N values made of 512-value parts (several
/// channels of a brick, each divided by its own scale so that distances
/// weigh every channel alike): part `p`'s differences are multiplied by
/// `scale[p]` (1 past the end) before `max_brick_error` is applied, so the
/// bound stays in the channels' own units.
pub fn cluster_scaled<const N: usize>(bricks: &[&[f32; N]], opts: &Options, scale: &[f32], progress: &(dyn Fn(usize, usize) + Sync), scanned: &(dyn Fn() + Sync)) -> Clustered<N> {
    let n = bricks.len();
    let mut stats = Stats { bricks_in: n, ..Stats::default() };
    let kind: Vec<u8> = map_scanned(bricks, scanned, |_, b| {
        let (mean, var, constant) = moments(b);
        let nv = if var == 0.0 {
            0.0
        } else if mean > 0.0 {
            var / mean
        } else {
            f64::INFINITY
        };
        // A brick with a non-finite value has a NaN variance: kept as it
        // is, like high-variance bricks (no centroid can stand for it).
        if constant {
            0
        } else if nv.is_nan() || nv > opts.variance_threshold {
            1
        } else {
            2
        }
    });
    stats.constant = kind.iter().filter(|&&k| k == 0).count();
    stats.high_variance = kind.iter().filter(|&&k| k == 1).count();
    let cand: Vec<usize> = (0..n).filter(|&i| kind[i] == 2).collect();
    stats.candidates = cand.len();

    let mut label: Vec<Option<u32>> = vec![None; n];
    let mut centroids = Vec::new();
    if opts.clusters > 0 && cand.len() > opts.clusters {
        let data: Vec<&[f32; N]> = cand.iter().map(|&i| bricks[i]).collect();
        centroids = seed_centroids_scanned(&data, opts.clusters, opts.seed, scanned);
        let steps = opts.iterations + 1;
        let mut labels = assign_scanned(&data, &centroids, None, scanned);
        progress(1, steps);
        for it in 0..opts.iterations {
            centroids = update_scanned(&data, &labels, &centroids, scanned);
            labels = assign_scanned(&data, &centroids, Some(&labels), scanned);
            progress(it + 2, steps);
        }
        // The error bound, brick by brick: the largest voxel difference.
        let over: Vec<bool> = match opts.max_brick_error {
            None => vec![false; data.len()],
            Some(e) => map_scanned(&data, scanned, |j, b| {
                let centroid = &centroids[labels[j].0 as usize];
                b.iter().zip(centroid.iter()).enumerate().any(|(v, (x, c))| (x - c).abs() * scale.get(v / BRICK).copied().unwrap_or(1.0) > e)
            }),
        };
        for (j, &i) in cand.iter().enumerate() {
            if over[j] {
                stats.over_error += 1;
            } else {
                label[i] = Some(labels[j].0);
            }
        }
    }

    // Output: unclustered bricks in input order, then the centroids in use.
    let mut kept: Vec<u32> = Vec::new();
    let mut used: Vec<[f32; N]> = Vec::new();
    let mut remap = vec![0u32; n];
    let mut merged = vec![false; n];
    for i in 0..n {
        if label[i].is_none() {
            remap[i] = kept.len() as u32;
            kept.push(i as u32);
        }
    }
    let mut centroid_slot: Vec<Option<u32>> = vec![None; centroids.len()];
    for i in 0..n {
        if let Some(l) = label[i] {
            let slot = *centroid_slot[l as usize].get_or_insert_with(|| {
                used.push(centroids[l as usize]);
                (kept.len() + used.len() - 1) as u32
            });
            remap[i] = slot;
            merged[i] = true;
            stats.clustered += 1;
        }
    }
    stats.centroids = used.len();
    stats.bricks_out = kept.len() + used.len();
    Clustered { kept, centroids: used, remap, merged, stats }
}

#[cfg(test)]
mod tests;
