//! The first stage: frames pushed one at a time into the flip-book builder
//! (the union tree of the channels, exact brick deduplication, L3
//! interning), each frame's coarser levels filtered and pushed beside it.

use crate::{ChannelSpec, CookOptions, Error};
use rayon::prelude::*;
use std::time::Instant;
use vdbcook_flipbook::Builder;
use vdbcook_grid::lod::{self, Filter};
use vdbcook_grid::{Grid, GridClass, Transform};
use vdbcook_vpak::resolution::voxel_size_text;
use vdbcook_vpak::{FrameInfo, LevelFigures, Resolution, SourceFile, MAX_LEVELS};

/// Streams frames into an asset: [`Cooker::push`] here, [`Cooker::finish`] in `assemble`.
pub struct Cooker {
    pub(crate) opts: CookOptions,
    pub(crate) channels: Vec<ChannelSpec>,
    /// Channel names and classes still to be taken from the first grid (single-channel cooks).
    infer: bool,
    pub(crate) builder: Builder,
    pub(crate) transform: Option<FirstTransform>,
    /// Per channel, once its first grid is seen: that grid's transform and
    /// where its voxels are in the asset's.
    pub(crate) placed: Vec<Option<Placed>>,
    /// Levels of the trees: the coarsest channel's level plus the levels of
    /// detail asked for (set by the first frame with grids).
    pub(crate) tree_levels: Option<u32>,
    pub(crate) frames: Vec<FrameInfo>,
    pub(crate) sources: Vec<SourceFile>,
    pub(crate) ranges: Vec<[f32; 2]>,
    pub(crate) build_secs: f64,
    /// Time spent filtering and pushing the coarser levels.
    pub(crate) level_secs: f64,
    /// The number of this cooker's first frame in the whole sequence (0 but for later segments).
    pub(crate) first_frame: usize,
    /// Per frame, its number in the source sequence ([`Cooker::number_next`]).
    pub(crate) numbers: Vec<i64>,
    /// The number of the frame pushed next, when the caller gave one.
    next_number: Option<i64>,
    /// The last frame number of the segments before this one's.
    number_before: Option<i64>,
}

/// The asset's transform and the grid that set it.
#[derive(Clone, Debug)]
pub(crate) struct FirstTransform {
    frame: usize,
    grid: String,
    pub(crate) transform: Transform,
    /// How errors name the frame that set it, when it was in an earlier segment.
    earlier: Option<String>,
}

/// A channel's own transform, the grid and frame that set it, and where its voxels are.
#[derive(Clone, Debug)]
pub(crate) struct Placed {
    pub(crate) first: FirstTransform,
    pub(crate) resolution: Resolution,
}

fn transform_text(t: &Transform) -> String {
    format!("{} {:?}", t.map_type.vdb_name(), t.matrix)
}

impl Cooker {
    /// A cooker of one channel, named after the first grid pushed.
    pub fn new(opts: CookOptions) -> Cooker {
        let mut c = Cooker::with_channels(opts, vec![ChannelSpec { value_type: "float".into(), ..ChannelSpec::default() }]);
        c.infer = true;
        c
    }

    /// A cooker of the given channels (one grid each per frame).
    pub fn with_channels(opts: CookOptions, channels: Vec<ChannelSpec>) -> Cooker {
        let n = channels.len().max(1);
        let mut builder = Builder::new(n);
        builder.spill_to(opts.spill.clone());
        Cooker {
            opts,
            channels,
            infer: false,
            builder,
            transform: None,
            placed: vec![None; n],
            tree_levels: None,
            frames: Vec::new(),
            sources: Vec::new(),
            ranges: vec![[f32::INFINITY, f32::NEG_INFINITY]; n],
            build_secs: 0.0,
            level_secs: 0.0,
            first_frame: 0,
            numbers: Vec::new(),
            next_number: None,
            number_before: None,
        }
    }

