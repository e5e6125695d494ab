//! The cooking pipeline, free of I/O and terminals: frames are pushed in one
//! at a time ([`Cooker::push`]), and [`Cooker::finish`] returns the bytes of
//! a `.vpak` asset and a [`CookReport`].  [`unpack_frame`] turns a frame of an
//! asset back into a [`Grid`].
//!
//! ```text
//! push(frame) ─▶ flipbook::Builder (exact brick dedup, L3 interning)
//! finish ─▶ encode bricks (parallel) ─▶ dedup encoded bricks ─▶ node arrays
//!        ─▶ atlases ─▶ vpak sections ─▶ bytes
//! ```

mod unpack;

pub use unpack::{load_nodes, unpack_frame};
pub use vdbcook_encode::{Format, Quality};

use rayon::prelude::*;
use std::time::Instant;
use vdbcook_encode::{Encodings, ErrorStats, Subset};
use vdbcook_flipbook::{Builder, Built, HashIndex, Nodes};
use vdbcook_grid::{Grid, Transform};
use vdbcook_vpak::{kind, AtlasInfo, FrameInfo, Metadata, Section, SourceFile};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Tree(#[from] vdbcook_flipbook::Error),
    #[error(transparent)]
    Asset(#[from] vdbcook_vpak::Error),
    #[error("frame {frame}: transform differs from the first frame's ({found} vs {expected})")]
    Transform { frame: usize, found: String, expected: String },
    #[error("the asset is inconsistent: {0}")]
    Corrupt(String),
    #[error("frame {frame} is out of range (the asset has {count} frames, numbered from 0)")]
    NoFrame { frame: usize, count: usize },
    #[error("unsupported voxel format \"{0}\"")]
    Format(String),
    #[error("frame {frame} unpacks to {leaves} leaves ({} MiB in memory), more than the {} MiB this machine has to spare", .bytes >> 20, .budget >> 20)]
    TooBig { frame: usize, leaves: u64, bytes: u64, budget: u64 },
}

/// Receives progress from long stages; every method does nothing by default.
pub trait Progress: Sync {
    fn start(&self, _stage: &str, _total: u64) {}
    fn advance(&self, _n: u64) {}
    fn finish(&self) {}
}

/// A [`Progress`] that reports nothing.
pub struct NoProgress;
impl Progress for NoProgress {}

#[derive(Clone, Debug)]
pub struct CookOptions {
    pub format: Format,
    /// BC7 encoder preset.
    pub quality: Quality,
    /// Largest 3D texture edge an atlas may use (wgpu's default limit is 2048).
    pub max_texture_dim: u32,
    /// Merge similar bricks with variance-gated k-means before encoding.
    pub clustering: Option<vdbcook_cluster::Options>,
    /// Every setting, recorded verbatim in the asset's metadata.
    pub settings: Vec<(String, String)>,
}

impl Default for CookOptions {
    fn default() -> Self {
        CookOptions { format: Format::F16, quality: Quality::VeryFast, max_texture_dim: 2048, clustering: None, settings: Vec::new() }
    }
}

/// What a cook did, for people and for `--json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CookReport {
    pub format: String,
    pub frames: usize,
    pub empty_frames: usize,
    pub active_voxels: u64,
    /// Leaves over all frames: the bricks a cooker without deduplication would store.
    pub bricks: u64,
    /// Distinct bricks after exact deduplication of the source values.
    pub unique_bricks: usize,
    /// Bricks stored in the atlases (after deduplicating encoded bricks too).
    pub stored_bricks: usize,
    pub l1_nodes: usize,
    pub l2_nodes: usize,
    pub l3_nodes: usize,
    pub tiles: usize,
    pub atlases: usize,
    /// (section name, bytes) in file order.
    pub sections: Vec<(String, u64)>,
    pub file_bytes: u64,
    /// Node arrays (frames, L1, L2, L3, entries, tiles) in bytes.
    pub tree_bytes: u64,
    /// What the seed thesis's layout needs for the same frames.
    pub thesis_tree_bytes: u64,
    pub bits_per_active_voxel: f64,
    pub value_range: [f32; 2],
    /// Voxel-domain error of the stored values against the source, over active voxels.
    pub voxel_rmse: f64,
    pub voxel_psnr: f64,
    pub voxel_max_error: f64,
    /// Per frame: (rmse, max error).
    pub frame_errors: Vec<(f64, f64)>,
    /// What clustering did, when it ran.
    pub clustering: Option<ClusterReport>,
    /// (stage, seconds).
    pub timings: Vec<(String, f64)>,
}

