//! Voxel encodings of bricks: the texels of each plane of an asset, made from
//! the brick pool.  Which voxel and channel is which texel, lane, block and
//! byte is `vdbcook_vpak::layout`'s to say (the format's one owner); this
//! crate computes the levels and runs the encoders.
//!
//! | format   | texel                                  | per brick and channel                  |
//! |----------|----------------------------------------|----------------------------------------|
//! | `f32`    | R32Float / RG32Float / RGBA32Float      | values as they are                     |
//! | `f16`    | R16Float / RG16Float / RGBA16Float      | IEEE half, round to nearest even       |
//! | `unorm8` | R8Unorm / RG8Unorm / RGBA8Unorm         | `round((v - min) / (max - min) · 255)` with the brick's own channel range |
//! | `bc4`    | Bc4RUnorm, one plane per channel        | our BC4 encoder over those levels      |
//! | `bc7`    | Bc7RgbaUnorm, lanes = channels × z-slices | intel_tex_2's BC7 over those levels  |
//!
//! Every brick records each channel's [min, max] (the brick range) over its
//! finite values: the ranged formats need it to decode, and a renderer can
//! skip empty bricks.  NaN and ±∞ voxels are kept by `f32` and `f16`; the
//! ranged formats cannot hold them and store each as the mean of its finite
//! neighbours ([`fill_non_finite`]), so no block is fitted through one.

use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;
pub use vdbcook_vpak::{BrickSource, Format, Plane, BRICK_VOXELS, MAX_BRICK_BYTES};

/// One brick of one channel (index `x·64 + y·8 + z`).
pub type Brick = [f32; BRICK_VOXELS];

/// Encoder presets of the block formats: for BC7, intel_tex_2's ISPC "alpha"
/// settings (all four channels carry voxels); for BC4, how far our encoder
/// searches around each block's least-squares endpoints.  `VeryFast` is the
/// default: see docs/benchmarks.md for the measurements behind it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Quality {
    UltraFast,
    VeryFast,
    Fast,
    Basic,
    Slow,
}

impl Quality {
    pub const ALL: [Quality; 5] = [Quality::UltraFast, Quality::VeryFast, Quality::Fast, Quality::Basic, Quality::Slow];

    pub fn name(self) -> &'static str {
        match self {
            Quality::UltraFast => "ultra-fast",
            Quality::VeryFast => "very-fast",
            Quality::Fast => "fast",
            Quality::Basic => "basic",
            Quality::Slow => "slow",
        }
    }

    pub fn parse(s: &str) -> Option<Quality> {
        Quality::ALL.into_iter().find(|q| q.name() == s)
    }
}

mod bc;
mod choose;
pub use choose::{cheapest, cheapest_all, decode_one, single_plane, within, Choice};

/// A plane and the channels in its slots, in lane order (`channel_slots` of
/// them at most; a BC7 plane of 3 channels leaves its fourth slot empty).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlaneSpec {
    pub plane: Plane,
    pub channels: Vec<usize>,
}

/// The planes of a group of channels stored in `format`: chunks of up to
/// four channels in order, a chunk of three split into two and one (no lane
/// to spare). Uncompressed formats put a chunk in one texture (R, RG, RGBA);
/// BC4 takes one plane per channel; BC7 one plane per chunk, each channel
/// with `4 / channels` consecutive z-slices in its lanes (one channel: four
/// z-slices, as single-channel assets; two: two slices each; four: one
/// voxel's channels, the classic channel packing).
pub fn group_planes(format: Format, channels: &[usize]) -> Vec<PlaneSpec> {
    if format == Format::Bc4 {
        return channels.iter().map(|&c| PlaneSpec { plane: Plane { format, lanes: 1, z_per_texel: 1 }, channels: vec![c] }).collect();
    }
    channels
        .chunks(4)
        .flat_map(|k| if k.len() == 3 { vec![&k[..2], &k[2..]] } else { vec![k] })
        .map(|k| {
            let plane = match format {
                Format::Bc7 => Plane { format, lanes: 4, z_per_texel: 4 / k.len() as u32 },
                _ => Plane::uncompressed(format, k.len() as u32),
            };
            PlaneSpec { plane, channels: k.to_vec() }
        })
        .collect()
}

