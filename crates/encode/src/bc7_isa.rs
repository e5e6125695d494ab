//! Do intel_tex_2's BC7 kernels for each x86 ISA give the same blocks?
//!
//! intel_tex_2 ships its ISPC kernel compiled for sse2, sse4, avx, avx2,
//! avx512knl and avx512skx, and `CompressBlocksBC7_ispc` picks one by CPU at
//! run time. Parts of one cook (`cook --part I/N`, then `join`) may run on
//! different machines. They do not all agree: the kernels fall in two
//! classes, without FMA (sse2, sse4, avx) and with it (avx2, avx512knl,
//! avx512skx: ISPC contracts multiply-adds there), which choose differently
//! for a few blocks: 2 to 8 of the survey's 31,360 at each preset, 11
//! distinct, 10 of them among the 21,120 brick-shaped ones (sparse, smooth
//! and noisy fields). Within a class the bytes are the same; that is
//! what [`isa_variants_agree_within_their_class`] guards, with the survey's
//! divergent blocks pinned. [`survey`] (ignored: ~45 s) re-measures:
//! `cargo test --release -p vdbcook-encode --lib bc7_isa::survey -- --ignored --nocapture`.

use crate::bc::bc7_settings;
use crate::texels::{bc7_texels, quantise, range_of};
use crate::{Brick, Quality, BRICK_VOXELS};
use intel_tex_2::bindings::kernel::{bc7_enc_settings, rgba_surface, CompressBlocksBC7_ispc};

type Kernel = unsafe extern "C" fn(*mut rgba_surface, *mut u8, *mut bc7_enc_settings);

// The per-ISA entry points behind `CompressBlocksBC7_ispc`, in the static
// library intel_tex_2 links.
unsafe extern "C" {
    fn CompressBlocksBC7_ispc_sse2(src: *mut rgba_surface, dst: *mut u8, settings: *mut bc7_enc_settings);
    fn CompressBlocksBC7_ispc_sse4(src: *mut rgba_surface, dst: *mut u8, settings: *mut bc7_enc_settings);
    fn CompressBlocksBC7_ispc_avx(src: *mut rgba_surface, dst: *mut u8, settings: *mut bc7_enc_settings);
    fn CompressBlocksBC7_ispc_avx2(src: *mut rgba_surface, dst: *mut u8, settings: *mut bc7_enc_settings);
    fn CompressBlocksBC7_ispc_avx512knl(src: *mut rgba_surface, dst: *mut u8, settings: *mut bc7_enc_settings);
    fn CompressBlocksBC7_ispc_avx512skx(src: *mut rgba_surface, dst: *mut u8, settings: *mut bc7_enc_settings);
}

/// The variants this CPU can run, with their class (whether ISPC used FMA).
/// ISPC's avx2 target also uses F16C and BMI; the avx512knl object uses
/// only AVX-512 F and CD instructions (no ER or PF: checked with objdump),
/// so it runs wherever those are, although the dispatcher picks it only on
/// Xeon Phi.
fn variants() -> Vec<(&'static str, bool, Kernel)> {
    let avx2 = ["avx2", "fma", "f16c", "bmi1", "bmi2"];
    let skx = ["avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"];
    let has = |fs: &[&str]| {
        fs.iter().all(|&f| match f {
            "sse2" => is_x86_feature_detected!("sse2"),
            "sse4.1" => is_x86_feature_detected!("sse4.1"),
            "sse4.2" => is_x86_feature_detected!("sse4.2"),
            "avx" => is_x86_feature_detected!("avx"),
            "avx2" => is_x86_feature_detected!("avx2"),
            "fma" => is_x86_feature_detected!("fma"),
            "f16c" => is_x86_feature_detected!("f16c"),
            "bmi1" => is_x86_feature_detected!("bmi1"),
            "bmi2" => is_x86_feature_detected!("bmi2"),
            "avx512f" => is_x86_feature_detected!("avx512f"),
            "avx512cd" => is_x86_feature_detected!("avx512cd"),
            "avx512bw" => is_x86_feature_detected!("avx512bw"),
            "avx512dq" => is_x86_feature_detected!("avx512dq"),
            "avx512vl" => is_x86_feature_detected!("avx512vl"),
            _ => unreachable!("{f}"),
        })
    };
    let all: [(&str, bool, bool, Kernel); 6] = [
        ("sse2", false, has(&["sse2"]), CompressBlocksBC7_ispc_sse2),
        ("sse4", false, has(&["sse4.1", "sse4.2"]), CompressBlocksBC7_ispc_sse4),
        ("avx", false, has(&["avx"]), CompressBlocksBC7_ispc_avx),
        ("avx2", true, has(&avx2), CompressBlocksBC7_ispc_avx2),
        ("avx512knl", true, has(&["avx512f", "avx512cd"]), CompressBlocksBC7_ispc_avx512knl),
        ("avx512skx", true, has(&skx), CompressBlocksBC7_ispc_avx512skx),
    ];
    all.into_iter().filter(|v| v.2).map(|(name, fma, _, k)| (name, fma, k)).collect()
}

