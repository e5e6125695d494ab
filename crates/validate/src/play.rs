//! Playing a flip-book: frames drawn in order, one segment on the GPU while
//! the next is read, restored and uploaded on a worker thread, so that at
//! most two segments (and the metadata) are resident at once.

use crate::resident::PlacedSegment;
use crate::{Error, Image, Renderer, Scene, View};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use vdbcook_vpak::runtime::{Prefetcher, Reader};

/// What to play and how.
#[derive(Clone, Debug)]
pub struct PlayOptions {
    /// Asset frames in the order drawn (a loop repeats them).
    pub frames: Vec<usize>,
    pub level: u32,
    pub view: View,
    pub width: u32,
    pub height: u32,
    /// Frames per second to hold to (sleeping before a frame that is early);
    /// `None`: as fast as frames are drawn.
    pub fps: Option<f64>,
}

/// One frame as played.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FrameStats {
    /// Position in the play order (from 0).
    pub index: usize,
    /// The asset frame and its source frame number.
    pub frame: usize,
    pub number: i64,
    pub segment: usize,
    /// Reading and restoring (decompressing) the segment that became
    /// resident for this frame, and uploading it; 0 when it already was.
    pub decode_ms: f64,
    pub upload_ms: f64,
    pub render_ms: f64,
    /// How long this frame waited for its segment (0 when prefetched in time).
    pub wait_ms: f64,
    /// Bytes on the GPU while the frame was drawn: the player's sum of its buffers and textures.
    pub resident_bytes: u64,
}

/// A whole play.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct PlaySummary {
    pub frames: usize,
    pub seconds: f64,
    /// Frames per second sustained over the play.
    pub fps: f64,
    /// The slowest frame, wait included.
    pub worst_frame_ms: f64,
    pub worst_frame: usize,
    pub peak_resident_bytes: u64,
    /// Bytes read from the file: its tables and metadata when opened, and
    /// each segment's body as stored (compressed or not) each time it is loaded.
    pub bytes_read: u64,
    pub segments_loaded: usize,
    /// Frames that waited for their segment after the first segment's load.
    pub frames_waited: usize,
}

/// A segment on the GPU, with what it took to get there.
struct Loaded {
    placed: PlacedSegment,
    decode_ms: f64,
    upload_ms: f64,
    resident: u64,
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The segments in the order `frames` visits them (a segment again when the play comes back to it).
fn visits(reader: &Reader, frames: &[usize]) -> Result<Vec<usize>, Error> {
    let mut out: Vec<usize> = Vec::new();
    for &f in frames {
        let (s, _) = reader.locate(f).ok_or(Error::Frame { frame: f, count: reader.frame_count() })?;
        if out.last() != Some(&s) {
            out.push(s);
        }
    }
    Ok(out)
}

/// Reads, restores and uploads segment `s` (on the prefetch worker).
fn load(renderer: &Renderer, reader: &Reader, s: usize, scene: &Scene, origin: [i32; 3]) -> Result<Loaded, Error> {
    let t0 = Instant::now();
    let seg = reader.segment_asset(s, Vec::new())?;
    let decoded = t0.elapsed();
    let t1 = Instant::now();
    let placed = PlacedSegment::upload(renderer, &seg, scene, origin)?;
    let uploaded = t1.elapsed();
    let resident = placed.gpu.resident_bytes();
    Ok(Loaded { placed, decode_ms: ms(decoded), upload_ms: ms(uploaded), resident })
}

/// Plays `opts.frames` of the asset `reader` reads in `scene`, calling
/// `on_frame` with each frame's figures and image. The runtime reader's
/// prefetch worker reads, restores and uploads the next segment while the
/// current one is drawn; it is asked for one segment ahead, so at most two
/// are on the GPU.
pub fn play(renderer: Arc<Renderer>, reader: Arc<Reader>, scene: &Scene, opts: &PlayOptions, on_frame: &mut dyn FnMut(&FrameStats, &Image) -> Result<(), Error>) -> Result<PlaySummary, Error> {
    let meta = reader.metadata();
    if let Some(why) = meta.missing_level(opts.level) {
        return Err(Error::Level(why));
    }
    let order = visits(&reader, &opts.frames)?;
    let origin = meta.index_offset;
    // Bytes of segments the worker has uploaded and the player not yet taken.
    let held = Arc::new(AtomicU64::new(0));
    let (worker_held, worker_scene, worker_renderer) = (held.clone(), *scene, renderer.clone());
    let mut ahead = Prefetcher::new(reader.clone(), move |r: &Reader, s| {
        let loaded = load(&worker_renderer, r, s, &worker_scene, origin)?;
        worker_held.fetch_add(loaded.resident, Ordering::SeqCst);
        Ok::<Loaded, Error>(loaded)
    });
    let start = Instant::now();
    let mut sum = PlaySummary::default();
    let mut now: Option<(usize, Loaded)> = None;
    let mut visit = 0;
    for (index, &frame) in opts.frames.iter().enumerate() {
        let (s, local) = reader.locate(frame).ok_or(Error::Frame { frame, count: reader.frame_count() })?;
        let t0 = Instant::now();
        let (mut wait_ms, mut decode_ms, mut upload_ms) = (0.0, 0.0, 0.0);
        if now.as_ref().is_none_or(|(at, _)| *at != s) {
            // The segment drawn so far goes before the next is taken.
            drop(now.take());
            let fetched = ahead.take(order[visit])?;
            visit += 1;
            if let Some(&next) = order.get(visit) {
                ahead.request(next);
            }
            let loaded = fetched.value;
            held.fetch_sub(loaded.resident, Ordering::SeqCst);
            wait_ms = ms(fetched.waited);
            if wait_ms >= 1.0 && sum.segments_loaded > 0 {
                sum.frames_waited += 1;
            }
            (decode_ms, upload_ms) = (loaded.decode_ms, loaded.upload_ms);
            sum.segments_loaded += 1;
            now = Some((s, loaded));
        }
        let Some((_, cur)) = now.as_ref() else { continue };
        if let Some(fps) = opts.fps {
            let due = Duration::from_secs_f64(index as f64 / fps);
            if let Some(early) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(early);
            }
        }
        let t1 = Instant::now();
        let image = cur.placed.draw(&renderer, scene, (local, opts.level), &[opts.view], (opts.width, opts.height))?.pop().ok_or_else(|| Error::Gpu("no image".into()))?;
        let render_ms = ms(t1.elapsed());
        // The next segment, once the worker has uploaded it, is resident as well.
        let resident = cur.resident + held.load(Ordering::SeqCst);
        let stats = FrameStats { index, frame, number: meta.frame_number(frame), segment: s, decode_ms, upload_ms, render_ms, wait_ms, resident_bytes: resident };
        let took = ms(t0.elapsed());
        if took > sum.worst_frame_ms {
            (sum.worst_frame_ms, sum.worst_frame) = (took, index);
        }
        sum.peak_resident_bytes = sum.peak_resident_bytes.max(resident);
        on_frame(&stats, &image)?;
    }
    sum.frames = opts.frames.len();
    sum.seconds = start.elapsed().as_secs_f64();
    sum.fps = if sum.seconds > 0.0 { sum.frames as f64 / sum.seconds } else { 0.0 };
    drop(ahead);
    sum.bytes_read = reader.bytes_read();
    Ok(sum)
}
