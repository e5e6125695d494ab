//! The renderer on real data: GPU against its CPU twin, an f32 asset against
//! itself, lossy and corrupted assets against the lossless reference. GPU
//! tests need an adapter (Mesa's lavapipe is enough); with CI=true a missing
//! adapter fails the test instead of skipping it.

use std::path::Path;
use vdbcook_cook::{CookOptions, Cooker, Format, NoProgress};
use vdbcook_validate::{compare, render_cpu, render_cpu_level, BcDecode, Renderer, Scene};
use vdbcook_vpak::Asset;

fn cook(files: &[&str], format: Format) -> Vec<u8> {
    cook_dim(files, format, 2048)
}

fn cook_dim(files: &[&str], format: Format, max_texture_dim: u32) -> Vec<u8> {
    cook_with(files, CookOptions { format, max_texture_dim, ..CookOptions::default() })
}

fn cook_with(files: &[&str], opts: CookOptions) -> Vec<u8> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut c = Cooker::new(opts);
    for f in files {
        let v = vdbcook_vdb::open(&root.join(f)).unwrap();
        c.push(&v.read_grid(v.select(None).unwrap()).unwrap(), None).unwrap();
    }
    vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)
}

fn renderer() -> Option<Renderer> {
    vdbcook_testkit::or_skip(Renderer::new(None), "GPU adapter")
}

#[test]
fn wgsl_parses_and_validates() {
    for source in vdbcook_validate::shader_sources() {
        let module = naga::front::wgsl::parse_str(source).expect("WGSL parses");
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all()).validate(&module).expect("WGSL validates");
    }
}

/// Levels of detail: the GPU draws each level as its CPU twin does; coarser
/// levels give other images (blurrier) that stay close to level 0's, since the
/// box mean keeps the optical depth; a level the asset lacks is an error.
#[test]
fn every_level_renders_on_the_gpu_like_its_cpu_twin() {
    let Some(r) = renderer() else { return };
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    for format in [Format::F32, Format::Bc7] {
        let mut c = Cooker::new(CookOptions { format, levels: vdbcook_vpak::LevelCount::new(4).unwrap(), ..CookOptions::default() });
        for f in SEQ {
            let v = vdbcook_vdb::open(&root.join(f)).unwrap();
            c.push(&v.read_grid(v.select(None).unwrap()).unwrap(), None).unwrap();
        }
        let asset = Asset::from_bytes(&vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)).unwrap();
        let scene = Scene::for_asset(&asset.metadata().unwrap());
        let gpu = r.upload(&asset).unwrap();
        let views = scene.orbit(2);
        let base = r.render_views_level(&gpu, &scene, 1, 0, &views, 48, 40).unwrap();
        assert_eq!(base, r.render_views(&gpu, &scene, 1, &views, 48, 40).unwrap(), "level 0 is the frame");
        for level in 1..4 {
            let imgs = r.render_views_level(&gpu, &scene, 1, level, &views, 48, 40).unwrap();
            for (i, (g, view)) in imgs.iter().zip(&views).enumerate() {
                let cpu = render_cpu_level(&asset, &scene, 1, level, view, 48, 40).unwrap();
                let m = compare(&cpu, g);
                assert!(m.max_error < 2e-3, "{format:?} level {level} view {i}: {m:?}");
                let d = compare(&base[i], g);
                assert!(d.rmse > 0.0, "{format:?} level {level} view {i}: the same image as level 0");
                assert!(d.psnr > 15.0, "{format:?} level {level} view {i}: far from level 0: {d:?}");
            }
        }
        assert!(r.render_views_level(&gpu, &scene, 1, 4, &views, 48, 40).is_err());
        assert!(render_cpu_level(&asset, &scene, 0, 4, &views[0], 8, 8).is_err());
    }
}

const SEQ: [&str; 2] = ["fixtures/smoke_seq/smoke_0001.vdb", "fixtures/smoke_seq/smoke_0004.vdb"];

