//! [`Cooker::finish`]: the trees the cooker built, to an asset.  `assemble`
//! reads as its list of steps, each in a module of its own (NanoVDB's
//! `IndexGridBuilder::getHandle` → `processLeafs/Lower/Upper/Root/Grid` is
//! the model): format choice (`choose`), clustering (`cluster`), encoding
//! (`encode`), deduplication and remapping (`dedup`), node arrays (the
//! flip-book), atlases and tables (`layout`), metadata (`metadata`), then,
//! while the caller writes the sections, error figures (`errors`) and the
//! report (`report`).

use crate::layout::Laid;
use crate::metadata::Placement;
use crate::report::{Parts, SectionSizes, TreeFigures};
use crate::{choose, cluster, dedup, encode, errors, layout};
use crate::{BudgetReport, BudgetTry, CookReport, Cooker, Error, Progress, MAX_CLUSTER_CHANNELS};
use std::time::Instant;
use vdbcook_flipbook::Built;
use vdbcook_grid::spill::Charge;
use vdbcook_vpak::{kind, Metadata, Section};

/// Records how long stage `stage` took, since `t0`.
fn lap(timings: &mut Vec<(String, f64)>, stage: &str, t0: Instant) {
    timings.push((stage.into(), t0.elapsed().as_secs_f64()));
}

/// Where a cooker's sections go as soon as they are laid out, with their
/// metadata: the caller can write them while the error figures, which only
/// the report needs, are measured.
pub type Deliver<'a> = dyn FnMut(&Metadata, Vec<Section>) + 'a;

/// One assembly of the trees: larger than the byte budget (its file's
/// bytes; nothing delivered), or delivered and reported.
enum Assembled {
    Over(u64),
    Done(Box<CookReport>),
}

impl Cooker {
    /// Encodes, lays out and serialises the asset.
    /// Returns the asset's sections (write them with `vdbcook_vpak::write_file`) and the report.
    /// With `max_bytes`, the finest levels that fit are kept (see [`CookReport::budget`]).
    pub fn finish(self, progress: &dyn Progress) -> Result<(Vec<Section>, CookReport), Error> {
        self.finish_before(None, progress)
    }

    /// [`Cooker::finish`], and the memory of its bricks handed to `next`
    /// (the cooker of the next segment, before its first frame) to hold its own.
    pub fn finish_before(self, next: Option<&mut Cooker>, progress: &dyn Progress) -> Result<(Vec<Section>, CookReport), Error> {
        let mut sections = Vec::new();
        let report = self.finish_into(next, progress, &mut |_, s| sections = s)?;
        Ok((sections, report))
    }

    /// [`Cooker::finish_before`], the sections given to `deliver` (once)
    /// before the error figures are measured.
    pub fn finish_into(mut self, next: Option<&mut Cooker>, progress: &dyn Progress, deliver: &mut Deliver) -> Result<CookReport, Error> {
        let levels = self.opts.levels.get();
        let timings = vec![("build".to_string(), self.build_secs - self.level_secs), ("levels".to_string(), self.level_secs)];
        let mut built = std::mem::take(&mut self.builder).finish()?;
        let Some(budget) = self.opts.max_bytes else {
            let done = self.assemble(&built, 0, timings, progress, u64::MAX, deliver);
            if let Some(next) = next {
                next.builder.reuse(built.pool.take_storage());
            }
            return match done? {
                Assembled::Done(report) => Ok(*report),
                // No file has more bytes than u64::MAX.
                Assembled::Over(bytes) => Err(Error::OverBudget { budget: u64::MAX, smallest: bytes, level: 0 }),
            };
        };
        // Each try leaves out one more of the finest levels (and the bricks
        // only they used); the coarsest level always stays.
        let started = Instant::now();
        let mut tries = Vec::new();
        let mut candidate = built;
        for first in 0..levels {
            if first > 0 {
                candidate = candidate.from_level(first)?;
            }
            let t0 = Instant::now();
            match self.assemble(&candidate, first, timings.clone(), progress, budget, deliver)? {
                Assembled::Over(bytes) => tries.push(BudgetTry { first_level: first, bytes }),
                Assembled::Done(mut report) => {
                    tries.push(BudgetTry { first_level: first, bytes: report.file_bytes });
                    report.timings.push(("earlier tries".into(), (t0 - started).as_secs_f64()));
                    report.budget = Some(BudgetReport { max_bytes: budget, dropped: (0..first).collect(), tries });
                    return Ok(*report);
                }
            }
        }
        Err(Error::OverBudget { budget, smallest: tries.last().map_or(0, |t| t.bytes), level: levels - 1 })
    }

