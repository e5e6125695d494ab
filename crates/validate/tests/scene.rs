//! The validation scene on generated grids: a fog renders whatever its name,
//! level sets render as surfaces, non-finite voxels never reach the image,
//! an absorbing-only medium shows against the backdrop, and the coverage
//! figure tells a blank picture from a drawn one. GPU tests need an adapter
//! (Mesa's lavapipe is enough); with CI=true a missing adapter fails them.

use vdbcook_cook::{CookOptions, Cooker, Format, NoProgress};
use vdbcook_grid::{leaf_local, Coord, Grid, GridClass, Leaf, LeafMask, Transform};
use vdbcook_validate::{compare, coverage, render_cpu, Image, Model, Renderer, Scene, View};
use vdbcook_vpak::Asset;

fn renderer() -> Option<Renderer> {
    vdbcook_testkit::or_skip(Renderer::new(None), "GPU adapter")
}

/// A grid whose voxels in [0, size)³ are active where `f` gives a value.
fn grid(name: &str, class: GridClass, background: f32, size: i32, f: impl Fn(i32, i32, i32) -> Option<f32>) -> Grid {
    let mut leaves = Vec::new();
    for ox in (0..size).step_by(8) {
        for oy in (0..size).step_by(8) {
            for oz in (0..size).step_by(8) {
                let (mut mask, mut values) = (LeafMask::default(), [background; 512]);
                for (v, value) in values.iter_mut().enumerate() {
                    let (x, y, z) = leaf_local(v);
                    let p = (ox + x, oy + y, oz + z);
                    if let (true, Some(val)) = (p.0 < size && p.1 < size && p.2 < size, f(p.0, p.1, p.2)) {
                        mask.set(v, true);
                        *value = val;
                    }
                }
                if !mask.is_empty() {
                    leaves.push(Leaf { origin: Coord::new(ox, oy, oz), mask, values });
                }
            }
        }
    }
    leaves.sort_by_key(|l| l.origin);
    Grid { name: name.into(), class, background, transform: Transform::identity(), leaves, tiles: Vec::new() }
}

fn dist(x: i32, y: i32, z: i32, c: i32) -> f32 {
    (((x - c) * (x - c) + (y - c) * (y - c) + (z - c) * (z - c)) as f32).sqrt()
}

/// A soft ball of fog (1 at the centre, 0 at radius 12) around (16, 16, 16).
fn fog(name: &str, class: GridClass) -> Grid {
    grid(name, class, 0.0, 32, |x, y, z| {
        let d = dist(x, y, z, 16);
        (d < 12.0).then(|| 1.0 - d / 12.0)
    })
}

/// A level-set sphere of `radius` voxels around (24, 24, 24), a band of 3 voxels each side.
fn sphere(radius: f32) -> Grid {
    grid("surface", GridClass::LevelSet, 3.0, 48, |x, y, z| {
        let v = dist(x, y, z, 24) - radius;
        (v.abs() < 3.0).then_some(v)
    })
}

fn cook(frames: &[Grid], opts: CookOptions) -> Asset {
    let mut c = Cooker::new(opts);
    for g in frames {
        c.push(g, None).unwrap();
    }
    Asset::from_bytes(&vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)).unwrap()
}

fn f32_cook(frames: &[Grid]) -> Asset {
    cook(frames, CookOptions { format: Format::F32, ..CookOptions::default() })
}

fn render(r: &Renderer, asset: &Asset, scene: &Scene, views: &[View], size: u32) -> Vec<Image> {
    let gpu = r.upload_for(asset, scene).unwrap();
    r.render_views(&gpu, scene, 0, views, size, size).unwrap()
}

#[test]
fn a_fog_renders_the_same_whatever_its_name() {
    let Some(r) = renderer() else { return };
    let density = f32_cook(&[fog("density", GridClass::FogVolume)]);
    let scene = Scene::for_asset(&density.metadata().unwrap());
    assert_eq!((scene.shown(), scene.model()), (0, Model::Scatter));
    let views = scene.orbit(2);
    let base = render(&r, &density, &scene, &views, 48);
    for (img, view) in base.iter().zip(&views) {
        let c = coverage(img, &scene.empty_image(view, 48, 48));
        assert!(c > 0.1, "the fog covers {c} of the image");
    }
    for (name, class) in [("smoke", GridClass::FogVolume), ("dens", GridClass::FogVolume), ("", GridClass::Unknown), ("", GridClass::FogVolume)] {
        let asset = f32_cook(&[fog(name, class)]);
        let meta = asset.metadata().unwrap();
        assert_eq!(meta.channels[0].name, name);
        let scene = Scene::for_asset(&meta);
        assert_eq!(scene.model(), Model::Scatter, "{name:?}");
        assert_eq!(render(&r, &asset, &scene, &views, 48), base, "{name:?} {class:?}: not the image of `density`");
        // Named, it scatters too; a name the asset lacks is a one-line error.
        assert_eq!(Scene::for_asset_with(&meta, Some(name)).unwrap(), scene);
        let e = Scene::for_asset_with(&meta, Some("missing")).unwrap_err().to_string();
        assert!(e.contains("\"missing\"") && e.contains(&format!("\"{name}\"")) && !e.contains('\n'), "{e}");
    }
}

