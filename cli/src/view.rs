//! `vdbcook view`: a window that plays an asset through the validation
//! ray-marcher, with keys and the mouse to step, scrub, orbit, zoom and
//! switch the level of detail and the channel.

mod hud;
mod present;

use crate::gpu::GpuArgs;
use crate::{exit, Usage};
use anyhow::{anyhow, Context, Result};
use present::Screen;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use vdbcook_validate::{Image, PlacedSegment, Renderer, Scene, Size, View};
use vdbcook_vpak::runtime::{Prefetcher, Reader};
use vdbcook_vpak::{Asset, Level, Metadata};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, KeyEvent, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

pub const AFTER_HELP: &str = "\
Keys:
  Space              play / pause
  Right, Left        next / previous frame (pauses)
  PageDown, PageUp   10 frames forward / back (pauses)
  Home, End          first / last frame (pauses)
  mouse drag, A D    orbit around the volume (A, D: 15° steps)
  W S                raise / lower the camera (15° steps)
  wheel, + -         zoom in / out
  R                  reset the camera
  L, 0-9             next level of detail / level N (levels the asset stores)
  C                  next channel (the validation scene's choice, then each scalar channel
                     drawn as a scattering fog)
  Escape, Q          quit

The picture is the one `vdbcook render` draws (the same ray-marcher and scene, the
camera starting at render's view 0), with the frame (its source frame number, and its
index counted from 0, as unpack and render count), the frames per second drawn, the GPU memory the asset holds (its buffers
and textures: one segment of a segmented asset at a time) and the channel on it, and
the same in the window's title. Playback steps one frame each 1/--fps seconds; where
drawing a frame takes longer, it plays slower (the fps shown is what is drawn).

It needs an X11 display (DISPLAY; under Wayland, XWayland). Without one it says so and
exits with 1. A GPU is not required: Mesa's CPU Vulkan driver (lavapipe) works.";

#[derive(clap::Args)]
pub struct ViewArgs {
    /// The .vpak asset to play.
    #[arg(value_name = "ASSET.vpak")]
    pub asset: PathBuf,
    /// Frames per second of playback (default: the asset's own rate, `cook --fps`).
    #[arg(long, value_name = "FPS", allow_negative_numbers = true)]
    pub fps: Option<vdbcook_vpak::Fps>,
    /// Window size in pixels (each side 8 to 8192); the picture follows the window.
    #[arg(long, value_name = "WxH", default_value = "640x480")]
    pub size: Size,
    /// The frame to start at (counted from 0).
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub frame: usize,
    /// Level of detail to start at (default: the asset's finest stored level).
    #[arg(long, value_name = "K")]
    pub lod: Option<Level>,
    /// The channel giving extinction at the start (default: the validation scene's choice).
    #[arg(long, value_name = "NAME")]
    pub extinction: Option<String>,
    /// Start paused.
    #[arg(long)]
    pub paused: bool,
    #[command(flatten)]
    pub gpu: GpuArgs,
}

/// Where the frames come from: the one place that obtains segments. The
/// runtime reader reads the file a segment at a time; its prefetch worker
/// restores the segment after the one drawn (in playing order, wrapping
/// around) while this one is shown, and the segment drawn is uploaded when
/// its first frame is: one segment on the GPU, the next one restored in
/// memory.
struct Frames {
    reader: Arc<Reader>,
    origin: [i32; 3],
    /// The segment on the GPU: (segment, index of the scene it was uploaded for, the segment).
    now: Option<(usize, usize, PlacedSegment)>,
    /// The worker and the segment asked of it (a jump elsewhere starts a new worker).
    ahead: Option<(Prefetcher<Asset>, usize)>,
}

impl Frames {
    fn new(reader: Arc<Reader>) -> Frames {
        let origin = reader.metadata().index_offset;
        Frames { reader, origin, now: None, ahead: None }
    }

    /// Segment `s` restored: the prefetched one when it was asked for, else read now.
    fn restored(&mut self, s: usize) -> Result<Asset> {
        if let Some((worker, asked)) = self.ahead.as_mut() {
            if *asked == s {
                let fetched = worker.take(s)?;
                self.ahead = None;
                return Ok(fetched.value);
            }
        }
        // Not the one prefetched (a jump, or another channel's upload): read it here.
        Ok(self.reader.segment_asset(s, Vec::new())?)
    }

