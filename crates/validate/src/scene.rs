//! What the validation scene shows of an asset: which channel is the medium
//! and how it is drawn ([`Model`]), the backdrop, and the coverage figure.

use crate::{Error, Image, Scene, View};
use vdbcook_vpak::Metadata;

/// How the scene draws the channel it shows ([`Scene::shown`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Model {
    /// A fog that absorbs and scatters (albedo 1), temperature and flames glowing in it.
    Scatter,
    /// No scattering medium: a glow channel (flames, else temperature) absorbs
    /// without scattering and glows, in front of a neutral backdrop.
    Glow,
    /// A level set drawn as a lit opaque surface at its zero crossing.
    Surface,
}

impl Model {
    /// "scatter", "glow" or "surface".
    pub fn name(self) -> &'static str {
        match self {
            Model::Scatter => "scatter",
            Model::Glow => "glow",
            Model::Surface => "surface",
        }
    }

    /// The code the shader reads (`params.channels.w`).
    pub(crate) fn code(self) -> u32 {
        match self {
            Model::Scatter => 0,
            Model::Glow => 1,
            Model::Surface => 2,
        }
    }
}

pub(crate) const TEMPERATURE: [&str; 2] = ["temperature", "heat"];
pub(crate) const FLAMES: [&str; 2] = ["flames", "flame"];

pub(crate) fn find(meta: &Metadata, names: &[&str]) -> Option<usize> {
    meta.channels.iter().position(|c| names.contains(&c.name.as_str()))
}

fn is_glow(name: &str) -> bool {
    TEMPERATURE.contains(&name) || FLAMES.contains(&name)
}

/// The channel a scene shows and how: the channel `extinction` names (an
/// error when the asset has none of that name); else `density`; else the
/// first scalar channel of class "fog volume" or "unknown" that is not a glow
/// channel; each of these scatters. Else the first scalar level set (a
/// surface); else flames, else temperature (they absorb and glow); else the
/// first channel, scattering.
pub(crate) fn choose(meta: &Metadata, extinction: Option<&str>) -> Result<(usize, Model), Error> {
    match extinction {
        Some(name) => find(meta, &[name]).map(|c| (c, Model::Scatter)).ok_or_else(|| Error::Extinction {
            name: name.to_string(),
            channels: if meta.channels.is_empty() { "none".into() } else { meta.channels.iter().map(|c| format!("\"{}\"", c.name)).collect::<Vec<_>>().join(", ") },
        }),
        None => Ok(choose_default(meta)),
    }
}

/// [`choose`] without a named channel.
pub(crate) fn choose_default(meta: &Metadata) -> (usize, Model) {
    let scalar = |class: &[&str]| meta.channels.iter().position(|c| c.component.is_none() && class.contains(&c.class.as_str()) && !is_glow(&c.name));
    if let Some(c) = find(meta, &["density"]).or_else(|| scalar(&["fog volume", "unknown"])) {
        return (c, Model::Scatter);
    }
    if let Some(c) = scalar(&["level set"]) {
        return (c, Model::Surface);
    }
    if let Some(c) = find(meta, &FLAMES).or_else(|| find(meta, &TEMPERATURE)) {
        return (c, Model::Glow);
    }
    (0, Model::Scatter)
}

/// The backdrop seen along the (normalised) ray direction `d`, as `backdrop`
/// in march.wgsl: a neutral grey, lighter upwards, with a soft checker of
/// about 18° cells, so that an absorbing medium shows against it and its
/// structure with it. Smooth everywhere: rounding differences between the
/// GPU and the CPU never flip a cell.
pub(crate) fn backdrop(d: [f32; 3]) -> f32 {
    let base = 0.2 + 0.1 * d[1];
    let checker = (10.0 * d[0]).sin() * (10.0 * d[1]).sin() * (10.0 * d[2]).sin();
    base * (1.0 + 0.5 * checker)
}

/// The ray direction of pixel (`x`, `y`) of a `width` × `height` image from
/// `view`, as `main` in march.wgsl.
pub(crate) fn ray_dir(basis: ([f32; 3], [f32; 3], [f32; 3]), tf: f32, x: u32, y: u32, width: u32, height: u32) -> [f32; 3] {
    let (r, u, f) = basis;
    let aspect = width as f32 / height as f32;
    let px = (x as f32 + 0.5) / width as f32 * 2.0 - 1.0;
    let py = 1.0 - (y as f32 + 0.5) / height as f32 * 2.0;
    let dir = [0, 1, 2].map(|a| f[a] + r[a] * (px * tf * aspect) + u[a] * (py * tf));
    let l = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
    dir.map(|c| c / l)
}

impl Scene {
    /// How the scene draws what it shows.
    pub fn model(&self) -> Model {
        self.model
    }

    /// The channel whose voxels the images show: the extinction channel, or
    /// the level set drawn as a surface.
    pub fn shown(&self) -> usize {
        self.channels[0] as usize
    }

    /// Whether the images have the backdrop behind the volume (the glow model).
    pub fn has_backdrop(&self) -> bool {
        self.model == Model::Glow
    }

