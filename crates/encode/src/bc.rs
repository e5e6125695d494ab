//! BC4 and BC7 bricks.
//!
//! A brick is 8×8 texels in x and y. BC4 keeps one voxel per texel and takes
//! 8 slices (z = slice); BC7 packs four consecutive z-slices into a texel's
//! RGBA (z = 4·slice + channel) and takes 2 slices. Each slice of a brick is
//! 2×2 blocks of 4×4 texels; an encoded brick is its blocks in the order
//! (slice, block row, block column): 32 × 8 bytes (BC4, 4 bits per voxel) or
//! 8 × 16 bytes (BC7, 2 bits per voxel). Voxels are first mapped to 8-bit
//! levels over the brick's own [min, max].

use crate::{Format, Quality, BRICK_VOXELS};

pub const BC4_BRICK_BYTES: usize = 8 * 4 * 8;
pub const BC7_BRICK_BYTES: usize = 2 * 4 * 16;

fn bc7_settings(q: Quality) -> intel_tex_2::bc7::EncodeSettings {
    use intel_tex_2::bc7;
    match q {
        Quality::UltraFast => bc7::alpha_ultra_fast_settings(),
        Quality::VeryFast => bc7::alpha_very_fast_settings(),
        Quality::Fast => bc7::alpha_fast_settings(),
        Quality::Basic => bc7::alpha_basic_settings(),
        Quality::Slow => bc7::alpha_slow_settings(),
    }
}

/// Encodes bricks of 8-bit levels (index `x·64 + y·8 + z`), side by side in
/// one surface per call (`8·n` texels wide, `8 · slices` tall), into `out`
/// (`brick_bytes` per brick).
pub fn encode(format: Format, quality: Quality, levels: &[[u8; BRICK_VOXELS]], out: &mut [u8]) {
    let n = levels.len();
    if n == 0 {
        return;
    }
    let sp = format.slices_per_brick() as usize;
    let comps = if format == Format::Bc7 { 4 } else { 1 };
    let (w, h) = (8 * n, 8 * sp);
    let mut surface = vec![0u8; w * h * comps];
    for (k, lv) in levels.iter().enumerate() {
        for s in 0..sp {
            for y in 0..8 {
                for x in 0..8 {
                    let px = ((s * 8 + y) * w + k * 8 + x) * comps;
                    for c in 0..comps {
                        // BC4: z = s; BC7: z = 4s + c.
                        let z = if comps == 4 { 4 * s + c } else { s };
                        surface[px + c] = lv[x * 64 + y * 8 + z];
                    }
                }
            }
        }
    }
    let bb = format.block_bytes();
    let blocks = if format == Format::Bc7 {
        let surf = intel_tex_2::RgbaSurface { data: &surface, width: w as u32, height: h as u32, stride: (w * 4) as u32 };
        intel_tex_2::bc7::compress_blocks(&bc7_settings(quality), &surf)
    } else {
        let surf = intel_tex_2::RSurface { data: &surface, width: w as u32, height: h as u32, stride: w as u32 };
        intel_tex_2::bc4::compress_blocks(&surf)
    };
    // Blocks come out row-major over the surface: row r = 2s + block row, column 2k + block column.
    let cols = w / 4;
    for (k, brick) in out.chunks_exact_mut(format.brick_bytes()).take(n).enumerate() {
        for (j, dst) in brick.chunks_exact_mut(bb).enumerate() {
            // Block j of a brick is (slice, block row, block column).
            let (s, br, bc) = (j / 4, (j / 2) % 2, j % 2);
            let i = ((2 * s + br) * cols + 2 * k + bc) * bb;
            if let Some(src) = blocks.get(i..i + bb) {
                dst.copy_from_slice(src);
            }
        }
    }
}