type Block = [[u8; 4]; 16];

/// Encodes `blocks` side by side in one 4-texel-tall surface with `kernel`,
/// as `intel_tex_2::bc7::compress_blocks_into` calls it.
fn encode(kernel: Kernel, q: Quality, blocks: &[Block]) -> Vec<u8> {
    let w = 4 * blocks.len();
    let mut surface = vec![0u8; w * 4 * 4];
    for (b, block) in blocks.iter().enumerate() {
        for (t, texel) in block.iter().enumerate() {
            let px = ((t / 4) * w + b * 4 + t % 4) * 4;
            surface[px..px + 4].copy_from_slice(texel);
        }
    }
    let s = bc7_settings(q);
    let mut settings = bc7_enc_settings {
        mode_selection: s.mode_selection,
        refineIterations: s.refine_iterations.map(|r| r as i32),
        skip_mode2: s.skip_mode2,
        fastSkipTreshold_mode1: s.fast_skip_threshold_mode1 as i32,
        fastSkipTreshold_mode3: s.fast_skip_threshold_mode3 as i32,
        fastSkipTreshold_mode7: s.fast_skip_threshold_mode7 as i32,
        mode45_channel0: s.mode45_channel0 as i32,
        refineIterations_channel: s.refine_iterations_channel as i32,
        channels: s.channels,
    };
    let mut rgba = rgba_surface { ptr: surface.as_mut_ptr(), width: w as i32, height: 4, stride: (w * 4) as i32 };
    let mut out = vec![0u8; blocks.len() * 16];
    // SAFETY: the surface holds width × height RGBA texels at `stride` bytes
    // per row and `out` one 16-byte block per 4×4 texels; the kernel only
    // reads the first two and writes the last.
    unsafe { kernel(&mut rgba, out.as_mut_ptr(), &mut settings) };
    out
}