    /// What the scene shows from `view` with no volume in it: the backdrop
    /// for the glow model, else black (the march's formula, on the CPU).
    pub fn empty_image(&self, view: &View, width: u32, height: u32) -> Image {
        let mut pixels = vec![0.0f32; width as usize * height as usize * 3];
        if self.has_backdrop() {
            let basis = view.basis();
            let tf = (view.fov_deg.to_radians() * 0.5).tan();
            for (i, px) in pixels.chunks_exact_mut(3).enumerate() {
                let (x, y) = ((i % width as usize) as u32, (i / width as usize) as u32);
                px.fill(backdrop(ray_dir(basis, tf, x, y, width, height)));
            }
        }
        Image { width, height, pixels }
    }
}

/// The share of pixels (0 to 1) where `reference` differs from `empty` (what
/// the scene shows without a volume, [`Scene::empty_image`]) by more than one
/// step in any channel of the 8-bit sRGB images the report's PNGs hold.
/// Images of different sizes cover everything (1).
pub fn coverage(reference: &Image, empty: &Image) -> f64 {
    if (reference.width, reference.height) != (empty.width, empty.height) || reference.pixels.len() != empty.pixels.len() {
        return 1.0;
    }
    coverage_srgb8(&crate::flip::srgb8(reference), &crate::flip::srgb8(empty))
}

/// [`coverage`] of two images already encoded as 8-bit sRGB RGB of one size.
pub fn coverage_srgb8(reference: &[u8], empty: &[u8]) -> f64 {
    let pixels = reference.len().min(empty.len()) / 3;
    if pixels == 0 {
        return 0.0;
    }
    let covered = reference.chunks_exact(3).zip(empty.chunks_exact(3)).filter(|(p, q)| p.iter().zip(q.iter()).any(|(x, y)| x.abs_diff(*y) > 1)).count();
    covered as f64 / pixels as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(channels: &[(&str, &str, Option<u32>)]) -> Metadata {
        let channels = channels
            .iter()
            .map(|&(name, class, component)| vdbcook_vpak::Channel {
                name: name.into(),
                grid: name.into(),
                component,
                value_type: "float".into(),
                class: class.into(),
                background: 0.0,
                value_range: [0.0, 1.0],
                group: 0,
                plane: 0,
                lane: 0,
                alternates: Vec::new(),
            })
            .collect();
        Metadata {
            tool: String::new(),
            frame_count: 1,
            map_type: String::new(),
            transform: [[0.0; 4]; 4],
            index_offset: [0; 3],
            index_bbox: None,
            channels,
            planes: Vec::new(),
            brick_count: 0,
            settings: Vec::new(),
            sources: Vec::new(),
            frames: Vec::new(),
            levels: 1,
            level_filters: Vec::new(),
            first_level: 0,
            time: None,
            resolutions: Vec::new(),
        }
    }

    #[test]
    fn the_medium_comes_from_what_the_grid_is() {
        let fog = "fog volume";
        let pick = |m: &Metadata| choose(m, None).unwrap();
        assert_eq!(pick(&meta(&[("temperature", fog, None), ("density", fog, None)])), (1, Model::Scatter));
        assert_eq!(pick(&meta(&[("temperature", fog, None), ("smoke", fog, None)])), (1, Model::Scatter));
        assert_eq!(pick(&meta(&[("", "unknown", None)])), (0, Model::Scatter));
        assert_eq!(pick(&meta(&[("vel.x", fog, Some(0)), ("flames", fog, None), ("dens", "unknown", None)])), (2, Model::Scatter));
        // A fog beats a level set; a level set beats glow.
        assert_eq!(pick(&meta(&[("surface", "level set", None), ("smoke", fog, None)])), (1, Model::Scatter));
        assert_eq!(pick(&meta(&[("heat", fog, None), ("surface", "level set", None)])), (1, Model::Surface));
        assert_eq!(pick(&meta(&[("temperature", fog, None), ("flame", fog, None)])), (1, Model::Glow));
        assert_eq!(pick(&meta(&[("temperature", fog, None)])), (0, Model::Glow));
        assert_eq!(pick(&meta(&[("vel.x", fog, Some(0)), ("stag", "staggered", None)])), (0, Model::Scatter));
        // A named channel scatters whatever it is; a missing one is an error naming the channels.
        assert_eq!(choose(&meta(&[("density", fog, None), ("flames", fog, None)]), Some("flames")).unwrap(), (1, Model::Scatter));
        let e = choose(&meta(&[("density", fog, None), ("flames", fog, None)]), Some("smoke")).unwrap_err().to_string();
        assert_eq!(e, "the asset has no channel \"smoke\" to give extinction (its channels: \"density\", \"flames\")");
        assert!(!e.contains('\n'));
    }

    #[test]
    fn coverage_counts_pixels_more_than_one_step_away() {
        let empty = Image { width: 2, height: 2, pixels: vec![0.0; 12] };
        let mut img = empty.clone();
        assert_eq!(coverage(&img, &empty), 0.0);
        // One 8-bit sRGB step at black is about 3.0e-4 linear: one step is not covered, two are.
        img.pixels[0] = 1.0 / 255.0 / 12.92;
        assert_eq!(coverage(&img, &empty), 0.0);
        img.pixels[4] = 2.0 / 255.0 / 12.92;
        assert_eq!(coverage(&img, &empty), 0.25);
        img.pixels[11] = 1.0;
        assert_eq!(coverage(&img, &empty), 0.5);
        // Values past [0, 1] are clamped as the PNGs do.
        let over = Image { width: 2, height: 2, pixels: vec![-1.0; 12] };
        assert_eq!(coverage(&over, &empty), 0.0);
    }
}