#[test]
fn gpu_matches_the_cpu_marcher() {
    let Some(r) = renderer() else { return };
    for files in [&SEQ[..], &["fixtures/tiles.vdb"][..]] {
        for format in Format::ALL {
            let bytes = cook(files, format);
            let asset = Asset::from_bytes(&bytes).unwrap();
            let scene = Scene::for_asset(&asset.metadata().unwrap());
            let gpu = r.upload(&asset).unwrap();
            for (i, view) in scene.orbit(3).iter().enumerate() {
                let frame = i % files.len();
                let g = r.render(&gpu, &scene, frame, view, 48, 40).unwrap();
                let c = render_cpu(&asset, &scene, frame, view, 48, 40).unwrap();
                let m = compare(&c, &g);
                assert!(m.max_error < 2e-3, "{files:?} {format:?} view {i}: {m:?}");
                assert!(g.pixels.iter().any(|&p| p > 0.01), "{files:?}: the image is empty");
            }
        }
    }
}

#[test]
fn an_f32_asset_renders_like_the_reference_and_lossy_ones_do_not() {
    let Some(r) = renderer() else { return };
    let reference = cook(&SEQ, Format::F32);
    let ref_asset = Asset::from_bytes(&reference).unwrap();
    let scene = Scene::for_asset(&ref_asset.metadata().unwrap());
    let views = scene.orbit(2);
    let ref_gpu = r.upload(&ref_asset).unwrap();
    let refs: Vec<_> = views.iter().map(|v| r.render(&ref_gpu, &scene, 1, v, 64, 64).unwrap()).collect();
    let rmse = |bytes: &[u8]| {
        let a = Asset::from_bytes(bytes).unwrap();
        let g = r.upload(&a).unwrap();
        views.iter().zip(&refs).map(|(v, reference)| compare(reference, &r.render(&g, &scene, 1, v, 64, 64).unwrap()).rmse).fold(0.0f64, f64::max)
    };
    assert!(rmse(&cook(&SEQ, Format::F32)) < 1e-6);
    let formats = if r.has_bc() { vec![Format::F16, Format::Unorm8, Format::Bc4, Format::Bc7] } else { vec![Format::F16, Format::Unorm8] };
    let mut last = 0.0;
    for f in formats {
        let e = rmse(&cook(&SEQ, f));
        assert!(e > 0.0 && e < 0.2, "{f:?}: {e}");
        if matches!(f, Format::Bc4 | Format::Bc7) {
            assert!(e > last, "{f:?} should cost more than the formats before it");
        }
        last = e;
    }
    // Corrupt the brick atlas (checksums bypassed: Asset::from_bytes does not verify).
    let mut bad = reference.clone();
    let atlas = ref_asset.sections.iter().find(|s| s.kind == vdbcook_vpak::kind::ATLAS).unwrap();
    for b in &mut bad[atlas.offset as usize..(atlas.offset + atlas.size) as usize] {
        if *b != 0 {
            *b ^= 0x40;
        }
    }
    assert!(Asset::from_bytes(&bad).unwrap().verify().is_err(), "the checksum catches it");
    assert!(rmse(&bad) > 0.05, "a corrupted atlas must show");
}

#[test]
fn several_atlases_render_like_one() {
    let Some(r) = renderer() else { return };
    let one = cook(&SEQ, Format::F32);
    let a1 = Asset::from_bytes(&one).unwrap();
    let scene = Scene::for_asset(&a1.metadata().unwrap());
    let view = scene.orbit(3)[1];
    let reference = r.render(&r.upload(&a1).unwrap(), &scene, 1, &view, 40, 40).unwrap();
    let mut formats = vec![(Format::F32, 32u32), (Format::Unorm8, 32)];
    if r.has_bc() {
        formats.push((Format::Bc4, 32));
        formats.push((Format::Bc7, 20));
    }
    for (format, dim) in formats {
        let bytes = cook_dim(&SEQ, format, dim);
        let asset = Asset::from_bytes(&bytes).unwrap();
        let n = asset.metadata().unwrap().planes[0].atlases.len();
        assert!((2..=4).contains(&n), "{format:?}: {n} atlases");
        let img = r.render(&r.upload(&asset).unwrap(), &scene, 1, &view, 40, 40).unwrap();
        if format == Format::F32 {
            assert!(compare(&reference, &img).rmse < 1e-6, "split f32 atlases must render identically");
            let cpu = render_cpu(&asset, &scene, 1, &view, 40, 40).unwrap();
            assert!(compare(&cpu, &img).max_error < 2e-3);
        } else {
            let same = Asset::from_bytes(&cook(&SEQ, format)).unwrap();
            let whole = r.render(&r.upload(&same).unwrap(), &scene, 1, &view, 40, 40).unwrap();
            assert!(compare(&whole, &img).rmse < 1e-6, "{format:?}: split atlases must render as one");
        }
    }
    let many = Asset::from_bytes(&cook_dim(&SEQ, Format::F32, 16)).unwrap();
    assert!(matches!(r.upload(&many), Err(vdbcook_validate::Error::Textures { .. })));
}

