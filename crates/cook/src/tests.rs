use super::*;
use crate::encode::union_masks;
use vdbcook_grid::{Coord, Grid, GridClass, Leaf, LeafMask, Tile, Transform};
use vdbcook_vpak::{kind, Asset, Checked};

fn frame(shift: i32) -> Grid {
    let mut leaves = Vec::new();
    for i in 0..40 {
        let mut mask = LeafMask::default();
        let mut values = [0.0f32; 512];
        for (v, value) in values.iter_mut().enumerate() {
            if (v + i) % 3 != 0 {
                mask.set(v, true);
                *value = (((v * 7 + i * 13) as f32) * 0.01 + shift as f32).sin().abs() * 0.1;
            }
        }
        leaves.push(Leaf { origin: Coord::new((i as i32 % 5) * 8 - 64, (i as i32 / 5) * 8 + shift * 8, 0), mask, values });
    }
    leaves.sort_by_key(|l| l.origin);
    Grid {
        name: "density".into(),
        class: GridClass::FogVolume,
        background: 0.0,
        transform: Transform::identity(),
        leaves,
        tiles: vec![Tile { origin: Coord::new(128, 0, 0), dim: 8, value: 0.5, active: true }],
    }
}

fn cook(format: Format, frames: &[Grid], max_dim: u32) -> (Vec<u8>, CookReport) {
    let mut c = Cooker::new(CookOptions { format, quality: Quality::Fast, max_texture_dim: max_dim, settings: vec![("format".into(), format.name().into())], ..CookOptions::default() });
    for f in frames {
        c.push(f, None).unwrap();
    }
    let (sections, report) = c.finish(&NoProgress).unwrap();
    let bytes = vdbcook_vpak::assemble(&sections);
    assert_eq!(bytes.len() as u64, report.file_bytes);
    (bytes, report)
}

#[test]
fn f32_round_trip_is_exact() {
    let frames = [frame(0), frame(1), frame(2)];
    let (bytes, report) = cook(Format::F32, &frames, 2048);
    assert_eq!(report.voxel_rmse, 0.0);
    let asset = Asset::from_bytes(&bytes).unwrap();
    asset.verify().unwrap();
    for (i, f) in frames.iter().enumerate() {
        let g = unpack_frame(&asset, i).unwrap().remove(0);
        assert_eq!(
            g.leaves,
            f.leaves
                .iter()
                .map(|l| {
                    let mut l = l.clone();
                    for v in 0..512 {
                        if !l.mask.is_on(v) {
                            l.values[v] = 0.0;
                        }
                    }
                    l
                })
                .collect::<Vec<_>>()
        );
        assert_eq!(g.tiles, f.tiles);
    }
    assert!(matches!(unpack_frame(&asset, 3), Err(Error::NoFrame { .. })));
}

#[test]
fn small_texture_limit_splits_atlases_and_still_round_trips() {
    let frames = [frame(0), frame(3)];
    let (bytes, report) = cook(Format::F16, &frames, 16);
    assert!(report.textures > 1, "{report:?}");
    let asset = Asset::from_bytes(&bytes).unwrap();
    let g = unpack_frame(&asset, 1).unwrap().remove(0);
    for (a, b) in g.leaves.iter().zip(&frames[1].leaves) {
        for v in b.mask.iter_on() {
            assert!((a.values[v] - b.values[v]).abs() <= b.values[v].abs() * 1e-3 + 1e-7);
        }
    }
}

#[test]
fn unorm8_error_is_reported_and_bounded() {
    let frames = [frame(0)];
    let (_, report) = cook(Format::Unorm8, &frames, 2048);
    assert!(report.voxel_rmse > 0.0);
    assert!(report.voxel_max_error <= 0.1 / 255.0 * 0.5 + 1e-6, "{}", report.voxel_max_error);
}

#[test]
fn an_unchanging_sequence_costs_about_one_frame() {
    let one = cook(Format::F16, &[frame(0)], 2048).0.len();
    let hundred = cook(Format::F16, &vec![frame(0); 100], 2048).0.len();
    assert!((hundred as f64) < one as f64 * 1.05, "{one} vs {hundred}");
}

#[test]
fn output_is_identical_on_any_thread_count() {
    let frames = [frame(0), frame(1), frame(5)];
    for format in Format::ALL {
        let run = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| cook(format, &frames, 2048).0);
        assert_eq!(run(1), run(2), "{format:?}");
        assert_eq!(run(1), run(3), "{format:?}");
    }
}

#[test]
fn changing_transform_is_an_error() {
    let mut c = Cooker::new(CookOptions::default());
    c.push(&frame(0), None).unwrap();
    let mut f = frame(1);
    f.transform = Transform::scale_translate(vdbcook_grid::MapType::UniformScale, [2.0; 3], [0.0; 3]);
    assert!(matches!(c.push(&f, None), Err(Error::Transform { first, .. }) if first == "frame 0"));
}

/// Smoke-like values: smooth in space, every voxel active.
fn smooth_frame(shift: i32) -> Grid {
    let mut g = frame(shift);
    for l in g.leaves.iter_mut() {
        l.mask = LeafMask([u64::MAX; 8]);
        for v in 0..512 {
            let (x, y, z) = ((l.origin.x + (v / 64) as i32) as f32, (l.origin.y + ((v / 8) % 8) as i32) as f32, (l.origin.z + (v % 8) as i32) as f32);
            l.values[v] = 0.05 * (1.0 + (x * 0.11).sin() * (y * 0.07 + z * 0.05).cos());
        }
    }
    g
}

#[test]
fn block_formats_round_trip_within_their_precision() {
    let frames = [smooth_frame(0), smooth_frame(2)];
    for (format, bits) in [(Format::Bc4, 4.0), (Format::Bc7, 2.0)] {
        let (bytes, report) = cook(format, &frames, 64);
        let asset = Asset::from_bytes(&bytes).unwrap();
        let atlas_bytes: u64 = asset.sections.iter().filter(|s| s.kind == vdbcook_vpak::kind::ATLAS).map(|s| s.size).sum();
        // Bricks fill the atlases up to the last layer's padding.
        assert!(atlas_bytes as f64 * 8.0 >= report.stored_bricks as f64 * 512.0 * bits, "{format:?}");
        let g = unpack_frame(&asset, 1).unwrap().remove(0);
        let mut worst = 0.0f32;
        for (a, b) in g.leaves.iter().zip(&frames[1].leaves) {
            for v in b.mask.iter_on() {
                worst = worst.max((a.values[v] - b.values[v]).abs());
            }
        }
        assert!(f64::from(worst) <= report.voxel_max_error + 1e-7, "{format:?}: {worst} vs reported {}", report.voxel_max_error);
        // Values span [0, 0.1]: a few 8-bit steps of error at most.
        assert!(report.voxel_rmse > 0.0 && report.voxel_rmse < 0.1 / 255.0 * 3.0, "{format:?}: {}", report.voxel_rmse);
    }
}