    /// Frame `frame` at `level` from `view` of the scene `shown` (`scenes[shown]`), as an image of `size`.
    fn draw(&mut self, renderer: &Renderer, (scene, shown): (&Scene, usize), (frame, level): (usize, u32), view: &View, size: (u32, u32)) -> Result<Image> {
        let count = self.reader.frame_count();
        let (s, local) = self.reader.locate(frame).ok_or_else(|| anyhow!("frame {frame} is out of range ({count} frames)"))?;
        if self.now.as_ref().is_none_or(|(at, for_scene, _)| (*at, *for_scene) != (s, shown)) {
            // The old copy goes before the new one comes.
            self.now = None;
            let seg = self.restored(s)?;
            self.now = Some((s, shown, PlacedSegment::upload(renderer, &seg, scene, self.origin)?));
        }
        // Prefetch the segment playing reaches next.
        let next = (s + 1) % self.reader.segment_count();
        if next != s && self.ahead.as_ref().is_none_or(|(_, asked)| *asked != next) {
            let mut worker = Prefetcher::new(self.reader.clone(), |r: &Reader, s| r.segment_asset(s, Vec::new()));
            worker.request(next);
            self.ahead = Some((worker, next));
        }
        let Some((_, _, placed)) = &self.now else { return Err(anyhow!("no segment on the GPU")) };
        placed.draw(renderer, scene, (local, level), std::slice::from_ref(view), size)?.pop().ok_or_else(|| anyhow!("no image"))
    }

    fn resident_bytes(&self) -> u64 {
        self.now.as_ref().map_or(0, |(_, _, placed)| placed.gpu.resident_bytes())
    }
}

/// A channel the viewer can show: its label and its scene.
struct Shown {
    label: String,
    scene: Scene,
}

/// The choices of `C`: the scene `extinction` asks for (else the validation
/// scene's choice), then each other scalar channel as a scattering fog.
fn channel_choices(meta: &Metadata, extinction: Option<&str>) -> Result<Vec<Shown>> {
    let first = Scene::for_asset_with(meta, extinction).map_err(|e| Usage(format!("--extinction: {e}")))?;
    let label = |s: &Scene| format!("{} ({})", meta.channels.get(s.shown()).map_or("?", |c| c.name.as_str()), s.model().name());
    let mut out = vec![Shown { label: label(&first), scene: first }];
    for (c, ch) in meta.channels.iter().enumerate() {
        if c != first.shown() && ch.component.is_none() {
            if let Ok(scene) = Scene::for_asset_with(meta, Some(&ch.name)) {
                out.push(Shown { label: label(&scene), scene });
            }
        }
    }
    Ok(out)
}

/// The orbiting camera: render's view 0 to start with (20° up, at the distance
/// that frames the box), turned and moved in and out from there.
#[derive(Clone, Copy, PartialEq)]
struct Camera {
    azimuth: f32,
    elevation: f32,
    /// Distance as a multiple of the framing one.
    zoom: f32,
}

impl Camera {
    const START: Camera = Camera { azimuth: 0.0, elevation: 20.0, zoom: 1.0 };

    /// The view from this camera, `start` being render's view 0 (`Scene::orbit`).
    fn view(&self, start: View) -> View {
        let t = start.target;
        let d = (0..3).map(|i| (start.eye[i] - t[i]).powi(2)).sum::<f32>().sqrt() * self.zoom;
        let (az, el) = (self.azimuth.to_radians(), self.elevation.to_radians());
        View { eye: [t[0] + d * el.cos() * az.cos(), t[1] + d * el.sin(), t[2] + d * el.cos() * az.sin()], ..start }
    }

    fn turn(&mut self, azimuth: f32, elevation: f32) {
        self.azimuth = (self.azimuth + azimuth).rem_euclid(360.0);
        self.elevation = (self.elevation + elevation).clamp(-89.0, 89.0);
    }

    fn zoom_by(&mut self, factor: f32) {
        self.zoom = (self.zoom * factor).clamp(0.1, 10.0);
    }
}