#[test]
fn bc_bricks_decoded_in_the_shader_render_like_the_texture_unit() {
    let Some(r) = renderer() else { return };
    let soft = Renderer::new(None).unwrap().with_bc_decode(BcDecode::Shader);
    let hard = r.has_bc().then(|| Renderer::new(None).unwrap().with_bc_decode(BcDecode::Texture));
    let reference = Asset::from_bytes(&cook(&SEQ, Format::F32)).unwrap();
    let scene = Scene::for_asset(&reference.metadata().unwrap());
    let views = scene.orbit(3);
    let ref_gpu = r.upload(&reference).unwrap();
    // 32 and 20 split the pool over several atlases; with 24, the last atlas is
    // narrower than the others (24×16×8 texels against 24×24×24); with 64, one
    // atlas of several layers, each holding fewer bricks than the limit allows
    // (the 91 bricks fit 7 × 1 × 13 exactly), so a sampler that assumed full
    // rows or layers would misplace them.
    for (files, format, dim) in
        [(&SEQ[..], Format::Bc4, 2048), (&SEQ, Format::Bc7, 2048), (&SEQ, Format::Bc4, 32), (&SEQ, Format::Bc7, 20), (&["fixtures/smoke_seq/smoke_0004.vdb"], Format::Bc4, 24), (&SEQ, Format::Bc7, 64)]
    {
        let bytes = cook_dim(files, format, dim);
        let asset = Asset::from_bytes(&bytes).unwrap();
        let meta = asset.metadata().unwrap();
        if dim == 24 {
            assert!(meta.planes[0].atlases.len() == 3 && meta.planes[0].atlases[2].bricks[1] < meta.planes[0].atlases[0].bricks[1], "{:?}", meta.planes[0].atlases);
        }
        if dim == 64 {
            // One atlas of several layers smaller than the limit's 8 × 8 bricks.
            let [bx, by, bz] = meta.planes[0].atlases[0].bricks;
            assert!(meta.planes[0].atlases.len() == 1 && bz > 1 && bx * by < 64 && bx < 8, "{:?}", meta.planes[0].atlases);
        }
        let in_shader = soft.upload(&asset).unwrap();
        assert!(in_shader.decodes_in_shader());
        for (i, view) in views.iter().enumerate() {
            let frame = i % files.len();
            let s = soft.render(&in_shader, &scene, frame, view, 48, 40).unwrap();
            // The CPU twin decodes blocks with bcdec_rs: any adapter must agree.
            let cpu = render_cpu(&asset, &scene, frame, view, 48, 40).unwrap();
            let m = compare(&cpu, &s);
            assert!(m.max_error < 2e-3, "{format:?} (max dim {dim}) view {i}: shader decode against the CPU twin: {m:?}");
            let lossless = r.render(&ref_gpu, &scene, frame, view, 48, 40).unwrap();
            let e = compare(&lossless, &s).rmse;
            assert!(e > 0.0 && e < 0.2, "{format:?} (max dim {dim}) view {i}: RMSE {e} against the lossless render");
            if let Some(hard) = &hard {
                let hw = hard.upload(&asset).unwrap();
                assert!(!hw.decodes_in_shader());
                let t = hard.render(&hw, &scene, frame, view, 48, 40).unwrap();
                let m = compare(&t, &s);
                // BC7 decodes to exact 8-bit values everywhere. A texture unit may
                // round BC4's interpolated values to 8 bits (lavapipe does); the
                // shader keeps them in float, as the CPU decoder of the cook report.
                let (max, rmse) = if format == Format::Bc7 { (1e-6, 1e-7) } else { (2e-3, 2e-4) };
                assert!(m.max_error <= max && m.rmse <= rmse, "{format:?} (max dim {dim}) view {i}: shader decode differs from the texture unit: {m:?}");
            }
        }
    }
    // Uncompressed formats never go through the decoder.
    assert!(!soft.upload(&reference).unwrap().decodes_in_shader());
}

