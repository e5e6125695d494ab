//! NVIDIA's FLIP (LDR-FLIP, Andersson et al. 2020) through the `nv-flip`
//! bindings to its C++ reference implementation.
//!
//! FLIP judges images as a display shows them: sRGB-encoded values in [0, 1]
//! seen at a number of pixels per degree of visual angle. The ray-marcher's
//! images are linear radiance, so both images are first turned into exactly
//! the 8-bit sRGB pixels of the report's PNGs ([`srgb8`]): linear values
//! clamped to [0, 1], the sRGB transfer curve, rounded to 8 bits. A
//! difference below one 8-bit step is invisible to FLIP (RMSE still sees it).

use crate::{Error, Image};

/// Pixels per degree of visual angle FLIP assumes by default: a 0.7 m wide
/// 4K monitor seen from 0.7 m (the FLIP paper's setting).
pub const DEFAULT_PPD: f32 = 67.0;

/// One image's FLIP error map: a value in [0, 1] per pixel, row-major from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct FlipMap {
    pub width: u32,
    pub height: u32,
    pub errors: Vec<f32>,
}

impl FlipMap {
    /// The mean error: the single figure the FLIP authors recommend.
    pub fn mean(&self) -> f64 {
        // Summed in f64, in pixel order: deterministic and free of float drift.
        self.errors.iter().map(|&e| f64::from(e)).sum::<f64>() / self.errors.len().max(1) as f64
    }

    /// The map through FLIP's magma colour map (as its own tool shows it), 8-bit RGB.
    pub fn magma_rgb8(&self) -> Vec<u8> {
        nv_flip::FlipImageFloat::with_data(self.width, self.height, &self.errors).apply_color_lut(&nv_flip::magma_lut()).to_vec()
    }
}

/// The sRGB transfer curve of a linear value, clamped to [0, 1], rounded to 8 bits.
pub fn srgb8_value(v: f32) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let s = if v <= 0.003_130_8 { v * 12.92 } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0).round() as u8
}

/// For each code k in 1..=255, the smallest linear value that [`srgb8_value`]
/// encodes as k or more (the curve only rises, so a value's code is the
/// number of thresholds at or below it).
fn srgb8_thresholds() -> &'static [f32; 255] {
    static T: std::sync::OnceLock<[f32; 255]> = std::sync::OnceLock::new();
    T.get_or_init(|| {
        std::array::from_fn(|i| {
            let k = i as u8 + 1;
            // Bisection over the bit patterns of [0, 1] (ordered as the values are).
            let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if srgb8_value(f32::from_bits(mid)) >= k {
                    hi = mid;
                } else {
                    lo = mid + 1;
                }
            }
            f32::from_bits(lo)
        })
    })
}

/// For each value of the top 16 bits of a float in [0, 1], the code of the
/// smallest float with those bits: where the search for a code in (0, 1) starts.
fn srgb8_starts() -> &'static [u8] {
    static S: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    S.get_or_init(|| {
        let t = srgb8_thresholds();
        (0..=1.0f32.to_bits() >> 16).map(|hi| t.partition_point(|&x| x <= f32::from_bits(hi << 16)) as u8).collect()
    })
}

/// The 8-bit sRGB pixels of a linear image (what the report's PNGs hold):
/// [`srgb8_value`] of each, found in a table of thresholds instead of a
/// power per value (validate encodes every image two or three times): the
/// number of thresholds at or below the value, counted on from the code of
/// the smallest float that shares its top 16 bits (a step or two at most).
pub fn srgb8(img: &Image) -> Vec<u8> {
    let (t, starts) = (srgb8_thresholds(), srgb8_starts());
    img.pixels
        .iter()
        .map(|&v| {
            if v > 0.0 && v < 1.0 {
                let mut code = starts.get((v.to_bits() >> 16) as usize).map_or(0, |&c| usize::from(c));
                while t.get(code).is_some_and(|&x| x <= v) {
                    code += 1;
                }
                code as u8
            } else {
                // Zero, negative, one and over, infinite, NaN.
                srgb8_value(v)
            }
        })
        .collect()
}