#[test]
fn clustering_reduces_bricks_and_reports_both_errors() {
    // Many nearly identical smooth bricks: one frame shifted by whole leaves.
    let mut frames = Vec::new();
    for k in 0..4 {
        let mut f = smooth_frame(0);
        for l in f.leaves.iter_mut() {
            for v in l.values.iter_mut() {
                *v += 0.0001 * k as f32;
            }
        }
        frames.push(f);
    }
    let co = vdbcook_cluster::Options { clusters: 8, iterations: 5, variance_threshold: 1.0, max_brick_error: Some(0.02), seed: 1 };
    let mut c = Cooker::new(CookOptions { format: Format::F32, clustering: Some(co), ..CookOptions::default() });
    for f in &frames {
        c.push(f, None).unwrap();
    }
    let (sections, report) = c.finish(&NoProgress).unwrap();
    let cr = report.clustering.clone().unwrap();
    assert_eq!(cr.stats.bricks_in, 160);
    assert!(cr.stats.bricks_out <= 8 + cr.stats.over_error, "{cr:?}");
    assert!(cr.ratio > 5.0, "{cr:?}");
    assert_eq!(cr.rmse_without, 0.0, "f32 without clustering is exact");
    assert!(cr.rmse_with > 0.0 && cr.rmse_with == report.voxel_rmse);
    assert!(report.voxel_max_error <= 0.02 + 1e-6, "{}", report.voxel_max_error);
    // Unpacked values match the report's error bound.
    let asset = Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap();
    let g = unpack_frame(&asset, 3).unwrap().remove(0);
    for (a, b) in g.leaves.iter().zip(&frames[3].leaves) {
        for v in 0..512 {
            assert!((a.values[v] - b.values[v]).abs() <= 0.02 + 1e-6);
        }
    }
}

#[test]
fn corrupted_assets_never_panic_even_unverified() {
    let (bytes, _) = cook(Format::Bc7, &[smooth_frame(0), frame(1)], 32);
    let mut rng = vdbcook_testkit::Rng::new(0x2545_F491_4F6C_DD1D);
    let read = |b: &[u8]| -> Result<usize, Error> {
        let asset = Asset::from_bytes(b)?;
        let mut n = 0;
        for f in 0..3 {
            if let Ok(g) = unpack_frame(&asset, f) {
                n += g.iter().map(|g| g.leaves.len()).sum::<usize>();
            }
        }
        Ok(n)
    };
    // Checksums bypassed: every byte outside the header is reachable.
    for _ in 0..3000 {
        let mut b = bytes.clone();
        let i = rng.below(b.len() as u64) as usize;
        b[i] ^= 1 << rng.below(8);
        // Re-seal the header so the flip gets past it.
        let sections = match Asset::from_bytes(&b) {
            Ok(a) => a.to_sections(),
            Err(_) => continue,
        };
        let resealed = vdbcook_vpak::assemble(&sections);
        assert!(std::panic::catch_unwind(|| read(&resealed)).is_ok(), "panic after flipping byte {i}");
    }
    for cut in (0..bytes.len()).step_by(97) {
        assert!(std::panic::catch_unwind(|| read(&bytes[..cut])).is_ok());
    }
}

/// A checksum-valid asset whose one L1 node points every slot at one L2 node
/// pointing every slot at one L3 node: 134 M leaves from a few hundred KB.
/// unpack must refuse it by the metadata's leaf count, not decode it.
#[test]
fn sealed_fan_out_assets_are_refused_not_expanded() {
    use vdbcook_vpak::nodes::{l1_mask_words, L1_LOG2, L2_MASK_WORDS};
    let (bytes, _) = cook(Format::F32, &[frame(0)], 2048);
    let asset = Asset::from_bytes(&bytes).unwrap();
    let mut sections = asset.to_sections();
    let full = |mask_words: usize| -> Vec<u32> {
        let mut w = vec![u32::MAX; mask_words];
        for k in 0..mask_words / 2 {
            w.push(((2 * k as u32 * 32) & 0xffff) | (((2 * k as u32 + 1) * 32) << 16));
        }
        w.push(0);
        w
    };
    let words = |v: Vec<u32>| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    for s in sections.iter_mut() {
        match s.kind {
            vdbcook_vpak::kind::FRAMES => s.data = words(vec![0]).into(),
            vdbcook_vpak::kind::L1_NODES => s.data = words([vec![L1_LOG2], full(l1_mask_words(L1_LOG2))].concat()).into(),
            vdbcook_vpak::kind::L1_ENTRIES => s.data = words(vec![0; 32768]).into(),
            vdbcook_vpak::kind::L2_NODES => s.data = words(full(L2_MASK_WORDS)).into(),
            vdbcook_vpak::kind::L2_ENTRIES => s.data = words(vec![0; 4096]).into(),
            _ => {}
        }
    }
    let hostile = Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap();
    hostile.verify().unwrap();
    assert!(matches!(unpack_frame(&hostile, 0), Err(Error::Corrupt(_))));
    // The same tree with metadata that owns up to all 134 M leaves: refused
    // for memory before anything is expanded.
    let mut meta = hostile.metadata().unwrap();
    meta.frames[0].leaves = 32 * 32 * 32 * 4096;
    for s in sections.iter_mut().filter(|s| s.kind == vdbcook_vpak::kind::METADATA) {
        s.data = meta.to_bytes().unwrap().into();
    }
    let honest = Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap();
    match unpack_frame(&honest, 0) {
        Err(e @ Error::TooBig { .. }) => assert!(e.to_string().contains("134217728 leaves"), "{e}"),
        other => panic!("expected TooBig, got {:?}", other.map(|g| g.len())),
    }
}

/// The validator's refusals (crates/vpak/tests/refusals.rs) reach the
/// callers of `unpack_frame` as errors.
#[test]
fn unpack_refuses_what_the_validator_refuses() {
    let (bytes, _) = cook(Format::Bc7, &[frame(0)], 2048);
    let asset = Asset::from_bytes(&bytes).unwrap();
    let mut meta = asset.metadata().unwrap();
    meta.channels[0].lane = 1;
    let mut sections = asset.to_sections();
    sections.iter_mut().find(|s| s.kind == kind::METADATA).unwrap().data = meta.to_bytes().unwrap().into();
    let sealed = Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap();
    sealed.verify().unwrap();
    match unpack_frame(&sealed, 0) {
        Err(Error::Asset(vdbcook_vpak::Error::Invalid(e))) => assert!(e.contains("channel 0"), "{e}"),
        other => panic!("expected the validator's error, got {:?}", other.map(|g| g.len())),
    }
}