/// The thesis's Figure 19 table for one cook: bricks before (`bricks_in`) and
/// after (`bricks_out`), their ratio, and the voxel RMSE with and without clustering.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ClusterReport {
    pub clusters: usize,
    pub iterations: usize,
    pub variance_threshold: f64,
    pub max_brick_error: Option<f32>,
    #[serde(flatten)]
    pub stats: vdbcook_cluster::Stats,
    pub ratio: f64,
    pub rmse_without: f64,
    pub rmse_with: f64,
}

/// Streams frames into an asset.
pub struct Cooker {
    opts: CookOptions,
    builder: Builder,
    first: Option<(String, String, Transform)>,
    frames: Vec<FrameInfo>,
    sources: Vec<SourceFile>,
    range: [f32; 2],
    build_secs: f64,
}

fn transform_text(t: &Transform) -> String {
    format!("{} {:?}", t.map_type.vdb_name(), t.matrix)
}

impl Cooker {
    pub fn new(opts: CookOptions) -> Cooker {
        Cooker { opts, builder: Builder::new(), first: None, frames: Vec::new(), sources: Vec::new(), range: [f32::INFINITY, f32::NEG_INFINITY], build_secs: 0.0 }
    }

    /// Records a source file once (a file listed twice is one source).
    fn add_source(&mut self, source: Option<SourceFile>) -> Option<u32> {
        source.map(|s| match self.sources.iter().position(|o| *o == s) {
            Some(i) => i as u32,
            None => {
                self.sources.push(s);
                (self.sources.len() - 1) as u32
            }
        })
    }