/// The expected silhouette radius in pixels of a sphere of `radius` at the
/// view's target, in a square image of `size` pixels.
fn projected_radius(view: &View, radius: f32, size: u32) -> f32 {
    let d = (0..3).map(|a| (view.eye[a] - view.target[a]).powi(2)).sum::<f32>().sqrt();
    (radius / d).asin().tan() / (view.fov_deg.to_radians() * 0.5).tan() * size as f32 * 0.5
}

#[test]
fn a_level_set_renders_as_a_surface_on_the_gpu_like_its_cpu_twin() {
    let Some(r) = renderer() else { return };
    let asset = f32_cook(&[sphere(10.0)]);
    let meta = asset.metadata().unwrap();
    let scene = Scene::for_asset(&meta);
    assert_eq!((scene.shown(), scene.model(), scene.model().name()), (0, Model::Surface, "surface"));
    let views = scene.orbit(3);
    let size = 96;
    let imgs = render(&r, &asset, &scene, &views, size);
    for (i, (g, view)) in imgs.iter().zip(&views).enumerate() {
        let c = render_cpu(&asset, &scene, 0, view, size, size).unwrap();
        let m = compare(&c, g);
        assert!(m.max_error < 2e-3, "view {i}: {m:?}");
        // The sphere's centre is the box's, which the views look at: the
        // silhouette is a disc around the image centre.
        let covered = g.pixels.chunks(3).filter(|p| p[0] > 0.0).count();
        assert!(g.pixels.chunks(3).all(|p| p[0] == 0.0 || p[0] >= 0.8 * 0.25 - 1e-6), "view {i}: lit surface or black background");
        let measured = (covered as f32 / std::f32::consts::PI).sqrt();
        let expected = projected_radius(view, 10.0, size);
        assert!((measured - expected).abs() < 1.0, "view {i}: silhouette radius {measured} px, the sphere's {expected} px");
        assert_eq!(scene.empty_image(view, size, size).pixels, vec![0.0; g.pixels.len()]);
        let c = coverage(g, &scene.empty_image(view, size, size));
        eprintln!("view {i}: silhouette radius {measured} px, expected {expected} px, coverage {c}");
        assert!(c > 0.05, "view {i}: coverage {c}");
    }
    // A coarser level draws the level's own voxels, as the twin does.
    let levels = cook(&[sphere(10.0)], CookOptions { format: Format::F32, levels: vdbcook_vpak::LevelCount::new(2).unwrap(), ..CookOptions::default() });
    let gpu = r.upload_for(&levels, &scene).unwrap();
    let coarse = r.render_views_level(&gpu, &scene, 0, 1, &views[..1], size, size).unwrap();
    let cpu = vdbcook_validate::render_cpu_level(&levels, &scene, 0, 1, &views[0], size, size).unwrap();
    assert!(compare(&cpu, &coarse[0]).max_error < 2e-3, "level 1: {:?}", compare(&cpu, &coarse[0]));
    assert!(compare(&imgs[0], &coarse[0]).rmse > 0.0 && coverage(&coarse[0], &scene.empty_image(&views[0], size, size)) > 0.05);
    // The same surface a voxel further out: another image.
    let moved = f32_cook(&[sphere(11.0)]);
    let moved_imgs = render(&r, &moved, &scene, &views, size);
    for (i, (a, b)) in imgs.iter().zip(&moved_imgs).enumerate() {
        let m = compare(a, b);
        assert!(m.rmse > 0.01, "view {i}: moving the surface a voxel changes little: {m:?}");
    }
}