/// Sizes in bytes as the HUD shows them.
fn bytes_text(b: u64) -> String {
    match b {
        b if b >= 1 << 30 => format!("{:.2} GiB", b as f64 / (1u64 << 30) as f64),
        b if b >= 1 << 20 => format!("{:.2} MiB", b as f64 / (1u64 << 20) as f64),
        b if b >= 1 << 10 => format!("{:.1} KiB", b as f64 / 1024.0),
        b => format!("{b} B"),
    }
}

struct App {
    name: String,
    frames: Frames,
    count: usize,
    frame: usize,
    levels: std::ops::Range<u32>,
    level: u32,
    shown: Vec<Shown>,
    channel: usize,
    camera: Camera,
    playing: bool,
    period: Duration,
    /// When playback shows the next frame.
    due: Instant,
    /// The window's first size.
    size: Size,
    gpu: GpuArgs,
    window: Option<Arc<Window>>,
    screen: Option<(Screen, Renderer)>,
    /// Where a left-button drag was last seen.
    drag: Option<(f64, f64)>,
    cursor: (f64, f64),
    /// When the last frames were shown (the fps figure).
    shown_at: std::collections::VecDeque<Instant>,
    /// Set when the picture must be drawn again.
    dirty: bool,
    error: Option<anyhow::Error>,
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: anyhow::Error) {
        self.error.get_or_insert(e);
        event_loop.exit();
    }

    /// Frames per second shown over the last two seconds.
    fn fps(&self) -> f64 {
        match (self.shown_at.front(), self.shown_at.back()) {
            (Some(a), Some(b)) if self.shown_at.len() > 1 && b > a => (self.shown_at.len() - 1) as f64 / (*b - *a).as_secs_f64(),
            _ => 0.0,
        }
    }

    /// What the HUD and the title say.
    fn status(&self) -> Vec<String> {
        let state = if self.playing { "playing" } else { "paused" };
        let channel = self.shown.get(self.channel).map_or("", |s| s.label.as_str());
        vec![
            format!("frame {} (index {}, 0-{})  {state}", self.frames.reader.metadata().frame_number(self.frame), self.frame, self.count.saturating_sub(1)),
            // A channel at its own voxel size is drawn at its stored level nearest the one asked for.
            format!("lod {}  {channel}", self.shown.get(self.channel).map_or(self.level, |s| s.scene.drawn_level(self.frames.reader.metadata(), self.level))),
            format!("{:.1} fps  gpu {}", self.fps(), bytes_text(self.frames.resident_bytes())),
        ]
    }

    fn redraw(&mut self) -> Result<()> {
        let (Some((screen, renderer)), Some(window)) = (&mut self.screen, &self.window) else { return Ok(()) };
        let size = window.inner_size();
        screen.resize(size.width, size.height);
        let scene = &self.shown[self.channel].scene;
        let img = self.frames.draw(renderer, (scene, self.channel), (self.frame, self.level), &self.camera.view(scene.orbit(1)[0]), screen.size()).with_context(|| self.name.clone())?;
        let now = Instant::now();
        self.shown_at.push_back(now);
        while self.shown_at.front().is_some_and(|t| now.duration_since(*t) > Duration::from_secs(2)) {
            self.shown_at.pop_front();
        }
        let lines = self.status();
        let (Some((screen, _)), Some(window)) = (&mut self.screen, &self.window) else { return Ok(()) };
        if screen.show(&img, &lines)? {
            self.dirty = false;
            window.set_title(&format!("vdbcook view {} | {}", self.name, lines.join(" | ")));
        }
        Ok(())
    }

    fn go_to(&mut self, frame: usize) {
        self.playing = false;
        self.frame = frame.min(self.count.saturating_sub(1));
        self.dirty = true;
    }

    fn key(&mut self, event_loop: &ActiveEventLoop, key: &KeyEvent) {
        let last = self.count.saturating_sub(1);
        // Held keys repeat for stepping, orbiting and zooming, not for toggles.
        let toggle = |k: &Key| matches!(k, Key::Named(NamedKey::Space)) || matches!(k, Key::Character(c) if matches!(c.as_str(), "l" | "L" | "c" | "C"));
        if key.repeat && toggle(&key.logical_key) {
            return;
        }
        let mut moved = true;
        match &key.logical_key {
            Key::Named(NamedKey::Escape) => event_loop.exit(),
            Key::Named(NamedKey::Space) => {
                self.playing = !self.playing;
                self.due = Instant::now() + self.period;
            }
            Key::Named(NamedKey::ArrowRight) => self.go_to(if self.frame >= last { 0 } else { self.frame + 1 }),
            Key::Named(NamedKey::ArrowLeft) => self.go_to(if self.frame == 0 { last } else { self.frame - 1 }),
            Key::Named(NamedKey::PageDown) => self.go_to(self.frame.saturating_add(10)),
            Key::Named(NamedKey::PageUp) => self.go_to(self.frame.saturating_sub(10)),
            Key::Named(NamedKey::Home) => self.go_to(0),
            Key::Named(NamedKey::End) => self.go_to(last),
            Key::Character(c) => match c.as_str() {
                "q" | "Q" => event_loop.exit(),
                "a" | "A" => self.camera.turn(15.0, 0.0),
                "d" | "D" => self.camera.turn(-15.0, 0.0),
                "w" | "W" => self.camera.turn(0.0, 15.0),
                "s" | "S" => self.camera.turn(0.0, -15.0),
                "+" | "=" => self.camera.zoom_by(0.9),
                "-" | "_" => self.camera.zoom_by(1.0 / 0.9),
                "r" | "R" => self.camera = Camera::START,
                "l" | "L" => self.level = if self.level + 1 >= self.levels.end { self.levels.start } else { self.level + 1 },
                // The segment is uploaded again for the new scene's channels at the next draw.
                "c" | "C" => self.channel = (self.channel + 1) % self.shown.len().max(1),
                d if d.len() == 1 && d.as_bytes()[0].is_ascii_digit() => {
                    let k = u32::from(d.as_bytes()[0] - b'0');
                    moved = self.levels.contains(&k);
                    if moved {
                        self.level = k;
                    }
                }
                _ => moved = false,
            },
            _ => moved = false,
        }
        self.dirty |= moved;
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        let attrs = Window::default_attributes().with_title(format!("vdbcook view {}", self.name)).with_inner_size(winit::dpi::PhysicalSize::new(self.size.width(), self.size.height()));
        let opened = event_loop.create_window(attrs).map_err(|e| anyhow!("cannot open a window: {e}")).and_then(|w| {
            let w = Arc::new(w);
            Screen::new(w.clone(), &self.gpu).map(|s| (w, s))
        });
        match opened {
            Ok((window, screen)) => {
                window.request_redraw();
                self.window = Some(window);
                self.screen = Some(screen);
                self.due = Instant::now() + self.period;
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(_) => self.dirty = true,
            // A press winit makes up when focus arrives with a key down is not the user's.
            WindowEvent::KeyboardInput { event, is_synthetic: false, .. } if event.state == ElementState::Pressed => self.key(event_loop, &event),
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => self.drag = (state == ElementState::Pressed).then_some(self.cursor),
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = (position.x, position.y);
                if let Some((x, y)) = self.drag.replace(self.cursor) {
                    // Half a degree a pixel: across a 640-pixel window, most of a turn.
                    self.camera.turn((x - position.x) as f32 * -0.5, (position.y - y) as f32 * 0.5);
                    self.dirty = true;
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                self.camera.zoom_by(0.9f32.powf(lines));
                self.dirty = true;
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        if self.playing {
            let now = Instant::now();
            if now >= self.due {
                self.frame = if self.frame + 1 >= self.count { 0 } else { self.frame + 1 };
                self.dirty = true;
                // Behind (a frame that took longer than the period): no catching up.
                self.due = (self.due + self.period).max(now);
            }
            event_loop.set_control_flow(ControlFlow::WaitUntil(self.due));
        } else {
            event_loop.set_control_flow(ControlFlow::Wait);
        }
        if self.dirty {
            if let Some(w) = &self.window {
                w.request_redraw();
            }
        }
    }
}

/// The X display to open, or why there is none.
fn display() -> Result<String> {
    match std::env::var("DISPLAY") {
        Ok(d) if !d.is_empty() => Ok(d),
        _ if std::env::var_os("WAYLAND_DISPLAY").is_some() => Err(anyhow!("no X display: DISPLAY is not set (vdbcook view opens an X11 window; under Wayland it needs XWayland)")),
        _ => Err(anyhow!("no display: DISPLAY is not set (vdbcook view opens a window; run it in a desktop session, with ssh -X, or under xvfb-run)")),
    }
}

pub fn run(args: ViewArgs, _quiet: bool) -> Result<u8> {
    let name = args.asset.display().to_string();
    if !args.asset.exists() {
        return Err(anyhow!("{name}: no such file"));
    }
    // The runtime reader: tables and metadata now, each segment when it is shown.
    let file = std::fs::File::open(&args.asset).with_context(|| name.clone())?;
    let reader = Arc::new(Reader::from_file(file).with_context(|| name.clone())?);
    let meta = reader.metadata().clone();
    let count = meta.frame_count as usize;
    if args.frame >= count {
        return Err(Usage(format!("--frame {} is out of range ({name} has {count} frames, numbered from 0)", args.frame)).into());
    }
    let level = args.lod.map_or(meta.first_level, Level::get);
    if let Some(why) = meta.missing_level(level) {
        return Err(Usage(format!("--lod {level}: {why}")).into());
    }
    let shown = channel_choices(&meta, args.extinction.as_deref())?;
    let display = display()?;
    // Unset WAYLAND_DISPLAY is not consulted: this winit is built for X11 only.
    let event_loop = EventLoop::new().map_err(|e| anyhow!("cannot open the X display \"{display}\": {}", winit_error(&e)))?;
    let mut app = App {
        name,
        frames: Frames::new(reader),
        count,
        frame: args.frame,
        levels: meta.stored_levels(),
        level,
        shown,
        channel: 0,
        camera: Camera::START,
        playing: !args.paused,
        period: Duration::from_secs_f64(1.0 / args.fps.map_or(meta.fps(), vdbcook_vpak::Fps::get)),
        due: Instant::now(),
        size: args.size,
        gpu: args.gpu,
        window: None,
        screen: None,
        drag: None,
        cursor: (0.0, 0.0),
        shown_at: Default::default(),
        dirty: true,
        error: None,
    };
    event_loop.run_app(&mut app).map_err(|e| anyhow!("the window's event loop failed: {}", winit_error(&e)))?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(exit::SUCCESS),
    }
}

/// A winit error without the source location its OS errors carry ("os error at src/…: ").
fn winit_error(e: &dyn std::fmt::Display) -> String {
    let text = e.to_string();
    match text.find("os error at ").and_then(|i| text[i..].find(": ").map(|j| i + j + 2)) {
        Some(start) => text[start..].to_string(),
        None => text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_camera_starts_at_render_view_0() {
        // View 0 of an orbit: azimuth 0, 20° up.
        let (d, el) = (50.0f32, 20f32.to_radians());
        let start = View { eye: [10.0 + d * el.cos(), 5.0 + d * el.sin(), 3.0], target: [10.0, 5.0, 3.0], fov_deg: 40.0 };
        let a = Camera::START.view(start);
        assert!((0..3).all(|i| (a.eye[i] - start.eye[i]).abs() < 1e-3), "{a:?} vs {start:?}");
        let mut c = Camera::START;
        c.turn(90.0, -20.0);
        c.zoom_by(0.5);
        let v = c.view(start);
        assert!((v.eye[0] - 10.0).abs() < 1e-3 && (v.eye[1] - 5.0).abs() < 1e-3 && (v.eye[2] - 28.0).abs() < 1e-3, "{v:?}");
        c.turn(0.0, 500.0);
        assert_eq!(c.elevation, 89.0);
        c.zoom_by(1e9);
        assert_eq!(c.zoom, 10.0);
    }

    #[test]
    fn sizes_and_errors_read_as_one_line() {
        assert_eq!(bytes_text(512), "512 B");
        assert_eq!(bytes_text(3 << 20), "3.00 MiB");
        assert_eq!(winit_error(&"os error at /x/src/platform_impl/linux/mod.rs:788: XOpenDisplay failed"), "XOpenDisplay failed");
        assert_eq!(winit_error(&"the event loop is gone"), "the event loop is gone");
    }
}
