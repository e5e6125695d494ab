use super::*;
use vdbcook_vpak::layout::{pack_atlas, plan_atlases, unpack_brick, AtlasLayout};

fn smoke(seed: f32) -> Brick {
    std::array::from_fn(|i| ((i as f32 * 0.37 + seed).sin() * 0.5 + 0.5) * 0.3)
}

#[test]
fn f32_is_exact_and_f16_within_half_precision() {
    let b = smoke(1.0);
    assert_eq!(round_trip(Format::F32, Quality::Fast, &b), b);
    let d = round_trip(Format::F16, Quality::Fast, &b);
    for (x, y) in b.iter().zip(d.iter()) {
        assert!((x - y).abs() <= x.abs() * 2f32.powi(-11) + 1e-7, "{x} {y}");
    }
}

#[test]
fn unorm8_within_half_a_step_of_the_brick_range() {
    let mut b = smoke(2.0);
    b[0] = 1e-4; // thin smoke must keep its own range
    let [lo, hi] = range_of(&b);
    let d = round_trip(Format::Unorm8, Quality::Fast, &b);
    let step = (hi - lo) / 255.0;
    for (x, y) in b.iter().zip(d.iter()) {
        assert!((x - y).abs() <= step * 0.5 + 1e-6, "{x} {y} step {step}");
    }
    let flat = [0.25f32; BRICK_VOXELS];
    assert_eq!(round_trip(Format::Unorm8, Quality::Fast, &flat), flat);
}

#[test]
fn unorm16_within_half_a_step_of_the_brick_range() {
    // NanoVDB's Fp16 bound, range / 131070, where f16's error grows with the value.
    let b: Brick = std::array::from_fn(|i| 1000.0 + (i as f32 * 0.37).sin() * 3.0);
    let [lo, hi] = range_of(&b);
    let step = (hi - lo) / 65535.0;
    let d = round_trip(Format::Unorm16, Quality::Fast, &b);
    let f16 = round_trip(Format::F16, Quality::Fast, &b);
    let worst = |d: &Brick| b.iter().zip(d).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
    // Half a step, and the f32 rounding of min + t·(max − min) near 1000.
    assert!(worst(&d) <= step * 0.5 + 1000.0 * f32::EPSILON, "{} step {step}", worst(&d));
    assert!(worst(&f16) > 50.0 * worst(&d), "f16 {} unorm16 {}", worst(&f16), worst(&d));
}

#[test]
fn every_format_keeps_voxel_order() {
    // A brick whose voxels differ along each axis by different steps
    // decodes with each voxel in its place, in every format.
    let ramp: Brick = std::array::from_fn(|i| (((i / 64) * 24 + ((i / 8) % 8) * 6 + i % 8 * 2) as f32) / 255.0);
    for format in Format::ALL {
        let d = round_trip(format, Quality::Fast, &ramp);
        let worst = ramp.iter().zip(d.iter()).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(worst <= 12.0 / 255.0, "{format:?}: worst error {worst}");
    }
}

/// Channel c of brick k: one affine ramp on the channel's own scale and
/// offset, so every BC7 block's lanes lie on a line (any lane or slice
/// mix-up shows as a large error, block compression does not).
fn channel_brick(k: usize, c: usize) -> Brick {
    std::array::from_fn(|i| {
        let (x, y, z) = ((i / 64) as f32, ((i / 8) % 8) as f32, (i % 8) as f32);
        (x * 9.0 + y * 5.0 + z * 20.0 + (k * 7) as f32) * (1.0 + c as f32) + 100.0 * c as f32
    })
}