/// Decodes an encoded brick to levels in [0, 1] (index `x·64 + y·8 + z`).
pub fn decode(format: Format, data: &[u8]) -> [f32; BRICK_VOXELS] {
    let mut out = [0.0f32; BRICK_VOXELS];
    let sp = format.slices_per_brick() as usize;
    let bb = format.block_bytes();
    for s in 0..sp {
        for br in 0..2 {
            for bc in 0..2 {
                let i = ((s * 2 + br) * 2 + bc) * bb;
                let Some(block) = data.get(i..i + bb) else { continue };
                if format == Format::Bc7 {
                    let mut rgba = [0u8; 64];
                    bcdec_rs::bc7(block, &mut rgba, 16);
                    for ty in 0..4 {
                        for tx in 0..4 {
                            let (x, y) = (bc * 4 + tx, br * 4 + ty);
                            for c in 0..4 {
                                out[x * 64 + y * 8 + 4 * s + c] = f32::from(rgba[(ty * 4 + tx) * 4 + c]) / 255.0;
                            }
                        }
                    }
                } else {
                    let mut r = [0.0f32; 16];
                    bcdec_rs::bc4_float(block, &mut r, 4, false);
                    for ty in 0..4 {
                        for tx in 0..4 {
                            let (x, y) = (bc * 4 + tx, br * 4 + ty);
                            out[x * 64 + y * 8 + s] = r[ty * 4 + tx];
                        }
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth field with one distinct value per (x, y, z) direction.
    fn ramp() -> [u8; BRICK_VOXELS] {
        std::array::from_fn(|i| {
            let (x, y, z) = (i / 64, (i / 8) % 8, i % 8);
            (x * 24 + y * 6 + z * 2) as u8
        })
    }

    #[test]
    fn bc4_round_trip_keeps_orientation() {
        let lv = ramp();
        let mut enc = [0u8; 2 * BC4_BRICK_BYTES];
        encode(Format::Bc4, Quality::Fast, &[lv, [200; BRICK_VOXELS]], &mut enc);
        let enc: Vec<&[u8]> = enc.chunks(BC4_BRICK_BYTES).collect();
        let d = decode(Format::Bc4, enc[0]);
        for i in 0..BRICK_VOXELS {
            assert!((d[i] * 255.0 - f32::from(lv[i])).abs() <= 6.0, "voxel {i}: {} vs {}", d[i] * 255.0, lv[i]);
        }
        let flat = decode(Format::Bc4, enc[1]);
        assert!(flat.iter().all(|&v| (v * 255.0 - 200.0).abs() < 0.5));
    }

    #[test]
    fn bc7_round_trip_keeps_orientation_and_channels() {
        let lv = ramp();
        for q in Quality::ALL {
            let mut enc = [0u8; 2 * BC7_BRICK_BYTES];
            encode(Format::Bc7, q, &[[7; BRICK_VOXELS], lv], &mut enc);
            let enc: Vec<&[u8]> = enc.chunks(BC7_BRICK_BYTES).collect();
            let d = decode(Format::Bc7, enc[1]);
            let mut worst = 0.0f32;
            for i in 0..BRICK_VOXELS {
                worst = worst.max((d[i] * 255.0 - f32::from(lv[i])).abs());
            }
            assert!(worst <= 12.0, "{q:?}: worst level error {worst}");
            assert!(decode(Format::Bc7, enc[0]).iter().all(|&v| (v * 255.0 - 7.0).abs() < 0.5));
        }
    }

    #[test]
    fn known_good_blocks_decode() {
        // A BC4 block with endpoints 255 and 0 and every index 0 is all 255;
        // index 1 everywhere is all 0 (the second endpoint).
        let mut b = [0u8; BC4_BRICK_BYTES];
        for blk in b.chunks_exact_mut(8) {
            blk[0] = 255;
            blk[1] = 0;
        }
        assert!(decode(Format::Bc4, &b).iter().all(|&v| v == 1.0));
        for blk in b.chunks_exact_mut(8) {
            // 16 three-bit indices of value 1: bit pattern 001 repeated.
            let bits: u64 = (0..16).fold(0, |acc, i| acc | (1u64 << (3 * i)));
            blk[2..8].copy_from_slice(&bits.to_le_bytes()[..6]);
        }
        assert!(decode(Format::Bc4, &b).iter().all(|&v| v == 0.0));
        // BC7 mode 6 block (bit 6 set) with all-zero endpoints and indices decodes to 0.
        let mut b7 = [0u8; BC7_BRICK_BYTES];
        for blk in b7.chunks_exact_mut(16) {
            blk[0] = 0x40;
        }
        assert!(decode(Format::Bc7, &b7).iter().all(|&v| v == 0.0));
    }
}