#[test]
fn bricks_equal_once_encoded_are_stored_once_but_only_with_equal_ranges() {
    // A; B = A with one voxel (neither its min nor its max) nudged below
    // half precision and below a unorm8 step; C = 2·A (the same unorm8
    // levels over twice the range).
    let a: [f32; 512] = std::array::from_fn(|i| 0.25 + (i % 37) as f32 / 64.0);
    let mut b = a;
    b[1] += 1e-7;
    let c = a.map(|v| v * 2.0);
    let leaves: Vec<Leaf> = [a, b, c].into_iter().enumerate().map(|(k, values)| Leaf { origin: Coord::new(8 * k as i32, 0, 0), mask: LeafMask([u64::MAX; 8]), values }).collect();
    let g = Grid { name: "density".into(), class: GridClass::FogVolume, background: 0.0, transform: Transform::identity(), leaves: leaves.clone(), tiles: vec![] };
    for (format, stored) in [(Format::F32, 3), (Format::F16, 2), (Format::Unorm8, 2)] {
        let (bytes, report) = cook(format, std::slice::from_ref(&g), 2048);
        assert_eq!((report.unique_bricks, report.stored_bricks), (3, stored), "{format:?}");
        let back = unpack_frame(&Asset::from_bytes(&bytes).unwrap(), 0).unwrap().remove(0);
        for (l, src) in back.leaves.iter().zip(&leaves) {
            let worst = l.values.iter().zip(&src.values).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
            assert!(worst <= 0.01, "{format:?}: {worst}");
        }
    }
}

#[test]
fn union_masks_ors_every_mask_given_for_an_item() {
    let m = |w: u64| [w, 0, 0, 0, 0, 0, 0, w];
    let u = union_masks(3, [(0, m(1)), (2, m(4)), (0, m(2)), (7, m(8))].into_iter(), None).unwrap();
    assert_eq!(&u[..], [m(3), [0; 8], m(4)]);
}

#[test]
fn non_finite_values_never_panic_any_format() {
    // NaN, infinities and huge values, in full and partly active leaves.
    let specials = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, -f32::MAX, 1e-38, 0.5];
    let leaves: Vec<Leaf> = (0..12)
        .map(|k| {
            let mut mask = LeafMask::default();
            let values = std::array::from_fn(|i| {
                mask.set(i, k % 2 == 0 || i % 3 == 0);
                if (i + k) % 5 == 0 {
                    specials[(i / 5 + k) % specials.len()]
                } else {
                    0.25
                }
            });
            Leaf { origin: Coord::new(8 * k as i32, 0, 0), mask, values }
        })
        .collect();
    let g = Grid { name: "density".into(), class: GridClass::FogVolume, background: 0.0, transform: Transform::identity(), leaves, tiles: vec![] };
    for format in Format::ALL {
        for clustering in [None, Some(vdbcook_cluster::Options { clusters: 3, ..vdbcook_cluster::Options::default() })] {
            let mut c = Cooker::new(CookOptions { format, quality: Quality::UltraFast, clustering, ..CookOptions::default() });
            c.push(&g, None).unwrap();
            let (sections, report) = c.finish(&NoProgress).unwrap();
            let asset = Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap();
            asset.verify().unwrap();
            assert_eq!(unpack_frame(&asset, 0).unwrap().remove(0).leaves.len(), 12, "{format:?}");
            assert_eq!(report.bricks, 12);
        }
    }
}

/// Three channels of one frame: density everywhere `smooth_frame` has
/// leaves, temperature (background 0.25) on every other leaf (one of them
/// active on half its voxels only), flames on a few leaves of `frame` and an
/// 8³ tile over one of density's leaves.
fn fire(shift: i32) -> [Grid; 3] {
    let d = smooth_frame(shift);
    let mut t = smooth_frame(shift + 1);
    t.name = "temperature".into();
    t.background = 0.25;
    t.tiles.clear();
    t.leaves = t.leaves.into_iter().step_by(2).collect();
    for l in t.leaves.iter_mut() {
        for v in l.values.iter_mut() {
            *v = *v * 40.0 + 3.0;
        }
    }
    for i in 0..256 {
        t.leaves[3].mask.set(i, false); // x < 4: a planar edge inside the leaf
    }
    let mut f = frame(shift);
    f.name = "flames".into();
    f.leaves.truncate(7);
    f.tiles = vec![Tile { origin: d.leaves[20].origin, dim: 8, value: 2.0, active: true }];
    [d, t, f]
}

fn specs(names: &[&str]) -> Vec<ChannelSpec> {
    names.iter().map(|n| ChannelSpec { name: n.to_string(), grid: n.to_string(), value_type: "float".into(), ..ChannelSpec::default() }).collect()
}

fn cook_fire(opts: CookOptions, frames: &[[Grid; 3]]) -> (Vec<u8>, CookReport) {
    let mut c = Cooker::with_channels(opts, specs(&["density", "temperature", "flames"]));
    for f in frames {
        c.push_channels(&[Some(&f[0]), Some(&f[1]), Some(&f[2])], None).unwrap();
    }
    let (sections, report) = c.finish(&NoProgress).unwrap();
    (vdbcook_vpak::assemble(&sections), report)
}

/// Every active voxel of every channel's source, as the unpacked grids give it.
fn worst_error(src: &[Grid; 3], back: &[Grid]) -> [f32; 3] {
    let mut worst = [0.0f32; 3];
    for c in 0..3 {
        for l in &src[c].leaves {
            for i in l.mask.iter_on() {
                let (x, y, z) = vdbcook_grid::leaf_local(i);
                let (v, on) = back[c].probe(l.origin.offset(x, y, z));
                assert!(on, "channel {c}: an active source voxel must be active");
                worst[c] = worst[c].max((v - l.values[i]).abs());
            }
        }
        for t in src[c].tiles.iter().filter(|t| t.active) {
            assert_eq!(back[c].probe(t.origin), (t.value, true), "channel {c}: tile");
        }
    }
    worst
}

#[test]
fn each_channel_is_measured_over_its_own_active_voxels() {
    // The fire's channels have leaves the others lack, a leaf whose mask is
    // part of the union's, and a tile over another channel's leaf.
    let frames = [fire(0), fire(2)];
    let mut b = vdbcook_flipbook::Builder::new(3);
    for f in &frames {
        b.push(&[Some(&f[0]), Some(&f[1]), Some(&f[2])]).unwrap();
    }
    let built = b.finish().unwrap();
    let decoded = |brick: u32, want: &[bool]| -> Option<Vec<Option<vdbcook_encode::Brick>>> {
        let channels = built.pool.brick(brick as usize)?;
        Some(channels.into_iter().zip(want).map(|(b, &w)| w.then_some(b)).collect())
    };
    let m = errors::measure(&built, 0, 1, &[0, 0, 0], &decoded, &|_| {}).unwrap();
    for (k, f) in frames.iter().enumerate() {
        for (c, g) in f.iter().enumerate() {
            let leaves: u64 = g.leaves.iter().map(|l| u64::from(l.mask.count_on())).sum();
            // An 8³ tile over a leaf of another channel is that channel's part of the leaf.
            let tiles_on_leaves = g.tiles.iter().filter(|t| t.dim == 8 && f.iter().any(|o| o.leaves.iter().any(|l| l.origin == t.origin))).count() as u64;
            assert_eq!(m.frames[k][c].count, leaves + 512 * tiles_on_leaves, "frame {k} channel {c}");
            assert_eq!(m.frames[k][c].max_abs, 0.0);
        }
    }
}