#[test]
fn every_channel_of_every_packing_decodes_in_its_place() {
    // 1 to 5 channels in every format: each channel decodes to its own
    // values (within the format's precision over its own range), so no
    // lane or z-slice is swapped between channels.
    for channels in 1..=5usize {
        let bricks: Vec<Brick> = (0..6).flat_map(|k| (0..channels).map(move |c| channel_brick(k, c))).collect();
        for format in Format::ALL {
            let specs = group_planes(format, &(0..channels).collect::<Vec<_>>());
            assert!(specs.iter().all(|s| s.plane.is_valid() && s.channels.len() as u32 <= s.plane.channel_slots()));
            assert_eq!(specs.iter().map(|s| s.channels.len()).sum::<usize>(), channels);
            let e = Encoded::new(specs, Quality::Fast, &bricks, channels, None, &|_| {});
            for k in 0..6 {
                let d = e.decode(k).unwrap();
                for (c, dc) in d.iter().enumerate() {
                    let src = channel_brick(k, c);
                    let [lo, hi] = range_of(&src);
                    let tol = match format {
                        Format::F32 => 0.0,
                        Format::F16 => hi.abs() * 2f32.powi(-10),
                        Format::Unorm8 => (hi - lo) / 255.0 * 0.5 + 1e-4,
                        _ => (hi - lo) / 255.0 * 12.0,
                    };
                    let worst = src.iter().zip(dc.iter()).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                    assert!(worst <= tol, "{format:?}, {channels} channels, brick {k} channel {c}: {worst} > {tol}");
                }
            }
        }
    }
}

#[test]
fn made_on_demand_planes_land_in_their_atlas() {
    // Voxel (x, y, z) of channel c is texel (8·px + x, 8·py + y, 8·pz + z)
    // of its plane, in lane `c`, for many brick counts and limits.
    let channels = 4;
    for (count, max_dim) in [(1usize, 2048u32), (7, 16), (37, 32)] {
        let bricks: Vec<Brick> = (0..count * channels).map(|k| std::array::from_fn(|v| (k * 1000 + v) as f32)).collect();
        let e = Encoded::new(group_planes(Format::F32, &[0, 1, 2, 3]), Quality::Fast, &bricks, channels, None, &|_| {});
        let keep: Vec<u32> = (0..count as u32).collect();
        let plane = e.specs[0].plane;
        for atlas in plan_atlases(8, count as u32, max_dim) {
            let layout = AtlasLayout { plane, atlas };
            let bytes = pack_atlas(&layout, &e.plane(0, &keep));
            for i in 0..atlas.count {
                let g = (atlas.first_brick + i) as usize;
                let [px, py, pz] = atlas.position(i);
                for v in (0..BRICK_VOXELS as u32).step_by(7) {
                    let (x, y, z) = (v / 64, (v / 8) % 8, v % 8);
                    for c in 0..channels {
                        let o = layout.texel_offset(px * 8 + x, py * 8 + y, pz * 8 + z) + 4 * c;
                        assert_eq!(f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()), ((g * channels + c) * 1000 + v as usize) as f32);
                    }
                }
                let mut want = vec![0u8; plane.brick_bytes()];
                assert!(e.write(0, g, &mut want));
                assert_eq!(unpack_brick(&layout, &bytes, i).unwrap(), want);
            }
        }
    }
}

#[test]
fn bc7_lanes_hold_channels_by_z_slices() {
    // Two channels, constant per z-slice: lane l of texel slice t holds
    // channel l / 2 at z = 2t + l % 2.
    let bricks: Vec<Brick> = (0..2).map(|c| std::array::from_fn(|i| ((i % 8) * 30 + c * 5) as f32)).collect();
    let e = Encoded::new(group_planes(Format::Bc7, &[0, 1]), Quality::Slow, &bricks, 2, None, &|_| {});
    let plane = e.specs[0].plane;
    assert_eq!((plane.z_per_texel, plane.slices_per_brick()), (2, 4));
    let mut data = vec![0u8; plane.brick_bytes()];
    assert!(e.write(0, 0, &mut data));
    let texels = plane.decode_brick(&data);
    for t in 0..4 {
        for (l, &got) in texels[t * 64].iter().enumerate() {
            let (c, z) = (l / 2, 2 * t + l % 2);
            let [lo, hi] = range_of(&bricks[c]);
            let want = ((z * 30 + c * 5) as f32 - lo) / (hi - lo);
            assert!((got - want).abs() < 3.0 / 255.0, "slice {t} lane {l}: {got} vs {want}");
        }
    }
}

