//! Voxel encodings of 8³ bricks and the 3D texture atlases that hold them.
//!
//! A brick's 512 values are indexed `x·64 + y·8 + z` (OpenVDB's leaf order).
//! In an atlas, brick `i` occupies an 8³ block of texels at brick position
//! [`AtlasLayout::position`]; voxel (x, y, z) of the brick is texel
//! `(8·bx + x, 8·by + y, 8·bz + z)`, and texels are stored x fastest, then
//! y, then z: the layout `queue.write_texture` expects for a 3D texture.
//!
//! | format   | texel            | per brick                                              |
//! |----------|------------------|--------------------------------------------------------|
//! | `f32`    | R32Float         | values as they are                                     |
//! | `f16`    | R16Float         | IEEE half, round to nearest even                       |
//! | `unorm8` | R8Unorm          | `round((v - min) / (max - min) · 255)` with the brick's own [min, max] |
//!
//! Every format records each brick's [min, max] (the brick range): unorm8
//! needs it to decode, and a renderer can use it to skip empty bricks.

use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

/// Voxels per brick.
pub const BRICK_VOXELS: usize = 512;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Format {
    F32,
    F16,
    Unorm8,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Format::F32 => "f32",
            Format::F16 => "f16",
            Format::Unorm8 => "unorm8",
        }
    }

    pub fn parse(s: &str) -> Option<Format> {
        Some(match s {
            "f32" => Format::F32,
            "f16" => Format::F16,
            "unorm8" => Format::Unorm8,
            _ => return None,
        })
    }

    pub fn bytes_per_voxel(self) -> usize {
        match self {
            Format::F32 => 4,
            Format::F16 => 2,
            Format::Unorm8 => 1,
        }
    }
}

/// One encoded brick: its range and `512 · bytes_per_voxel` bytes in brick order.
#[derive(Clone, Debug, PartialEq)]
pub struct EncodedBrick {
    pub range: [f32; 2],
    pub data: Vec<u8>,
}