#[test]
fn several_channels_round_trip_in_every_format() {
    let frames = [fire(0), fire(2)];
    for format in Format::ALL {
        let (bytes, report) = cook_fire(CookOptions { format, quality: Quality::Fast, ..CookOptions::default() }, &frames);
        assert_eq!(report.channels.len(), 3);
        let asset = Asset::from_bytes(&bytes).unwrap();
        let meta = asset.metadata().unwrap();
        assert_eq!(meta.channels.iter().map(|c| c.name.as_str()).collect::<Vec<_>>(), ["density", "temperature", "flames"]);
        assert_eq!(meta.channels[1].background, 0.25);
        for (k, f) in frames.iter().enumerate() {
            let back = unpack_frame(&asset, k).unwrap();
            assert_eq!(back.len(), 3);
            // Where only other channels are active, a channel reads its background.
            let d_only = f[0].leaves.iter().find(|l| f[1].leaves.iter().all(|t| t.origin != l.origin)).unwrap();
            assert_eq!(back[1].probe(d_only.origin.offset(0, 0, 1)), (0.25, true), "{format:?}");
            for (c, &worst) in worst_error(f, &back).iter().enumerate() {
                let [lo, hi] = meta.channels[c].value_range;
                // Block formats have no per-voxel bound (a jump to a channel's
                // background inside a 4x4 block costs what it costs): their
                // report must hold and their RMSE stay a small part of the range.
                let bound = match format {
                    Format::F32 => 0.0,
                    Format::F16 => hi.abs().max(lo.abs()) * 2f32.powi(-11),
                    Format::Unorm8 => (hi - lo) / 255.0 * 0.5,
                    Format::Unorm16 => (hi - lo) / 65535.0 * 0.5 + hi.abs().max(lo.abs()) * 1e-6,
                    _ => f32::INFINITY,
                };
                assert!(worst <= bound + 1e-6, "{format:?} channel {c}: worst {} over bound {bound}", worst);
                assert!(f64::from(worst) <= report.channels[c].voxel_max_error + 1e-4, "{format:?} channel {c}: worst {} over the report's max error {}", worst, report.channels[c].voxel_max_error);
                assert!(report.channels[c].voxel_rmse <= f64::from(hi - lo) * 0.05, "{format:?} channel {c}: rmse {}", report.channels[c].voxel_rmse);
            }
        }
        if format == Format::F32 {
            assert!(report.channels.iter().all(|c| c.voxel_rmse == 0.0));
        }
    }
}

#[test]
fn channel_groups_choose_formats_and_planes() {
    let frames = [fire(0)];
    let groups = vec![ChannelGroup { channels: vec!["temperature".into(), "flames".into()], format: Format::Bc7 }];
    let (bytes, report) = cook_fire(CookOptions { format: Format::Bc4, groups, ..CookOptions::default() }, &frames);
    let meta = Asset::from_bytes(&bytes).unwrap().metadata().unwrap();
    // temperature + flames share one BC7 plane (two z-slices each per texel); density is BC4.
    assert_eq!(meta.planes.len(), 2);
    assert_eq!((meta.planes[0].plane.format, meta.planes[0].plane.z_per_texel), (Format::Bc7, 2));
    assert_eq!(meta.planes[1].plane.format, Format::Bc4);
    assert_eq!((meta.channels[1].plane, meta.channels[1].lane, meta.channels[2].plane, meta.channels[2].lane), (0, 0, 0, 2));
    assert_eq!(meta.channels[0].plane, 1);
    assert_eq!(report.format, "bc7+bc4");
    // A group must name channels of the cook, each once.
    for (groups, want) in [
        (vec![ChannelGroup { channels: vec!["smoke".into()], format: Format::F16 }], "smoke"),
        (vec![ChannelGroup { channels: vec!["flames".into()], format: Format::F16 }, ChannelGroup { channels: vec!["flames".into()], format: Format::Bc4 }], "two channel groups"),
    ] {
        let mut c = Cooker::with_channels(CookOptions { groups, ..CookOptions::default() }, specs(&["density", "temperature", "flames"]));
        let f = fire(0);
        c.push_channels(&[Some(&f[0]), Some(&f[1]), Some(&f[2])], None).unwrap();
        let e = c.finish(&NoProgress).err().unwrap().to_string();
        assert!(e.contains(want), "{e}");
    }
}

#[test]
fn several_channels_are_deterministic_and_share_one_tree() {
    let frames = [fire(0), fire(1), fire(1)];
    for format in [Format::Unorm8, Format::Bc4, Format::Bc7] {
        let run = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| cook_fire(CookOptions { format, ..CookOptions::default() }, &frames).0);
        let one = run(1);
        assert_eq!(one, run(2), "{format:?}");
        assert_eq!(one, run(3), "{format:?}");
    }
    // One tree for all channels: the node arrays of the 3-channel asset are
    // those of its union, not three trees (frames 1 and 2 are equal: one L1 node).
    let (_, report) = cook_fire(CookOptions::default(), &frames);
    assert_eq!(report.l1_nodes, 2);
    let union_leaves: usize = {
        let mut o: Vec<_> = frames[0].iter().flat_map(|g| g.leaves.iter().map(|l| l.origin)).collect();
        o.sort();
        o.dedup();
        o.len()
    };
    assert!(report.l3_nodes >= union_leaves && report.l3_nodes <= 3 * union_leaves);
}

#[test]
fn clustering_runs_over_every_channel_each_on_its_own_scale() {
    // Four copies of the fire, shifted by tiny amounts: many similar bricks.
    // Temperature is ~100x larger than density: unnormalised, it alone would
    // decide every distance; each channel must stay within the error bound in
    // its own units.
    let frames: Vec<[Grid; 3]> = (0..4)
        .map(|k| {
            let mut f = fire(0);
            for g in f.iter_mut() {
                for l in g.leaves.iter_mut() {
                    for v in l.values.iter_mut() {
                        *v += 0.0001 * k as f32;
                    }
                }
            }
            f
        })
        .collect();
    let co = vdbcook_cluster::Options { clusters: 8, iterations: 5, variance_threshold: 10.0, max_brick_error: Some(0.05), seed: 1 };
    let (bytes, report) = cook_fire(CookOptions { format: Format::F32, clustering: Some(co), ..CookOptions::default() }, &frames);
    let cr = report.clustering.clone().unwrap();
    assert!(cr.stats.bricks_out < cr.stats.bricks_in, "{cr:?}");
    assert!(cr.stats.clustered > 0, "{cr:?}");
    let asset = Asset::from_bytes(&bytes).unwrap();
    for (k, f) in frames.iter().enumerate() {
        let back = unpack_frame(&asset, k).unwrap();
        for (c, w) in worst_error(f, &back).iter().enumerate() {
            assert!(*w <= 0.05 + 1e-4, "frame {k} channel {c}: {w} over the bound");
        }
    }
    // Beyond eight channels, clustering is refused with a clear error.
    let names: Vec<String> = (0..9).map(|i| format!("c{i}")).collect();
    let mut c = Cooker::with_channels(CookOptions { clustering: Some(vdbcook_cluster::Options::default()), ..CookOptions::default() }, specs(&names.iter().map(String::as_str).collect::<Vec<_>>()));
    let g = smooth_frame(0);
    c.push_channels(&[Some(&g); 9], None).unwrap();
    assert!(c.finish(&NoProgress).err().unwrap().to_string().contains("at most 8 channels"));
}