/// A random smooth brick (a tilted ramp plus a wave, on a random scale
/// and offset), with `noise` levels of its range of noise on top.
fn random_brick(rng: &mut vdbcook_testkit::Rng, noise: f32) -> Brick {
    let (scale, offset) = (0.01 + rng.unit() * 100.0, rng.unit() * 50.0 - 25.0);
    let (gx, gy, gz, f, p) = (rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() * 0.8, rng.unit() * 6.0);
    std::array::from_fn(|i| {
        let (x, y, z) = ((i / 64) as f32, ((i / 8) % 8) as f32, (i % 8) as f32);
        let v = gx * x + gy * y + gz * z + (f * (x + 2.0 * y - z) + p).sin() + noise / 255.0 * 8.0 * (rng.unit() - 0.5);
        offset + scale * v
    })
}

/// The largest error of `decoded` against `source` over the voxels
/// where `pick` holds; infinite if one of them decodes to NaN or ±∞.
fn worst(source: &Brick, decoded: &Brick, pick: impl Fn(usize) -> bool) -> f32 {
    (0..BRICK_VOXELS).filter(|&i| pick(i)).map(|i| if decoded[i].is_finite() { (decoded[i] - source[i]).abs() } else { f32::INFINITY }).fold(0.0, f32::max)
}

#[test]
fn non_finite_voxels_cost_their_neighbours_nothing_in_any_format() {
    // Random bricks, each with 1 to 6 voxels set to NaN, +∞ or −∞: in
    // every format and quality, the finite voxels decode within the
    // format's bound over the brick's finite range, and about as well as
    // the same brick without the non-finite voxels; the non-finite ones
    // decode as documented (kept by f32 and f16, the fill of their finite
    // neighbours by the ranged formats).
    let mut rng = vdbcook_testkit::Rng::new(0x4e4e);
    let specials = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
    for trial in 0..24 {
        let clean = random_brick(&mut rng, if trial % 3 == 0 { 6.0 } else { 0.0 });
        let mut dirty = clean;
        let mut odd = [false; BRICK_VOXELS];
        for k in 0..1 + rng.below(6) as usize {
            let i = rng.below(BRICK_VOXELS as u64) as usize;
            dirty[i] = specials[(trial + k) % 3];
            odd[i] = true;
        }
        let [lo, hi] = range_of(&dirty);
        assert!(lo.is_finite() && hi.is_finite() && lo <= hi, "{lo} {hi}");
        let fill = fill_non_finite(&dirty).unwrap();
        let step = (hi - lo) / 255.0;
        for format in Format::ALL {
            for quality in [Quality::UltraFast, Quality::VeryFast, Quality::Slow] {
                let d = round_trip(format, quality, &dirty);
                let c = round_trip(format, quality, &clean);
                let what = format!("brick {trial}, {format:?} {quality:?}");
                let finite = |i: usize| !odd[i];
                let (got, clean_worst) = (worst(&clean, &d, finite), worst(&clean, &c, finite));
                let bound = match format {
                    Format::F32 => 0.0,
                    Format::F16 => hi.abs().max(lo.abs()) * 2f32.powi(-11),
                    Format::Unorm8 => step * 0.501,
                    // Block formats: their usual error (these smooth bricks
                    // stay within a few levels), a little either way.
                    _ => (clean_worst * 1.25).max(clean_worst + 2.0 * step),
                };
                assert!(got <= bound, "{what}: finite voxels off by {got} (levels: {}), the clean brick's by {clean_worst}", got / step);
                for i in (0..BRICK_VOXELS).filter(|&i| odd[i]) {
                    match format {
                        Format::F32 => assert_eq!(d[i].to_bits(), dirty[i].to_bits(), "{what}: voxel {i}"),
                        Format::F16 => assert!(d[i] == dirty[i] || d[i].is_nan() && dirty[i].is_nan(), "{what}: voxel {i}: {} became {}", dirty[i], d[i]),
                        _ => {
                            assert!(d[i] >= lo && d[i] <= hi, "{what}: voxel {i}: {} became {}, outside [{lo}, {hi}]", dirty[i], d[i]);
                            let tol = if format == Format::Unorm8 { step * 0.501 } else { bound };
                            assert!((d[i] - fill[i]).abs() <= tol, "{what}: voxel {i}: decodes to {}, its fill is {}", d[i], fill[i]);
                        }
                    }
                }
                if !format.is_block() {
                    break;
                }
            }
        }
    }
}

