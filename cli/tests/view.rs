//! `vdbcook view` in a real window under Xvfb, driven by xdotool and
//! screenshotted with ImageMagick's `import`: the frame, level and channel
//! keys change what the title says, and the picture below the HUD is the one
//! `vdbcook render` draws of the same frame, level and channel. Without a
//! display, and with a bad asset, one line and exit code 1.

mod common;
use common::*;
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Screen size of the viewer's window in these tests.
const SIZE: (u32, u32) = (320, 240);
/// Rows at the top the HUD may cover (three lines: 3 × 20 + 8 pixels).
const HUD_ROWS: u32 = 68;

/// True when xvfb-run, xdotool and import are installed; in CI their absence is a failure.
fn tools_available() -> bool {
    for (tool, package) in [("xvfb-run", "xvfb"), ("xdotool", "xdotool"), ("import", "imagemagick")] {
        let found = Command::new("sh").args(["-c", &format!("command -v {tool}")]).output().is_ok_and(|o| o.status.success());
        if !found {
            assert!(!in_ci(), "CI=true but {tool} is missing (scripts/test.sh installs {package})");
            eprintln!("note: {tool} not found, skipping the window test (Debian: apt-get install {package})");
            return false;
        }
    }
    true
}

/// An Xvfb server for the test's lifetime: xvfb-run runs a shell that prints
/// the display and its authority file, then waits on its stdin; closing that
/// (on drop, or when the test process dies) ends it and xvfb-run stops the server.
struct Xvfb {
    child: Child,
    env: Vec<(String, String)>,
    /// The private XDG_RUNTIME_DIR given to the programs (Mesa warns without one).
    runtime: PathBuf,
}