#[test]
fn each_plane_stores_its_own_distinct_bricks() {
    // Flames' leaves hold its background, and its one 8³ tile (2.0) lies over
    // a density leaf, so it becomes a brick: flames has two distinct bricks
    // (background and 2.0) however many the other channels have. Each plane
    // stores only its own distinct bricks.
    let mut frames = [fire(0), fire(1)];
    for f in frames.iter_mut() {
        for l in f[2].leaves.iter_mut() {
            l.values = [f[2].background; 512];
        }
    }
    for format in [Format::F16, Format::Bc4, Format::Bc7] {
        // All three in one group: f16 packs density and temperature into one RG plane, flames alone (a chunk of three is two and one).
        let (bytes, report) =
            cook_fire(CookOptions { format, groups: vec![ChannelGroup { channels: vec!["density".into(), "temperature".into(), "flames".into()], format }], ..CookOptions::default() }, &frames);
        let asset = Asset::from_bytes(&bytes).unwrap();
        let meta = asset.metadata().unwrap();
        let c = Checked::new(&asset).unwrap();
        let flames = meta.channels[2].plane as usize;
        assert_eq!(meta.planes[flames].bricks, 2, "{format:?}: {:?}", report.channels);
        assert!(c.tables[flames].is_some_and(|t| t.len() == meta.brick_count as usize && t.iter().all(|&pb| pb < 2)));
        let density = meta.channels[0].plane as usize;
        assert!(meta.planes[density].bricks > 1, "{format:?}");
        assert!(report.channels[2].bytes * 10 < report.channels[0].bytes, "{format:?}: {:?}", report.channels);
        // Every channel still reads back as before.
        for (k, f) in frames.iter().enumerate() {
            let back = unpack_frame(&asset, k).unwrap();
            let worst = worst_error(f, &back);
            assert_eq!(worst[2], 0.0, "{format:?}: a constant channel is exact");
            assert!(worst[0] < 0.01 && worst[1] < 0.5, "{format:?}: {worst:?}");
        }
    }
}

#[test]
fn non_finite_voxels_are_counted_and_left_out_of_the_figures() {
    // One NaN, one +inf and one -inf among smooth values: in every format
    // the figures are those of the finite voxels (about what the same grid
    // without them gets), the PSNR's peak is the finite range, and the
    // report counts the three.
    let clean = smooth_frame(0);
    let mut dirty = clean.clone();
    for (l, v, x) in [(3, 100, f32::NAN), (3, 101, f32::INFINITY), (17, 300, f32::NEG_INFINITY)] {
        dirty.leaves[l].values[v] = x;
    }
    for format in Format::ALL {
        let (_, want) = cook(format, std::slice::from_ref(&clean), 2048);
        let (_, got) = cook(format, std::slice::from_ref(&dirty), 2048);
        assert_eq!(got.non_finite_voxels, 3);
        assert_eq!(got.channels[0].non_finite, NonFinite { nan: 1, pos_inf: 1, neg_inf: 1 });
        assert_eq!(want.non_finite_voxels, 0);
        assert!(got.voxel_rmse.is_finite() && got.voxel_max_error.is_finite(), "{format:?}: {got:?}");
        assert!((got.voxel_rmse - want.voxel_rmse).abs() <= want.voxel_rmse * 0.05, "{format:?}: rmse {} against {} without them", got.voxel_rmse, want.voxel_rmse);
        assert!(got.voxel_max_error <= want.voxel_max_error * 1.25, "{format:?}: max {} against {} without them", got.voxel_max_error, want.voxel_max_error);
        if format == Format::F32 {
            assert!(got.voxel_psnr == f64::INFINITY && got.voxel_max_error == 0.0);
        } else {
            assert!((got.voxel_psnr - want.voxel_psnr).abs() < 0.5, "{format:?}: psnr {} against {}", got.voxel_psnr, want.voxel_psnr);
        }
        // The value range is the truth ([lo, +inf]); JSON spells what it cannot hold.
        assert_eq!(got.value_range, [-f32::INFINITY, f32::INFINITY]);
        let json = serde_json::to_value(&got).unwrap();
        assert_eq!(json["value_range"], serde_json::json!(["-Infinity", "Infinity"]));
        assert_eq!(json["channels"][0]["non_finite"], serde_json::json!({"nan": 1, "pos_inf": 1, "neg_inf": 1}));
        assert_eq!(json["voxel_psnr"], if format == Format::F32 { serde_json::json!("Infinity") } else { serde_json::json!(got.voxel_psnr) });
    }
}

#[test]
fn a_transform_mismatch_names_both_frames() {
    let source = |p: &str| Some(vdbcook_vpak::SourceFile { path: p.into(), bytes: 1, xxh3_128: String::new() });
    let mut odd = frame(1);
    odd.transform = Transform::scale_translate(vdbcook_grid::MapType::UniformScale, [0.5; 3], [0.0; 3]);
    let mut c = Cooker::new(CookOptions::default());
    c.push(&frame(0), source("a_1.vdb")).unwrap();
    c.push(&frame(1), source("a_2.vdb")).unwrap();
    let e = c.push(&odd, source("a_3.vdb")).unwrap_err().to_string();
    // The caller names this frame and its file; the message names the other.
    assert!(!e.contains("frame 2") && !e.contains("a_3.vdb"), "{e}");
    assert!(e.contains("grid \"density\" has transform UniformScaleMap [[0.5"), "{e}");
    assert!(e.contains("set by grid \"density\" of frame 0 (a_1.vdb), is UniformScaleMap [[1.0"), "{e}");
}

#[test]
fn a_background_mismatch_names_the_grid_once() {
    let mut odd = frame(1);
    odd.background = 0.5;
    let mut c = Cooker::new(CookOptions::default());
    c.push(&frame(0), None).unwrap();
    let e = c.push(&odd, None).unwrap_err().to_string();
    // The caller names the frame and its file.
    assert!(!e.contains("frame 1"), "{e}");
    assert!(e.contains("grid \"density\" has background 0.5, earlier frames 0"), "{e}");
}

fn max_error_options(e: f32) -> CookOptions {
    CookOptions { max_error: Some(crate::ErrorBound::new(e).unwrap()), quality: Quality::Fast, ..CookOptions::default() }
}

