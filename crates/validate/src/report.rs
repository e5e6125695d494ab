//! Images as PNG, error heat-maps, report previews, and the self-contained HTML report.

use crate::{Error, FlipMap, Image, Renderer, Scene};
use vdbcook_vpak::Asset;

/// Where a preview puts the bright end of its volume (linear, before sRGB).
pub const PREVIEW_WHITE: f32 = 0.8;

/// A `size`×`size` PNG preview of `asset` for reports: its middle frame from
/// the first of 8 orbiting views, through [`expose`]. Validation images keep
/// the fixed scene; only previews are exposed.
pub fn thumbnail(renderer: &Renderer, asset: &Asset, size: u32) -> Result<Vec<u8>, Error> {
    let meta = asset.metadata()?;
    let scene = Scene::for_asset(&meta);
    let view = scene.orbit(8)[0];
    let drawn = crate::Resident::new(asset, meta.index_offset).draw(renderer, &scene, (meta.frame_count as usize / 2, meta.first_level), &[view], (size, size))?;
    let mut img = drawn.into_iter().next().ok_or_else(|| Error::Gpu("no image".into()))?;
    expose(&mut img);
    Ok(png_rgb(&img))
}

/// Scales a linear image so that the 98th percentile of the luminance of the
/// pixels the volume covers (luminance above 1e-3: the scene's background is
/// black) lands at [`PREVIEW_WHITE`]: a dim smoke or a small fire fills the
/// preview's range, a bright cloud is toned down. The gain stays within
/// 1/8 to 64; an image with nothing in it is left as it is. Returns the gain.
pub fn expose(img: &mut Image) -> f32 {
    let mut lum: Vec<f32> = img.pixels.chunks_exact(3).map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]).filter(|l| l.is_finite() && *l > 1e-3).collect();
    if lum.is_empty() {
        return 1.0;
    }
    let k = ((lum.len() - 1) as f64 * 0.98).round() as usize;
    let (_, high, _) = lum.select_nth_unstable_by(k, f32::total_cmp);
    let gain = (PREVIEW_WHITE / *high).clamp(0.125, 64.0);
    for v in &mut img.pixels {
        *v *= gain;
    }
    gain
}

/// 8-bit RGB PNG of an image (values clamped to [0, 1], sRGB-encoded: the pixels FLIP compares).
pub fn png_rgb(img: &Image) -> Vec<u8> {
    encode(img.width, img.height, png::ColorType::Rgb, &crate::flip::srgb8(img))
}

/// RGB PNG of a FLIP error map through FLIP's magma colour map (black: no error, pale yellow: 1).
pub fn png_flip(map: &FlipMap) -> Vec<u8> {
    encode(map.width, map.height, png::ColorType::Rgb, &map.magma_rgb8())
}

/// RGB heat-map PNG of the largest |a - b| over a pixel's colours, full
/// scale at `scale` (black, red, yellow, white).
pub fn png_heat(a: &Image, b: &Image, scale: f32) -> Vec<u8> {
    let scale = if scale > 0.0 { scale } else { 1.0 };
    let mut px = Vec::with_capacity(a.pixels.len());
    for (x, y) in a.pixels.chunks_exact(3).zip(b.pixels.chunks_exact(3)) {
        let d = x.iter().zip(y).map(|(x, y)| (x.clamp(0.0, 1.0) - y.clamp(0.0, 1.0)).abs()).fold(0.0f32, f32::max);
        let t = (d / scale).clamp(0.0, 1.0) * 3.0;
        let c = [t.min(1.0), (t - 1.0).clamp(0.0, 1.0), (t - 2.0).clamp(0.0, 1.0)];
        px.extend(c.map(|v| (v * 255.0).round() as u8));
    }
    encode(a.width, a.height, png::ColorType::Rgb, &px)
}

fn encode(w: u32, h: u32, color: png::ColorType, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(color);
        enc.set_depth(png::BitDepth::Eight);
        // Writing into a Vec cannot fail for a well-sized buffer.
        if let Ok(mut writer) = enc.write_header() {
            let _ = writer.write_image_data(data);
        }
    }
    out
}