#[test]
fn per_brick_formats_render_like_the_cpu_twin_on_both_paths() {
    // Assets whose channel is spread over constant, bc7, bc4, unorm8,
    // unorm16 (and f16/f32) planes, some split over several atlases: the
    // texture path and the shader-decode path render what the CPU twin does.
    let Some(r) = renderer() else { return };
    let soft = Renderer::new(None).unwrap().with_bc_decode(BcDecode::Shader);
    for (files, e, dim) in [(&SEQ[..], 0.01, 2048), (&SEQ, 0.001, 2048), (&SEQ, 0.001, 24), (&["fixtures/tiles.vdb"][..], 0.002, 2048)] {
        let asset = Asset::from_bytes(&cook_with(files, CookOptions { max_error: Some(vdbcook_cook::ErrorBound::new(e).unwrap()), max_texture_dim: dim, ..CookOptions::default() })).unwrap();
        let meta = asset.metadata().unwrap();
        if files.len() == 2 {
            assert!(meta.planes.len() >= 4 && !meta.channels[0].alternates.is_empty(), "E = {e}: {:?}", meta.planes.iter().map(|p| p.plane.format).collect::<Vec<_>>());
        }
        let scene = Scene::for_asset(&meta);
        for renderer in [&r, &soft] {
            let gpu = renderer.upload(&asset).unwrap();
            for (i, view) in scene.orbit(3).iter().enumerate() {
                let frame = i % files.len();
                let g = renderer.render(&gpu, &scene, frame, view, 48, 40).unwrap();
                let c = render_cpu(&asset, &scene, frame, view, 48, 40).unwrap();
                let m = compare(&c, &g);
                assert!(m.max_error < 2e-3, "{files:?} E = {e} dim {dim} view {i} (shader decode {}): {m:?}", gpu.decodes_in_shader());
                assert!(g.pixels.iter().any(|&p| p > 0.01), "{files:?}: the image is empty");
            }
        }
    }
}

/// Checksum-valid assets with one flipped bit (the file is resealed after the
/// flip) never panic the renderers: they render, or give an error.
#[test]
fn resealed_corrupt_assets_never_panic_the_renderers() {
    let Some(r) = renderer() else { return };
    let soft = Renderer::new(None).unwrap().with_bc_decode(BcDecode::Shader);
    let mut rng = vdbcook_testkit::Rng::new(0x9E37_79B9_7F4A_7C15);
    let (mut changed, mut refused) = (0, 0);
    for (format, dim) in [(Format::Unorm8, 32), (Format::Bc7, 20), (Format::Bc4, 2048)] {
        let bytes = cook_dim(&SEQ, format, dim);
        let clean = Asset::from_bytes(&bytes).unwrap();
        let scene = Scene::for_asset(&clean.metadata().unwrap());
        let view = scene.orbit(2)[1];
        let expected = render_cpu(&clean, &scene, 1, &view, 32, 24).unwrap();
        let meta = clean.sections.iter().find(|s| s.kind == vdbcook_vpak::kind::METADATA).unwrap();
        for k in 0..80 {
            let mut b = bytes.clone();
            // Every other flip in the metadata, the rest anywhere past the header
            // and the section table.
            let i = if k % 2 == 0 { meta.offset + rng.below(meta.size) } else { 512 + rng.below(b.len() as u64 - 512) } as usize;
            b[i] ^= 1 << rng.below(8);
            let Ok(a) = Asset::from_bytes(&b) else { continue };
            let sealed = vdbcook_vpak::assemble(&a.to_sections());
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                let asset = Asset::from_bytes(&sealed).unwrap();
                // The scene of the clean asset: a flipped bbox must not change the camera.
                let cpu = render_cpu(&asset, &scene, 1, &view, 32, 24).ok();
                for renderer in [&r, &soft] {
                    if let Ok(g) = renderer.upload(&asset) {
                        let _ = renderer.render(&g, &scene, 1, &view, 32, 24);
                    }
                }
                cpu
            }));
            match outcome {
                Ok(Some(img)) => changed += usize::from(img.pixels != expected.pixels),
                Ok(None) => refused += 1,
                Err(_) => panic!("{format:?}: a panic after flipping byte {i}"),
            }
        }
    }
    // The flips reached the renderers: some images changed, some assets were refused.
    eprintln!("corrupt assets: {changed} changed images, {refused} refused");
    assert!(changed >= 3 && refused >= 3, "changed {changed}, refused {refused}");
}