#[test]
fn bricks_without_finite_values() {
    // Decoded by every ranged format as the range's one finite value.
    for (v, m) in [(f32::INFINITY, f32::MAX), (f32::NEG_INFINITY, -f32::MAX), (f32::NAN, 0.0)] {
        let b = [v; BRICK_VOXELS];
        assert_eq!(range_of(&b), [m, m]);
        assert!(fill_non_finite(&b).is_none());
        for format in [Format::Unorm8, Format::Bc4, Format::Bc7] {
            assert!(round_trip(format, Quality::Fast, &b).iter().all(|&d| d == m), "{format:?} {v}");
        }
    }
    let mut mixed = [f32::NAN; BRICK_VOXELS];
    mixed[7] = f32::NEG_INFINITY;
    mixed[9] = f32::INFINITY;
    assert_eq!(range_of(&mixed), [f32::MAX, f32::MAX]);
    // One finite voxel fills the brick.
    mixed[100] = 0.5;
    assert_eq!(range_of(&mixed), [0.5, 0.5]);
    assert_eq!(fill_non_finite(&mixed), Some([0.5; BRICK_VOXELS]));
}

#[test]
fn error_figures_leave_non_finite_references_out() {
    let mut reference = smoke(3.0);
    let decoded = reference.map(|v| v + 0.25);
    reference[3] = f32::NAN;
    reference[200] = f32::INFINITY;
    reference[511] = f32::NEG_INFINITY;
    let mut all = ErrorStats::default();
    all.add_masked(&reference, &decoded, &[u64::MAX; 8]);
    // The voxel-by-voxel path (a mask with a voxel missing) agrees.
    let mut part = ErrorStats::default();
    let mut mask = [u64::MAX; 8];
    mask[1] &= !1;
    part.add_masked(&reference, &decoded, &mask);
    for (e, n) in [(all, 509), (part, 508)] {
        assert_eq!(e.count, n);
        assert_eq!(e.non_finite, NonFinite { nan: 1, pos_inf: 1, neg_inf: 1 });
        assert!((e.rmse() - 0.25).abs() < 1e-6 && (e.max_abs - 0.25).abs() < 1e-6, "{e:?}");
    }
    all.merge(&part);
    assert_eq!(all.non_finite.total(), 6);
}

#[test]
fn half_conversions_of_a_brick_match_half_value_by_value() {
    // The brick-at-once conversion (F16C where the CPU has it) against
    // `half` one value at a time: random bits (NaN payloads, subnormals,
    // infinities), ties to even, values past half's range.
    let mut rng = vdbcook_testkit::Rng::new(16);
    let edges = [0.0f32, -0.0, 65504.0, 65520.0, -65520.0, 1e-8, 5.96e-8, 2.98e-8, 1.0 + 1.0 / 2048.0, 1.0 + 3.0 / 2048.0, f32::INFINITY, f32::NAN, f32::from_bits(0x7f80_0001)];
    for round in 0..64 {
        let b: Brick = std::array::from_fn(|i| if round == 0 && i < edges.len() { edges[i] } else { f32::from_bits(rng.next_u64() as u32) });
        let h = crate::texels::to_half(&b);
        for (v, &x) in b.iter().zip(&h) {
            assert_eq!(x, half::f16::from_f32(*v).to_bits(), "{v:e} ({:#x})", v.to_bits());
        }
        let mut back = [0.0f32; BRICK_VOXELS];
        crate::texels::from_half(&h, &mut back);
        for (&x, y) in h.iter().zip(back) {
            assert_eq!(half::f16::from_bits(x).to_f32().to_bits(), y.to_bits(), "{x:#x}");
        }
    }
}

#[test]
fn levels_round_as_round_does() {
    // quantise's rounding against f32::round over every 8-bit step's
    // neighbourhood and halves, and random levels up to 65535.
    let mut rng = vdbcook_testkit::Rng::new(7);
    let mut probes: Vec<f32> = (0..=65535u32).flat_map(|k| [k as f32, k as f32 + 0.5]).collect();
    probes.extend((0..100_000).map(|_| rng.unit() * 65535.0));
    for &l in &probes {
        for x in [l, f32::from_bits(l.to_bits().saturating_sub(1)), f32::from_bits(l.to_bits() + 1)].into_iter().filter(|x| (0.0..=65535.0).contains(x)) {
            let mut b = [0.0f32; BRICK_VOXELS];
            b[1] = 65535.0;
            b[0] = x;
            assert_eq!(u32::from(crate::texels::quantise16(&b, [0.0, 65535.0])[0]), x.round() as u32, "{x}");
        }
    }
}