/// The smallest and largest of a brick's finite values (NaN and ±∞ left
/// out, so that the ranged formats keep their precision and decode to finite
/// values); for a brick without any finite value, `[m, m]` with m = `f32::MAX`
/// if it holds +∞, else `-f32::MAX` if it holds −∞, else 0 (all NaN).
pub fn range_of(values: &Brick) -> [f32; 2] {
    // Eight independent lanes, so the compiler can vectorise.
    let mut lo = [f32::INFINITY; 8];
    let mut hi = [f32::NEG_INFINITY; 8];
    for c in values.chunks_exact(8) {
        for k in 0..8 {
            let finite = c[k].is_finite();
            lo[k] = lo[k].min(if finite { c[k] } else { f32::INFINITY });
            hi[k] = hi[k].max(if finite { c[k] } else { f32::NEG_INFINITY });
        }
    }
    let (lo, hi) = (lo.iter().copied().fold(f32::INFINITY, f32::min), hi.iter().copied().fold(f32::NEG_INFINITY, f32::max));
    if lo <= hi {
        return [lo, hi];
    }
    let m = if values.contains(&f32::INFINITY) {
        f32::MAX
    } else if values.contains(&f32::NEG_INFINITY) {
        -f32::MAX
    } else {
        0.0
    };
    [m, m]
}

/// A brick whose NaN and ±∞ voxels are replaced as the ranged formats store
/// them: like inactive voxels, each takes the mean of its finite 6-neighbours
/// (in the order −x, +x, −y, +y, −z, +z), front by front outwards from the
/// finite voxels, so it lies within their range and a block encoder fits
/// nothing through it.  `None` when every voxel is finite (the common case)
/// or none is.
pub fn fill_non_finite(values: &Brick) -> Option<Brick> {
    if values.iter().fold(true, |all, v| all & v.is_finite()) {
        return None;
    }
    let mut known = [0u64; 8];
    for (i, v) in values.iter().enumerate() {
        known[i >> 6] |= u64::from(v.is_finite()) << (i & 63);
    }
    if known == [0; 8] {
        return None;
    }
    let mut out = *values;
    // Fronts reach every voxel of a brick (at most 21 steps apart).
    vdbcook_grid::fill_from_neighbours(&mut out, known, BRICK_VOXELS);
    Some(out)
}

/// A brick's values as levels in [0, top] over its own range (not rounded);
/// non-finite voxels as [`fill_non_finite`] replaces them.
fn levels(values: &Brick, [lo, hi]: [f32; 2], top: f32) -> Brick {
    let filled = fill_non_finite(values);
    let values = filled.as_ref().unwrap_or(values);
    let span = hi - lo;
    let mut out = [0.0f32; BRICK_VOXELS];
    if span > 0.0 && span.is_finite() {
        let scale = top / span;
        for (o, &v) in out.iter_mut().zip(values) {
            *o = ((v - lo) * scale).clamp(0.0, top);
        }
    }
    out
}

/// 8-bit levels of a brick over its own range.
fn quantise(values: &Brick, range: [f32; 2]) -> [u8; BRICK_VOXELS] {
    levels(values, range, 255.0).map(|l| l.round() as u8)
}

/// 16-bit levels of a brick over its own range.
fn quantise16(values: &Brick, range: [f32; 2]) -> [u16; BRICK_VOXELS] {
    levels(values, range, 65535.0).map(|l| l.round() as u16)
}