fn range_of(values: &[f32; BRICK_VOXELS]) -> [f32; 2] {
    // Eight independent lanes, so the compiler can vectorise.
    let mut lo = [f32::INFINITY; 8];
    let mut hi = [f32::NEG_INFINITY; 8];
    for c in values.chunks_exact(8) {
        for k in 0..8 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    [lo.iter().copied().fold(f32::INFINITY, f32::min), hi.iter().copied().fold(f32::NEG_INFINITY, f32::max)]
}

pub fn encode_brick(format: Format, values: &[f32; BRICK_VOXELS]) -> EncodedBrick {
    let range = range_of(values);
    let mut data = Vec::with_capacity(BRICK_VOXELS * format.bytes_per_voxel());
    match format {
        Format::F32 => {
            for v in values {
                data.extend_from_slice(&v.to_le_bytes());
            }
        }
        Format::F16 => {
            let mut h = [half::f16::ZERO; BRICK_VOXELS];
            h.convert_from_f32_slice(values);
            for v in h {
                data.extend_from_slice(&v.to_bits().to_le_bytes());
            }
        }
        Format::Unorm8 => {
            let [lo, hi] = range;
            let span = hi - lo;
            if span > 0.0 && span.is_finite() {
                let scale = 255.0 / span;
                data.extend(values.iter().map(|&v| ((v - lo) * scale).round().clamp(0.0, 255.0) as u8));
            } else {
                data.resize(BRICK_VOXELS, 0);
            }
        }
    }
    EncodedBrick { range, data }
}

/// Decodes `data` (one brick in `format`) back to values.
pub fn decode_brick(format: Format, range: [f32; 2], data: &[u8]) -> [f32; BRICK_VOXELS] {
    let mut out = [0.0f32; BRICK_VOXELS];
    match format {
        Format::F32 => {
            for (o, b) in out.iter_mut().zip(data.chunks_exact(4)) {
                *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
        Format::F16 => {
            for (o, b) in out.iter_mut().zip(data.chunks_exact(2)) {
                *o = half::f16::from_bits(u16::from_le_bytes([b[0], b[1]])).to_f32();
            }
        }
        Format::Unorm8 => {
            let [lo, hi] = range;
            for (o, &q) in out.iter_mut().zip(data) {
                *o = if hi > lo { lo + (f32::from(q) / 255.0) * (hi - lo) } else { lo };
            }
        }
    }
    out
}

/// Encodes every brick (in parallel; the output order is the input order).
pub fn encode_all(format: Format, bricks: &[[f32; BRICK_VOXELS]]) -> Vec<EncodedBrick> {
    bricks.par_iter().map(|b| encode_brick(format, b)).collect()
}

/// Where a run of consecutive bricks lives: one 3D texture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AtlasLayout {
    /// Bricks along x, y, z.
    pub bricks: [u32; 3],
    /// Global index of the first brick in this atlas.
    pub first_brick: u32,
    /// Bricks stored (the last z layer may be partly empty).
    pub count: u32,
}

impl AtlasLayout {
    /// Texture size in texels.
    pub fn texels(&self) -> [u32; 3] {
        self.bricks.map(|b| b * 8)
    }

    /// Brick position (in bricks) of local brick `i`.
    pub fn position(&self, i: u32) -> [u32; 3] {
        let [bx, by, _] = self.bricks;
        [i % bx, (i / bx) % by, i / (bx * by)]
    }

    /// Byte offset of texel (x, y, z) for `bpv` bytes per texel.
    pub fn texel_offset(&self, x: u32, y: u32, z: u32, bpv: usize) -> usize {
        let [w, h, _] = self.texels();
        ((z as usize * h as usize + y as usize) * w as usize + x as usize) * bpv
    }

    pub fn byte_len(&self, bpv: usize) -> usize {
        let [w, h, d] = self.texels();
        w as usize * h as usize * d as usize * bpv
    }
}

/// Splits `count` bricks over as few atlases as fit a `max_dim`³ texture limit.
pub fn plan_atlases(count: u32, max_dim: u32) -> Vec<AtlasLayout> {
    let per = (max_dim / 8).max(1);
    let cap = per.saturating_mul(per).saturating_mul(per);
    let mut out = Vec::new();
    let mut first = 0u32;
    while first < count {
        let n = (count - first).min(cap);
        let bx = n.min(per);
        let by = n.div_ceil(bx).min(per);
        let bz = n.div_ceil(bx * by);
        out.push(AtlasLayout { bricks: [bx, by, bz], first_brick: first, count: n });
        first += n;
    }
    out
}

/// Lays the bricks of one atlas out as texture bytes (in parallel over layers of bricks).
pub fn pack_atlas(layout: &AtlasLayout, bricks: &[EncodedBrick], format: Format) -> Vec<u8> {
    match format.bytes_per_voxel() {
        1 => pack_atlas_n::<1>(layout, bricks),
        2 => pack_atlas_n::<2>(layout, bricks),
        _ => pack_atlas_n::<4>(layout, bricks),
    }
}

/// [`pack_atlas`] for `N` bytes per voxel (a constant, so each copy is one move).
/// The output is written strictly in order: slice by slice, row by row, and
/// along a row eight texels from each brick in turn.
fn pack_atlas_n<const N: usize>(layout: &AtlasLayout, bricks: &[EncodedBrick]) -> Vec<u8> {
    let mut out = vec![0u8; layout.byte_len(N)];
    let [bx, by, _] = layout.bricks.map(|b| b as usize);
    let [w, h, _] = layout.texels().map(|t| t as usize);
    let row = w * N;
    let first = layout.first_brick as usize;
    let end = first + layout.count as usize;
    let empty = [0u8; BRICK_VOXELS * 4];
    // One chunk per texel slice; slice `s` is z = s % 8 of brick layer s / 8.
    out.par_chunks_mut((row * h).max(1)).enumerate().for_each(|(s, slice)| {
        let (layer, z) = (s / 8, s % 8);
        for (ty, line) in slice.chunks_exact_mut(row).enumerate() {
            let (py, y) = (ty / 8, ty % 8);
            for (px, texels) in line.chunks_exact_mut(8 * N).enumerate() {
                let b = first + (layer * by + py) * bx + px;
                let data = if b < end { bricks.get(b).map_or(&empty[..], |e| &e.data[..]) } else { &empty[..] };
                for (x, t) in texels.chunks_exact_mut(N).enumerate() {
                    let src = (x * 64 + y * 8 + z) * N;
                    if let Some(v) = data.get(src..src + N) {
                        t.copy_from_slice(v);
                    }
                }
            }
        }
    });
    out
}

/// Reads local brick `i` back out of atlas bytes (brick order, `512 · bpv` bytes).
pub fn unpack_brick(layout: &AtlasLayout, atlas: &[u8], i: u32, format: Format) -> Option<Vec<u8>> {
    let bpv = format.bytes_per_voxel();
    if i >= layout.count || atlas.len() < layout.byte_len(bpv) {
        return None;
    }
    let [px, py, pz] = layout.position(i);
    let mut out = vec![0u8; BRICK_VOXELS * bpv];
    for x in 0..8u32 {
        for y in 0..8u32 {
            for z in 0..8u32 {
                let dst = ((x * 64 + y * 8 + z) as usize) * bpv;
                let src = layout.texel_offset(px * 8 + x, py * 8 + y, pz * 8 + z, bpv);
                out[dst..dst + bpv].copy_from_slice(atlas.get(src..src + bpv)?);
            }
        }
    }
    Some(out)
}

/// Voxel-domain error figures (RMSE, PSNR with the given peak, max abs error).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ErrorStats {
    pub count: u64,
    pub sum_sq: f64,
    pub max_abs: f64,
}

impl ErrorStats {
    pub fn add(&mut self, reference: f32, value: f32) {
        let d = f64::from(value) - f64::from(reference);
        self.count += 1;
        self.sum_sq += d * d;
        self.max_abs = self.max_abs.max(d.abs());
    }
    pub fn merge(&mut self, o: &ErrorStats) {
        self.count += o.count;
        self.sum_sq += o.sum_sq;
        self.max_abs = self.max_abs.max(o.max_abs);
    }
    pub fn rmse(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            (self.sum_sq / self.count as f64).sqrt()
        }
    }
    /// PSNR in dB for the given peak (the value range); infinite when exact.
    pub fn psnr(&self, peak: f64) -> f64 {
        let r = self.rmse();
        if r == 0.0 {
            f64::INFINITY
        } else {
            20.0 * (peak / r).log10()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn smoke(seed: f32) -> [f32; BRICK_VOXELS] {
        std::array::from_fn(|i| ((i as f32 * 0.37 + seed).sin() * 0.5 + 0.5) * 0.3)
    }

    #[test]
    fn f32_is_exact_and_f16_within_half_precision() {
        let b = smoke(1.0);
        assert_eq!(decode_brick(Format::F32, [0.0, 0.0], &encode_brick(Format::F32, &b).data), b);
        let e = encode_brick(Format::F16, &b);
        let d = decode_brick(Format::F16, e.range, &e.data);
        for (x, y) in b.iter().zip(d.iter()) {
            assert!((x - y).abs() <= x.abs() * 2f32.powi(-11) + 1e-7, "{x} {y}");
        }
    }

    #[test]
    fn unorm8_within_half_a_step_of_the_brick_range() {
        let mut b = smoke(2.0);
        b[0] = 1e-4; // thin smoke must keep its own range
        let e = encode_brick(Format::Unorm8, &b);
        let [lo, hi] = e.range;
        let d = decode_brick(Format::Unorm8, e.range, &e.data);
        let step = (hi - lo) / 255.0;
        for (x, y) in b.iter().zip(d.iter()) {
            assert!((x - y).abs() <= step * 0.5 + 1e-6, "{x} {y} step {step}");
        }
        let flat = [0.25f32; BRICK_VOXELS];
        let e = encode_brick(Format::Unorm8, &flat);
        assert_eq!(decode_brick(Format::Unorm8, e.range, &e.data), flat);
    }

    #[test]
    fn atlases_respect_the_texture_limit() {
        let p = plan_atlases(5, 2048);
        assert_eq!(p, vec![AtlasLayout { bricks: [5, 1, 1], first_brick: 0, count: 5 }]);
        let p = plan_atlases(300, 64); // 8 bricks per axis, 512 per atlas
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].bricks, [8, 8, 5]);
        let p = plan_atlases(1100, 64);
        assert_eq!(p.iter().map(|a| a.count).collect::<Vec<_>>(), vec![512, 512, 76]);
        assert!(p.iter().all(|a| a.texels().iter().all(|&t| t <= 64)));
        assert!(plan_atlases(0, 2048).is_empty());
    }

    #[test]
    fn every_voxel_lands_at_its_brick_coordinate() {
        // Property: for many brick counts and limits, packing then reading
        // back each brick (and each texel directly) gives its own values.
        for (count, max_dim) in [(1u32, 2048u32), (7, 16), (37, 32), (130, 40)] {
            let bricks: Vec<EncodedBrick> = (0..count)
                .map(|i| EncodedBrick { range: [0.0, 1.0], data: (0..512u32).flat_map(|v| (i * 1000 + v).to_le_bytes()).collect() })
                .collect();
            for layout in plan_atlases(count, max_dim) {
                let atlas = pack_atlas(&layout, &bricks, Format::F32);
                for i in 0..layout.count {
                    let g = layout.first_brick + i;
                    assert_eq!(unpack_brick(&layout, &atlas, i, Format::F32).unwrap(), bricks[g as usize].data);
                    let [px, py, pz] = layout.position(i);
                    let (x, y, z) = (3u32, 5u32, 6u32);
                    let o = layout.texel_offset(px * 8 + x, py * 8 + y, pz * 8 + z, 4);
                    assert_eq!(u32::from_le_bytes(atlas[o..o + 4].try_into().unwrap()), g * 1000 + x * 64 + y * 8 + z);
                }
            }
        }
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
}
