//! The report of an asset cooked in segments: its segments' reports added
//! up, error figures from their sums (so they are what one measurement over
//! every frame would give).

use crate::report::{ClusterReport, FormatShare, Sums};
use crate::{CookReport, ErrorFigures};
use vdbcook_encode::ErrorStats;
use vdbcook_vpak::{union_names, Metadata};

fn union_range(a: [f32; 2], b: [f32; 2]) -> [f32; 2] {
    [a[0].min(b[0]), a[1].max(b[1])]
}

fn add_stats(acc: &mut [ErrorStats], more: &[ErrorStats]) {
    acc.iter_mut().zip(more).for_each(|(a, m)| a.merge(m));
}

/// Adds `(name, amount)` pairs up by name, in order of first appearance.
fn add_by_name<T: std::ops::AddAssign + Copy>(acc: &mut Vec<(String, T)>, more: &[(String, T)]) {
    for (n, v) in more {
        match acc.iter_mut().find(|(m, _)| m == n) {
            Some((_, a)) => *a += *v,
            None => acc.push((n.clone(), *v)),
        }
    }
}

impl CookReport {
    /// The report of an asset made of segments whose reports are `parts`
    /// (in order), whose metadata (the whole sequence's) is `metadata` and
    /// whose file is `file_bytes` long.
    pub fn merged(parts: Vec<CookReport>, metadata: Metadata, file_bytes: u64) -> Option<CookReport> {
        let mut parts = parts.into_iter();
        let mut r = parts.next()?;
        for p in parts {
            r.format = union_names(&r.format, &p.format);
            r.frames += p.frames;
            r.empty_frames += p.empty_frames;
            r.active_voxels += p.active_voxels;
            r.bricks += p.bricks;
            r.unique_bricks += p.unique_bricks;
            r.stored_bricks += p.stored_bricks;
            r.l1_nodes += p.l1_nodes;
            r.l2_nodes += p.l2_nodes;
            r.l3_nodes += p.l3_nodes;
            r.tiles += p.tiles;
            r.textures += p.textures;
            add_by_name(&mut r.sections, &p.sections);
            add_by_name(&mut r.disk_sections, &p.disk_sections);
            r.gpu_bytes += p.gpu_bytes;
            r.tree_bytes += p.tree_bytes;
            r.value_range = union_range(r.value_range, p.value_range);
            r.non_finite_voxels += p.non_finite_voxels;
            r.frame_errors.extend(p.frame_errors);
            for (l, pl) in r.levels.iter_mut().zip(&p.levels) {
                l.leaves += pl.leaves;
                l.tiles += pl.tiles;
                l.active_voxels += pl.active_voxels;
            }
            for (c, pc) in r.channels.iter_mut().zip(p.channels) {
                c.format = union_names(&c.format, &pc.format);
                c.bytes += pc.bytes;
                c.bricks += pc.bricks;
                c.value_range = union_range(c.value_range, pc.value_range);
                c.non_finite.merge(&pc.non_finite);
                for f in pc.formats {
                    match c.formats.iter_mut().find(|g| g.format == f.format) {
                        Some(g) => {
                            g.bricks += f.bricks;
                            g.bytes += f.bytes;
                        }
                        None => c.formats.push(FormatShare { ..f }),
                    }
                }
            }
            r.clustering = match (r.clustering.take(), p.clustering) {
                (Some(a), Some(b)) => Some(merge_clustering(a, b)),
                (a, b) => a.or(b),
            };
            add_by_name(&mut r.timings, &p.timings);
            r.spilled_bytes = r.spilled_bytes.max(p.spilled_bytes);
            r.segments.extend(p.segments);
            r.sums.add(&p.sums);
        }
        r.sums.take_peaks(&metadata);
        if let Some(e) = r.sums.worst() {
            r.error = e;
        }
        let Sums { totals, levels, peaks } = &r.sums;
        let psnr = |stats: &[ErrorStats], c: usize| stats[c].psnr(peaks[c]);
        let worst = |stats: &[ErrorStats]| (0..stats.len()).min_by(|&a, &b| psnr(stats, a).total_cmp(&psnr(stats, b))).unwrap_or(0);
        for (c, ch) in r.channels.iter_mut().enumerate() {
            if let (Some(t), Some(&p)) = (totals.get(c), peaks.get(c)) {
                ch.error = ErrorFigures::of(t, p);
            }
        }
        for (l, stats) in r.levels.iter_mut().zip(levels) {
            if !stats.is_empty() {
                let w = worst(stats);
                l.error = ErrorFigures::of(&stats[w], peaks[w]);
            }
        }
        if let (Some(c), Some(t)) = (r.clustering.as_mut(), totals.first()) {
            c.rmse_with = t.rmse();
        }
        r.file_bytes = file_bytes;
        r.thesis_tree_bytes = vdbcook_flipbook::thesis_tree_bytes(r.frames, r.bricks);
        r.bits_per_active_voxel = if r.active_voxels > 0 { file_bytes as f64 * 8.0 / r.active_voxels as f64 } else { 0.0 };
        r.metadata = metadata;
        Some(r)
    }
}

impl Sums {
    /// Adds a later segment's sums (in segment order: the float sums depend on it).
    fn add(&mut self, p: &Sums) {
        add_stats(&mut self.totals, &p.totals);
        for (l, pl) in self.levels.iter_mut().zip(&p.levels) {
            add_stats(l, pl);
        }
        self.peaks.iter_mut().zip(&p.peaks).for_each(|(a, b)| *a = a.max(*b));
    }

    /// Peaks: the span of the whole sequence's range where it is finite and not empty.
    fn take_peaks(&mut self, metadata: &Metadata) {
        for (peak, ch) in self.peaks.iter_mut().zip(&metadata.channels) {
            let span = f64::from(ch.value_range[1] - ch.value_range[0]);
            if span > 0.0 && span.is_finite() {
                *peak = span;
            }
        }
    }

    /// The figures of the channel of lowest PSNR (none without channels).
    fn worst(&self) -> Option<ErrorFigures> {
        let psnr = |c: usize| self.totals[c].psnr(self.peaks[c]);
        let w = (0..self.totals.len()).min_by(|&a, &b| psnr(a).total_cmp(&psnr(b)))?;
        Some(ErrorFigures::of(&self.totals[w], self.peaks[w]))
    }

    /// The error figures of a sequence from its segments' sums (in order)
    /// and its whole metadata: what [`CookReport::merged`] gives the cook of
    /// every segment in one process, to the bit, however the segments were
    /// cooked (`bake` joins parts so).
    pub fn sequence_error(segments: &[Sums], metadata: &Metadata) -> Option<ErrorFigures> {
        let (first, rest) = segments.split_first()?;
        let mut s = first.clone();
        rest.iter().for_each(|p| s.add(p));
        s.take_peaks(metadata);
        s.worst()
    }
}

fn merge_clustering(mut a: ClusterReport, b: ClusterReport) -> ClusterReport {
    let (s, t) = (&mut a.stats, &b.stats);
    s.bricks_in += t.bricks_in;
    s.constant += t.constant;
    s.high_variance += t.high_variance;
    s.candidates += t.candidates;
    s.over_error += t.over_error;
    s.clustered += t.clustered;
    s.centroids += t.centroids;
    s.bricks_out += t.bricks_out;
    a.ratio = s.bricks_in as f64 / s.bricks_out.max(1) as f64;
    a.without.merge(&b.without);
    a.rmse_without = a.without.rmse();
    a
}
