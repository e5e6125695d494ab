//! The first stage: frames pushed one at a time into the flip-book builder
//! (the union tree of the channels, exact brick deduplication, L3
//! interning), each frame's coarser levels filtered and pushed beside it.

use crate::{ChannelSpec, CookOptions, Error};
use rayon::prelude::*;
use std::time::Instant;
use vdbcook_flipbook::Builder;
use vdbcook_grid::lod::{self, Filter};
use vdbcook_grid::{Grid, GridClass, Transform};
use vdbcook_vpak::{FrameInfo, LevelFigures, SourceFile};

/// Streams frames into an asset: [`Cooker::push`] here, [`Cooker::finish`] in `assemble`.
pub struct Cooker {
    pub(crate) opts: CookOptions,
    pub(crate) channels: Vec<ChannelSpec>,
    /// Channel names and classes still to be taken from the first grid (single-channel cooks).
    infer: bool,
    pub(crate) builder: Builder,
    pub(crate) transform: Option<FirstTransform>,
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
        Cooker {
            opts,
            channels,
            infer: false,
            builder: Builder::new(n),
            transform: None,
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
        let transform = self.transform.as_ref().map(|t| {
            let file = self.frames.get(t.frame).and_then(|f| f.source).and_then(|s| self.sources.get(s as usize));
            let frame = self.first_frame + t.frame;
            let earlier = t.earlier.clone().unwrap_or_else(|| file.map_or_else(|| format!("frame {frame}"), |s| format!("frame {frame} ({})", s.path)));
            FirstTransform { earlier: Some(earlier), ..t.clone() }
        });
        Cooker {
            opts: self.opts.clone(),
            channels: self.channels.clone(),
            infer: self.infer,
            builder: self.builder.successor(),
            transform,
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

    /// Adds the next frame of a one-channel cook.
    pub fn push(&mut self, grid: &Grid, source: Option<SourceFile>) -> Result<(), Error> {
        self.push_channels(&[Some(grid)], source)
    }

    /// Adds the next frame: one grid per channel (`None`: empty in this frame).
    pub fn push_channels(&mut self, grids: &[Option<&Grid>], source: Option<SourceFile>) -> Result<(), Error> {
        let t0 = Instant::now();
        let frame = self.frames.len();
        for (c, g) in grids.iter().enumerate() {
            let Some(g) = g else { continue };
            match &self.transform {
                None => self.transform = Some(FirstTransform { frame, grid: g.name.clone(), transform: g.transform, earlier: None }),
                Some(first) if first.transform != g.transform => {
                    // Name the other frame by its file too: inputs are put in
                    // natural order, so it need not be the first one given.
                    let file = self.frames.get(first.frame).and_then(|f| f.source).and_then(|s| self.sources.get(s as usize));
                    let first_name = match file {
                        _ if first.earlier.is_some() => first.earlier.clone().unwrap_or_default(),
                        _ if first.frame == frame => "this frame".to_string(),
                        Some(s) => format!("frame {} ({})", first.frame, s.path),
                        None => format!("frame {}", first.frame),
                    };
                    return Err(Error::Transform {
                        grid: g.name.clone(),
                        found: transform_text(&g.transform),
                        first: first_name,
                        first_grid: first.grid.clone(),
                        expected: transform_text(&first.transform),
                    });
                }
                Some(_) => {}
            }
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
        let fs = self.builder.push(grids).map_err(|e| match e {
            // The caller names this frame and its file; name the grid.
            vdbcook_flipbook::Error::Background { channel, found, expected, .. } => {
                let grid = self.channels.get(channel).map_or_else(|| format!("channel {channel}"), |s| format!("grid \"{}\"", s.name));
                Error::Background { grid, found, expected }
            }
            e => e.into(),
        })?;
        for (acc, r) in self.ranges.iter_mut().zip(&fs.ranges) {
            if let Some([lo, hi]) = r {
                *acc = [acc[0].min(*lo), acc[1].max(*hi)];
            }
        }
        let coarse = self.push_levels(grids)?;
        let source = self.add_source(source);
        self.take_number();
        self.frames.push(FrameInfo { source, active_voxels: fs.active_voxels, leaves: fs.leaves as u32, tiles: fs.tiles as u32, coarse });
        self.build_secs += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// The filter of each channel's coarser levels, by its class.
    pub(crate) fn filters(&self) -> Vec<Filter> {
        self.channels.iter().map(|s| Filter::for_class(GridClass::from_vdb_name(&s.class))).collect()
    }

    /// Filters a frame's grids to levels 1 … levels − 1 (each from the one
    /// before) and pushes each level's tree.
    fn push_levels(&mut self, grids: &[Option<&Grid>]) -> Result<Vec<LevelFigures>, Error> {
        let levels = self.opts.levels.get();
        let t0 = Instant::now();
        let filters = self.filters();
        let mut figures = Vec::with_capacity(levels as usize - 1);
        let mut prev: Vec<Option<Grid>> = Vec::new();
        for k in 1..levels {
            let next: Vec<Option<Grid>> = grids
                .par_iter()
                .enumerate()
                .map(|(c, g)| {
                    let filter = filters.get(c).copied().unwrap_or(Filter::Mean);
                    match prev.get(c) {
                        Some(p) => p.as_ref().map(|p| lod::coarsen(p, filter)),
                        None => g.map(|g| lod::coarsen(g, filter)),
                    }
                })
                .collect();
            let refs: Vec<Option<&Grid>> = next.iter().map(Option::as_ref).collect();
            let fs = self.builder.push_level(k, &refs)?;
            figures.push(LevelFigures { active_voxels: fs.active_voxels, leaves: fs.leaves as u32, tiles: fs.tiles as u32 });
            prev = next;
        }
        self.level_secs += t0.elapsed().as_secs_f64();
        Ok(figures)
    }

    /// Adds an empty frame (a source without the grids, with `--allow-missing`).
    pub fn push_empty(&mut self, source: Option<SourceFile>) {
        self.builder.push_empty();
        let levels = self.opts.levels.get();
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