/// Standard base64 (for images inlined in the HTML report).
pub fn base64(data: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(data.len().div_ceil(3) * 4);
    for c in data.chunks(3) {
        let n = (u32::from(c[0]) << 16) | (u32::from(*c.get(1).unwrap_or(&0)) << 8) | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                s.push(T[((n >> (18 - 6 * k)) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// Escapes text for HTML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// An SVG line plot of per-frame values (the worst view's RMSE of each
/// frame), with a dot per frame (one frame is a dot), labelled with the
/// first and last frame numbers.
pub fn svg_plot(values: &[f64], frames: &[usize], label: &str) -> String {
    let (w, h, pad) = (640.0, 220.0, 40.0);
    let max = values.iter().copied().fold(0.0f64, f64::max).max(1e-12);
    let n = values.len().max(2) - 1;
    let xy: Vec<(f64, f64)> = values.iter().enumerate().map(|(i, v)| (pad + (w - 2.0 * pad) * i as f64 / n as f64, h - pad - (h - 2.0 * pad) * v / max)).collect();
    let pts: Vec<String> = xy.iter().map(|(x, y)| format!("{x:.1},{y:.1}")).collect();
    let dots: String = xy.iter().map(|(x, y)| format!("<circle cx='{x:.1}' cy='{y:.1}' r='3' fill='#c33'/>")).collect();
    let (first, last) = (frames.first().copied().unwrap_or(0), frames.last().copied().unwrap_or(0));
    format!(
        "<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' style='background:#fff;border:1px solid #ccc'>\
<text x='{pad}' y='20' font-size='12'>{}: max {:.3e}</text>\
<line x1='{pad}' y1='{}' x2='{}' y2='{}' stroke='#888'/><line x1='{pad}' y1='{pad}' x2='{pad}' y2='{}' stroke='#888'/>\
<polyline fill='none' stroke='#c33' stroke-width='2' points='{}'/>{dots}\
<text x='{pad}' y='{}' font-size='11'>frame {first}</text><text x='{}' y='{}' font-size='11' text-anchor='end'>frame {last}</text></svg>",
        esc(label),
        max,
        h - pad,
        w - pad,
        h - pad,
        h - pad,
        pts.join(" "),
        h - pad + 15.0,
        w - pad,
        h - pad + 15.0,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn previews_are_exposed_from_the_volume() {
        // A dim volume on black: its bright end goes to PREVIEW_WHITE, the background stays black.
        let mut pixels = vec![0.0f32; 3 * 100];
        for (i, p) in pixels.chunks_exact_mut(3).enumerate().take(50) {
            p.fill(0.01 + 0.04 * i as f32 / 49.0);
        }
        let mut img = Image { width: 10, height: 10, pixels };
        let gain = expose(&mut img);
        let top = img.pixels.iter().copied().fold(0.0f32, f32::max);
        assert!((gain - PREVIEW_WHITE / 0.0492).abs() / gain < 0.02, "{gain}");
        assert!(top > PREVIEW_WHITE && top < 0.85, "{top}");
        assert!(img.pixels[150..].iter().all(|&v| v == 0.0));
        // A bright one is toned down; an empty one is left alone.
        let mut bright = Image { width: 1, height: 2, pixels: vec![3.0; 6] };
        assert_eq!(expose(&mut bright), PREVIEW_WHITE / 3.0);
        let mut empty = Image { width: 2, height: 1, pixels: vec![0.0; 6] };
        assert_eq!(expose(&mut empty), 1.0);
        assert_eq!(empty.pixels, vec![0.0; 6]);
    }

    #[test]
    fn base64_matches_the_standard() {
        assert_eq!(base64(b""), "");
        assert_eq!(base64(b"f"), "Zg==");
        assert_eq!(base64(b"fo"), "Zm8=");
        assert_eq!(base64(b"foo"), "Zm9v");
        assert_eq!(base64(b"foobar"), "Zm9vYmFy");
    }

    #[test]
    fn pngs_are_pngs() {
        let img = Image { width: 3, height: 2, pixels: (0..18).map(|k| k as f32 / 12.0 - 0.2).collect() };
        let p = png_rgb(&img);
        assert_eq!(&p[..8], &[0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a]);
        let dec = png::Decoder::new(std::io::Cursor::new(p)).read_info().unwrap();
        assert_eq!((dec.info().width, dec.info().height), (3, 2));
        let h = png_heat(&img, &Image { width: 3, height: 2, pixels: vec![0.0; 18] }, 1.0);
        assert!(h.starts_with(&[0x89, b'P', b'N', b'G']));
        let plot = svg_plot(&[0.1, 0.3, 0.2], &[4, 5, 6], "rmse");
        assert!(plot.contains("polyline") && plot.matches("<circle").count() == 3 && plot.contains("frame 4") && plot.contains("frame 6"));
        // One frame: a dot, labelled with its number.
        let one = svg_plot(&[0.2], &[3], "rmse");
        assert!(one.matches("<circle").count() == 1 && one.contains("frame 3") && !one.contains("frame 0"));
    }
}