/// FLIP of two 8-bit sRGB RGB images of `width` × `height` pixels.
pub fn flip_srgb8(reference: &[u8], test: &[u8], width: u32, height: u32, ppd: f32) -> Result<FlipMap, Error> {
    let n = width as usize * height as usize * 3;
    if reference.len() != n || test.len() != n {
        return Err(Error::Flip(format!("FLIP needs two {width}x{height} RGB images ({n} bytes), got {} and {} bytes", reference.len(), test.len())));
    }
    if !(ppd.is_finite() && ppd > 0.0) {
        return Err(Error::Flip(format!("FLIP needs a positive number of pixels per degree, not {ppd}")));
    }
    let mut errors = vec![0.0f32; n / 3];
    // FLIP's error at a pixel depends only on the pixels within its filters'
    // reach, and is exactly 0 where both images agree over all of them. So
    // only the box around the pixels that differ, widened by twice that reach
    // (then every pixel whose window the box cuts sees equal images in either
    // computation), is computed: the same map, bit for bit, for less work.
    let Some([x0, y0, x1, y1]) = differing_box(reference, test, width as usize) else {
        return Ok(FlipMap { width, height, errors });
    };
    let margin = 2 * filter_reach(ppd) + 1;
    let (x0, y0) = (x0.saturating_sub(margin), y0.saturating_sub(margin));
    let (x1, y1) = ((x1 + margin).min(width as usize), (y1 + margin).min(height as usize));
    let crop = |img: &[u8]| -> Vec<u8> { (y0..y1).flat_map(|y| &img[(y * width as usize + x0) * 3..(y * width as usize + x1) * 3]).copied().collect() };
    let cw = x1 - x0;
    let map = flip_whole(&crop(reference), &crop(test), cw as u32, (y1 - y0) as u32, ppd);
    for (y, row) in (y0..y1).zip(map.chunks_exact(cw)) {
        errors[y * width as usize + x0..y * width as usize + x1].copy_from_slice(row);
    }
    Ok(FlipMap { width, height, errors })
}

/// FLIP's map of two whole RGB images (no cropping): nv-flip's C++ code.
fn flip_whole(reference: &[u8], test: &[u8], width: u32, height: u32, ppd: f32) -> Vec<f32> {
    if reference.is_empty() {
        return Vec::new();
    }
    let r = nv_flip::FlipImageRgb8::with_data(width, height, reference);
    let t = nv_flip::FlipImageRgb8::with_data(width, height, test);
    nv_flip::flip(r, t, ppd).to_vec()
}

/// `[x0, y0, x1, y1)`: the smallest box holding every pixel where two RGB
/// images of rows `width` pixels long differ; `None` when they are equal.
fn differing_box(reference: &[u8], test: &[u8], width: usize) -> Option<[usize; 4]> {
    let mut b: Option<[usize; 4]> = None;
    for (y, (r, t)) in reference.chunks_exact(width * 3).zip(test.chunks_exact(width * 3)).enumerate() {
        if r == t {
            continue;
        }
        let differs = |x: &usize| r[x * 3..x * 3 + 3] != t[x * 3..x * 3 + 3];
        let first = (0..width).find(differs).unwrap_or(0);
        let last = (0..width).rev().find(differs).unwrap_or(width - 1);
        b = Some(match b {
            None => [first, y, last + 1, y + 1],
            Some([x0, y0, x1, _]) => [x0.min(first), y0, x1.max(last + 1), y + 1],
        });
    }
    b
}

/// How far (in pixels, either axis) FLIP's filters reach from a pixel at
/// `ppd` pixels per degree, with a pixel to spare: the larger radius of its
/// two, computed as its C++ does (`calculateSpatialFilterRadius`: three
/// deviations of the widest Gaussian, scale 0.04; the feature filter: three
/// deviations of 0.5 · 0.082 · ppd).
fn filter_reach(ppd: f32) -> usize {
    let pi = std::f32::consts::PI; // FLIP's 3.14159265358979f is the same float
    let spatial = (3.0 * (0.04 / (2.0 * (pi * pi))).sqrt() * ppd).ceil();
    let feature = (3.0 * (0.5 * 0.082 * ppd)).ceil();
    spatial.max(feature) as usize + 1
}