/// BC7 texels of bricks (per brick, its channels' 8-bit levels in slot
/// order): lane `l` of texel (x, y, t) holds slot `l / zpt` at
/// z = `t · zpt + l % zpt` (`vdbcook_vpak::Plane::locate`); empty slots are 0.
fn bc7_texels(bricks: &[Vec<[u8; BRICK_VOXELS]>], zpt: usize) -> Vec<[u8; 4]> {
    let slices = 8 / zpt;
    let mut out = vec![[0u8; 4]; bricks.len() * slices * 64];
    for (k, slots) in bricks.iter().enumerate() {
        for t in 0..slices {
            for y in 0..8 {
                for x in 0..8 {
                    let px = &mut out[(k * slices + t) * 64 + y * 8 + x];
                    for (l, v) in px.iter_mut().enumerate() {
                        if let Some(lv) = slots.get(l / zpt) {
                            *v = lv[x * 64 + y * 8 + t * zpt + l % zpt];
                        }
                    }
                }
            }
        }
    }
    out
}

/// Swaps the x and z axes of a brick: leaf order (`x·64 + y·8 + z`) to texel
/// order (`z·64 + y·8 + x`) and back.
fn swap_xz<T: Copy>(a: &[T; BRICK_VOXELS]) -> [T; BRICK_VOXELS] {
    std::array::from_fn(|i| a[(i & 7) << 6 | (i & 0o70) | i >> 6])
}

/// One uncompressed brick of a plane: its channels' values lane by lane, in
/// texel order, little-endian.
fn encode_texels(plane: &Plane, slots: &[(&Brick, [f32; 2])], out: &mut [u8]) {
    let lanes = plane.lanes as usize;
    let lb = plane.format.lane_bytes();
    for (l, (values, range)) in slots.iter().enumerate().take(lanes) {
        let put = |out: &mut [u8], t: usize, b: &[u8]| {
            let at = (t * lanes + l) * lb;
            out[at..at + lb].copy_from_slice(b);
        };
        match plane.format {
            Format::F32 => {
                for (t, v) in swap_xz(values).iter().enumerate() {
                    put(out, t, &v.to_le_bytes());
                }
            }
            Format::F16 => {
                let mut h = [half::f16::ZERO; BRICK_VOXELS];
                h.convert_from_f32_slice(&swap_xz(values));
                for (t, v) in h.iter().enumerate() {
                    put(out, t, &v.to_le_bytes());
                }
            }
            Format::Unorm16 => {
                for (t, q) in swap_xz(&quantise16(values, *range)).iter().enumerate() {
                    put(out, t, &q.to_le_bytes());
                }
            }
            Format::Unorm8 => {
                for (t, q) in swap_xz(&quantise(values, *range)).iter().enumerate() {
                    put(out, t, &[*q]);
                }
            }
            // No texels; block formats are encoded elsewhere.
            Format::Constant | Format::Bc4 | Format::Bc7 => {}
        }
    }
}

/// The encoded bricks of one plane: kept (block formats, whose encoders are
/// slow), made from the pool whenever asked for (uncompressed formats, so
/// no copy of the pool is kept), or, with per-brick formats, kept for the
/// bricks that chose the plane's format (`at[i]`: brick i's place among
/// them, or `u32::MAX`).
enum PlaneData {
    Kept(Vec<u8>),
    OnDemand,
    Chosen { bytes: Vec<u8>, at: Vec<u32> },
}

/// Every plane of every brick of a pool (`channels` [`Brick`]s per brick),
/// with each brick's channel ranges.
pub struct Encoded<'a> {
    pub specs: Vec<PlaneSpec>,
    bricks: &'a [Brick],
    channels: usize,
    /// (min, max) per brick per channel.
    ranges: Vec<[f32; 2]>,
    planes: Vec<PlaneData>,
}

/// Bricks per parallel work item of the block encoders.
const CHUNK: usize = 256;

