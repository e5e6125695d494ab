//! An asset on the GPU a segment at a time: the segment holding the frame
//! drawn last is resident, and each segment is drawn in its own index space
//! (the scene and views shifted from the scene's to the segment's offset).

use crate::{Error, GpuAsset, Image, Renderer, Scene, View};
use std::sync::Arc;
use vdbcook_vpak::Asset;

/// A segment on the GPU, placed in a scene made for the whole asset: its GPU
/// copy and the shift of its index space from the scene's. Drawing shifts the
/// scene and the views to the segment's index space.
pub struct PlacedSegment {
    pub gpu: GpuAsset,
    pub shift: [i32; 3],
}

impl PlacedSegment {
    /// Uploads `seg` (a restored segment) for drawing in `scene`, made for index offset `origin`.
    pub fn upload(renderer: &Renderer, seg: &Asset, scene: &Scene, origin: [i32; 3]) -> Result<PlacedSegment, Error> {
        let offset = seg.metadata()?.index_offset;
        let shift = std::array::from_fn(|i| offset[i] - origin[i]);
        Ok(PlacedSegment { gpu: renderer.upload_for(seg, &scene.shifted(shift))?, shift })
    }

    /// The segment's frame `local` at level `level`, from each of `views` of
    /// `scene` (the whole asset's), as images of `(width, height)`.
    pub fn draw(&self, renderer: &Renderer, scene: &Scene, (local, level): (usize, u32), views: &[View], (width, height): (u32, u32)) -> Result<Vec<Image>, Error> {
        let views: Vec<View> = views.iter().map(|v| v.shifted(self.shift)).collect();
        renderer.render_views_level(&self.gpu, &scene.shifted(self.shift), local, level, &views, width, height)
    }
}

/// The resident segment of `asset`.
pub struct Resident<'a> {
    asset: &'a Asset,
    /// The scene's index offset: segments are drawn with the scene shifted to theirs.
    origin: [i32; 3],
    now: Option<(usize, Arc<PlacedSegment>)>,
}

impl<'a> Resident<'a> {
    /// `asset`, drawn in a scene made for index offset `origin` (the
    /// whole asset's, from [`Asset::metadata`]).
    pub fn new(asset: &'a Asset, origin: [i32; 3]) -> Resident<'a> {
        Resident { asset, origin, now: None }
    }

    /// Frame `frame`'s segment on the GPU, and the frame's index there.
    pub fn at(&mut self, renderer: &Renderer, scene: &Scene, frame: usize) -> Result<(Arc<PlacedSegment>, usize), Error> {
        let Some((s, local)) = self.asset.locate(frame) else { return Err(Error::Frame { frame, count: self.asset.frame_count()? }) };
        match &self.now {
            Some((now, placed)) if *now == s => Ok((placed.clone(), local)),
            _ => {
                // The old segment goes before the new one comes.
                self.now = None;
                let seg = self.asset.segment(s)?;
                let placed = Arc::new(PlacedSegment::upload(renderer, &seg, scene, self.origin)?);
                // On the GPU now: its pages need not stay in this process's memory.
                seg.release();
                self.now = Some((s, placed.clone()));
                Ok((placed, local))
            }
        }
    }

    /// Frame `frame` at level `level`, from each of `views` of `scene`, as images of `size`.
    pub fn draw(&mut self, renderer: &Renderer, scene: &Scene, (frame, level): (usize, u32), views: &[View], size: (u32, u32)) -> Result<Vec<Image>, Error> {
        let (placed, local) = self.at(renderer, scene, frame)?;
        placed.draw(renderer, scene, (local, level), views, size)
    }
}