/// FLIP of two linear images of the same size, compared as 8-bit sRGB (see the module notes).
pub fn flip(reference: &Image, test: &Image, ppd: f32) -> Result<FlipMap, Error> {
    if (reference.width, reference.height) != (test.width, test.height) {
        return Err(Error::Flip(format!("FLIP compares images of one size, not {}x{} and {}x{}", reference.width, reference.height, test.width, test.height)));
    }
    flip_srgb8(&srgb8(reference), &srgb8(test), reference.width, reference.height, ppd)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_threshold_table_encodes_as_the_curve_does() {
        // Every 211th float of [0, 1], the ends, values out of range and NaN.
        let mut values: Vec<f32> = (0..=1.0f32.to_bits()).step_by(211).map(f32::from_bits).collect();
        values.extend([0.0, -0.0, 1.0, -0.5, 2.0, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 0.003_130_8, 1e-30, f32::MIN_POSITIVE, 1e-45]);
        // Each threshold and the floats either side of it.
        values.extend(super::srgb8_thresholds().iter().flat_map(|t| [t.to_bits() - 1, t.to_bits(), t.to_bits() + 1]).map(f32::from_bits));
        let img = super::Image { width: values.len() as u32, height: 1, pixels: values.clone() };
        let fast = super::srgb8(&img);
        for (v, f) in values.iter().zip(&fast) {
            assert_eq!(*f, super::srgb8_value(*v), "{v:e}");
        }
        // Every code is reached, and each threshold is where its code starts.
        assert_eq!(fast.iter().copied().max(), Some(255));
        for (i, &t) in super::srgb8_thresholds().iter().enumerate() {
            assert_eq!(super::srgb8_value(t), i as u8 + 1);
            assert_eq!(super::srgb8_value(f32::from_bits(t.to_bits() - 1)), i as u8, "{t:e}");
        }
    }

    use super::*;

    /// The synthetic pair of `scripts/flip_oracle.py`, built from integers so
    /// both languages make the same bytes: a smooth two-axis gradient with a
    /// soft blob (the kind of content the ray-marcher draws) and a test image
    /// changed by `case`.
    fn oracle_pair(case: u32) -> (Vec<u8>, Vec<u8>, u32, u32) {
        let (w, h) = (96u32, 64u32);
        let mut r = Vec::new();
        let mut t = Vec::new();
        let mut lcg: u32 = 12345;
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as i32 - 40, y as i32 - 30);
                let d2 = (dx * dx + dy * dy) as u32;
                let blob = 200u32.saturating_sub(d2 / 2);
                let px = [(x * 255 / (w - 1) + blob).min(255), (y * 255 / (h - 1)).min(255), (blob + 30).min(255)];
                let mut q = px;
                match case {
                    // Brightness lowered by 12 steps everywhere.
                    1 => q = px.map(|v| v.saturating_sub(12)),
                    // A 16×16 block turned grey.
                    2 if (48..64).contains(&x) && (16..32).contains(&y) => q = [128, 128, 128],
                    // Uniform noise of ±8 steps from a 32-bit LCG.
                    3 => {
                        for v in &mut q {
                            lcg = lcg.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                            *v = (*v as i32 + ((lcg >> 24) % 17) as i32 - 8).clamp(0, 255) as u32;
                        }
                    }
                    _ => {}
                }
                r.extend(px.map(|v| v as u8));
                t.extend(q.map(|v| v as u8));
            }
        }
        (r, t, w, h)
    }

    #[test]
    fn identical_images_have_no_error() {
        let (r, t, w, h) = oracle_pair(0);
        assert_eq!(r, t);
        let m = flip_srgb8(&r, &t, w, h, DEFAULT_PPD).unwrap();
        assert_eq!(m.errors.len(), (w * h) as usize);
        assert_eq!(m.mean(), 0.0);
        assert!(m.errors.iter().all(|&e| e == 0.0));
    }

    /// Mean FLIP against NVIDIA's own FLIP 1.7 (PyPI `flip-evaluator`, a
    /// separate build of the reference code): `python3 scripts/flip_oracle.py`
    /// prints these numbers for the same pixels.
    const ORACLE_1: f64 = 0.258_309_66;
    const ORACLE_2: f64 = 0.041_952_96;
    const ORACLE_3: f64 = 0.058_293_37;

    #[test]
    fn flip_matches_the_reference_implementation() {
        const ORACLE: [(u32, f64); 3] = [(1, ORACLE_1), (2, ORACLE_2), (3, ORACLE_3)];
        for (case, expected) in ORACLE {
            let (r, t, w, h) = oracle_pair(case);
            let m = flip_srgb8(&r, &t, w, h, DEFAULT_PPD).unwrap();
            assert!((m.mean() - expected).abs() < 1e-6, "case {case}: FLIP {} vs the reference's {expected}", m.mean());
            assert!(m.errors.iter().all(|e| (0.0..=1.0).contains(e)));
        }
        // More change, more error: the block and the noise are plainly visible.
        let mean = |c| {
            let (r, t, w, h) = oracle_pair(c);
            flip_srgb8(&r, &t, w, h, DEFAULT_PPD).unwrap().mean()
        };
        assert!(mean(2) > 0.01 && mean(3) > 0.01, "{} {}", mean(2), mean(3));
    }

    #[test]
    fn linear_images_are_compared_as_their_pngs() {
        let img = Image { width: 16, height: 8, pixels: (0..16 * 8 * 3).map(|k| (k % 97) as f32 / 80.0 - 0.1).collect() };
        let png = crate::report::png_rgb(&img);
        let mut dec = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
        let mut buf = vec![0; dec.output_buffer_size().unwrap()];
        let info = dec.next_frame(&mut buf).unwrap();
        assert_eq!(&buf[..info.buffer_size()], srgb8(&img).as_slice());
        assert_eq!(flip(&img, &img, DEFAULT_PPD).unwrap().mean(), 0.0);
        // A change below one 8-bit step is invisible to FLIP.
        let mut tiny = img.clone();
        tiny.pixels[100] += 1e-5;
        assert_eq!(flip(&img, &tiny, DEFAULT_PPD).unwrap().mean(), 0.0);
        let mut dark = img.clone();
        dark.pixels.iter_mut().for_each(|v| *v *= 0.5);
        assert!(flip(&img, &dark, DEFAULT_PPD).unwrap().mean() > 0.01);
    }

    #[test]
    fn the_cropped_map_is_the_whole_map() {
        // Blobs of change at the corners, edges and middle of a textured
        // image, alone and together, at several viewing distances: the map
        // computed over the box around the change is FLIP's map of the whole
        // images, bit for bit (so is every figure made from it).
        let (w, h) = (160usize, 112usize);
        let base: Vec<u8> = (0..w * h * 3).map(|i| ((i * 7919 + (i / (w * 3)) * 31) % 251) as u8 / 2 + 40).collect();
        let spots: [&[(usize, usize)]; 6] = [&[(0, 0)], &[(w - 1, h - 1)], &[(80, 0)], &[(80, 56)], &[(30, 90), (130, 20)], &[(3, 60), (150, 60)]];
        for ppd in [10.0, DEFAULT_PPD, 120.0] {
            for spot in spots {
                let mut test = base.clone();
                for &(cx, cy) in spot {
                    for y in cy.saturating_sub(2)..(cy + 3).min(h) {
                        for x in cx.saturating_sub(3)..(cx + 2).min(w) {
                            test[(y * w + x) * 3 + (x + y) % 3] ^= 0x55;
                        }
                    }
                }
                let whole = flip_whole(&base, &test, w as u32, h as u32, ppd);
                let cropped = flip_srgb8(&base, &test, w as u32, h as u32, ppd).unwrap();
                assert_eq!(cropped.errors.len(), whole.len());
                let same = cropped.errors.iter().zip(&whole).all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "ppd {ppd}, spots {spot:?}");
                assert!(cropped.mean() > 0.0);
            }
        }
        // Equal images: an all-zero map, as FLIP gives.
        let same = flip_srgb8(&base, &base, w as u32, h as u32, DEFAULT_PPD).unwrap();
        assert!(same.errors.iter().zip(flip_whole(&base, &base, w as u32, h as u32, DEFAULT_PPD)).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    fn the_reach_covers_flips_filters() {
        // At FLIP's default distance its filters reach 10 pixels (spatial)
        // and 9 (features), by its own formulas worked in f64.
        for ppd in [1.0f32, 10.0, DEFAULT_PPD, 120.0, 1000.0] {
            let p = f64::from(ppd);
            let spatial = (3.0 * (0.04 / (2.0 * std::f64::consts::PI * std::f64::consts::PI)).sqrt() * p).ceil() as usize;
            let feature = (1.5 * 0.082 * p).ceil() as usize;
            assert!(filter_reach(ppd) > spatial.max(feature), "{ppd}");
        }
        assert_eq!(filter_reach(DEFAULT_PPD), 11);
    }

    #[test]
    fn mismatched_inputs_are_errors_not_panics() {
        let a = Image { width: 8, height: 8, pixels: vec![0.5; 8 * 8 * 3] };
        let b = Image { width: 8, height: 4, pixels: vec![0.5; 8 * 4 * 3] };
        assert!(matches!(flip(&a, &b, DEFAULT_PPD), Err(Error::Flip(_))));
        assert!(matches!(flip_srgb8(&[0; 10], &[0; 12], 2, 2, DEFAULT_PPD), Err(Error::Flip(_))));
        assert!(matches!(flip(&a, &a, f32::NAN), Err(Error::Flip(_))));
        assert!(matches!(flip(&a, &a, 0.0), Err(Error::Flip(_))));
    }

    #[test]
    fn the_magma_map_is_rgb() {
        let (r, t, w, h) = oracle_pair(2);
        let m = flip_srgb8(&r, &t, w, h, DEFAULT_PPD).unwrap();
        let rgb = m.magma_rgb8();
        assert_eq!(rgb.len(), (w * h * 3) as usize);
        // Magma's zero is near-black, its one a pale yellow: an unchanged pixel is dark.
        assert!(rgb[..3].iter().all(|&c| c < 16), "{:?}", &rgb[..3]);
    }
}
