//! `bake`'s report.html in headless Chromium: it loads, sorts, and fits a
//! 1280-pixel window with a fire, a smoke, a cloud and a level set.

use super::*;

/// The first Chromium on the PATH; none outside CI skips (in CI it fails).
fn chromium() -> Option<&'static str> {
    let found = ["chromium", "chromium-browser", "google-chrome"].into_iter().find(|c| Command::new(c).arg("--version").output().is_ok_and(|o| o.status.success()));
    if found.is_none() {
        assert!(!in_ci(), "CI=true but there is no chromium (scripts/test.sh installs it)");
        eprintln!("note: no chromium; skipping the HTML check");
    }
    found
}

/// Screenshots `html` at `size` ("W,H") into `shot`: it loads, and logs nothing.
fn screenshot(chromium: &str, html: &Path, shot: &Path, size: &str) {
    let o = Command::new(chromium)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--enable-logging=stderr", "--v=0", &format!("--window-size={size}")])
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", html.display()))
        .output()
        .unwrap();
    let log = err(&o);
    assert!(o.status.success(), "{log}");
    assert!(!log.contains("CONSOLE") && !log.contains("Uncaught"), "the page logs nothing: {log}");
    assert!(std::fs::read(shot).unwrap().starts_with(&[0x89, b'P', b'N', b'G']));
}

/// Loads a copy of `html` (in `dir`) at `size` with `probe` (JavaScript run
/// on load) added; Chromium's log, where the probe's console.log lines are.
fn probed(chromium: &str, html: &Path, dir: &Path, size: &str, probe: &str) -> String {
    let text = std::fs::read_to_string(html).unwrap();
    let copy = dir.join("probed.html");
    std::fs::write(&copy, text.replace("</body>", &format!("<script>window.addEventListener('load', function () {{{probe}}});</script></body>"))).unwrap();
    let o = Command::new(chromium)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--enable-logging=stderr", "--v=0", "--virtual-time-budget=3000", &format!("--window-size={size}"), "--dump-dom"])
        .arg(format!("file://{}", copy.display()))
        .output()
        .unwrap();
    let log = err(&o);
    assert!(!log.contains("Uncaught"), "{log}");
    log
}

const PROBE_IMAGES: &str = "var imgs = Array.prototype.slice.call(document.images);\
var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;\
console.log('probe images ' + ok + '/' + imgs.length);";

