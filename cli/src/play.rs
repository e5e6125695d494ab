//! `vdbcook play`: the flip-book drawn frame after frame, streaming its
//! segments (one drawn, the next read and uploaded behind it).

use crate::gpu::GpuArgs;
use crate::{exit, Usage};
use anyhow::{anyhow, Context, Result};
use std::path::PathBuf;
use vdbcook_pipeline::options::FrameRange;
use vdbcook_validate::{PlayOptions, Scene, Viewing};
use vdbcook_vpak::runtime::Reader;
use vdbcook_vpak::Level;

pub const AFTER_HELP: &str = "\
The asset is streamed a segment at a time (cook --segment-frames): while one segment is
drawn, a worker thread reads the next, restores it (supercompressed sections are
decompressed) and uploads it, so at most two segments are on the GPU. Frames are drawn
by the ray-marcher of `render` and `validate`, offscreen: --out writes them as numbered
PNGs (00000.png, 00001.png, ...: a preview clip), identical to `render` of each frame.

Headless play runs as fast as frames are drawn, unless --fps is given; the asset's own
frame rate (cook --fps) is reported. --json prints one document (docs/play-json.md):
per frame its index, asset frame, source frame number, segment, decode_ms (reading and
restoring the segment that became resident for it), upload_ms, render_ms, wait_ms (how
long it waited for its segment) and resident_bytes (the player's buffers and textures
on the GPU), then a summary: fps sustained, the worst frame, peak resident bytes, bytes
read from disk.

Without --headless the asset plays in a window instead: `vdbcook view`'s, looping, with
its keys (space pauses; arrows step; L and C switch level and channel).";

#[derive(clap::Args)]
pub struct PlayArgs {
    /// The asset.
    #[arg(value_name = "ASSET.vpak")]
    pub asset: PathBuf,
    /// Draw offscreen, with no window: for CI, benchmarks and preview clips. Without it the
    /// asset plays in `vdbcook view`'s window (looping, from the first frame of --frames).
    #[arg(long)]
    pub headless: bool,
    /// Asset frames to play, counted from 0: A-B or A-B:STEP (default: all); in a window, N
    /// (the frame to start at).
    #[arg(long, value_name = "RANGE")]
    pub frames: Option<FrameRange>,
    /// Play the frames N times (default 1).
    #[arg(long = "loop", value_name = "N", default_value_t = 1)]
    pub loops: u32,
    /// Hold playback to this many frames per second (default: as fast as frames are drawn).
    #[arg(long, value_name = "FPS", allow_negative_numbers = true)]
    pub fps: Option<vdbcook_vpak::Fps>,
    /// Level of detail to draw (default: the asset's finest stored level).
    #[arg(long, value_name = "K")]
    pub lod: Option<Level>,
    /// Which of --views orbiting cameras to use (from 0).
    #[arg(long, default_value_t = 0)]
    pub view: u32,
    #[command(flatten)]
    pub viewing: Viewing,
    #[command(flatten)]
    pub gpu: GpuArgs,
    /// Write each frame drawn to DIR as a numbered PNG (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Print one JSON document on stdout: per frame figures and a summary.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: PlayArgs, quiet: bool) -> Result<u8> {
    let name = args.asset.display().to_string();
    if args.loops == 0 {
        return Err(Usage("--loop must be at least 1".into()).into());
    }
    let (views, size) = (args.viewing.views, args.viewing.size);
    if args.view >= views.get() {
        return Err(Usage(format!("--view {} is out of range (0 to {})", args.view, views.get() - 1)).into());
    }
    // The runtime reader: tables and metadata now, each segment when it is played.
    let file = std::fs::File::open(&args.asset).with_context(|| name.clone())?;
    let reader = std::sync::Arc::new(Reader::from_file(file).with_context(|| name.clone())?);
    let meta = reader.metadata().clone();
    let count = meta.frame_count as usize;
    let frames: Vec<usize> = match args.frames {
        Some(r) => r.frames().map(|f| usize::try_from(f).unwrap_or(usize::MAX)).collect(),
        None => (0..count).collect(),
    };
    if let Some(&f) = frames.iter().find(|&&f| f >= count) {
        return Err(anyhow!("{name}: frame {f} is out of range (it has {count} frames, numbered from 0)"));
    }
    let lod = args.lod.map_or(meta.first_level, Level::get);
    if let Some(why) = meta.missing_level(lod) {
        return Err(anyhow!("{name}: {why}"));
    }
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
    }
    let scene = Scene::for_asset_with(&meta, args.viewing.extinction.as_deref()).map_err(|e| Usage(format!("--extinction: {e}")))?;
    let renderer = std::sync::Arc::new(args.gpu.renderer()?);
    let opts = PlayOptions {
        frames: frames.iter().copied().cycle().take(frames.len() * args.loops as usize).collect(),
        level: lod,
        view: scene.orbit(views.count())[args.view as usize],
        width: size.width(),
        height: size.height(),
        fps: args.fps.map(vdbcook_vpak::Fps::get),
    };
    let mut per_frame = Vec::new();
    let mut write_err = None;
    let summary = vdbcook_validate::play(renderer.clone(), reader.clone(), &scene, &opts, &mut |stats, image| {
        if let Some(dir) = &args.out {
            let path = dir.join(format!("{:05}.png", stats.index));
            if let Err(e) = vdbcook_vpak::write_atomic(&path, &vdbcook_validate::report::png_rgb(image), true) {
                write_err = Some(anyhow!("{}: {e}", path.display()));
                return Err(vdbcook_validate::Error::Gpu("stopped: a frame could not be written".into()));
            }
        }
        per_frame.push(stats.clone());
        Ok(())
    });
    if let Some(e) = write_err {
        return Err(e);
    }
    let summary = summary.with_context(|| name.clone())?;
    let segments = reader.segment_count();
    if args.json {
        let doc = serde_json::json!({
            "asset": name,
            "adapter": renderer.adapter,
            "width": size.width(),
            "height": size.height(),
            "level": lod,
            "asset_fps": meta.fps(),
            "fps_held": args.fps.map(vdbcook_vpak::Fps::get),
            "segments": segments,
            "frames": per_frame,
            "summary": summary,
        });
        crate::emit_final(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
    } else if !quiet {
        let numbers: Vec<i64> = frames.iter().map(|&f| meta.frame_number(f)).collect();
        crate::emit_final(&format!(
            "played {} frame{} of {name} (source frames {}, {segments} segment{}) in {:.2} s: {:.1} fps sustained (the asset's rate: {} fps), worst frame {:.1} ms (#{}), peak {:.2} MB on the GPU, {:.2} MB read; {} frame{} waited for a segment after the first{}\n",
            summary.frames,
            if summary.frames == 1 { "" } else { "s" },
            vdbcook_vpak::time::numbers_text(&numbers),
            if segments == 1 { "" } else { "s" },
            summary.seconds,
            summary.fps,
            meta.fps(),
            summary.worst_frame_ms,
            summary.worst_frame,
            summary.peak_resident_bytes as f64 / 1e6,
            summary.bytes_read as f64 / 1e6,
            summary.frames_waited,
            if summary.frames_waited == 1 { "" } else { "s" },
            args.out.as_ref().map_or(String::new(), |d| format!("; frames in {}", d.display())),
        ))?;
    }
    Ok(exit::SUCCESS)
}