impl<'a> Encoded<'a> {
    /// Encodes the block planes now, in parallel (`progress(n)` after each
    /// chunk of `n` bricks of a plane); uncompressed planes are made when
    /// asked for.  `masks` (512 bits per brick) says which voxels count for
    /// the encoders that can use it (BC4): readers take the others from the
    /// background.
    pub fn new(specs: Vec<PlaneSpec>, quality: Quality, bricks: &'a [Brick], channels: usize, masks: Option<&[[u64; 8]]>, progress: &(dyn Fn(usize) + Sync)) -> Encoded<'a> {
        let channels = channels.max(1);
        let ranges: Vec<[f32; 2]> = bricks.par_iter().map(range_of).collect();
        let n = bricks.len() / channels;
        let mut planes = Vec::with_capacity(specs.len());
        for spec in &specs {
            if !spec.plane.format.is_block() {
                progress(n);
                planes.push(PlaneData::OnDemand);
                continue;
            }
            let bb = spec.plane.brick_bytes();
            let mut data = vec![0u8; n * bb];
            vdbcook_grid::mem::advise_huge_pages(&data);
            data.par_chunks_mut(CHUNK * bb).enumerate().for_each(|(k, out)| {
                let first = k * CHUNK;
                let count = out.len() / bb;
                let slot = |b: usize, c: usize| (&bricks[b * channels + c], ranges[b * channels + c]);
                match spec.plane.format {
                    Format::Bc4 => {
                        let c = spec.channels[0];
                        let lv: Vec<Brick> = (first..first + count).map(|b| levels(slot(b, c).0, slot(b, c).1, 255.0)).collect();
                        bc::encode_bc4(quality, &lv, masks.and_then(|m| m.get(first..first + count)), out);
                    }
                    _ => {
                        let lv: Vec<Vec<[u8; BRICK_VOXELS]>> = (first..first + count).map(|b| spec.channels.iter().map(|&c| quantise(slot(b, c).0, slot(b, c).1)).collect()).collect();
                        let zpt = spec.plane.z_per_texel as usize;
                        bc::encode_bc7(quality, 8 / zpt, &bc7_texels(&lv, zpt), out);
                    }
                }
                progress(count);
            });
            planes.push(PlaneData::Kept(data));
        }
        Encoded { specs, bricks, channels, ranges, planes }
    }

    /// Bricks.
    pub fn len(&self) -> usize {
        self.bricks.len() / self.channels
    }

    pub fn is_empty(&self) -> bool {
        self.bricks.is_empty()
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Brick `i`'s range in channel `c`.
    pub fn range(&self, i: usize, c: usize) -> [f32; 2] {
        self.ranges.get(i * self.channels + c).copied().unwrap_or_default()
    }

    /// Writes brick `i`'s encoding in plane `p` (`brick_bytes` bytes, in the
    /// order `vdbcook_vpak::layout::brick_runs` describes) to `out`; false
    /// past the end.
    pub fn write(&self, p: usize, i: usize, out: &mut [u8]) -> bool {
        let (Some(spec), Some(data)) = (self.specs.get(p), self.planes.get(p)) else { return false };
        let bb = spec.plane.brick_bytes();
        if i >= self.len() || out.len() != bb {
            return false;
        }
        match data {
            PlaneData::Kept(d) => out.copy_from_slice(&d[i * bb..(i + 1) * bb]),
            PlaneData::Chosen { bytes, at } => match at[i] {
                u32::MAX => return false,
                k => out.copy_from_slice(&bytes[k as usize * bb..(k as usize + 1) * bb]),
            },
            PlaneData::OnDemand => {
                let slots: Vec<(&Brick, [f32; 2])> = spec.channels.iter().map(|&c| (&self.bricks[i * self.channels + c], self.range(i, c))).collect();
                encode_texels(&spec.plane, &slots, out);
            }
        }
        true
    }

    /// True when plane `p` stores brick `i` (with per-brick formats, the
    /// planes of the formats it did not choose do not).
    pub fn holds(&self, p: usize, i: usize) -> bool {
        match self.planes.get(p) {
            Some(PlaneData::Chosen { at, .. }) => at.get(i).is_some_and(|&k| k != u32::MAX),
            Some(_) => i < self.len(),
            None => false,
        }
    }

    /// Brick `i` decoded back to values, one [`Brick`] per channel.
    pub fn decode(&self, i: usize) -> Option<Vec<Brick>> {
        let mut out = vec![[0.0f32; BRICK_VOXELS]; self.channels];
        let mut buf = vec![0u8; MAX_BRICK_BYTES];
        for (p, spec) in self.specs.iter().enumerate() {
            if !self.holds(p, i) {
                continue;
            }
            let data = &mut buf[..spec.plane.brick_bytes()];
            if !self.write(p, i, data) {
                return None;
            }
            let texels = spec.plane.decode_brick(data);
            for (slot, &c) in spec.channels.iter().enumerate() {
                out[c] = spec.plane.channel_values(&texels, slot as u32 * spec.plane.z_per_texel, self.range(i, c));
            }
        }
        Some(out)
    }

    /// Plane `p` of the bricks `keep[0]`, `keep[1]`, …, renumbered from 0, for `vdbcook_vpak::layout::pack_atlas`.
    pub fn plane<'s>(&'s self, p: usize, keep: &'s [usize]) -> PlaneBricks<'s> {
        PlaneBricks { encoded: self, plane: p, keep }
    }
}

impl<'a> Encoded<'a> {
    /// Per-brick formats: `choices[i · channels + c]` is channel c of brick
    /// i ([`cheapest`]); each channel is stored in one plane of its own per
    /// format its bricks chose, in [`Format::BY_COST`] order.  Bricks not
    /// `used` are in no plane.
    pub fn from_choices(bricks: &'a [Brick], channels: usize, mut choices: Vec<Choice>, used: &[bool]) -> Encoded<'a> {
        let channels = channels.max(1);
        let n = bricks.len() / channels;
        let ranges = choices.iter().map(|ch| ch.range).collect();
        let (mut specs, mut planes) = (Vec::new(), Vec::new());
        for c in 0..channels {
            for format in Format::BY_COST {
                let members: Vec<usize> = (0..n).filter(|&i| used.get(i).copied().unwrap_or(true) && choices[i * channels + c].format == format).collect();
                if members.is_empty() {
                    continue;
                }
                let mut at = vec![u32::MAX; n];
                let mut bytes = Vec::with_capacity(members.len() * single_plane(format).brick_bytes());
                for (k, &i) in members.iter().enumerate() {
                    at[i] = k as u32;
                    bytes.extend_from_slice(&std::mem::take(&mut choices[i * channels + c].bytes));
                }
                specs.push(PlaneSpec { plane: single_plane(format), channels: vec![c] });
                planes.push(PlaneData::Chosen { bytes, at });
            }
        }
        Encoded { specs, bricks, channels, ranges, planes }
    }
}

/// One plane of a subset of an [`Encoded`] pool.
pub struct PlaneBricks<'s> {
    encoded: &'s Encoded<'s>,
    plane: usize,
    keep: &'s [usize],
}

impl BrickSource for PlaneBricks<'_> {
    fn write_brick(&self, i: usize, out: &mut [u8]) -> bool {
        self.keep.get(i).is_some_and(|&k| self.encoded.write(self.plane, k, out))
    }
}

/// Single-channel bricks encoded in `format`, back to back (tests and tools).
pub fn encode_bricks(format: Format, quality: Quality, bricks: &[Brick]) -> Vec<u8> {
    let e = Encoded::new(group_planes(format, &[0]), quality, bricks, 1, None, &|_| {});
    let n = e.specs[0].plane.brick_bytes();
    let mut out = vec![0u8; n * bricks.len()];
    for (i, o) in out.chunks_exact_mut(n).enumerate() {
        e.write(0, i, o);
    }
    out
}

/// Encodes one single-channel brick in `format` and decodes it back (tests and tools).
pub fn round_trip(format: Format, quality: Quality, values: &Brick) -> Brick {
    let e = Encoded::new(group_planes(format, &[0]), quality, std::slice::from_ref(values), 1, None, &|_| {});
    e.decode(0).map_or([0.0; BRICK_VOXELS], |d| d[0])
}

/// Counts of non-finite values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct NonFinite {
    pub nan: u64,
    pub pos_inf: u64,
    pub neg_inf: u64,
}