#[test]
fn the_html_report_loads_in_headless_chromium() {
    if !gpu_available() {
        return;
    }
    let Some(chromium) = chromium() else { return };
    // Kept after the test: the screenshot is for people to look at.
    let keep = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bake-html");
    let _ = std::fs::remove_dir_all(&keep);
    std::fs::create_dir_all(&keep).unwrap();
    let dir = scratch("html");
    let m = mixed(&dir, false);
    let (code, v, e) = bake(&[s(&m), "--out-dir", s(&keep)], &[]);
    assert_eq!(code, Some(1), "{e}");
    let html_path = keep.join("report.html");
    let html = std::fs::read_to_string(&html_path).unwrap();
    let thumbs = v["assets"].as_array().unwrap().iter().filter(|a| a["thumbnail"].is_string()).count();
    assert_eq!(thumbs, 2, "every cooked asset has a preview");
    assert_eq!(html.matches("<img ").count(), thumbs);
    screenshot(chromium, &html_path, &keep.join("report.png"), "1280,800");

    // Every image decoded, and a click sorts by bytes.
    let probe = format!(
        "{PROBE_IMAGES}\
var th = document.querySelectorAll('#assets th')[5]; th.click(); th.click();\
var names = Array.prototype.map.call(document.querySelectorAll('#assets tbody tr'), function (r) {{ return r.cells[1].firstChild.textContent; }});\
console.log('probe sorted ' + names.join(','));"
    );
    let log = probed(chromium, &html_path, &dir, "1280,800", &probe);
    assert!(log.contains(&format!("probe images {thumbs}/{thumbs}")), "{log}");
    // Descending by bytes: the bc7 sequence, the f16 tiles, then the failed asset (no size) last.
    assert!(log.contains("probe sorted strict,good,broken"), "{log}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Writes a fire (density, temperature, flames), a smoke, a cloud and a
/// level-set sphere with OpenVDB, 32³ voxels each, into argv[1].
const FOUR_VOLUMES: &str = r#"
import sys, numpy as np, pyopenvdb as vdb
out, n = sys.argv[1], 32
x, y, z = np.meshgrid(*[np.linspace(-1.0, 1.0, n)] * 3, indexing="ij")
r = np.sqrt(x * x + y * y + z * z)
def grid(name, a):
    g = vdb.FloatGrid()
    g.copyFromArray(np.ascontiguousarray(a, dtype=np.float32), tolerance=1e-3)
    g.name, g.gridClass = name, vdb.GridClass.FOG_VOLUME
    g.transform = vdb.createLinearTransform(voxelSize=0.1)
    return g
plume = np.clip(1.0 - np.sqrt(x * x + z * z) / (0.15 + 0.3 * (1.0 - y)), 0.0, 1.0) * (y < 0.9)
lick = 0.75 + 0.25 * np.sin(9.0 * y + 4.0 * x) * np.cos(7.0 * z)
vdb.write(out + "/fire.vdb", grids=[grid("density", 0.3 * plume * lick), grid("temperature", 2.5 * plume ** 0.7 * (1.1 - y) / 2.1), grid("flames", np.where(plume > 0.5, plume * lick, 0.0))])
vdb.write(out + "/smoke.vdb", grids=[grid("density", np.clip(1.0 - r / 0.8, 0.0, 1.0) * (0.6 + 0.4 * np.sin(6 * x) * np.cos(5 * y) * np.sin(4 * z)))])
vdb.write(out + "/cloud.vdb", grids=[grid("density", np.clip(3.0 * (1.0 - r / 0.9), 0.0, 1.0) * (0.8 + 0.2 * np.cos(3 * x + 2 * z)))])
ls = vdb.createLevelSetSphere(radius=1.0, center=(0.0, 0.0, 0.0), voxelSize=0.1, halfWidth=3.0)
ls.name = "surface"
vdb.write(out + "/sphere.vdb", grids=[ls])
"#;

#[test]
fn the_report_of_four_assets_fits_a_1280_pixel_window() {
    if !gpu_available() || !oracle_available() {
        return;
    }
    let Some(chromium) = chromium() else { return };
    let dir = scratch("fit");
    let o = Command::new("/usr/bin/python3").args(["-c", FOUR_VOLUMES, s(&dir)]).output().unwrap();
    assert!(o.status.success(), "{}", err(&o));
    let m = dir.join("bake.toml");
    let assets = [
        ("fire", "fire.vdb", "grids = \"density,temperature,flames\"\nmax_error = 0.02\nlods = 3"),
        ("smoke", "smoke.vdb", ""),
        ("cloud", "cloud.vdb", "format = \"bc4\""),
        ("level_set", "sphere.vdb", "format = \"unorm8\""),
    ];
    let mut text = "[defaults]\nformat = \"bc7\"\nquality = \"ultra-fast\"\nvalidate = true\nviews = 1\nsize = \"48x48\"\n".to_string();
    for (name, input, extra) in assets {
        text += &format!("\n[[asset]]\nname = \"{name}\"\noutput = \"{name}.vpak\"\ninputs = [\"{input}\"]\n{extra}\n");
    }
    std::fs::write(&m, text).unwrap();
    // Kept after the test: the screenshot is for people to look at.
    let keep = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bake-fit");
    let _ = std::fs::remove_dir_all(&keep);
    let (code, v, e) = bake(&[s(&m), "--out-dir", s(&keep)], &[]);
    assert_eq!(code, Some(0), "{e}");
    let fire = &v["assets"][0];
    let names: Vec<&str> = fire["channels"].as_array().unwrap().iter().map(|c| c["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["density", "temperature", "flames"], "{fire}");
    assert!(fire["channels"].as_array().unwrap().iter().any(|c| c["formats"].as_array().unwrap().len() >= 2), "--max-error mixes formats: {fire}");
    let html_path = keep.join("report.html");
    let html = std::fs::read_to_string(&html_path).unwrap();
    assert!(html.contains("<b>temperature</b> ") && html.contains("&nbsp;%, "), "formats per channel, with shares");
    screenshot(chromium, &html_path, &keep.join("report.png"), "1280,800");

    // Nothing is wider than the window; the previews are 256 px, and the
    // volumes' previews are exposed (the brightest pixel near white).
    let probe = format!(
        "{PROBE_IMAGES}\
var right = 0; Array.prototype.forEach.call(document.querySelectorAll('*'), function (el) {{ right = Math.max(right, el.getBoundingClientRect().right); }});\
console.log('probe fit ' + window.innerWidth + ' ' + document.documentElement.scrollWidth + ' ' + Math.ceil(right));\
var c = document.createElement('canvas'), g = c.getContext('2d');\
console.log('probe previews ' + imgs.map(function (i) {{ c.width = i.naturalWidth; c.height = i.naturalHeight; g.drawImage(i, 0, 0);\
var d = g.getImageData(0, 0, c.width, c.height).data, top = 0; for (var k = 0; k < d.length; k += 4) {{ top = Math.max(top, (d[k] + d[k + 1] + d[k + 2]) / 3); }}\
return i.alt + ':' + i.width + 'x' + i.naturalWidth + ':' + Math.round(top); }}).join(' '));"
    );
    let log = probed(chromium, &html_path, &dir, "1280,800", &probe);
    assert!(log.contains("probe images 4/4"), "{log}");
    let fit = log.split("probe fit ").nth(1).and_then(|l| l.split('"').next()).unwrap_or_else(|| panic!("{log}"));
    let w: Vec<u32> = fit.split_whitespace().map(|x| x.parse().unwrap()).collect();
    assert_eq!(w[0], 1280, "{log}");
    assert!(w[1] <= 1280 && w[2] <= 1280, "the page is {} px wide, its widest element ends at {} px (window 1280): {log}", w[1], w[2]);
    let previews = log.split("probe previews ").nth(1).and_then(|l| l.split('"').next()).unwrap_or_else(|| panic!("{log}"));
    for p in previews.split_whitespace() {
        let f: Vec<&str> = p.split(':').collect();
        assert_eq!(f[1], "256x256", "shown and rendered at 256 px: {p}");
        let top: u32 = f[2].parse().unwrap();
        assert!(f[0] == "level_set" || top >= 200, "{p}: the brightest pixel of an exposed preview is near white");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