/// 4×4 blocks of several kinds: uniform noise, linear gradients, smooth
/// noise, constant and nearly constant blocks, and the BC7 texels of bricks
/// of smooth and noisy fields (one, two, three and four channels) made by
/// the cook's own path; `scale` times as many of each.
fn test_blocks(scale: usize) -> Vec<Block> {
    let mut rng = vdbcook_testkit::Rng::new(0xbc7);
    let mut blocks: Vec<Block> = Vec::new();
    for _ in 0..64 * scale {
        blocks.push(std::array::from_fn(|_| std::array::from_fn(|_| rng.below(256) as u8)));
    }
    for _ in 0..64 * scale {
        let c: [(f32, f32, f32); 4] = std::array::from_fn(|_| (rng.unit() * 255.0, rng.unit() * 80.0 - 40.0, rng.unit() * 80.0 - 40.0));
        blocks.push(std::array::from_fn(|t| c.map(|(b, dx, dy)| (b + dx * (t % 4) as f32 + dy * (t / 4) as f32).clamp(0.0, 255.0) as u8)));
    }
    for _ in 0..64 * scale {
        // Bilinear over a random 2×2 lattice per channel.
        let l: [[f32; 4]; 4] = std::array::from_fn(|_| std::array::from_fn(|_| rng.unit() * 255.0));
        blocks.push(std::array::from_fn(|t| {
            let (u, v) = ((t % 4) as f32 / 3.0, (t / 4) as f32 / 3.0);
            l.map(|c| (c[0] * (1.0 - u) * (1.0 - v) + c[1] * u * (1.0 - v) + c[2] * (1.0 - u) * v + c[3] * u * v).round() as u8)
        }));
    }
    for k in 0..32 * scale {
        let c: [u8; 4] = std::array::from_fn(|_| rng.below(256) as u8);
        // Constants, including all 0 and all 255.
        blocks.push(
            [match k {
                0 => [0; 4],
                1 => [255; 4],
                _ => c,
            }; 16],
        );
        blocks.push(std::array::from_fn(|_| c.map(|v| v.saturating_add(rng.below(3) as u8).saturating_sub(1))));
    }
    // Bricks: a smooth blob (a fog-like sphere), its noisy copy, and a sparse
    // one (mostly 0 with a few voxels set), as one to four channels.
    let brick = |k: usize, rng: &mut vdbcook_testkit::Rng| -> Brick {
        let (cx, cy, cz, r) = (rng.unit() * 8.0, rng.unit() * 8.0, rng.unit() * 8.0, 2.0 + rng.unit() * 8.0);
        std::array::from_fn(|i| {
            let (x, y, z) = ((i / 64) as f32, ((i / 8) % 8) as f32, (i % 8) as f32);
            let d = ((x - cx).powi(2) + (y - cy).powi(2) + (z - cz).powi(2)).sqrt();
            let smooth = (1.0 - d / r).max(0.0);
            match k % 3 {
                0 => smooth,
                1 => smooth + rng.unit() * 0.1,
                _ => {
                    if rng.below(10) == 0 {
                        rng.unit()
                    } else {
                        0.0
                    }
                }
            }
        })
    };
    for (channels, zpt) in [(1, 4), (2, 2), (3, 1), (4, 1)] {
        let bricks: Vec<Vec<[u8; BRICK_VOXELS]>> = (0..6 * scale)
            .map(|k| {
                (0..channels)
                    .map(|_| {
                        let b = brick(k, &mut rng);
                        quantise(&b, range_of(&b))
                    })
                    .collect()
            })
            .collect();
        // Texels per brick in the order (slice, y, x), 8×8 per slice.
        let texels = bc7_texels(&bricks, zpt);
        for slice in texels.chunks_exact(64) {
            for (by, bx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                blocks.push(std::array::from_fn(|t| slice[(by * 4 + t / 4) * 8 + bx * 4 + t % 4]));
            }
        }
    }
    blocks
}

/// The blocks of `test_blocks(40)` on which the two classes differed (at
/// the presets noted), as their 16 RGBA texels.
const DIVERGENT: [&str; 11] = [
    "2b1074dc400055b45500358c6a0016654e3573ce631553a77800347f8d001558715b71c1863a52999b1a3372b000134a948070b4a960518cbe3f3265d41f123d", // gradient; very-fast to slow
    "00000000000000000000000000203633000000000000000000000000000012100000000000000000000000000000000000000000000000000000000000000000", // 1 channel; very-fast, fast
    "0000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000110b", // 1 channel; all five
    "616fa9b07980a6c189a5abb587939baa5c8c94a781a3929e7f9e948d929d7f885e83737f859a71778fae7a7a97b26b746f785e626383526b788c576a81ae5648", // 2 channels; ultra-fast
    "6a49563a72506d4e7351805d6d4c8a665d3e573b65456f4f6646815e5f418b674a2e513552356849523579584d308360341a442a3a20593d3b21694b361c7252", // 2 channels; very-fast to slow
    "00000000000000000000e6000000000000000000000000000000e3000000000000000000000038000000000000000000aa630000000000000000000000004c00", // 3 channels; fast
    "0e0e1600111216000b04120010110a000b1104001008180010191a0013171600181c04001903080015141a00150a16000b020e0013160900161c0e0018031800", // 3 channels; very-fast
    "51020e0e3c14160737050711130e0f1355090513430a1b002d0e020b28161018521703075314061140090c0d2a0b020f551214053e140c0a310a160e21071409", // 4 channels; fast
    "c06c4389fa554994f46446aac83a42b0c97a4b73da72668ee0605ca3bd4e5bb78c916584ab857a85a2747f929a5d6daf6383836b7e8076806e7f8a915f5d8c88", // 4 channels; very-fast to slow
    "a0aa006200000000000000000000000000001300000000000000000000000000360300000000000000000000000000000000000000c983000000000000000000", // 4 channels; slow
    "76937a8ba1726c89ca44567cec103c6767b855ad8d8e49aaae5a379ac52120814ebe2fca6f9225c58a5d16b19a23029330a009da4c7d01d4624c00bc6f17009c", // 4 channels; very-fast to slow
];

