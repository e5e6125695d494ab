//! Channels at their own voxel size: a coarse channel stored at the level
//! whose voxels are its own, round trips, levels of detail and refusals.

use super::*;
use vdbcook_grid::{Coord, Grid, GridClass, Leaf, LeafMask, MapType, Transform};
use vdbcook_vpak::{Asset, Resolution};

/// A grid of `leaves` leaves in a row, every voxel active, values from `seed`.
fn grid(name: &str, transform: Transform, leaves: i32, seed: f32) -> Grid {
    let leaves = (0..leaves)
        .map(|i| {
            let mut values = [0.0f32; 512];
            for (v, value) in values.iter_mut().enumerate() {
                *value = ((v as f32) * 0.37 + seed + i as f32).sin() * 0.5 + 0.5;
            }
            Leaf { origin: Coord::new(i * 8, 0, -8), mask: LeafMask([u64::MAX; 8]), values }
        })
        .collect();
    Grid { name: name.into(), class: GridClass::FogVolume, background: 0.0, transform, leaves, tiles: Vec::new() }
}

fn specs(names: &[&str]) -> Vec<ChannelSpec> {
    names.iter().map(|n| ChannelSpec { name: n.to_string(), grid: n.to_string(), value_type: "float".into(), ..ChannelSpec::default() }).collect()
}

fn scale(s: f64, t: f64) -> Transform {
    Transform::scale_translate(MapType::UniformScaleTranslate, [s; 3], [t; 3])
}

/// Cooks frames of (density, vel) in `format` with `lods` levels of detail.
fn cook(frames: &[[Grid; 2]], format: Format, lods: u32) -> Result<(Asset, CookReport), Error> {
    let opts = CookOptions { format, levels: LevelCount::new(lods).unwrap(), ..CookOptions::default() };
    let mut c = Cooker::with_channels(opts, specs(&["density", "vel"]));
    for f in frames {
        c.push_channels(&[Some(&f[0]), Some(&f[1])], None)?;
    }
    let (sections, report) = c.finish(&NoProgress)?;
    Ok((Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap(), report))
}

fn pyro(frames: usize, vel_transform: Transform) -> Vec<[Grid; 2]> {
    (0..frames).map(|f| [grid("density", scale(0.1, 0.0), 6, f as f32), grid("vel", vel_transform, 3, 10.0 + f as f32)]).collect()
}

#[test]
fn a_coarse_channel_is_stored_at_its_own_voxels() {
    let frames = pyro(3, scale(0.2, 0.0));
    let (asset, report) = cook(&frames, Format::F32, 1).unwrap();
    let meta = asset.metadata().unwrap();
    // vel's voxel j is centred at density's 2j; level 1's voxel j at 2j + 0.5.
    assert_eq!(meta.resolutions, vec![Resolution::default(), Resolution { level: 1, half_offset: [-1; 3] }]);
    assert_eq!((meta.levels, meta.detail_levels(), meta.channel_levels(0), meta.channel_levels(1)), (2, 1, 0..1, 1..2));
    assert_eq!(report.channels.iter().map(|c| c.level).collect::<Vec<_>>(), vec![0, 1]);
    assert!((report.channels[1].voxel_size[0] - 0.2).abs() < 1e-12);
    for (f, src) in frames.iter().enumerate() {
        let back = unpack_frame(&asset, f).unwrap();
        for (g, s) in back.iter().zip(src) {
            assert_eq!(g.leaves.len(), s.leaves.len(), "{}", s.name);
            for (a, b) in g.leaves.iter().zip(&s.leaves) {
                assert_eq!((a.origin, a.values), (b.origin, b.values), "{} frame {f}", s.name);
            }
            for r in 0..4 {
                for c in 0..4 {
                    assert!((g.transform.matrix[r][c] - s.transform.matrix[r][c]).abs() < 1e-12, "{} transform {:?}", s.name, g.transform);
                }
            }
        }
        // Level 0 holds no vel, level 1 no density: each is empty where the channel is not stored.
        assert!(unpack_level(&asset, f, 0).unwrap()[1].leaves.is_empty());
        assert!(unpack_level(&asset, f, 1).unwrap()[0].leaves.is_empty());
    }
    // Errors per channel at its own voxels: exact in f32, and counted over each channel's own voxels.
    assert_eq!(report.voxel_rmse, 0.0);
    let f16 = cook(&frames, Format::F16, 1).unwrap().1;
    assert!(f16.channels.iter().all(|c| c.error.voxel_rmse > 0.0), "{:?}", f16.channels.iter().map(|c| c.error.voxel_rmse).collect::<Vec<_>>());
}