#[test]
fn per_brick_formats_keep_every_voxel_within_the_bound() {
    // Noisy, smooth and constant bricks of three channels of very different
    // ranges, at bounds from loose to tight: every active source voxel of every
    // channel unpacks within E, the channels spread over several formats, and
    // a looser bound never costs more.
    let mut frames = [fire(0), fire(2)];
    for l in frames[0][0].leaves.iter_mut().step_by(5) {
        l.values = [0.03; 512];
    }
    let mut last = u64::MAX;
    for e in [0.0001f32, 0.001, 0.01, 0.1] {
        let (bytes, report) = cook_fire(max_error_options(e), &frames);
        let asset = Asset::from_bytes(&bytes).unwrap();
        let meta = asset.metadata().unwrap();
        for (k, f) in frames.iter().enumerate() {
            let back = unpack_frame(&asset, k).unwrap();
            for (c, &worst) in worst_error(f, &back).iter().enumerate() {
                assert!(worst <= e, "E = {e}: channel {c} ({}) is off by {worst}", report.channels[c].format);
            }
        }
        for (c, ch) in report.channels.iter().enumerate() {
            assert!(ch.voxel_max_error <= f64::from(e), "E = {e}: {} reports {}", ch.name, ch.voxel_max_error);
            assert_eq!(ch.formats.len(), 1 + meta.channels[c].alternates.len());
            assert_eq!(ch.format, ch.formats.iter().map(|f| f.format.name()).collect::<Vec<_>>().join("+"));
        }
        let formats: std::collections::BTreeSet<Format> = report.channels.iter().flat_map(|c| c.formats.iter().map(|f| f.format)).collect();
        assert!(formats.len() >= if e <= 0.01 { 3 } else { 2 }, "E = {e}: {formats:?}");
        assert!(report.file_bytes <= last, "E = {e}: {} bytes, tighter bound {last}", report.file_bytes);
        last = report.file_bytes;
    }
    // The density bricks set to a constant are stored without texels.
    let (bytes, report) = cook_fire(max_error_options(0.001), &frames);
    assert!(report.channels[0].formats.iter().any(|f| f.format == Format::Constant && f.bricks >= 1), "{:?}", report.channels[0].formats);
    let meta = Asset::from_bytes(&bytes).unwrap().metadata().unwrap();
    assert!(meta.planes.iter().filter(|p| p.plane.format == Format::Constant).all(|p| p.atlases.is_empty()));
}

#[test]
fn per_brick_formats_are_deterministic() {
    let frames = [fire(0), fire(1)];
    let run = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| cook_fire(max_error_options(0.002), &frames).0);
    let one = run(1);
    assert_eq!(one, run(2));
    assert_eq!(one, run(3));
}

#[test]
fn clustered_bricks_are_held_to_the_bound_too() {
    // Clustering with no error bound of its own merges bricks far apart; with
    // a maximum error, a merged brick its cluster leaves past E is stored on its own.
    let frames: Vec<Grid> = (0..6).map(smooth_frame).chain((0..3).map(frame)).collect();
    let co = vdbcook_cluster::Options { clusters: 4, iterations: 3, variance_threshold: 10.0, max_brick_error: None, seed: 3 };
    for e in [0.005f32, 0.05] {
        let mut c = Cooker::new(CookOptions { clustering: Some(co.clone()), ..max_error_options(e) });
        for f in &frames {
            c.push(f, None).unwrap();
        }
        let (sections, report) = c.finish(&NoProgress).unwrap();
        let asset = Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap();
        let cr = report.clustering.unwrap();
        assert!(cr.stats.over_error > 0 || e > 0.01, "E = {e}: {cr:?}");
        assert!(cr.stats.clustered > 0 || e < 0.01, "E = {e}: {cr:?}");
        // Every brick not merged is its own, plus the centroids still used.
        assert_eq!(cr.stats.bricks_out, cr.stats.bricks_in - cr.stats.clustered + cr.stats.centroids, "E = {e}: {cr:?}");
        for (k, f) in frames.iter().enumerate() {
            let back = unpack_frame(&asset, k).unwrap();
            for l in &f.leaves {
                for i in l.mask.iter_on() {
                    let (x, y, z) = vdbcook_grid::leaf_local(i);
                    let (v, on) = back[0].probe(l.origin.offset(x, y, z));
                    assert!(on && (v - l.values[i]).abs() <= e, "E = {e} frame {k}: {v} for {}", l.values[i]);
                }
            }
        }
    }
}

#[test]
fn a_maximum_error_is_checked_with_the_settings() {
    // The bound checks itself; the cooker checks what it is combined with.
    for e in [-1.0, f32::NAN, f32::INFINITY] {
        assert!(crate::ErrorBound::new(e).is_err(), "{e}");
    }
    for (opts, want) in [
        (CookOptions { groups: vec!["density,flames=bc7".parse().unwrap()], ..max_error_options(0.01) }, "takes no channel groups"),
        (CookOptions { format: Format::Constant, ..CookOptions::default() }, "format constant is chosen per brick"),
    ] {
        let mut c = Cooker::with_channels(opts, specs(&["density", "temperature", "flames"]));
        let f = fire(0);
        c.push_channels(&[Some(&f[0]), Some(&f[1]), Some(&f[2])], None).unwrap();
        let e = c.finish(&NoProgress).err().unwrap();
        assert!(e.is_settings_error() && e.to_string().contains(want), "{e}");
    }
    assert!("density=constant".parse::<ChannelGroup>().is_err());
}

fn cook_levels(format: Format, frames: &[Grid], levels: u32) -> (Vec<u8>, CookReport) {
    let mut c = Cooker::new(CookOptions { format, levels: LevelCount::new(levels).unwrap(), ..CookOptions::default() });
    for f in frames {
        c.push(f, None).unwrap();
    }
    let (sections, report) = c.finish(&NoProgress).unwrap();
    (vdbcook_vpak::assemble(&sections), report)
}

/// The grid as a reader sees it: inactive voxels at the background, leaves without an active voxel gone.
fn as_read(g: &Grid) -> (Vec<Leaf>, Vec<Tile>) {
    let leaves = g
        .leaves
        .iter()
        .filter(|l| !l.mask.is_empty())
        .map(|l| {
            let mut l = l.clone();
            for v in 0..512 {
                if !l.mask.is_on(v) {
                    l.values[v] = g.background;
                }
            }
            l
        })
        .collect();
    let mut tiles: Vec<Tile> = g.tiles.iter().filter(|t| t.active).copied().collect();
    tiles.sort_by_key(|t| (t.origin, t.dim));
    (leaves, tiles)
}