#[test]
fn a_lossy_level_set_moves_the_surface_more_as_the_error_bound_grows() {
    let Some(r) = renderer() else { return };
    let frames = [sphere(10.3)];
    let reference = f32_cook(&frames);
    let scene = Scene::for_asset(&reference.metadata().unwrap());
    let views = scene.orbit(2);
    let refs = render(&r, &reference, &scene, &views, 64);
    let rmse = |asset: &Asset| render(&r, asset, &scene, &views, 64).iter().zip(&refs).map(|(a, b)| compare(b, a).rmse).fold(0.0f64, f64::max);
    for format in [Format::Unorm8, Format::Bc7] {
        let e = rmse(&cook(&frames, CookOptions { format, ..CookOptions::default() }));
        assert!(e > 0.0, "{format:?}: the image error of a lossy level set is 0");
    }
    let series: Vec<f64> = [0.003f32, 0.03, 0.3].iter().map(|&e| rmse(&cook(&frames, CookOptions { max_error: Some(vdbcook_cook::ErrorBound::new(e).unwrap()), ..CookOptions::default() }))).collect();
    eprintln!("level set, image RMSE at --max-error 0.003, 0.03, 0.3: {series:?}");
    assert!(series[0] > 0.0 && series.windows(2).all(|w| w[0] <= w[1]) && series[2] > series[0], "{series:?}");
}

#[test]
fn non_finite_voxels_never_reach_the_image() {
    let Some(r) = renderer() else { return };
    let clean = f32_cook(&[fog("density", GridClass::FogVolume)]);
    let scene = Scene::for_asset(&clean.metadata().unwrap());
    let views = scene.orbit(2);
    let base = render(&r, &clean, &scene, &views, 48);
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        for format in [Format::F32, Format::F16] {
            let mut g = fog("density", GridClass::FogVolume);
            let mut faulty = 0;
            for l in g.leaves.iter_mut() {
                for v in 0..512 {
                    let (x, y, z) = leaf_local(v);
                    let p = (l.origin.x + x, l.origin.y + y, l.origin.z + z);
                    // Not the peak (16, 16, 16): the scene's extinction scale stays.
                    if [(16, 17, 16), (15, 16, 16), (16, 20, 14)].contains(&p) {
                        l.values[v] = bad;
                        faulty += 1;
                    }
                }
            }
            assert_eq!(faulty, 3);
            let asset = cook(&[g], CookOptions { format, ..CookOptions::default() });
            // Validation draws both with the reference's scene; the asset's own stays usable.
            let own = Scene::for_asset(&asset.metadata().unwrap());
            assert!(own.density_scale.is_finite() && own.density_scale > 0.0, "{bad} {format:?}: {own:?}");
            for (i, (img, view)) in render(&r, &asset, &scene, &views, 48).iter().zip(&views).enumerate() {
                let m = compare(&base[i], img);
                assert!(m.rmse < 2e-3 && m.max_error < 0.03, "{bad} {format:?} view {i}: {m:?}");
                assert!(coverage(img, &scene.empty_image(view, 48, 48)) > 0.1, "{bad} {format:?} view {i}: blank");
                let cpu = render_cpu(&asset, &scene, 0, view, 48, 48).unwrap();
                assert!(compare(&cpu, img).max_error < 2e-3, "{bad} {format:?} view {i}: against the CPU twin");
            }
        }
    }
}

/// 8-bit sRGB pixels of two images differ by at most one step.
fn within_one_step(a: &Image, b: &Image) -> bool {
    coverage(a, b) == 0.0
}