/// `files` cooked with the named grids as channels.
fn cook_channels(files: &[&str], names: &[&str], opts: CookOptions) -> Vec<u8> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let specs = names.iter().map(|n| vdbcook_cook::ChannelSpec { name: n.to_string(), grid: n.to_string(), value_type: "float".into(), ..Default::default() }).collect();
    let mut c = Cooker::with_channels(opts, specs);
    for f in files {
        let v = vdbcook_vdb::open(&root.join(f)).unwrap();
        let grids: Vec<Option<vdbcook_grid::Grid>> = names.iter().map(|n| v.grids.iter().position(|g| g.name == *n).map(|i| v.read_grid(i).unwrap())).collect();
        c.push_channels(&grids.iter().map(Option::as_ref).collect::<Vec<_>>(), None).unwrap();
    }
    vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)
}

#[test]
fn fire_renders_on_the_gpu_like_its_cpu_twin_in_every_packing() {
    let Some(r) = renderer() else { return };
    let soft = Renderer::new(None).unwrap().with_bc_decode(BcDecode::Shader);
    let Some(samples) = std::env::var_os("CARGO_MANIFEST_DIR").map(|d| Path::new(&d).join("../../../shared/vdb-samples")).filter(|p| p.is_dir()) else {
        assert!(std::env::var("CI").ok().as_deref() != Some("true"), "CI=true and ../shared/vdb-samples is missing");
        return;
    };
    let fire: Vec<String> = [1, 3].iter().map(|k| samples.join(format!("vfx-toolkit-embergen/embergen_fire_a_{k}.vdb")).to_string_lossy().into_owned()).collect();
    let smoke: Vec<String> = ["0150", "0152"].iter().map(|k| samples.join(format!("waveletturbulence/fluid_data_{k}.vdb")).to_string_lossy().into_owned()).collect();
    let group = |names: &[&str], format| vdbcook_cook::ChannelGroup { channels: names.iter().map(|n| n.to_string()).collect(), format };
    let cases: Vec<(&[String], Vec<&str>, CookOptions)> = vec![
        (&fire, vec!["temperature", "flames"], CookOptions { format: Format::F16, ..CookOptions::default() }),
        (&fire, vec!["temperature", "flames"], CookOptions { format: Format::Bc7, groups: vec![group(&["temperature", "flames"], Format::Bc7)], ..CookOptions::default() }),
        (&fire, vec!["temperature", "flames"], CookOptions { format: Format::Unorm8, groups: vec![group(&["temperature"], Format::Bc4)], max_texture_dim: 40, ..CookOptions::default() }),
        (&smoke, vec!["density", "temperature", "flame"], CookOptions { format: Format::Unorm8, ..CookOptions::default() }),
        (&smoke, vec!["density", "temperature", "flame"], CookOptions { format: Format::Bc7, groups: vec![group(&["density", "temperature", "flame"], Format::Bc7)], ..CookOptions::default() }),
    ];
    for (files, names, opts) in cases {
        let paths: Vec<&str> = files.iter().map(String::as_str).collect();
        let what = format!("{names:?} {:?} {:?}", opts.format, opts.groups);
        let asset = Asset::from_bytes(&cook_channels(&paths, &names, opts)).unwrap();
        let scene = Scene::for_asset(&asset.metadata().unwrap());
        let fire_asset = names.contains(&"flames");
        if fire_asset {
            assert!(scene.channels[1] != vdbcook_validate::NONE && scene.channels[2] != vdbcook_validate::NONE, "{what}: temperature and flames glow");
        }
        for renderer in [&r, &soft] {
            let gpu = renderer.upload(&asset).unwrap();
            for (i, view) in scene.orbit(2).iter().enumerate() {
                let g = renderer.render(&gpu, &scene, 1, view, 40, 36).unwrap();
                let c = render_cpu(&asset, &scene, 1, view, 40, 36).unwrap();
                let m = compare(&c, &g);
                assert!(m.max_error < 2e-3, "{what} view {i} (shader decode {}): {m:?}", gpu.decodes_in_shader());
                // Fire is coloured: somewhere red is well above blue.
                if fire_asset {
                    assert!(g.pixels.chunks(3).any(|p| p[0] > 0.2 && p[0] > 2.0 * p[2]), "{what}: no fire colour");
                }
            }
        }
    }
}