#[test]
fn fast_paths_of_ranges_and_error_figures_agree_with_voxel_by_voxel() {
    // range_of and add_masked take a fast path when nothing is NaN or ±∞;
    // both must give what a plain loop over the voxels gives, with and
    // without non-finite voxels, over full and partial masks.
    let mut rng = vdbcook_testkit::Rng::new(0x5eed);
    let specials = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, f32::MAX, -f32::MAX];
    for case in 0..200 {
        let mut b = random_brick(&mut rng, 0.5);
        for _ in 0..(case % 4) * (case % 3) {
            b[rng.below(512) as usize] = specials[rng.below(specials.len() as u64) as usize];
        }
        let finite: Vec<f32> = b.iter().copied().filter(|v| v.is_finite()).collect();
        if !finite.is_empty() {
            let lo = finite.iter().copied().fold(f32::INFINITY, f32::min);
            let hi = finite.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            assert_eq!(range_of(&b), [lo, hi], "case {case}");
        }
        let mut decoded = b;
        for v in decoded.iter_mut() {
            *v += rng.unit() * 0.01;
        }
        if case % 7 == 0 {
            decoded[rng.below(512) as usize] = f32::NAN;
        }
        let mask: [u64; 8] = if case % 2 == 0 { [u64::MAX; 8] } else { std::array::from_fn(|_| rng.next_u64()) };
        let mut fast = ErrorStats::default();
        fast.add_masked(&b, &decoded, &mask);
        let mut plain = ErrorStats::default();
        for i in (0..512).filter(|&i| mask[i / 64] >> (i % 64) & 1 == 1) {
            plain.add(b[i], decoded[i]);
        }
        assert_eq!((fast.count, fast.non_finite), (plain.count, plain.non_finite), "case {case}");
        assert_eq!(fast.max_abs.to_bits(), plain.max_abs.to_bits(), "case {case}");
        let close = (fast.sum_sq - plain.sum_sq).abs() <= 1e-12 * plain.sum_sq.abs() || (fast.sum_sq.is_nan() && plain.sum_sq.is_nan()) || fast.sum_sq == plain.sum_sq;
        assert!(close, "case {case}: {} against {}", fast.sum_sq, plain.sum_sq);
    }
}

/// A random brick of one of the kinds `--max-error` meets: smooth,
/// noisy, constant, with extreme values, with non-finite voxels.
fn kind_of_brick(rng: &mut vdbcook_testkit::Rng, kind: u64) -> Brick {
    match kind {
        0 => random_brick(rng, 0.0),
        1 => random_brick(rng, 40.0),
        2 => [rng.unit() * 10.0 - 5.0; BRICK_VOXELS],
        3 => {
            let mut b = random_brick(rng, 2.0);
            let big = [f32::MAX, -f32::MAX, 3e38, 1e-30];
            for _ in 0..1 + rng.below(4) {
                b[rng.below(BRICK_VOXELS as u64) as usize] = big[rng.below(4) as usize];
            }
            b
        }
        _ => {
            let mut b = random_brick(rng, 1.0);
            let odd = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
            for _ in 0..1 + rng.below(3) {
                b[rng.below(BRICK_VOXELS as u64) as usize] = odd[rng.below(3) as usize];
            }
            b
        }
    }
}