    /// A cooker for the frames after this one's, the next segment of the
    /// sequence: the same options and channels, held to the transform and the
    /// backgrounds of the frames before; `first_frame` is its first frame's
    /// number in the whole sequence (what errors call it).
    pub fn next_segment(&self, first_frame: usize) -> Cooker {
        let carry = |t: &FirstTransform| {
            let file = self.frames.get(t.frame).and_then(|f| f.source).and_then(|s| self.sources.get(s as usize));
            let frame = self.first_frame + t.frame;
            let earlier = t.earlier.clone().unwrap_or_else(|| file.map_or_else(|| format!("frame {frame}"), |s| format!("frame {frame} ({})", s.path)));
            FirstTransform { earlier: Some(earlier), ..t.clone() }
        };
        Cooker {
            opts: self.opts.clone(),
            channels: self.channels.clone(),
            infer: self.infer,
            builder: self.builder.successor(),
            transform: self.transform.as_ref().map(carry),
            placed: self.placed.iter().map(|p| p.as_ref().map(|p| Placed { first: carry(&p.first), resolution: p.resolution })).collect(),
            tree_levels: self.tree_levels,
            frames: Vec::new(),
            sources: Vec::new(),
            ranges: vec![[f32::INFINITY, f32::NEG_INFINITY]; self.ranges.len()],
            build_secs: 0.0,
            level_secs: 0.0,
            first_frame,
            numbers: Vec::new(),
            next_number: None,
            number_before: self.last_number(),
        }
    }

    /// Gives the next frame pushed its number in the source sequence
    /// (`fire_1001.vdb`: 1001); numbers must increase. Without one, a frame's
    /// number is its index in the whole sequence.
    pub fn number_next(&mut self, number: i64) -> Result<(), Error> {
        match self.last_number() {
            Some(after) if number <= after => Err(Error::FrameNumber { number, after }),
            _ => {
                self.next_number = Some(number);
                Ok(())
            }
        }
    }

    /// The number of the last frame pushed, in this segment or before.
    fn last_number(&self) -> Option<i64> {
        self.numbers.last().copied().or(self.number_before)
    }