    /// Adds the next frame.
    pub fn push(&mut self, grid: &Grid, source: Option<SourceFile>) -> Result<(), Error> {
        let t0 = Instant::now();
        let frame = self.frames.len();
        match &self.first {
            None => self.first = Some((grid.name.clone(), grid.class.vdb_name().to_string(), grid.transform)),
            Some((_, _, t)) if *t != grid.transform => {
                return Err(Error::Transform { frame, found: transform_text(&grid.transform), expected: transform_text(t) });
            }
            Some(_) => {}
        }
        let fs = self.builder.push(grid)?;
        if let Some([lo, hi]) = fs.range {
            self.range = [self.range[0].min(lo), self.range[1].max(hi)];
        }
        let source = self.add_source(source);
        self.frames.push(FrameInfo { source, active_voxels: fs.active_voxels, leaves: fs.leaves as u32, tiles: fs.tiles as u32 });
        self.build_secs += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// Adds an empty frame (a source without the grid, with `--allow-missing`).
    pub fn push_empty(&mut self, source: Option<SourceFile>) {
        self.builder.push_empty();
        let source = self.add_source(source);
        self.frames.push(FrameInfo { source, active_voxels: 0, leaves: 0, tiles: 0 });
    }

    pub fn frame_count(&self) -> usize {
        self.frames.len()
    }

    /// Encodes, lays out and serialises the asset.
    /// Returns the asset's sections (write them with `vdbcook_vpak::write_file`) and the report.
    pub fn finish(self, progress: &dyn Progress) -> Result<(Vec<Section>, CookReport), Error> {
        let mut timings = vec![("build".to_string(), self.build_secs)];
        let format = self.opts.format;
        let mut built = self.builder.finish()?;

        // Optionally merge similar bricks; then encode every brick and store
        // identical encodings once.
        let pool = built.pool.bricks();
        let clustered = self.opts.clustering.as_ref().map(|co| {
            let t0 = Instant::now();
            progress.start("clustering", co.iterations as u64 + 1);
            let c = vdbcook_cluster::cluster(pool, co, &|_, _| progress.advance(1));
            progress.finish();
            timings.push(("cluster".into(), t0.elapsed().as_secs_f64()));
            c
        });
        let work: &[vdbcook_flipbook::Brick] = clustered.as_ref().map_or(pool, |c| &c.bricks[..]);
        // Which voxels of each brick some L3 node shows (block encoders may
        // spend nothing on the others).
        let pool_masks = format.is_block().then(|| union_masks(pool.len(), built.l3.iter().map(|l| (l.brick as usize, l.mask))));
        let work_masks = pool_masks.as_ref().map(|m| match &clustered {
            Some(c) => union_masks(work.len(), c.remap.iter().zip(m).map(|(&w, &mask)| (w as usize, mask))),
            None => m.clone(),
        });
        let t0 = Instant::now();
        progress.start("encoding", work.len() as u64);
        let encoded = vdbcook_encode::encodings(format, self.opts.quality, work, work_masks.as_deref(), &|n| progress.advance(n as u64));
        progress.finish();
        let (keep, enc_remap) = dedup_encoded(&*encoded);
        let stored = Subset { inner: &*encoded, keep: &keep };
        // Pool brick -> stored brick.
        let remap: Vec<u32> = match &clustered {
            Some(c) => c.remap.iter().map(|&w| enc_remap[w as usize]).collect(),
            None => enc_remap,
        };
        timings.push(("encode".into(), t0.elapsed().as_secs_f64()));

        // Node arrays over the final brick ids.
        let t0 = Instant::now();
        progress.start("building nodes", built.frames.len() as u64);
        let nodes = built.nodes(|b| remap.get(b as usize).copied().unwrap_or(0))?;
        progress.finish();
        timings.push(("nodes".into(), t0.elapsed().as_secs_f64()));

        // Voxel-domain error of what is stored, per frame (and, with
        // clustering, what it would have been without: merged bricks encoded
        // on their own).
        let t0 = Instant::now();
        let decode_stored = |b: u32| remap.get(b as usize).and_then(|&i| stored.decode(i as usize));
        let frame_err = voxel_errors(&built, &decode_stored);
        let mut total = ErrorStats::default();
        for e in &frame_err {
            total.merge(e);
        }
        let cluster_report = clustered.as_ref().zip(self.opts.clustering.as_ref()).map(|(c, co)| {
            let merged: Vec<usize> = (0..c.merged.len()).filter(|&i| c.merged[i]).collect();
            let own: Vec<vdbcook_flipbook::Brick> = merged.iter().map(|&i| pool[i]).collect();
            let own_masks: Option<Vec<[u64; 8]>> = pool_masks.as_ref().map(|m| merged.iter().map(|&i| m[i]).collect());
            let own_enc = vdbcook_encode::encodings(format, self.opts.quality, &own, own_masks.as_deref(), &|_| {});
            let mut slot = vec![u32::MAX; c.merged.len()];
            for (k, &i) in merged.iter().enumerate() {
                slot[i] = k as u32;
            }
            let decode_unclustered = |b: u32| match slot.get(b as usize) {
                Some(&k) if k != u32::MAX => own_enc.decode(k as usize),
                _ => decode_stored(b),
            };
            let mut without = ErrorStats::default();
            for e in voxel_errors(&built, &decode_unclustered) {
                without.merge(&e);
            }
            ClusterReport {
                clusters: co.clusters,
                iterations: co.iterations,
                variance_threshold: co.variance_threshold,
                max_brick_error: co.max_brick_error,
                stats: c.stats.clone(),
                ratio: c.stats.bricks_in as f64 / c.stats.bricks_out.max(1) as f64,
                rmse_without: without.rmse(),
                rmse_with: total.rmse(),
            }
        });
        timings.push(("error".into(), t0.elapsed().as_secs_f64()));

        let unique_bricks = built.pool.len();
        let t0 = Instant::now();
        let layouts = vdbcook_encode::plan_atlases(format, stored.len() as u32, self.opts.max_texture_dim);
        let mut sections = node_sections(&nodes);
        let ranges: Vec<u32> = (0..stored.len()).flat_map(|i| stored.range(i).unwrap_or_default().map(f32::to_bits)).collect();
        sections.push(Section { kind: kind::BRICK_RANGES, index: 0, data: words(&ranges) });
        for (i, l) in layouts.iter().enumerate() {
            sections.push(Section { kind: kind::ATLAS, index: i as u32, data: vdbcook_encode::pack_atlas(l, &stored) });
        }
        let stored_bricks = stored.len();
        // The source-precision bricks are not needed any more.
        drop(encoded);
        drop(clustered);
        drop(std::mem::take(&mut built.pool));
        let (grid_name, grid_class, transform) = self.first.clone().unwrap_or_else(|| (String::new(), "unknown".into(), Transform::identity()));
        let range = if self.range[0] <= self.range[1] { self.range } else { [built.background; 2] };
        let meta = Metadata {
            tool: concat!("vdbcook ", env!("CARGO_PKG_VERSION")).to_string(),
            format: format.name().to_string(),
            frame_count: self.frames.len() as u32,
            grid_name,
            grid_class,
            map_type: transform.map_type.vdb_name().to_string(),
            transform: transform.matrix,
            index_offset: nodes.offset.to_array(),
            index_bbox: built.bbox.map(|b| (b.min.to_array(), b.max.to_array())),
            background: built.background,
            value_range: range,
            brick_count: stored_bricks as u32,
            atlases: layouts.iter().map(|l| AtlasInfo { bricks: l.bricks, texels: l.texels(), first_brick: l.first_brick, count: l.count }).collect(),
            settings: self.opts.settings.clone(),
            sources: self.sources.clone(),
            frames: self.frames.clone(),
        };
        sections.insert(0, Section { kind: kind::METADATA, index: 0, data: meta.to_bytes()? });
        let report_sections: Vec<(String, u64)> =
            sections.iter().map(|s| (if s.kind == kind::ATLAS { format!("{} {}", kind::name(s.kind), s.index) } else { kind::name(s.kind).to_string() }, s.data.len() as u64)).collect();
        let file_bytes = vdbcook_vpak::file_len(&sections);
        timings.push(("layout".into(), t0.elapsed().as_secs_f64()));

        let tree_bytes: u64 = nodes.byte_sizes().iter().map(|(_, b)| *b as u64).sum();
        let active: u64 = self.frames.iter().map(|f| f.active_voxels).sum();
        let peak = f64::from(range[1] - range[0]);
        let report = CookReport {
            format: format.name().into(),
            frames: self.frames.len(),
            empty_frames: self.frames.iter().filter(|f| f.leaves == 0 && f.tiles == 0).count(),
            active_voxels: active,
            bricks: built.leaves_in,
            unique_bricks,
            stored_bricks,
            l1_nodes: nodes.l1_count(),
            l2_nodes: nodes.l2_count(),
            l3_nodes: nodes.l3_count(),
            tiles: nodes.tiles.len() / 2,
            atlases: layouts.len(),
            sections: report_sections,
            file_bytes,
            tree_bytes,
            thesis_tree_bytes: vdbcook_flipbook::thesis_tree_bytes(self.frames.len(), built.leaves_in),
            bits_per_active_voxel: if active > 0 { file_bytes as f64 * 8.0 / active as f64 } else { 0.0 },
            value_range: range,
            voxel_rmse: total.rmse(),
            voxel_psnr: total.psnr(if peak > 0.0 { peak } else { 1.0 }),
            voxel_max_error: total.max_abs,
            frame_errors: frame_err.iter().map(|e| (e.rmse(), e.max_abs)).collect(),
            clustering: cluster_report,
            timings,
        };
        Ok((sections, report))
    }
}

/// Per item `0..n`, the union of the masks given for it.
fn union_masks(n: usize, masks: impl Iterator<Item = (usize, [u64; 8])>) -> Vec<[u64; 8]> {
    let mut out = vec![[0u64; 8]; n];
    for (i, m) in masks {
        if let Some(o) = out.get_mut(i) {
            for (o, m) in o.iter_mut().zip(m) {
                *o |= m;
            }
        }
    }
    out
}

/// Finds the distinct encodings (the first of equal ones, in order):
/// returns their indices and, per pool brick, its stored index.
fn dedup_encoded(encoded: &dyn Encodings) -> (Vec<usize>, Vec<u32>) {
    let n = encoded.format().brick_bytes();
    let write = |i: usize, buf: &mut [u8; vdbcook_encode::MAX_BRICK_BYTES]| {
        encoded.write(i, &mut buf[..n]);
    };
    // A brick's hash covers its bytes and its range.
    let ranges: Vec<[u32; 2]> = (0..encoded.len()).map(|i| encoded.range(i).unwrap_or_default().map(f32::to_bits)).collect();
    let hashes: Vec<u64> = (0..encoded.len())
        .into_par_iter()
        .map_init(
            || [0u8; vdbcook_encode::MAX_BRICK_BYTES],
            |buf, i| {
                write(i, buf);
                let [lo, hi] = ranges[i];
                xxhash_rust::xxh3::xxh3_64_with_seed(&buf[..n], u64::from(lo) << 32 | u64::from(hi))
            },
        )
        .collect();
    let mut index = HashIndex::default();
    index.reserve(encoded.len());
    let mut keep: Vec<usize> = Vec::new();
    let mut remap = Vec::with_capacity(encoded.len());
    for (i, &h) in hashes.iter().enumerate() {
        let same = |k: u32| {
            let j = keep[k as usize];
            if ranges[j] != ranges[i] {
                return false;
            }
            // Equal hashes are rare: encode both again to compare.
            let (mut x, mut y) = ([0u8; vdbcook_encode::MAX_BRICK_BYTES], [0u8; vdbcook_encode::MAX_BRICK_BYTES]);
            write(j, &mut x);
            write(i, &mut y);
            x[..n] == y[..n]
        };
        let id = match index.find(h, same) {
            Some(k) => k,
            None => {
                let k = keep.len() as u32;
                index.add(h, k);
                keep.push(i);
                k
            }
        };
        remap.push(id);
    }
    (keep, remap)
}

/// Error of decoded bricks (`decoded(pool brick)`) against the source over
/// each frame's active voxels.
fn voxel_errors(built: &Built, decoded: &(dyn Fn(u32) -> Option<[f32; 512]> + Sync)) -> Vec<ErrorStats> {
    // Per L3 node: its error over its own active voxels.
    let per_l3: Vec<ErrorStats> = built
        .l3
        .par_iter()
        .map(|l| {
            let mut e = ErrorStats::default();
            if let (Some(src), Some(dec)) = (built.pool.bricks().get(l.brick as usize), decoded(l.brick)) {
                e.add_masked(src, &dec, &l.mask);
            }
            e
        })
        .collect();
    built
        .frames
        .iter()
        .map(|f| {
            let mut e = ErrorStats::default();
            for &(_, id) in &f.leaves {
                e.merge(&per_l3[id as usize]);
            }
            e
        })
        .collect()
}

/// Little-endian bytes of `u32`s (a plain copy on little-endian machines).
fn words(v: &[u32]) -> Vec<u8> {
    if cfg!(target_endian = "little") {
        bytemuck::cast_slice(v).to_vec()
    } else {
        v.iter().flat_map(|w| w.to_le_bytes()).collect()
    }
}

fn node_sections(n: &Nodes) -> Vec<Section> {
    [
        (kind::FRAMES, &n.frames),
        (kind::L1_NODES, &n.l1),
        (kind::L1_ENTRIES, &n.l1_entries),
        (kind::L2_NODES, &n.l2),
        (kind::L2_ENTRIES, &n.l2_entries),
        (kind::L3_NODES, &n.l3),
        (kind::TILES, &n.tiles),
    ]
    .into_iter()
    .map(|(k, v)| Section { kind: k, index: 0, data: words(v) })
    .collect()
}

#[cfg(test)]
mod tests;