impl Xvfb {
    fn start() -> Xvfb {
        let mut child = Command::new("xvfb-run")
            .args(["-a", "-s", "-screen 0 800x600x24", "sh", "-c", "echo \"$DISPLAY\"; echo \"$XAUTHORITY\"; exec cat >/dev/null"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("run xvfb-run");
        let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
        let mut next = || lines.next().and_then(Result::ok).unwrap_or_default();
        let (display, auth) = (next(), next());
        assert!(display.starts_with(':'), "xvfb-run gave no display ({display:?})");
        let runtime = std::env::temp_dir().join(format!("vdbcook-view-runtime-{}", std::process::id()));
        std::fs::create_dir_all(&runtime).unwrap();
        let env = vec![("DISPLAY".into(), display), ("XAUTHORITY".into(), auth), ("XDG_RUNTIME_DIR".into(), runtime.display().to_string())];
        Xvfb { child, env, runtime }
    }

    /// `program` with this display's environment (and no Wayland to prefer).
    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env_remove("WAYLAND_DISPLAY").envs(self.env.iter().map(|(k, v)| (k, v)));
        c
    }

    fn run(&self, program: &str, args: &[&str]) -> Output {
        self.command(program).args(args).output().unwrap_or_else(|e| panic!("run {program}: {e}"))
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        drop(self.child.stdin.take());
        let _ = wait_exit(&mut self.child, Duration::from_secs(10)).or_else(|| {
            let _ = self.child.kill();
            self.child.wait().ok()
        });
        let _ = std::fs::remove_dir_all(&self.runtime);
    }
}

/// The child's exit status, if it exits within `limit`.
fn wait_exit(child: &mut Child, limit: Duration) -> Option<std::process::ExitStatus> {
    let start = Instant::now();
    loop {
        if let Ok(Some(status)) = child.try_wait() {
            return Some(status);
        }
        if start.elapsed() > limit {
            return None;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Polls `f` every 200 ms until it gives a value; the last attempt's description on timeout.
fn poll<T>(what: &str, limit: Duration, mut f: impl FnMut() -> Result<T, String>) -> T {
    let start = Instant::now();
    loop {
        match f() {
            Ok(v) => return v,
            Err(last) if start.elapsed() > limit => panic!("timed out waiting for {what}: {last}"),
            Err(_) => std::thread::sleep(Duration::from_millis(200)),
        }
    }
}

/// An 8-bit RGB picture.
struct Picture {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Picture {
    fn read(path: &Path) -> Result<Picture, String> {
        let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
        let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
        decoder.set_transformations(png::Transformations::normalize_to_color8());
        let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
        let mut buf = vec![0; reader.output_buffer_size().ok_or("no size")?];
        let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
        let channels = info.color_type.samples();
        let rgb = buf[..info.buffer_size()].chunks_exact(channels).flat_map(|p| if channels >= 3 { [p[0], p[1], p[2]] } else { [p[0]; 3] }).collect();
        Ok(Picture { width: info.width, height: info.height, rgb })
    }

    fn px(&self, x: u32, y: u32) -> [u8; 3] {
        let i = 3 * (y * self.width + x) as usize;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Rows below the HUD: (pixels not black, pixels differing from `other` by more than one step).
    fn below_hud(&self, other: Option<&Picture>) -> (usize, usize) {
        let (mut lit, mut differ) = (0, 0);
        for y in HUD_ROWS..self.height {
            for x in 0..self.width {
                let p = self.px(x, y);
                lit += usize::from(p.iter().any(|&c| c > 8));
                differ += usize::from(other.is_some_and(|o| p.iter().zip(o.px(x, y)).any(|(a, b)| a.abs_diff(b) > 1)));
            }
        }
        (lit, differ)
    }
}

/// The viewer process; killed if the test ends before it quits.
struct Viewer(Child);

impl Drop for Viewer {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Screenshots and what the test made: kept under target/tmp/view for a look.
fn output_dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("view");
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn the_window_plays_steps_and_switches_level_and_channel() {
    if !tools_available() || !gpu_available() {
        return;
    }
    let out = output_dir();
    // Four frames in two segments, two levels, two channels (density, temperature).
    let asset = cook_into(&out, "smoke.vpak", &["fixtures/smoke_seq"], &["--grids", "density,temperature", "--lods", "2", "--segment-frames", "2", "--format", "f16"]);
    let x = Xvfb::start();
    let (w, h) = (SIZE.0.to_string(), SIZE.1.to_string());
    let log = std::fs::File::create(out.join("view.log")).unwrap();
    let mut viewer = Viewer(
        x.command(env!("CARGO_BIN_EXE_vdbcook"))
            .args(["view", "--paused", "--size", &format!("{w}x{h}"), s(&asset)])
            .current_dir(root())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("run vdbcook view"),
    );
    let log_text = || std::fs::read_to_string(out.join("view.log")).unwrap_or_default();
    let found = x.run("timeout", &["60", "xdotool", "search", "--sync", "--name", "^vdbcook view"]);
    let win = String::from_utf8_lossy(&found.stdout).lines().next().unwrap_or_default().trim().to_string();
    assert!(!win.is_empty(), "no viewer window: {}{}", String::from_utf8_lossy(&found.stderr), log_text());
    let title = || String::from_utf8_lossy(&x.run("xdotool", &["getwindowname", &win]).stdout).trim().to_string();
    // The title after the draw that `want` describes; the screenshot that shows it.
    let shot = |tag: &str, want: &[&str], reference: &Picture| -> (String, Picture) {
        let t = poll(&format!("a title with {want:?}"), Duration::from_secs(120), || {
            let t = title();
            want.iter().all(|w| t.contains(w)).then_some(t.clone()).ok_or(t)
        });
        let path = out.join(format!("{tag}.png"));
        // Presentation lags the title: poll until the picture is the reference's below the HUD.
        let pic = poll(&format!("the {tag} picture to match render's"), Duration::from_secs(60), || {
            let r = x.run("import", &["-window", &win, s(&path)]);
            let p = Picture::read(&path).map_err(|e| format!("{e}: {}", String::from_utf8_lossy(&r.stderr)))?;
            let (lit, differ) = p.below_hud(Some(reference));
            match (p.width, p.height) == SIZE && differ == 0 {
                true => Ok(p),
                false => Err(format!("{}x{}, {lit} lit pixels, {differ} differ from render's", p.width, p.height)),
            }
        });
        eprintln!("{tag}: {t}; screenshot {}", path.display());
        (t, pic)
    };
    // What `render` draws of the same frame, level and channel from its view 0, at the window's size.
    let render = |tag: &str, extra: &[&str]| -> Picture {
        let path = out.join(format!("{tag}-render.png"));
        let size = format!("{w}x{h}");
        let mut args = vec!["render", "-q", "--force", "--size", &size, s(&asset), "-o", s(&path)];
        args.extend(extra);
        ok(vdbcook(&args));
        Picture::read(&path).unwrap()
    };

    let r0 = render("frame0", &["--frame", "0"]);
    let (lit, _) = r0.below_hud(None);
    let area = (SIZE.0 * (SIZE.1 - HUD_ROWS)) as usize;
    assert!(lit * 20 > area, "the volume covers only {lit} of {area} pixels below the HUD in render's picture");
    let (t0, p0) = shot("frame0", &["frame 1 (index 0, 0-3)", "lod 0", "paused", "density (scatter)", "fps", "gpu "], &r0);
    let gpu_bytes = |t: &str| t.split("gpu ").nth(1).and_then(|s| s.split(' ').next()).and_then(|n| n.parse::<f64>().ok()).unwrap_or(0.0);
    assert!(gpu_bytes(&t0) > 0.0, "no resident memory in the title: {t0}");
    // The HUD is drawn: white text on the darkened band.
    assert!((0..HUD_ROWS).any(|y| (0..SIZE.0).any(|x| p0.px(x, y) == [255; 3])), "no HUD text in the screenshot");

    x.run("xdotool", &["windowfocus", "--sync", &win, "key", "Right"]);
    let r1 = render("frame1", &["--frame", "1"]);
    let (_, p1) = shot("frame1", &["frame 2 (index 1, 0-3)", "lod 0"], &r1);
    assert!(p1.below_hud(Some(&p0)).1 > 0, "frames 0 and 1 look the same");

    // Frame 2 is in the second segment.
    x.run("xdotool", &["windowfocus", "--sync", &win, "key", "Right", "l"]);
    let r2 = render("frame2-lod1", &["--frame", "2", "--lod", "1"]);
    shot("frame2-lod1", &["frame 3 (index 2, 0-3)", "lod 1", "density (scatter)"], &r2);

    x.run("xdotool", &["windowfocus", "--sync", &win, "key", "c"]);
    let r3 = render("frame2-lod1-temperature", &["--frame", "2", "--lod", "1", "--extinction", "temperature"]);
    shot("frame2-lod1-temperature", &["frame 3 (index 2, 0-3)", "lod 1", "temperature (scatter)"], &r3);

    x.run("xdotool", &["windowfocus", "--sync", &win, "key", "Escape"]);
    let status = wait_exit(&mut viewer.0, Duration::from_secs(20)).unwrap_or_else(|| panic!("the viewer did not quit on Escape: {}", log_text()));
    assert!(status.success(), "the viewer exited with {status}: {}", log_text());
}

#[test]
fn without_a_display_it_says_so_in_one_line() {
    let dir = scratch_dir("view", "nodisplay");
    let asset = cook_into(&dir, "smoke.vpak", &["fixtures/smoke_seq/smoke_0001.vdb"], &[]);
    let r = Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(["view", s(&asset)]).env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY").output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.starts_with("vdbcook: error: no display: DISPLAY is not set") && err.lines().count() == 1, "{err}");

    // A bad asset is named before any window is tried.
    let bad = dir.join("bad.vpak");
    std::fs::write(&bad, b"not an asset at all").unwrap();
    let r = Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(["view", s(&bad)]).env_remove("DISPLAY").output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.starts_with(&format!("vdbcook: error: {}: ", bad.display())) && err.lines().count() == 1, "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