    /// Takes the number of the frame being pushed.
    fn take_number(&mut self) {
        let n = self.next_number.take().unwrap_or_else(|| self.last_number().map_or(self.first_frame as i64, |l| l.saturating_add(1)));
        self.numbers.push(n);
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

    /// Records files the frame just pushed was also read from (several files
    /// per frame: `cook --with`): listed among the sources, each once; a
    /// frame names only its main file.
    pub fn add_sources(&mut self, extra: impl IntoIterator<Item = SourceFile>) {
        for s in extra {
            self.add_source(Some(s));
        }
    }

    /// Adds the next frame of a one-channel cook.
    pub fn push(&mut self, grid: &Grid, source: Option<SourceFile>) -> Result<(), Error> {
        self.push_channels(&[Some(grid)], source)
    }

    /// How errors name the frame that set `t`.
    fn frame_text(&self, t: &FirstTransform, frame: usize) -> String {
        // Name the other frame by its file too: inputs are put in natural
        // order, so it need not be the first one given.
        let file = self.frames.get(t.frame).and_then(|f| f.source).and_then(|s| self.sources.get(s as usize));
        match file {
            _ if t.earlier.is_some() => t.earlier.clone().unwrap_or_default(),
            _ if t.frame == frame => "this frame".to_string(),
            Some(s) => format!("frame {} ({})", t.frame, s.path),
            None => format!("frame {}", t.frame),
        }
    }

    /// Checks each grid's transform: a channel keeps the transform of its
    /// first grid, and its voxels must be the asset's (the finest grid's of
    /// the first frame with grids) or 2, 4 or 8 times as wide, on a whole or
    /// half voxel of the asset's.
    fn place(&mut self, grids: &[Option<&Grid>]) -> Result<(), Error> {
        let frame = self.frames.len();
        if self.transform.is_none() {
            let volume = |g: &&Grid| g.transform.voxel_size().iter().product::<f64>();
            if let Some(g) = grids.iter().flatten().min_by(|a, b| volume(a).total_cmp(&volume(b))) {
                self.transform = Some(FirstTransform { frame, grid: g.name.clone(), transform: g.transform, earlier: None });
            }
        }
        let Some(asset) = &self.transform else {
            self.tree_levels.get_or_insert(self.opts.levels.get());
            return Ok(());
        };
        for (c, g) in grids.iter().enumerate() {
            let Some(g) = g else { continue };
            match self.placed.get(c).and_then(Option::as_ref) {
                Some(p) if p.first.transform != g.transform => {
                    return Err(Error::Transform {
                        grid: g.name.clone(),
                        found: transform_text(&g.transform),
                        first: self.frame_text(&p.first, frame),
                        first_grid: p.first.grid.clone(),
                        expected: transform_text(&p.first.transform),
                    })
                }
                Some(_) => {}
                None => {
                    let resolution = match asset.transform.relative_scale(&g.transform) {
                        Some((level, half)) => Resolution { level, half_offset: half.map(|h| h - ((1i32 << level) - 1)) },
                        None => {
                            return Err(Error::Resolution {
                                grid: g.name.clone(),
                                found: format!("voxel size {} ({})", voxel_size_text(g.transform.voxel_size()), transform_text(&g.transform)),
                                first: format!(
                                    "\"{}\" of {} voxel size {} ({})",
                                    asset.grid,
                                    self.frame_text(asset, frame),
                                    voxel_size_text(asset.transform.voxel_size()),
                                    transform_text(&asset.transform)
                                ),
                            })
                        }
                    };
                    let levels = resolution.level + self.opts.levels.get();
                    match self.tree_levels {
                        _ if levels > MAX_LEVELS => return Err(Error::TooManyLevels { grid: g.name.clone(), level: resolution.level, lods: self.opts.levels.get() }),
                        Some(t) if levels > t => return Err(Error::LateCoarseChannel { grid: g.name.clone(), level: resolution.level }),
                        _ => {}
                    }
                    if let Some(p) = self.placed.get_mut(c) {
                        *p = Some(Placed { first: FirstTransform { frame, grid: g.name.clone(), transform: g.transform, earlier: None }, resolution });
                    }
                }
            }
        }
        if self.tree_levels.is_none() {
            let coarsest = self.placed.iter().flatten().map(|p| p.resolution.level).max().unwrap_or(0);
            self.tree_levels = Some(coarsest + self.opts.levels.get());
        }
        Ok(())
    }

    /// Each channel's level (0 until its first grid is seen).
    pub(crate) fn channel_levels(&self) -> Vec<u32> {
        self.placed.iter().map(|p| p.as_ref().map_or(0, |p| p.resolution.level)).collect()
    }

    /// The levels at which each channel is stored when the finest stored is
    /// `first` (as `Metadata::channel_levels` reads them back): from its own
    /// level, or `first`, to its own plus the levels of detail asked for.
    pub(crate) fn stored_levels(&self, first: u32) -> Vec<std::ops::Range<u32>> {
        self.channel_levels().into_iter().map(|l| l.max(first)..l + self.opts.levels.get()).collect()
    }

    /// Levels of the trees of every frame (see `tree_levels`).
    pub(crate) fn levels(&self) -> u32 {
        self.tree_levels.unwrap_or(self.opts.levels.get())
    }

    /// Adds the next frame: one grid per channel (`None`: empty in this frame).
    /// A channel whose voxels are 2^k times the asset's is pushed at level k
    /// of the frame, and into the levels of detail from there.
    pub fn push_channels(&mut self, grids: &[Option<&Grid>], source: Option<SourceFile>) -> Result<(), Error> {
        let t0 = Instant::now();
        self.place(grids)?;
        for (c, g) in grids.iter().enumerate() {
            let Some(g) = g else { continue };
            if let Some(spec) = self.channels.get_mut(c) {
                if self.infer && spec.name.is_empty() {
                    spec.name = g.name.clone();
                    spec.grid = g.name.clone();
                }
                if spec.class.is_empty() {
                    spec.class = g.class.vdb_name().to_string();
                }
            }
        }
        let own = self.channel_levels();
        let at_level = |k: u32| -> Vec<Option<&Grid>> { grids.iter().zip(&own).map(|(g, &l)| if l == k { *g } else { None }).collect() };
        let fs = self.builder.push(&at_level(0)).map_err(|e| self.background_error(e))?;
        self.add_ranges(&fs.ranges, &own, 0);
        let coarse = self.push_levels(grids, &own)?;
        let source = self.add_source(source);
        self.take_number();
        self.frames.push(FrameInfo { source, active_voxels: fs.active_voxels, leaves: fs.leaves as u32, tiles: fs.tiles as u32, coarse });
        self.build_secs += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// The builder's background error, naming the grid (the caller names the frame and its file).
    fn background_error(&self, e: vdbcook_flipbook::Error) -> Error {
        match e {
            vdbcook_flipbook::Error::Background { channel, found, expected, .. } => {
                let grid = self.channels.get(channel).map_or_else(|| format!("channel {channel}"), |s| format!("grid \"{}\"", s.name));
                Error::Background { grid, found, expected }
            }
            e => e.into(),
        }
    }

    /// Takes in the value ranges of the channels whose own level is `level`.
    fn add_ranges(&mut self, ranges: &[Option<[f32; 2]>], own: &[u32], level: u32) {
        for ((acc, r), &l) in self.ranges.iter_mut().zip(ranges).zip(own) {
            if let (Some([lo, hi]), true) = (r, l == level) {
                *acc = [acc[0].min(*lo), acc[1].max(*hi)];
            }
        }
    }

    /// The filter of each channel's coarser levels, by its class.
    pub(crate) fn filters(&self) -> Vec<Filter> {
        self.channels.iter().map(|s| Filter::for_class(GridClass::from_vdb_name(&s.class))).collect()
    }

    /// Pushes levels 1 … levels − 1 of a frame: at level k, each channel
    /// whose own level is k as it is, the channels with finer own levels
    /// filtered from level k − 1 for as many levels of detail as asked for,
    /// and no other channel.
    fn push_levels(&mut self, grids: &[Option<&Grid>], own: &[u32]) -> Result<Vec<LevelFigures>, Error> {
        let levels = self.levels();
        let detail = self.opts.levels.get();
        let t0 = Instant::now();
        let filters = self.filters();
        let mut figures = Vec::with_capacity(levels as usize - 1);
        let mut prev: Vec<Option<Grid>> = vec![None; grids.len()];
        for k in 1..levels {
            let next: Vec<Option<Grid>> = grids
                .par_iter()
                .enumerate()
                .map(|(c, g)| {
                    let filter = filters.get(c).copied().unwrap_or(Filter::Mean);
                    let l = own.get(c).copied().unwrap_or(0);
                    match k {
                        _ if k <= l || k >= l + detail => None,
                        _ if k == l + 1 => g.map(|g| lod::coarsen(g, filter)),
                        _ => prev.get(c).and_then(Option::as_ref).map(|p| lod::coarsen(p, filter)),
                    }
                })
                .collect();
            let refs: Vec<Option<&Grid>> = next.iter().zip(grids.iter().zip(own)).map(|(n, (g, &l))| if l == k { *g } else { n.as_ref() }).collect();
            let fs = self.builder.push_level(k, &refs).map_err(|e| self.background_error(e))?;
            self.add_ranges(&fs.ranges, own, k);
            figures.push(LevelFigures { active_voxels: fs.active_voxels, leaves: fs.leaves as u32, tiles: fs.tiles as u32 });
            prev = next;
        }
        self.level_secs += t0.elapsed().as_secs_f64();
        Ok(figures)
    }

    /// Adds an empty frame (a source without the grids, with `--allow-missing`).
    pub fn push_empty(&mut self, source: Option<SourceFile>) {
        self.builder.push_empty();
        let levels = *self.tree_levels.get_or_insert(self.opts.levels.get());
        for k in 1..levels {
            self.builder.push_empty_level(k);
        }
        let source = self.add_source(source);
        self.take_number();
        self.frames.push(FrameInfo { source, active_voxels: 0, leaves: 0, tiles: 0, coarse: vec![LevelFigures::default(); levels as usize - 1] });
    }

    pub fn frame_count(&self) -> usize {
        self.frames.len()
    }
}