#[test]
fn a_half_voxel_offset_and_levels_of_detail() {
    // Centres on density's voxel corners' midpoints: vel's index origin at density's 0.5.
    let frames = pyro(2, scale(0.4, 0.05));
    let (asset, _) = cook(&frames, Format::F32, 2).unwrap();
    let meta = asset.metadata().unwrap();
    // Level 2's voxel 0 is centred at 1.5; vel's at 0.5: one voxel (two halves) before.
    assert_eq!(meta.resolutions[1], Resolution { level: 2, half_offset: [-2; 3] });
    assert_eq!((meta.levels, meta.channel_levels(0), meta.channel_levels(1)), (4, 0..2, 2..4));
    let back = unpack_frame(&asset, 1).unwrap();
    assert_eq!(back[1].leaves.iter().map(|l| l.values).collect::<Vec<_>>(), frames[1][1].leaves.iter().map(|l| l.values).collect::<Vec<_>>());
    // Level 3 of vel is its mean filter, on a transform twice as coarse.
    let l3 = unpack_near(&asset, 1, Some(3)).unwrap();
    assert!((l3[1].transform.voxel_size()[0] - 0.8).abs() < 1e-12 && !l3[1].leaves.is_empty());
    assert!((l3[0].transform.voxel_size()[0] - 0.2).abs() < 1e-12, "density's coarsest is level 1");
}

#[test]
fn transforms_that_do_not_combine_are_settings_errors() {
    for (t, what) in [(scale(0.3, 0.0), "voxel size 0.3"), (scale(0.2, 0.033), "offset from them by a whole or half voxel"), (scale(1.6, 0.0), "voxel size 1.6")] {
        let Err(e) = cook(&pyro(1, t), Format::F16, 1) else { panic!("{what}: cooked") };
        assert!(e.is_settings_error(), "{e}");
        let text = e.to_string();
        assert!(text.contains("grid \"vel\"") && text.contains("grid \"density\"") && text.contains("voxel size 0.1") && text.contains(what), "{text}");
    }
    // Eight times coarser with four levels of detail from its own would need seven levels.
    let Err(e) = cook(&pyro(1, scale(0.8, 0.0)), Format::F16, 4) else { panic!("cooked") };
    assert!(e.is_settings_error() && e.to_string().contains("--lods"), "{e}");
    // A channel keeps its transform from frame to frame.
    let mut frames = pyro(2, scale(0.2, 0.0));
    frames[1][1].transform = scale(0.4, 0.0);
    let Err(e) = cook(&frames, Format::F16, 1) else { panic!("cooked") };
    assert!(matches!(e, Error::Transform { .. }), "{e}");
}

#[test]
fn the_asset_takes_the_finest_grid_whatever_the_channel_order() {
    let opts = CookOptions { format: Format::F32, ..CookOptions::default() };
    let mut c = Cooker::with_channels(opts, specs(&["vel", "density"]));
    let f = &pyro(1, scale(0.2, 0.0))[0];
    c.push_channels(&[Some(&f[1]), Some(&f[0])], None).unwrap();
    let (sections, _) = c.finish(&NoProgress).unwrap();
    let meta = Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap().metadata().unwrap();
    assert_eq!(meta.resolutions.iter().map(|r| r.level).collect::<Vec<_>>(), vec![1, 0]);
    assert!((meta.transform[0][0] - 0.1).abs() < 1e-12);
}
