//! An asset on the GPU a segment at a time: the segment holding the frame
//! drawn last is resident, and each segment is drawn in its own index space
//! (the scene and views shifted from the scene's to the segment's offset).

use crate::{Error, GpuAsset, Image, Renderer, Scene, View};
use std::sync::Arc;
use vdbcook_vpak::Asset;

/// Uploads a segment (restored) for drawing in `scene`, made for index offset
/// `origin`: the GPU copy and the shift of the segment's index space from the scene's.
pub fn upload_segment(renderer: &Renderer, seg: &Asset, scene: &Scene, origin: [i32; 3]) -> Result<(GpuAsset, [i32; 3]), Error> {
    let offset = seg.metadata()?.index_offset;
    let d = std::array::from_fn(|i| offset[i] - origin[i]);
    Ok((renderer.upload_for(seg, &scene.shifted(d))?, d))
}

/// The resident segment of `asset`.
pub struct Resident<'a> {
    asset: &'a Asset,
    /// The scene's index offset: segments are drawn with the scene shifted to theirs.
    origin: [i32; 3],
    now: Option<(usize, Arc<GpuAsset>, [i32; 3])>,
}

impl<'a> Resident<'a> {
    /// `asset`, drawn in a scene made for index offset `origin` (the
    /// whole asset's, from [`Asset::metadata`]).
    pub fn new(asset: &'a Asset, origin: [i32; 3]) -> Resident<'a> {
        Resident { asset, origin, now: None }
    }

    /// The GPU copy of frame `frame`'s segment, the frame's index there and
    /// the shift of the segment's index space from the scene's.
    pub fn at(&mut self, renderer: &Renderer, scene: &Scene, frame: usize) -> Result<(Arc<GpuAsset>, usize, [i32; 3]), Error> {
        let Some((s, local)) = self.asset.locate(frame) else { return Err(Error::Frame { frame, count: self.asset.frame_count()? }) };
        match &self.now {
            Some((now, gpu, d)) if *now == s => Ok((gpu.clone(), local, *d)),
            _ => {
                // The old segment goes before the new one comes.
                self.now = None;
                let seg = self.asset.segment(s)?;
                let (gpu, d) = upload_segment(renderer, &seg, scene, self.origin)?;
                // On the GPU now: its pages need not stay in this process's memory.
                seg.release();
                let gpu = Arc::new(gpu);
                self.now = Some((s, gpu.clone(), d));
                Ok((gpu, local, d))
            }
        }
    }

    /// Frame `frame` at level `level`, from each of `views` of `scene`, as images of `(width, height)`.
    pub fn draw(&mut self, renderer: &Renderer, scene: &Scene, (frame, level): (usize, u32), views: &[View], (width, height): (u32, u32)) -> Result<Vec<Image>, Error> {
        let (gpu, local, d) = self.at(renderer, scene, frame)?;
        let views: Vec<View> = views.iter().map(|v| v.shifted(d)).collect();
        renderer.render_views_level(&gpu, &scene.shifted(d), local, level, &views, width, height)
    }
}