fn divergent_blocks() -> Vec<Block> {
    DIVERGENT
        .iter()
        .map(|hex| {
            let b: Vec<u8> = (0..64).map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap()).collect();
            std::array::from_fn(|t| std::array::from_fn(|c| b[4 * t + c]))
        })
        .collect()
}

/// Encodes `blocks` with every variant this CPU runs at every preset;
/// returns the disagreements within each class (empty when none) and, per
/// preset, how many blocks differ between the classes (when both run).
fn compare(blocks: &[Block]) -> (Vec<String>, Vec<(Quality, usize)>) {
    let variants = variants();
    let (mut within, mut across) = (Vec::new(), Vec::new());
    let differ = |a: &[u8], b: &[u8]| a.chunks_exact(16).zip(b.chunks_exact(16)).filter(|(a, b)| a != b).count();
    for q in Quality::ALL {
        let outs: Vec<Vec<u8>> = variants.iter().map(|v| encode(v.2, q, blocks)).collect();
        let first = |fma: bool| variants.iter().position(|v| v.1 == fma);
        for (v, out) in variants.iter().zip(&outs) {
            let n = differ(out, &outs[first(v.1).unwrap()]);
            if n > 0 {
                within.push(format!("{} {}: {n} of {} blocks differ from its class", v.0, q.name(), blocks.len()));
            }
        }
        // The cook calls the dispatcher: it must be one of the variants.
        let cooked = encode(CompressBlocksBC7_ispc, q, blocks);
        if !outs.contains(&cooked) {
            within.push(format!("{}: the dispatcher's blocks are no variant's", q.name()));
        }
        if let (Some(a), Some(b)) = (first(false), first(true)) {
            across.push((q, differ(&outs[a], &outs[b])));
        }
    }
    (within, across)
}

#[test]
fn isa_variants_agree_within_their_class() {
    let mut blocks = test_blocks(1);
    blocks.extend(divergent_blocks());
    let (within, across) = compare(&blocks);
    let names: Vec<&str> = variants().iter().map(|v| v.0).collect();
    eprintln!("{} blocks × {} presets × variants {names:?}; blocks differing between the classes: {across:?}", blocks.len(), Quality::ALL.len());
    assert!(within.is_empty(), "BC7 blocks differ within an ISA class:\n{}", within.join("\n"));
    // The cook's own call is the dispatcher's.
    let surface: Vec<u8> = (0..4).flat_map(|row| blocks.iter().flat_map(move |b| b[row * 4..row * 4 + 4].iter().flatten().copied())).collect();
    let w = 4 * blocks.len() as u32;
    for q in Quality::ALL {
        let cooked = intel_tex_2::bc7::compress_blocks(&bc7_settings(q), &intel_tex_2::RgbaSurface { data: &surface, width: w, height: 4, stride: 4 * w });
        assert!(cooked == encode(CompressBlocksBC7_ispc, q, &blocks), "{q:?}: intel_tex_2::bc7::compress_blocks is not the dispatching kernel");
    }
}

/// The survey behind the module's numbers (~45 s in release).
#[test]
#[ignore]
fn survey() {
    let blocks = test_blocks(40);
    let (within, across) = compare(&blocks);
    eprintln!("{} blocks × {} presets; blocks differing between the classes: {across:?}", blocks.len(), Quality::ALL.len());
    assert!(within.is_empty(), "BC7 blocks differ within an ISA class:\n{}", within.join("\n"));
}