impl NonFinite {
    /// Counts `v` if it is NaN or ±∞.
    pub fn tally(&mut self, v: f32) {
        if v.is_nan() {
            self.nan += 1;
        } else if v == f32::INFINITY {
            self.pos_inf += 1;
        } else if v == f32::NEG_INFINITY {
            self.neg_inf += 1;
        }
    }
    pub fn total(&self) -> u64 {
        self.nan + self.pos_inf + self.neg_inf
    }
    pub fn merge(&mut self, o: &NonFinite) {
        self.nan += o.nan;
        self.pos_inf += o.pos_inf;
        self.neg_inf += o.neg_inf;
    }
}

/// Voxel-domain error figures (RMSE, PSNR with the given peak, max abs
/// error) over the voxels whose reference value is finite: a NaN or ±∞
/// reference has no error to measure (and one would make every figure NaN),
/// so it is only counted, in `non_finite`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ErrorStats {
    /// Voxels measured (finite reference values).
    pub count: u64,
    pub sum_sq: f64,
    pub max_abs: f64,
    /// Voxels left out: their reference value is NaN or ±∞.
    pub non_finite: NonFinite,
}

impl ErrorStats {
    pub fn add(&mut self, reference: f32, value: f32) {
        if !reference.is_finite() {
            self.non_finite.tally(reference);
            return;
        }
        let d = f64::from(value) - f64::from(reference);
        self.count += 1;
        self.sum_sq += d * d;
        self.max_abs = self.max_abs.max(d.abs());
    }
    /// Adds the voxels of `mask` (512 bits) of a reference brick and its decoding.
    pub fn add_masked(&mut self, reference: &[f32; BRICK_VOXELS], value: &[f32; BRICK_VOXELS], mask: &[u64; 8]) {
        if mask.iter().all(|&w| w == u64::MAX) {
            // Every voxel: eight fixed lanes the compiler can vectorise.
            let (mut sq, mut mx, mut finite) = ([0.0f64; 8], [0.0f64; 8], [0u64; 8]);
            for (r, v) in reference.chunks_exact(8).zip(value.chunks_exact(8)) {
                for k in 0..8 {
                    let ok = r[k].is_finite();
                    let d = if ok { f64::from(v[k]) - f64::from(r[k]) } else { 0.0 };
                    sq[k] += d * d;
                    mx[k] = mx[k].max(d.abs());
                    finite[k] += u64::from(ok);
                }
            }
            let n: u64 = finite.iter().sum();
            self.count += n;
            self.sum_sq += sq.iter().sum::<f64>();
            self.max_abs = mx.iter().copied().fold(self.max_abs, f64::max);
            if n < BRICK_VOXELS as u64 {
                for &r in reference {
                    self.non_finite.tally(r);
                }
            }
            return;
        }
        for (w, &word) in mask.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let i = w * 64 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                self.add(reference[i], value[i]);
            }
        }
    }

    pub fn merge(&mut self, o: &ErrorStats) {
        self.count += o.count;
        self.sum_sq += o.sum_sq;
        self.max_abs = self.max_abs.max(o.max_abs);
        self.non_finite.merge(&o.non_finite);
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
            let keep: Vec<usize> = (0..count).collect();
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
            let choice = cheapest(&brick, &mask, e, Quality::VeryFast);
            seen.insert(choice.format);
            let encoded = Encoded::from_choices(std::slice::from_ref(&brick), 1, vec![choice.clone()], &[true]);
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
}