#[test]
fn every_level_unpacks_to_the_filtered_source_exactly_in_f32() {
    let frames = [frame(0), frame(1), frame(2)];
    let levels = vdbcook_vpak::MAX_LEVELS;
    let (bytes, report) = cook_levels(Format::F32, &frames, levels);
    assert_eq!(report.levels.len(), levels as usize - 1);
    assert!(report.levels.iter().all(|l| l.voxel_rmse == 0.0 && l.leaves > 0), "{:?}", report.levels);
    let asset = Asset::from_bytes(&bytes).unwrap();
    let checked = Checked::new(&asset).unwrap();
    assert_eq!((checked.meta.levels, checked.frames.len()), (levels, 3 * levels as usize));
    assert_eq!(checked.meta.level_filters, vec![vdbcook_vpak::LevelFilter::Mean]);
    for (f, src) in frames.iter().enumerate() {
        let mut want = src.clone();
        for k in 0..levels {
            if k > 0 {
                want = vdbcook_grid::lod::coarsen(&want, vdbcook_grid::lod::Filter::Mean);
            }
            let g = unpack_level(&asset, f, k).unwrap().remove(0);
            let (leaves, tiles) = as_read(&want);
            assert_eq!(g.leaves, leaves, "frame {f} level {k}: leaves");
            let mut got_tiles = g.tiles.clone();
            got_tiles.sort_by_key(|t| (t.origin, t.dim));
            assert_eq!(got_tiles, tiles, "frame {f} level {k}: tiles");
            assert_eq!(g.transform.matrix, checked.meta.level_transform(k));
            let t = vdbcook_grid::lod::coarsen_transform(&vdbcook_grid::Transform::identity());
            if k == 1 {
                assert_eq!(g.transform, t, "level 1's transform is the coarsened one");
            }
            assert_eq!(checked.meta.level_leaves(f, k) as usize, leaves.len());
        }
    }
    // Level 0 is what a cook without levels stores; the levels add trees, not other bricks for level 0.
    let (plain, _) = cook_levels(Format::F32, &frames, 1);
    let plain = Asset::from_bytes(&plain).unwrap();
    for f in 0..3 {
        assert_eq!(unpack_frame(&plain, f).unwrap(), unpack_frame(&asset, f).unwrap());
    }
    assert!(matches!(unpack_level(&asset, 0, levels), Err(Error::NoLevel { .. })));
    assert!(matches!(unpack_level(&plain, 0, 1), Err(Error::NoLevel { .. })));
    // Per level bytes: each level alone is smaller than level 0, and every one is counted.
    let bytes0 = checked.level_bytes(0);
    for k in 1..levels {
        assert!(checked.level_bytes(k) > 0 && checked.level_bytes(k) < bytes0, "level {k}");
    }
}

#[test]
fn levels_are_deterministic_and_lossy_formats_report_their_error() {
    let frames = [frame(0), frame(1)];
    let run = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| cook_levels(Format::Bc4, &frames, 4).0);
    assert_eq!(run(1), run(3));
    let (_, report) = cook_levels(Format::Unorm8, &frames, 4);
    assert!(report.levels.iter().all(|l| l.voxel_rmse > 0.0 && l.voxel_max_error < 0.1 / 255.0), "{:?}", report.levels);
}

/// `max_bytes`: each try leaves out one more of the finest levels; what stays
/// is the full asset's levels value for value, over only the bricks they use;
/// below the coarsest level alone, the error names that size.
#[test]
fn a_byte_budget_keeps_the_finest_levels_that_fit() {
    let frames = [frame(0), frame(1), frame(2)];
    let levels = 4;
    // A lossy format: the report's figures are the first stored level's.
    let cook = |max_bytes: Option<u64>| {
        let mut c = Cooker::new(CookOptions { format: Format::Unorm8, levels: LevelCount::new(levels).unwrap(), max_bytes, ..CookOptions::default() });
        for f in &frames {
            c.push(f, None).unwrap();
        }
        c.finish(&NoProgress).map(|(s, r)| (vdbcook_vpak::assemble(&s), r))
    };
    let (full, full_report) = cook(None).unwrap();
    let full_asset = Asset::from_bytes(&full).unwrap();
    let full_checked = Checked::new(&full_asset).unwrap();
    // A budget the whole asset meets changes nothing.
    let (same, r) = cook(Some(full.len() as u64)).unwrap();
    assert!(same == full, "a budget that fits changes the asset");
    let b = r.budget.unwrap();
    assert!(b.dropped.is_empty() && b.tries.len() == 1 && b.tries[0].bytes == full.len() as u64, "{b:?}");
    // Each budget one byte below the last asset leaves out exactly one more level.
    let mut last = full.len() as u64;
    for first in 1..levels {
        let (bytes, r) = cook(Some(last - 1)).unwrap();
        assert!((bytes.len() as u64) < last, "level {first}: {} bytes", bytes.len());
        let b = r.budget.clone().unwrap();
        assert_eq!(b.dropped, (0..first).collect::<Vec<_>>());
        assert_eq!(b.tries.first().unwrap().bytes, full.len() as u64);
        assert_eq!(b.tries.last().unwrap().bytes, bytes.len() as u64);
        assert_eq!((r.first_level, r.levels.len()), (first, (levels - first - 1) as usize));
        assert!(r.levels.iter().zip(first + 1..).all(|(l, k)| l.level == k), "{:?}", r.levels);
        let was = &full_report.levels[first as usize - 1];
        assert!(r.frame_errors.len() == frames.len() && r.voxel_rmse == was.voxel_rmse && r.voxel_rmse > 0.0, "level {first}: {} against {was:?}", r.voxel_rmse);
        assert!(r.levels.iter().zip(&full_report.levels[first as usize..]).all(|(a, b)| a.voxel_rmse == b.voxel_rmse && a.leaves == b.leaves), "{:?}", r.levels);
        let asset = Asset::from_bytes(&bytes).unwrap();
        let checked = Checked::new(&asset).unwrap();
        assert_eq!((checked.meta.first_level, checked.meta.levels, checked.frames.len()), (first, levels, 3 * (levels - first) as usize));
        for f in 0..frames.len() {
            for k in 0..levels {
                match k < first {
                    true => assert!(matches!(unpack_level(&asset, f, k), Err(Error::NoLevel(ref why)) if why.contains("left out")), "frame {f} level {k}"),
                    false => assert_eq!(unpack_level(&asset, f, k).unwrap(), unpack_level(&full_asset, f, k).unwrap(), "frame {f} level {k}"),
                }
            }
        }
        // Only the bricks the stored levels use: those the full asset's trees of these levels reach.
        let full_checked = &full_checked;
        let roots: Vec<u32> = (first..levels).flat_map(|k| (0..frames.len()).filter_map(move |f| full_checked.tree(f, k))).collect();
        assert_eq!(checked.meta.brick_count as usize, full_checked.nodes().usage(&roots).bricks.len());
        last = bytes.len() as u64;
    }
    // Not even the coarsest level alone fits: the error says how small an asset can be.
    match cook(Some(last - 1)) {
        Err(Error::OverBudget { budget, smallest, level }) => assert_eq!((budget, smallest, level), (last - 1, last, levels - 1)),
        other => panic!("{:?}", other.map(|(b, _)| b.len())),
    }
    // Any thread count, the same bytes.
    let run = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| cook(Some(full.len() as u64 / 2)).unwrap().0);
    assert!(run(1) == run(3), "thread count changed the asset");
}