#[test]
fn absorbing_only_media_show_against_the_backdrop_and_fogs_do_not_get_one() {
    let Some(r) = renderer() else { return };
    let hot = f32_cook(&[fog("temperature", GridClass::FogVolume)]);
    let scene = Scene::for_asset(&hot.metadata().unwrap());
    assert_eq!((scene.model(), scene.has_backdrop(), scene.emission[3]), (Model::Glow, true, 0.0));
    let views = scene.orbit(2);
    let size = 64;
    for (i, (g, view)) in render(&r, &hot, &scene, &views, size).iter().zip(&views).enumerate() {
        let empty = scene.empty_image(view, size, size);
        let c = coverage(g, &empty);
        assert!(c > 0.05 && c < 0.9, "view {i}: coverage {c}");
        let cpu = render_cpu(&hot, &scene, 0, view, size, size).unwrap();
        assert!(compare(&cpu, g).max_error < 2e-3, "view {i}: against the CPU twin");
        // The backdrop is there and not flat; a corner the volume does not cover is the empty scene's.
        assert!(empty.pixels.iter().all(|&p| p > 0.02) && empty.pixels.iter().any(|&p| (p - empty.pixels[0]).abs() > 0.02));
        let corner = |img: &Image| Image { width: 4, height: 4, pixels: (0..16).flat_map(|k| img.pixels[3 * ((k / 4) * size as usize + k % 4)..][..3].to_vec()).collect() };
        assert!(within_one_step(&corner(g), &corner(&empty)), "view {i}: the corner differs from the empty scene");
    }
    // A scattering fog: no backdrop (a pixel off the volume is exactly 0), the CPU twin agrees.
    let smoke = f32_cook(&[fog("smoke", GridClass::FogVolume)]);
    let scene = Scene::for_asset(&smoke.metadata().unwrap());
    assert!(!scene.has_backdrop());
    for (i, (g, view)) in render(&r, &smoke, &scene, &views, size).iter().zip(&views).enumerate() {
        assert_eq!(&g.pixels[..3], &[0.0; 3], "view {i}");
        assert_eq!(scene.empty_image(view, size, size).pixels, vec![0.0; g.pixels.len()]);
        let cpu = render_cpu(&smoke, &scene, 0, view, size, size).unwrap();
        assert!(compare(&cpu, g).max_error < 2e-3, "view {i}: against the CPU twin");
    }
}

#[test]
fn the_empty_image_is_what_an_asset_without_active_voxels_renders() {
    let Some(r) = renderer() else { return };
    // A sequence whose first frame has nothing: that frame renders as the empty scene.
    let frames = [grid("temperature", GridClass::FogVolume, 0.0, 16, |_, _, _| None), fog("temperature", GridClass::FogVolume)];
    let asset = f32_cook(&frames);
    let scene = Scene::for_asset(&asset.metadata().unwrap());
    assert_eq!(scene.model(), Model::Glow);
    let views = scene.orbit(3);
    let gpu = r.upload_for(&asset, &scene).unwrap();
    for (i, view) in views.iter().enumerate() {
        let empty = scene.empty_image(view, 40, 32);
        let g = r.render(&gpu, &scene, 0, view, 40, 32).unwrap();
        assert!(within_one_step(&g, &empty) && compare(&g, &empty).max_error < 1e-4, "view {i}: {:?}", compare(&g, &empty));
        assert_eq!(render_cpu(&asset, &scene, 0, view, 40, 32).unwrap(), empty, "view {i}: the CPU twin draws the backdrop with the same formula");
        assert!(coverage(&r.render(&gpu, &scene, 1, view, 40, 32).unwrap(), &empty) > 0.05);
    }
    // Without a backdrop the empty scene is black.
    let frames = [grid("density", GridClass::FogVolume, 0.0, 16, |_, _, _| None), fog("density", GridClass::FogVolume)];
    let asset = f32_cook(&frames);
    let scene = Scene::for_asset(&asset.metadata().unwrap());
    let view = scene.orbit(1)[0];
    let g = r.render(&r.upload(&asset).unwrap(), &scene, 0, &view, 40, 32).unwrap();
    assert_eq!(g, scene.empty_image(&view, 40, 32));
    assert_eq!(coverage(&g, &scene.empty_image(&view, 40, 32)), 0.0);
}

#[test]
fn a_fog_beside_a_level_set_is_the_medium() {
    let Some(r) = renderer() else { return };
    let mut c = Cooker::with_channels(
        CookOptions { format: Format::F32, ..CookOptions::default() },
        ["surface", "smoke"].iter().map(|n| vdbcook_cook::ChannelSpec { name: n.to_string(), grid: n.to_string(), value_type: "float".into(), ..Default::default() }).collect(),
    );
    let (s, f) = (sphere(10.0), fog("smoke", GridClass::FogVolume));
    c.push_channels(&[Some(&s), Some(&f)], None).unwrap();
    let asset = Asset::from_bytes(&vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)).unwrap();
    let meta = asset.metadata().unwrap();
    let scene = Scene::for_asset(&meta);
    assert_eq!((scene.shown(), scene.model()), (1, Model::Scatter));
    assert_eq!(vdbcook_validate::extinction_channel(&meta), 1);
    let view = scene.orbit(1)[0];
    let g = r.render(&r.upload(&asset).unwrap(), &scene, 0, &view, 40, 40).unwrap();
    assert!(compare(&render_cpu(&asset, &scene, 0, &view, 40, 40).unwrap(), &g).max_error < 2e-3);
    assert!(coverage(&g, &scene.empty_image(&view, 40, 40)) > 0.05);
}