    /// Encodes, lays out and serialises the trees of `built`, whose finest level is `first`.
    /// Its sections go to `deliver` when the file is at most `budget` bytes.
    fn assemble(&self, built: &Built, first: u32, mut timings: Vec<(String, f64)>, progress: &dyn Progress, budget: u64, deliver: &mut Deliver) -> Result<Assembled, Error> {
        let opts = &self.opts;
        let channels = self.channels.len().max(1);
        let pool = built.pool.bricks();

        // Format choice: the planes of the channel groups' formats.
        let (specs, group_of) = choose::plan_planes(opts, &self.channels)?;
        if opts.clustering.is_some() && channels > MAX_CLUSTER_CHANNELS {
            return Err(Error::MultiChannelClustering(channels));
        }

        // Clustering: similar bricks merged into work bricks.
        let clustered = opts.clustering.as_ref().map(|co| {
            let t0 = Instant::now();
            let c = cluster::cluster(pool, &self.ranges, co, opts.spill.as_ref(), progress);
            lap(&mut timings, "cluster", t0);
            c
        });
        let mut clustered = clustered.transpose()?;

        // Encoding: the work bricks in their planes' formats, or each brick
        // channel in the cheapest format within the maximum error (strays
        // split off their clusters); then deduplication and remapping.
        let max_error = opts.max_error.map(crate::ErrorBound::get);
        // Each channel's stored levels: elsewhere its bricks hold nothing a reader samples.
        let stored_levels = self.stored_levels(first);
        let masks = encode::shown_masks(built, &specs, max_error, opts.spill.as_ref())?;
        let t0 = Instant::now();
        let encoded = match max_error {
            None => {
                let absent = encode::absent_channels(built, &stored_levels);
                encode::in_planes(pool, specs, opts.quality, masks.as_deref(), absent, clustered.as_ref(), opts.spill.as_ref(), progress)?
            }
            Some(bound) => {
                let choices = choose::per_brick(pool, masks.as_deref().unwrap_or(&[]), bound, opts, clustered.as_mut(), progress)?;
                encode::as_chosen(pool, choices, clustered.as_ref())
            }
        };
        encode::check_planes(&encoded)?;
        let mut stored = dedup::store(&encoded, clustered.as_ref())?;
        lap(&mut timings, "encode", t0);
        // What the stages from here hold per brick and node beside their
        // stores, counted against the spill budget so that the stores spill
        // sooner and memory stays near it however long the segment.
        let mut charge = Charge::new(opts.spill.clone());
        charge.set(encoded.table_bytes() + stored.heap_bytes());

        // Node arrays over the stored bricks.
        let t0 = Instant::now();
        progress.start("building nodes", built.frames.len() as u64);
        let nodes = built.nodes(|b| stored.remap.get(b as usize).copied().unwrap_or(0))?;
        progress.advance(built.frames.len() as u64);
        progress.finish();
        lap(&mut timings, "nodes", t0);
        charge.set(encoded.table_bytes() + stored.heap_bytes() + nodes.heap_bytes());

        // Layout: node arrays, brick ranges and tables, channel tables, atlases.
        let t0 = Instant::now();
        let planes_of = layout::planes_of(&encoded.specs, channels);
        // The node arrays move into their sections: what else needs of them, first.
        let (tree, index_offset) = (TreeFigures::of(&nodes), nodes.offset);
        let brick_tables = std::mem::take(&mut stored.tables);
        let Laid { mut sections, planes, plane_bytes, channel_table_bytes } = layout::lay_out(nodes, &encoded, &stored, brick_tables, opts.max_texture_dim, opts.spill.as_ref(), progress)?;
        // The brick tables and node arrays are sections now (stores under a spill policy, which count themselves).
        charge.set(encoded.table_bytes() + stored.heap_bytes());
        let value_ranges = self.value_ranges(built, channels);
        let peaks = errors::peaks(built, &value_ranges);
        let specs = encoded.specs.clone();

        // Metadata, the first section.
        let placement = Placement { specs: &specs, group_of: &group_of, planes_of: &planes_of, planes, bricks: stored.keep.len() };
        let meta = self.metadata(built, first, index_offset, &value_ranges, placement);
        sections.insert(0, Section { kind: kind::METADATA, index: 0, data: meta.to_bytes()?.into() });
        lap(&mut timings, "layout", t0);
        let sizes = SectionSizes::of(&sections);
        if sizes.file_bytes > budget {
            return Ok(Assembled::Over(sizes.file_bytes));
        }
        // Written by the caller meanwhile: the error figures are the report's alone.
        deliver(&meta, sections);

        // Error figures of what is stored, per tree and channel (and, with
        // clustering, what they would have been without).
        let t0 = Instant::now();
        let decode_stored = |b: u32, want: &[bool]| stored.decode(&encoded, b, want);
        let own: Vec<u32> = stored_levels.iter().map(|r| r.start).collect();
        // One pass, and with clustering one more for the figures without it.
        progress.start("measuring error", (errors::work(built) * (1 + usize::from(clustered.is_some()))) as u64);
        let advance = |n: usize| progress.advance(n as u64);
        let measured = errors::measure(built, first, self.levels(), &own, &decode_stored, &advance)?;
        let cluster_report = clustered
            .as_ref()
            .zip(opts.clustering.as_ref())
            .map(|(c, co)| {
                let without = cluster::Unclustered {
                    built,
                    first,
                    own: &own,
                    channels,
                    specs: &encoded.specs,
                    quality: opts.quality,
                    max_error,
                    disk: opts.disk,
                    masks: masks.as_deref(),
                    spill: opts.spill.as_ref(),
                };
                cluster::report(c, co, &without, &decode_stored, measured.totals[0].rmse(), &advance)
            })
            .transpose()?;
        progress.finish();
        lap(&mut timings, "error", t0);

        // The source-precision bricks are not needed any more.
        drop(encoded);
        drop(clustered);

        // The report.
        let parts = Parts {
            built,
            first,
            tree,
            meta: &meta,
            sections: sizes,
            stored_bricks: stored.keep.len(),
            specs: &specs,
            planes_of: &planes_of,
            plane_bytes: &plane_bytes,
            channel_table_bytes: &channel_table_bytes,
            measured: &measured,
            peaks: &peaks,
        };
        Ok(Assembled::Done(Box::new(self.report(parts, cluster_report, timings))))
    }
}