#[test]
fn level_sets_get_the_active_mean_and_empty_frames_every_level() {
    let mut ls = frame(0);
    ls.class = GridClass::LevelSet;
    ls.background = 0.3;
    let mut c = Cooker::new(CookOptions { format: Format::F32, levels: LevelCount::new(3).unwrap(), ..CookOptions::default() });
    c.push(&ls, None).unwrap();
    c.push_empty(None);
    let (sections, _) = c.finish(&NoProgress).unwrap();
    let asset = Asset::from_bytes(&vdbcook_vpak::assemble(&sections)).unwrap();
    let meta = Checked::new(&asset).unwrap().meta;
    assert_eq!(meta.level_filters, vec![vdbcook_vpak::LevelFilter::ActiveMean]);
    let want = vdbcook_grid::lod::coarsen(&ls, vdbcook_grid::lod::Filter::ActiveMean);
    assert_eq!(unpack_level(&asset, 0, 1).unwrap()[0].leaves, as_read(&want).0);
    for k in 0..3 {
        let g = unpack_level(&asset, 1, k).unwrap().remove(0);
        assert!(g.leaves.is_empty() && g.tiles.is_empty(), "level {k} of the empty frame");
    }
}

#[test]
fn a_zero_bound_is_exact_even_with_several_channels_clustered() {
    // Several channels are clustered in scaled units (v / s · s need not be
    // v): with E = 0 every voxel of every channel still unpacks exactly.
    let frames = [fire(0), fire(1), fire(3)];
    let co = vdbcook_cluster::Options { clusters: 6, iterations: 3, variance_threshold: 0.002, max_brick_error: None, seed: 5 };
    let (bytes, report) = cook_fire(CookOptions { clustering: Some(co), ..max_error_options(0.0) }, &frames);
    let asset = Asset::from_bytes(&bytes).unwrap();
    for (k, f) in frames.iter().enumerate() {
        assert_eq!(worst_error(f, &unpack_frame(&asset, k).unwrap()), [0.0; 3], "frame {k}");
    }
    assert!(report.channels.iter().all(|c| c.voxel_max_error == 0.0));
}

/// The report's typed metadata is the metadata section, byte for byte, with or without a byte budget.
#[test]
fn the_report_carries_the_metadata_it_wrote() {
    for max_bytes in [None, Some(1 << 40)] {
        let mut c = Cooker::new(CookOptions { levels: LevelCount::new(2).unwrap(), max_bytes, ..CookOptions::default() });
        c.push(&frame(0), None).unwrap();
        c.push_empty(None);
        let (sections, report) = c.finish(&NoProgress).unwrap();
        let written = sections.iter().find(|s| s.kind == kind::METADATA).unwrap();
        assert_eq!(written.data[..], report.metadata.to_bytes().unwrap()[..]);
        assert_eq!(report.metadata.frame_count, 2);
    }
}

#[test]
fn clustered_cooks_spilled_write_what_they_write_in_memory() {
    // Near-duplicate fires: clustering merges bricks, so the work bricks mix
    // kept pool bricks and centroids (with --max-error, strays too).
    let frames: Vec<[Grid; 3]> = (0..4)
        .map(|k| {
            let mut f = fire(0);
            f.iter_mut().flat_map(|g| g.leaves.iter_mut()).flat_map(|l| l.values.iter_mut()).for_each(|v| *v += 0.0003 * k as f32);
            f
        })
        .collect();
    let co = vdbcook_cluster::Options { clusters: 6, iterations: 3, variance_threshold: 10.0, max_brick_error: Some(0.05), seed: 2 };
    let spilled = || Some(vdbcook_grid::spill::SpillPolicy::new(std::env::temp_dir(), 1));
    for opts in [CookOptions { format: Format::Unorm8, clustering: Some(co.clone()), ..CookOptions::default() }, CookOptions { clustering: Some(co.clone()), ..max_error_options(0.02) }] {
        let (memory, report) = cook_fire(opts.clone(), &frames);
        assert!(report.clustering.as_ref().is_some_and(|c| c.stats.clustered > 0), "{:?}", report.clustering);
        let policy = spilled();
        let (from_files, spilled_report) = cook_fire(CookOptions { spill: policy.clone(), ..opts.clone() }, &frames);
        assert!(memory == from_files, "{:?}: the spilled cook wrote another asset", opts.max_error);
        // The error figures, read from the spilled pool in groups, are the same too.
        assert_eq!(report.frame_errors, spilled_report.frame_errors);
        let without = |r: &CookReport| r.clustering.as_ref().map(|c| c.rmse_without.to_bits());
        assert_eq!(without(&report), without(&spilled_report));
        assert!(policy.is_some_and(|p| p.peak_in_files() > 0));
        // One channel: the pool is dense, its kept bricks read in place.
        let one: Vec<Grid> = frames.iter().map(|f| f[0].clone()).collect();
        let cook_one = |spill| {
            let mut c = Cooker::new(CookOptions { spill, ..opts.clone() });
            one.iter().for_each(|f| c.push(f, None).unwrap());
            let (sections, report) = c.finish(&NoProgress).unwrap();
            (vdbcook_vpak::assemble(&sections), report.frame_errors)
        };
        assert!(cook_one(None) == cook_one(spilled()), "{:?}: one channel spilled wrote another asset or error figures", opts.max_error);
    }
}

/// Records each stage's total and what was advanced in it.
#[derive(Default)]
struct Stages(std::sync::Mutex<Vec<(String, u64, u64)>>);

impl Progress for Stages {
    fn start(&self, stage: &str, total: u64) {
        self.0.lock().unwrap().push((stage.to_string(), total, 0));
    }
    fn advance(&self, n: u64) {
        if let Some(s) = self.0.lock().unwrap().last_mut() {
            s.2 += n;
        }
    }
}

#[test]
fn every_stage_of_the_finish_reports_progress_up_to_its_total() {
    let frames: Vec<[Grid; 3]> = (0..3).map(|k| fire(k % 2)).collect();
    let co = vdbcook_cluster::Options { clusters: 4, iterations: 2, variance_threshold: 10.0, max_brick_error: None, seed: 1 };
    let one = |o: CookOptions| {
        let mut c = Cooker::new(o);
        frames.iter().for_each(|f| c.push(&f[0], None).unwrap());
        c
    };
    let three = |o: CookOptions| {
        let mut c = Cooker::with_channels(o, specs(&["density", "temperature", "flames"]));
        frames.iter().for_each(|f| c.push_channels(&[Some(&f[0]), Some(&f[1]), Some(&f[2])], None).unwrap());
        c
    };
    let clustered = CookOptions { format: Format::Unorm8, clustering: Some(co), ..CookOptions::default() };
    for (cooker, expect) in [
        (one(clustered.clone()), vec!["clustering", "encoding", "building nodes", "laying out", "measuring error"]),
        (three(CookOptions { format: Format::Bc7, ..CookOptions::default() }), vec!["encoding", "building nodes", "laying out", "measuring error"]),
        (one(max_error_options(0.01)), vec!["choosing formats", "building nodes", "laying out", "measuring error"]),
    ] {
        let stages = Stages::default();
        cooker.finish(&stages).unwrap();
        let stages = stages.0.into_inner().unwrap();
        assert_eq!(stages.iter().map(|s| s.0.as_str()).collect::<Vec<_>>(), expect);
        for (stage, total, done) in &stages {
            assert!(*total > 0 && done == total, "{stage}: {done} of {total}");
        }
    }
}