#[test]
fn supercompressed_choices_keep_the_bound_with_ranges_of_few_mantissa_bits() {
    // For a supercompressed asset the constant's value and a ranged brick's
    // min are the floats of fewest mantissa bits the bound allows: never more
    // bits than the plain choice's, and every shown voxel still within E.
    let mut rng = vdbcook_testkit::Rng::new(0x5ca1e);
    let bits = |x: f32| 32 - x.to_bits().trailing_zeros().min(32);
    let (mut fewer, mut ranged) = (0, 0);
    for trial in 0..60u64 {
        let brick = kind_of_brick(&mut rng, trial % 5);
        let mask: [u64; 8] = if trial % 3 == 0 { std::array::from_fn(|_| rng.next_u64() & rng.next_u64()) } else { [u64::MAX; 8] };
        let e = 10f32.powf(-4.0 + 3.5 * rng.unit());
        let plain = cheapest(&brick, &mask, e, Quality::VeryFast, None);
        for disk in [crate::Optimize::Gpu, crate::Optimize::Disk] {
            let choice = cheapest(&brick, &mask, e, Quality::VeryFast, Some(disk));
            let decoded = decode_one(choice.format, &choice.bytes, choice.range);
            assert!(within(&brick, &decoded, &mask, e), "trial {trial} {disk:?}: {} breaks {e}", choice.format.name());
            if choice.format == plain.format && matches!(choice.format, Format::Constant | Format::Unorm8 | Format::Unorm16) {
                assert!(bits(choice.range[0]) <= bits(plain.range[0]), "trial {trial} {disk:?}: {:?} from {:?}", choice.range, plain.range);
                fewer += usize::from(bits(choice.range[0]) < bits(plain.range[0]));
                ranged += 1;
            }
        }
    }
    assert!(ranged >= 20 && fewer * 2 > ranged, "{fewer} of {ranged} choices with a shorter min");
}

#[test]
fn per_brick_formats_meet_the_bound_with_the_cheapest_format() {
    // For random bricks (five kinds, fully or partly shown) and random
    // bounds E: every shown voxel, decoded through the plane the choice
    // lands in, is within E (NaN and ±∞ decode to themselves); and every
    // cheaper format, encoded and decoded on its own, breaks E somewhere.
    let mut rng = vdbcook_testkit::Rng::new(0xe4405);
    let mut seen = std::collections::BTreeSet::new();
    for trial in 0..120u64 {
        let brick = kind_of_brick(&mut rng, trial % 5);
        let mask: [u64; 8] = if trial % 3 == 0 { std::array::from_fn(|_| rng.next_u64() & rng.next_u64()) } else { [u64::MAX; 8] };
        let e = 10f32.powf(-6.0 + 6.0 * rng.unit());
        let choice = cheapest(&brick, &mask, e, Quality::VeryFast, None);
        seen.insert(choice.format);
        let mut choices = crate::Choices::new(1, None);
        choices.push(choice.clone()).unwrap();
        let encoded = Encoded::from_choices(crate::Bricks::dense(std::slice::from_ref(&brick), 1), choices, &[true]);
        assert_eq!(encoded.specs.len(), 1);
        assert_eq!(encoded.specs[0].plane, single_plane(choice.format));
        let decoded = encoded.decode(0).unwrap()[0];
        for i in (0..BRICK_VOXELS).filter(|&i| mask[i >> 6] >> (i & 63) & 1 == 1) {
            let (v, d) = (brick[i], decoded[i]);
            let ok = if v.is_nan() {
                d.is_nan()
            } else if v.is_infinite() {
                d == v
            } else {
                (f64::from(d) - f64::from(v)).abs() <= f64::from(e)
            };
            assert!(ok, "trial {trial}: {} voxel {i}: {v} decodes to {d}, bound {e}", choice.format.name());
        }
        let cost = |f: Format| Format::BY_COST.iter().position(|&g| g == f).unwrap();
        for cheaper in Format::BY_COST.into_iter().take(cost(choice.format)) {
            let meets = match cheaper {
                // A constant within E exists exactly when the shown voxels are finite and span at most 2E.
                Format::Constant => {
                    let shown: Vec<f32> = (0..BRICK_VOXELS).filter(|&i| mask[i >> 6] >> (i & 63) & 1 == 1).map(|i| brick[i]).collect();
                    let (lo, hi) = shown.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
                    shown.iter().all(|v| v.is_finite()) && f64::from(hi) - f64::from(lo) <= 2.0 * f64::from(e) * 0.999
                }
                f => within(&brick, &round_trip(f, Quality::VeryFast, &brick), &mask, e),
            };
            assert!(!meets, "trial {trial}: chose {} but {} meets {e}", choice.format.name(), cheaper.name());
        }
    }
    // The trials reach most of the ladder.
    assert!(seen.len() >= 5, "{seen:?}");
}

