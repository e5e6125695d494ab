//! Metadata: the asset's description of its frames, channels, planes and
//! levels, the section every reader starts from.

use crate::Cooker;
use vdbcook_encode::PlaneSpec;
use vdbcook_flipbook::Built;
use vdbcook_grid::lod::Filter;
use vdbcook_grid::Transform;
use vdbcook_vpak::{Channel, LevelFilter, Metadata, PlaneInfo};

/// Where the channels are stored.
pub(crate) struct Placement<'a> {
    pub(crate) specs: &'a [PlaneSpec],
    /// Per channel: its group, and its planes (the first, then its alternates).
    pub(crate) group_of: &'a [u32],
    pub(crate) planes_of: &'a [Vec<usize>],
    pub(crate) planes: Vec<PlaneInfo>,
    /// Bricks stored.
    pub(crate) bricks: usize,
}

impl Cooker {
    /// The metadata of the trees of `built` (finest level `first`), whose
    /// channels hold `value_ranges`.
    pub(crate) fn metadata(&self, built: &Built, first: u32, index_offset: [i32; 3], value_ranges: &[[f32; 2]], at: Placement) -> Metadata {
        let transform = self.transform.as_ref().map_or_else(Transform::identity, |f| f.transform);
        // Each channel's place: its (first) plane and first lane there.
        let place: Vec<(u32, u32)> = at
            .planes_of
            .iter()
            .enumerate()
            .map(|(c, planes)| {
                let p = planes.first().copied().unwrap_or(0);
                let slot = at.specs[p].channels.iter().position(|&k| k == c).unwrap_or(0) as u32;
                (p as u32, slot * at.specs[p].plane.z_per_texel)
            })
            .collect();
        Metadata {
            tool: concat!("vdbcook ", env!("CARGO_PKG_VERSION")).to_string(),
            frame_count: self.frames.len() as u32,
            map_type: transform.map_type.vdb_name().to_string(),
            transform: transform.matrix,
            index_offset,
            index_bbox: built.bbox.map(|b| (b.min.to_array(), b.max.to_array())),
            channels: self
                .channels
                .iter()
                .enumerate()
                .map(|(c, s)| Channel {
                    name: s.name.clone(),
                    grid: s.grid.clone(),
                    component: s.component,
                    value_type: s.value_type.clone(),
                    class: if s.class.is_empty() { "unknown".into() } else { s.class.clone() },
                    background: built.backgrounds[c],
                    value_range: value_ranges[c],
                    group: at.group_of[c],
                    plane: place[c].0,
                    lane: place[c].1,
                    alternates: at.planes_of[c].iter().skip(1).map(|&p| p as u32).collect(),
                })
                .collect(),
            planes: at.planes,
            brick_count: at.bricks as u32,
            settings: self.opts.settings.clone(),
            sources: self.sources.clone(),
            frames: self.frames.clone(),
            levels: self.levels(),
            level_filters: if self.levels() > 1 { self.filters().into_iter().map(level_filter).collect() } else { Vec::new() },
            first_level: first,
            time: Some(vdbcook_vpak::Time { fps: self.opts.fps.get(), numbers: self.numbers.clone() }),
            resolutions: self.resolutions(),
        }
    }

    /// Each channel's resolution; none recorded when all are the asset's own.
    pub(crate) fn resolutions(&self) -> Vec<vdbcook_vpak::Resolution> {
        let r: Vec<_> = self.placed.iter().map(|p| p.as_ref().map(|p| p.resolution).unwrap_or_default()).collect();
        match r.iter().all(|r| *r == Default::default()) {
            true => Vec::new(),
            false => r,
        }
    }

    /// Each channel's value range: over its source values, or its background when it has none.
    pub(crate) fn value_ranges(&self, built: &Built, channels: usize) -> Vec<[f32; 2]> {
        (0..channels).map(|c| if self.ranges[c][0] <= self.ranges[c][1] { self.ranges[c] } else { [built.backgrounds[c]; 2] }).collect()
    }
}

fn level_filter(f: Filter) -> LevelFilter {
    match f {
        Filter::Mean => LevelFilter::Mean,
        Filter::ActiveMean => LevelFilter::ActiveMean,
    }
}
