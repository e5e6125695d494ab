//! A channel at its own voxel size drawn by both renderers: at its own level,
//! moved by its half-voxel offset, where its voxels straddle the asset's.

use std::path::Path;
use vdbcook_cook::{ChannelSpec, CookOptions, Cooker, Format, NoProgress};
use vdbcook_grid::lod::{coarsen, Filter};
use vdbcook_validate::{compare, render_cpu, Renderer, Scene};
use vdbcook_vpak::{Asset, Resolution};

fn renderer() -> Option<Renderer> {
    vdbcook_testkit::or_skip(Renderer::new(None), "GPU adapter")
}

/// The smoke fixture as `density`, and its mean filter at twice the voxel
/// size as `smoke`, on a transform that shares the fine grid's origin (its
/// voxel j centred on density's voxel 2j: half a voxel off level 1's).
fn cook(format: Format) -> Asset {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let v = vdbcook_vdb::open(&root.join("fixtures/smoke_seq/smoke_0001.vdb")).unwrap();
    let density = v.read_grid(v.select(None).unwrap()).unwrap();
    let mut smoke = coarsen(&density, Filter::Mean);
    smoke.name = "smoke".into();
    for c in 0..3 {
        smoke.transform.matrix[3][c] = density.transform.matrix[3][c];
    }
    let specs = ["density", "smoke"].map(|n| ChannelSpec { name: n.into(), grid: n.into(), value_type: "float".into(), ..ChannelSpec::default() });
    let mut c = Cooker::with_channels(CookOptions { format, ..CookOptions::default() }, specs.to_vec());
    c.push_channels(&[Some(&density), Some(&smoke)], None).unwrap();
    Asset::from_bytes(&vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)).unwrap()
}

#[test]
fn a_coarse_channel_renders_on_the_gpu_like_its_cpu_twin_at_its_offset() {
    let Some(r) = renderer() else { return };
    for format in [Format::F32, Format::F16, Format::Bc7] {
        let asset = cook(format);
        let meta = asset.metadata().unwrap();
        assert_eq!(meta.resolution(1), Resolution { level: 1, half_offset: [-1; 3] });
        let scene = Scene::for_asset_with(&meta, Some("smoke")).unwrap();
        assert_eq!((scene.shown(), scene.shift, scene.drawn_level(&meta, 0)), (1, [-0.5; 3], 1));
        let fine = Scene::for_asset(&meta);
        assert_eq!((fine.shown(), fine.shift, fine.drawn_level(&meta, 1)), (0, [0.0; 3], 0));
        let gpu = r.upload_for(&asset, &scene).unwrap();
        let gpu_fine = r.upload(&asset).unwrap();
        // Straight on along an axis and at angles: rays cross coarse voxels
        // whose faces lie on fine voxel centres.
        for (i, view) in scene.orbit(4).iter().enumerate() {
            let g = r.render(&gpu, &scene, 0, view, 48, 40).unwrap();
            let c = render_cpu(&asset, &scene, 0, view, 48, 40).unwrap();
            let m = compare(&c, &g);
            assert!(m.max_error < 2e-3, "{format:?} view {i}: {m:?}");
            assert!(g.pixels.iter().any(|&p| p > 0.01), "{format:?} view {i}: the image is empty");
            // The offset moves the picture: drawn without it, the image differs.
            let mut unmoved = scene;
            unmoved.shift = [0.0; 3];
            let u = r.render(&gpu, &unmoved, 0, view, 48, 40).unwrap();
            assert!(compare(&u, &g).rmse > 0.0, "{format:?} view {i}: the offset changed nothing");
            // And the fine channel is its own picture, not the coarse one's.
            assert!(compare(&r.render(&gpu_fine, &fine, 0, view, 48, 40).unwrap(), &g).rmse > 0.0);
        }
    }
}