#[test]
fn error_stats() {
    let mut e = ErrorStats::default();
    e.add(1.0, 1.5);
    e.add(0.0, 0.0);
    assert!((e.rmse() - (0.125f64).sqrt()).abs() < 1e-12);
    assert_eq!(e.max_abs, 0.5);
    assert!(ErrorStats::default().psnr(1.0).is_infinite());
}

/// Bricks encoded on demand decode value by value (`round_trip`) to exactly
/// what a reader gets from their bytes, in every uncompressed format and
/// packing, with non-finite and constant bricks among them.
#[test]
fn on_demand_decoding_is_the_readers_decoding() {
    let mut rng = vdbcook_testkit::Rng::new(7);
    let mut bricks: Vec<Brick> = (0..6).map(|_| random_brick(&mut rng, 40.0)).collect();
    bricks[1][5] = f32::NAN;
    bricks[2][9] = f32::INFINITY;
    bricks[3] = [2.5; BRICK_VOXELS];
    bricks[4][0] = -0.0;
    for format in [Format::F32, Format::F16, Format::Unorm8, Format::Unorm16] {
        for channels in [1usize, 2, 3] {
            let e = Encoded::new(group_planes(format, &(0..channels).collect::<Vec<_>>()), Quality::Fast, &bricks, channels, None, &|_| {});
            for i in 0..e.len() {
                let direct = e.decode(i).unwrap();
                for (p, spec) in e.specs.iter().enumerate() {
                    let mut data = vec![0u8; spec.plane.brick_bytes()];
                    assert!(e.write(p, i, &mut data));
                    let texels = spec.plane.decode_brick(&data);
                    for (slot, &c) in spec.channels.iter().enumerate() {
                        let read = spec.plane.channel_values(&texels, slot as u32 * spec.plane.z_per_texel, e.range(i, c));
                        let bits = |b: &Brick| b.map(f32::to_bits);
                        assert_eq!(bits(&direct[c]), bits(&read), "{format:?}, {channels} channels, brick {i}, channel {c}");
                    }
                }
            }
        }
    }
}

#[test]
fn decoding_wanted_channels_matches_decoding_all_over_a_slotted_pool() {
    // Three channels in planes of their own (f16, bc7, unorm8) over a
    // slotted view: channel 2 of brick 1 is a constant brick held once.
    let a: Brick = std::array::from_fn(|i| (i % 17) as f32 * 0.05);
    let b: Brick = std::array::from_fn(|i| 1.0 - (i % 5) as f32 * 0.1);
    let constant = [0.25f32; BRICK_VOXELS];
    let stored = [a, b, a, b, a];
    let slots = [0u32, 1, 2, 3, 4, vdbcook_grid::CONSTANT];
    let bricks = crate::Bricks::sparse(&slots, &stored, std::slice::from_ref(&constant), 3);
    assert_eq!((bricks.len(), bricks.get(1, 2), bricks.constant_of(1, 2), bricks.constant_of(1, 1)), (2, &constant, Some(0), None));
    assert!(bricks.try_get(2, 0).is_none() && bricks.try_get(0, 3).is_none());
    let mut specs = group_planes(Format::F16, &[0]);
    specs.extend(group_planes(Format::Bc7, &[1]));
    specs.extend(group_planes(Format::Unorm8, &[2]));
    let e = Encoded::with_absent(specs, Quality::Fast, bricks, None, None, None, &|_| {}).unwrap();
    for i in 0..2 {
        let all = e.decode(i).unwrap();
        for want in [[true, false, false], [false, true, true], [false, false, true]] {
            let some = e.decode_wanted(i, &want).unwrap();
            for c in 0..3 {
                let expected = want[c].then_some(all[c]);
                assert_eq!(some[c], expected, "brick {i} channel {c} wanted {want:?}");
            }
        }
    }
    // The constant brick's range is the range of its values.
    assert_eq!(e.range(1, 2), [0.25, 0.25]);
}

#[test]
fn choosing_in_batches_picks_what_each_brick_alone_picks() {
    // More brick channels than a BC7 batch, of every kind, fully, partly and
    // not shown: the batched BC7 candidates are the lone brick's.
    let mut rng = vdbcook_testkit::Rng::new(0xba7c);
    // Every kind, and smooth ramps, which BC7 holds within a loose bound.
    let ramp = |t: u64| -> Brick { std::array::from_fn(|i| ((i / 64) as f32 * 0.1 + ((i / 8) % 8) as f32 * 0.03 + (i % 8) as f32 * 0.01) * (1.0 + t as f32 * 0.01)) };
    let bricks: Vec<Brick> = (0..90u64).map(|t| if t % 6 == 5 { ramp(t) } else { kind_of_brick(&mut rng, t % 6) }).collect();
    let view = crate::Bricks::dense(&bricks, 2);
    let masks: Vec<[u64; 8]> = (0..view.len())
        .map(|i| match i % 3 {
            0 => [u64::MAX; 8],
            1 => std::array::from_fn(|_| rng.next_u64() & rng.next_u64() & rng.next_u64()),
            _ => [0, 0, 0, 0, 0, 0xff00, 0, 0],
        })
        .collect();
    let mut formats = std::collections::BTreeSet::new();
    for (e, disk) in [(0.02, None), (0.3, None), (0.3, Some(crate::Optimize::Disk))] {
        let mut c = crate::Choices::new(2, None);
        c.choose(view, &masks, e, Quality::VeryFast, disk, &|_| {}).unwrap();
        assert_eq!(c.len(), bricks.len());
        for (j, pick) in (0..c.len()).map(|j| (j, c.pick(j).unwrap())) {
            let alone = cheapest(&bricks[j], &masks[j / 2], e, Quality::VeryFast, disk);
            assert_eq!((pick.format, pick.range), (alone.format, alone.range), "brick channel {j} (E {e}, {disk:?})");
            assert_eq!(c.bytes(j), &alone.bytes[..], "brick channel {j} (E {e}, {disk:?})");
            formats.insert(pick.format);
        }
    }
    assert!(formats.contains(&Format::Bc7) && formats.len() >= 4, "{formats:?}");
}

#[test]
fn chosen_bricks_spilled_to_a_file_encode_as_those_in_memory() {
    // Two channels of bricks of every kind, chosen in memory and with every
    // store past a 1-byte budget (in spill files where the system has them).
    let mut rng = vdbcook_testkit::Rng::new(0x5b11);
    let bricks: Vec<Brick> = (0..40u64).map(|t| kind_of_brick(&mut rng, t % 5)).collect();
    let view = crate::Bricks::dense(&bricks, 2);
    let masks = vec![[u64::MAX; 8]; view.len()];
    let chosen = |spill: Option<vdbcook_grid::spill::SpillPolicy>| {
        let mut c = crate::Choices::new(2, spill);
        c.choose(view, &masks, 0.01, Quality::VeryFast, None, &|_| {}).unwrap();
        c
    };
    let (mem, file) = (chosen(None), chosen(Some(vdbcook_grid::spill::SpillPolicy::new(std::env::temp_dir(), 1))));
    // The per-brick tables grow with the segment: they are stores too.
    #[cfg(target_os = "linux")]
    assert!(file.formats.is_spilled() && file.ranges.is_spilled() && file.at.is_spilled());
    let picks = |c: &crate::Choices| (0..c.len()).map(|j| c.pick(j).unwrap()).collect::<Vec<_>>();
    let (mem_picks, file_picks) = (picks(&mem), picks(&file));
    assert_eq!(mem_picks.len(), bricks.len());
    assert_eq!(mem_picks, file_picks);
    assert!(mem_picks.iter().any(|p| p.format != mem_picks[0].format), "one format only: the stores are not exercised");
    for j in 0..mem.len() {
        assert_eq!(mem.bytes(j), file.bytes(j));
    }
    let used = vec![true; view.len()];
    let (a, b) = (Encoded::from_choices(view, mem, &used), Encoded::from_choices(view, file, &used));
    // Bit for bit (the kinds of bricks hold NaN).
    let bits = |e: &Encoded, i: usize| e.decode(i).map(|d| d.iter().flatten().map(|v| v.to_bits()).collect::<Vec<u32>>());
    for i in 0..view.len() {
        assert_eq!(bits(&a, i), bits(&b, i));
    }
}
