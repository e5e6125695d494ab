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

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Format {
    F32,
    F16,
    Unorm8,
    /// BC4: one channel, 8 bytes per 4×4 block, 4 bits per voxel.
    Bc4,
    /// BC7 with four consecutive z-slices in RGBA: 16 bytes per 4×4×4 voxels, 2 bits per voxel.
    Bc7,
}

impl Format {
    pub const ALL: [Format; 5] = [Format::F32, Format::F16, Format::Unorm8, Format::Bc4, Format::Bc7];

    pub fn name(self) -> &'static str {
        match self {
            Format::F32 => "f32",
            Format::F16 => "f16",
            Format::Unorm8 => "unorm8",
            Format::Bc4 => "bc4",
            Format::Bc7 => "bc7",
        }
    }

    pub fn parse(s: &str) -> Option<Format> {
        Format::ALL.into_iter().find(|f| f.name() == s)
    }

    /// Bytes per texel for the uncompressed formats.
    pub fn bytes_per_voxel(self) -> usize {
        match self {
            Format::F32 => 4,
            Format::F16 => 2,
            Format::Unorm8 | Format::Bc4 | Format::Bc7 => 1,
        }
    }

    /// True for the block-compressed formats.
    pub fn is_block(self) -> bool {
        matches!(self, Format::Bc4 | Format::Bc7)
    }

    /// Texture slices one brick takes (BC7 packs four z-slices into RGBA).
    pub fn slices_per_brick(self) -> u32 {
        if self == Format::Bc7 {
            2
        } else {
            8
        }
    }

    /// Stored bytes per brick.
    pub fn brick_bytes(self) -> usize {
        match self {
            Format::Bc4 => bc::BC4_BRICK_BYTES,
            Format::Bc7 => bc::BC7_BRICK_BYTES,
            f => BRICK_VOXELS * f.bytes_per_voxel(),
        }
    }

    /// Bytes of one 4×4 block (block formats only).
    pub fn block_bytes(self) -> usize {
        if self == Format::Bc7 {
            16
        } else {
            8
        }
    }
}

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

/// Encoded bricks side by side: brick `i` is `format.brick_bytes()` bytes at
/// `data[i · brick_bytes ..]`, with range `ranges[i]`.  Inside a brick,
/// uncompressed formats hold their texels in atlas order (x fastest, then y,
/// then z: each 8-texel row is one copy into the atlas); block formats hold
/// their blocks in the order `bc.rs` describes.
#[derive(Clone, Debug, PartialEq)]
pub struct EncodedBricks {
    pub format: Format,
    pub ranges: Vec<[f32; 2]>,
    pub data: Vec<u8>,
}

impl EncodedBricks {
    /// The encoded bytes of brick `i`.
    pub fn brick(&self, i: usize) -> Option<&[u8]> {
        let n = self.format.brick_bytes();
        self.data.get(i.checked_mul(n)?..(i + 1).checked_mul(n)?)
    }
}

/// Where each brick's encoding comes from: computed once and kept
/// ([`EncodedBricks`], for the block formats, whose encoder is slow), or
/// computed from the source brick whenever it is asked for ([`SourceBricks`],
/// for the uncompressed formats, so that no copy of the whole pool is kept).
pub trait Encodings: Sync {
    fn format(&self) -> Format;
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Brick `i`'s range (`None` past the end).
    fn range(&self, i: usize) -> Option<[f32; 2]>;
    /// Writes brick `i`'s encoding (`format().brick_bytes()` bytes, in the
    /// order [`EncodedBricks`] describes) to `out`; false past the end.
    fn write(&self, i: usize, out: &mut [u8]) -> bool;
    /// Brick `i` decoded back to values (index `x·64 + y·8 + z`).
    fn decode(&self, i: usize) -> Option<[f32; BRICK_VOXELS]> {
        let mut buf = [0u8; MAX_BRICK_BYTES];
        let data = buf.get_mut(..self.format().brick_bytes())?;
        self.write(i, data).then(|| decode_brick(self.format(), self.range(i).unwrap_or_default(), data))
    }
}

/// The largest encoded brick (f32).
pub const MAX_BRICK_BYTES: usize = BRICK_VOXELS * 4;

impl Encodings for EncodedBricks {
    fn format(&self) -> Format {
        self.format
    }
    fn len(&self) -> usize {
        self.ranges.len()
    }
    fn range(&self, i: usize) -> Option<[f32; 2]> {
        self.ranges.get(i).copied()
    }
    fn write(&self, i: usize, out: &mut [u8]) -> bool {
        match self.brick(i) {
            Some(b) if b.len() == out.len() => {
                out.copy_from_slice(b);
                true
            }
            _ => false,
        }
    }
}

/// Uncompressed encodings of source bricks, made when asked for.
pub struct SourceBricks<'a> {
    format: Format,
    bricks: &'a [[f32; BRICK_VOXELS]],
    ranges: Vec<[f32; 2]>,
}

impl<'a> SourceBricks<'a> {
    /// `None` for a block format.
    pub fn new(format: Format, bricks: &'a [[f32; BRICK_VOXELS]]) -> Option<SourceBricks<'a>> {
        (!format.is_block()).then(|| SourceBricks { format, bricks, ranges: bricks.par_iter().map(range_of).collect() })
    }
}

impl Encodings for SourceBricks<'_> {
    fn format(&self) -> Format {
        self.format
    }
    fn len(&self) -> usize {
        self.bricks.len()
    }
    fn range(&self, i: usize) -> Option<[f32; 2]> {
        self.ranges.get(i).copied()
    }
    fn write(&self, i: usize, out: &mut [u8]) -> bool {
        match (self.bricks.get(i), self.ranges.get(i)) {
            (Some(b), Some(r)) if out.len() == self.format.brick_bytes() => {
                encode_voxels(self.format, b, *r, out);
                true
            }
            _ => false,
        }
    }
}

/// The bricks `keep[0]`, `keep[1]`, … of `inner`, renumbered from 0.
pub struct Subset<'a> {
    pub inner: &'a dyn Encodings,
    pub keep: &'a [usize],
}

impl Encodings for Subset<'_> {
    fn format(&self) -> Format {
        self.inner.format()
    }
    fn len(&self) -> usize {
        self.keep.len()
    }
    fn range(&self, i: usize) -> Option<[f32; 2]> {
        self.inner.range(*self.keep.get(i)?)
    }
    fn write(&self, i: usize, out: &mut [u8]) -> bool {
        self.keep.get(i).is_some_and(|&k| self.inner.write(k, out))
    }
}

/// The encodings of `bricks` in `format`: block formats are encoded now, in
/// parallel (`progress(n)` after each chunk of `n` bricks); uncompressed
/// formats when asked for.  `masks` (see [`encode_all`]) says which voxels
/// count.
pub fn encodings<'a>(format: Format, quality: Quality, bricks: &'a [[f32; BRICK_VOXELS]], masks: Option<&[[u64; 8]]>, progress: &(dyn Fn(usize) + Sync)) -> Box<dyn Encodings + 'a> {
    match SourceBricks::new(format, bricks) {
        Some(s) => {
            progress(bricks.len());
            Box::new(s)
        }
        None => Box::new(encode_all(format, quality, bricks, masks, progress)),
    }
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

/// Encodes one brick (BC7 at `Quality::Fast`; use [`encode_all`] to choose).
pub fn encode_brick(format: Format, values: &[f32; BRICK_VOXELS]) -> EncodedBricks {
    encode_all(format, Quality::Fast, std::slice::from_ref(values), None, &|_| {})
}

/// A brick's values as levels in [0, 255] over its own range (not rounded).
fn levels(values: &[f32; BRICK_VOXELS], [lo, hi]: [f32; 2]) -> [f32; BRICK_VOXELS] {
    let span = hi - lo;
    let mut out = [0.0f32; BRICK_VOXELS];
    if span > 0.0 && span.is_finite() {
        let scale = 255.0 / span;
        for (o, &v) in out.iter_mut().zip(values) {
            *o = ((v - lo) * scale).clamp(0.0, 255.0);
        }
    }
    out
}

/// 8-bit levels of a brick over its own range.
fn quantise(values: &[f32; BRICK_VOXELS], range: [f32; 2]) -> [u8; BRICK_VOXELS] {
    levels(values, range).map(|l| l.round() as u8)
}

/// Swaps the x and z axes of a brick: leaf order (`x·64 + y·8 + z`) to atlas
/// order (`z·64 + y·8 + x`) and back.
fn swap_xz<T: Copy>(a: &[T; BRICK_VOXELS]) -> [T; BRICK_VOXELS] {
    std::array::from_fn(|i| a[(i & 7) << 6 | (i & 0o70) | i >> 6])
}

/// Encodes `bricks` into `ranges` and `out` (`brick_bytes` each).
fn encode_chunk(format: Format, quality: Quality, bricks: &[[f32; BRICK_VOXELS]], masks: Option<&[[u64; 8]]>, ranges: &mut [[f32; 2]], out: &mut [u8]) {
    for (r, b) in ranges.iter_mut().zip(bricks) {
        *r = range_of(b);
    }
    match format {
        Format::Bc4 => {
            let lv: Vec<[f32; BRICK_VOXELS]> = bricks.iter().zip(ranges.iter()).map(|(b, r)| levels(b, *r)).collect();
            return bc::encode_bc4(quality, &lv, masks, out);
        }
        Format::Bc7 => {
            let lv: Vec<[u8; BRICK_VOXELS]> = bricks.iter().zip(ranges.iter()).map(|(b, r)| quantise(b, *r)).collect();
            return bc::encode_bc7(quality, &lv, out);
        }
        _ => {}
    }
    for ((values, range), o) in bricks.iter().zip(ranges.iter()).zip(out.chunks_exact_mut(format.brick_bytes())) {
        encode_voxels(format, values, *range, o);
    }
}

/// One uncompressed brick, in atlas order, little-endian.
fn encode_voxels(format: Format, values: &[f32; BRICK_VOXELS], range: [f32; 2], out: &mut [u8]) {
    match format {
        Format::F32 => {
            for (o, v) in out.chunks_exact_mut(4).zip(swap_xz(values)) {
                o.copy_from_slice(&v.to_le_bytes());
            }
        }
        Format::F16 => {
            let mut h = [half::f16::ZERO; BRICK_VOXELS];
            h.convert_from_f32_slice(&swap_xz(values));
            for (o, v) in out.chunks_exact_mut(2).zip(h) {
                o.copy_from_slice(&v.to_le_bytes());
            }
        }
        _ => out.copy_from_slice(&swap_xz(&quantise(values, range))),
    }
}

/// Decodes `data` (one brick in `format`, as [`EncodedBricks`] holds it)
/// back to values (index `x·64 + y·8 + z`).
pub fn decode_brick(format: Format, range: [f32; 2], data: &[u8]) -> [f32; BRICK_VOXELS] {
    let mut out = [0.0f32; BRICK_VOXELS];
    let [lo, hi] = range;
    let scaled = |t: f32| if hi > lo { lo + t * (hi - lo) } else { lo };
    match format {
        Format::F32 => {
            for (o, b) in out.iter_mut().zip(data.chunks_exact(4)) {
                *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
        Format::F16 => {
            // Bits first, then one slice conversion (vectorised where the CPU has F16C).
            let mut h = [half::f16::ZERO; BRICK_VOXELS];
            for (o, b) in h.iter_mut().zip(data.chunks_exact(2)) {
                *o = half::f16::from_bits(u16::from_le_bytes([b[0], b[1]]));
            }
            h.convert_to_f32_slice(&mut out);
        }
        Format::Unorm8 => {
            for (o, &q) in out.iter_mut().zip(data) {
                *o = scaled(f32::from(q) / 255.0);
            }
        }
        Format::Bc4 | Format::Bc7 => return bc::decode(format, data).map(scaled),
    }
    swap_xz(&out)
}

/// Bricks per parallel work item of [`encode_all`].
const CHUNK: usize = 256;

/// Encodes every brick in parallel chunks (the output order is the input
/// order); `progress(n)` is called after each chunk of `n` bricks.  With
/// `masks` (512 bits per brick), only the set voxels of a brick count for the
/// encoders that can use it (BC4): readers take the others from the
/// background.
pub fn encode_all(format: Format, quality: Quality, bricks: &[[f32; BRICK_VOXELS]], masks: Option<&[[u64; 8]]>, progress: &(dyn Fn(usize) + Sync)) -> EncodedBricks {
    let n = format.brick_bytes();
    let mut ranges = vec![[0.0f32; 2]; bricks.len()];
    let mut data = vec![0u8; bricks.len() * n];
    vdbcook_grid::mem::advise_huge_pages(&data);
    data.par_chunks_mut(CHUNK * n).zip(ranges.par_chunks_mut(CHUNK)).zip(bricks.par_chunks(CHUNK)).enumerate().for_each(|(c, ((out, r), chunk))| {
        let m = masks.and_then(|m| m.get(c * CHUNK..c * CHUNK + chunk.len()));
        encode_chunk(format, quality, chunk, m, r, out);
        progress(chunk.len());
    });
    EncodedBricks { format, ranges, data }
}

/// Where a run of consecutive bricks lives: one 3D texture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AtlasLayout {
    pub format: Format,
    /// Bricks along x, y, z.
    pub bricks: [u32; 3],
    /// Global index of the first brick in this atlas.
    pub first_brick: u32,
    /// Bricks stored (the last z layer may be partly empty).
    pub count: u32,
}

impl AtlasLayout {
    /// Texture size in texels (a brick is 8×8 texels and 8 slices, or 2 for BC7).
    pub fn texels(&self) -> [u32; 3] {
        let [bx, by, bz] = self.bricks;
        [bx.saturating_mul(8), by.saturating_mul(8), bz.saturating_mul(self.format.slices_per_brick())]
    }

    /// True when the layout is self-consistent: no empty axis, and room for its bricks.
    pub fn is_valid(&self) -> bool {
        let [bx, by, bz] = self.bricks.map(u64::from);
        bx > 0 && by > 0 && bz > 0 && u64::from(self.count) <= bx * by * bz
    }

    /// Brick position (in bricks) of local brick `i`.
    pub fn position(&self, i: u32) -> [u32; 3] {
        let [bx, by, _] = self.bricks;
        [i % bx, (i / bx) % by, i / (bx * by)]
    }

    /// Bytes of one texture slice: texel rows, or rows of 4×4 blocks.
    pub fn slice_bytes(&self) -> usize {
        let [w, h, _] = self.texels().map(|t| t as usize);
        if self.format.is_block() {
            (w / 4).saturating_mul(h / 4).saturating_mul(self.format.block_bytes())
        } else {
            w.saturating_mul(h).saturating_mul(self.format.bytes_per_voxel())
        }
    }

    /// Bytes of one row in a slice (texels, or one row of blocks): wgpu's `bytes_per_row`.
    pub fn row_bytes(&self) -> usize {
        let w = self.texels()[0] as usize;
        if self.format.is_block() {
            (w / 4) * self.format.block_bytes()
        } else {
            w * self.format.bytes_per_voxel()
        }
    }

    pub fn byte_len(&self) -> usize {
        self.slice_bytes().saturating_mul(self.texels()[2] as usize)
    }

    /// Byte offset of uncompressed texel (x, y, z).
    pub fn texel_offset(&self, x: u32, y: u32, z: u32) -> usize {
        let [w, h, _] = self.texels();
        ((z as usize * h as usize + y as usize) * w as usize + x as usize) * self.format.bytes_per_voxel()
    }
}

/// Splits `count` bricks over as few atlases as fit a `max_dim`³ texture limit.
pub fn plan_atlases(format: Format, count: u32, max_dim: u32) -> Vec<AtlasLayout> {
    let per = (max_dim / 8).max(1);
    let per_z = (max_dim / format.slices_per_brick()).max(1);
    let cap = per.saturating_mul(per).saturating_mul(per_z);
    let single = count <= cap;
    let mut out = Vec::new();
    let mut first = 0u32;
    while first < count {
        let n = (count - first).min(cap);
        let bricks = if single {
            tightest_shape(n, per, per_z)
        } else {
            // Samplers place every atlas's bricks with the first one's shape:
            // the last keeps full layers.
            let bx = n.min(per);
            let by = n.div_ceil(bx).min(per);
            [bx, by, n.div_ceil(bx * by)]
        };
        out.push(AtlasLayout { format, bricks, first_brick: first, count: n });
        first += n;
    }
    out
}

/// The shape, at most `per` bricks along x and y and `per_z` along z, that
/// holds `n` bricks with the fewest empty positions (then the fewest layers,
/// then the widest rows).  A texture has no partial rows, so a fixed row
/// width can leave most of a small atlas empty: 268 bricks in rows of 256
/// took 512 positions; 134 × 2 takes 268.  Some shape holds them: a caller
/// gives at most `per² · per_z` bricks.
fn tightest_shape(n: u32, per: u32, per_z: u32) -> [u32; 3] {
    let (n64, per64) = (u64::from(n), u64::from(per));
    let mut best = [n.min(per), 1, 1];
    let mut best_key = (u64::MAX, u64::MAX, u64::MAX);
    let min_bz = n64.div_ceil(per64 * per64).max(1);
    for bz in min_bz..=u64::from(per_z).min(n64.max(1)) {
        for bx in 1..=per64.min(n64.max(1)) {
            let by = n64.div_ceil(bx * bz).max(1);
            if by > per64 {
                continue;
            }
            let key = (bx * by * bz - n64, bz, u64::MAX - bx);
            if key < best_key {
                best_key = key;
                // All three fit in u32: bx, by ≤ per and bz ≤ per_z.
                best = [bx as u32, by as u32, bz as u32];
            }
        }
        if best_key.0 == 0 {
            break; // no later layer count can beat an exact fit with fewer layers
        }
    }
    best
}

/// How a brick's encoding is cut into runs that are contiguous both in it
/// and in an atlas: per slice of the brick, `rows` × `per_row` runs of `run`
/// bytes (8 × 1 rows of 8 texels, or 2 × 2 blocks), run `(slice, r, c)` at
/// `((slice · rows + r) · per_row + c) · run` in the encoding.  Returns
/// (run, rows, per_row).
fn brick_runs(format: Format) -> (usize, usize, usize) {
    if format.is_block() {
        (format.block_bytes(), 2, 2)
    } else {
        (8 * format.bytes_per_voxel(), 8, 1)
    }
}

/// Lays the bricks of one atlas out as texture bytes (global brick
/// `layout.first_brick + i` of `bricks` at local position `i`), in parallel
/// over rows of bricks; each brick's encoding is made or fetched once.
pub fn pack_atlas(layout: &AtlasLayout, bricks: &dyn Encodings) -> Vec<u8> {
    let mut out = vec![0u8; layout.byte_len()];
    vdbcook_grid::mem::advise_huge_pages(&out);
    let format = layout.format;
    if format != bricks.format() || !layout.is_valid() {
        return out;
    }
    let [bx, by, _] = layout.bricks.map(|b| b as usize);
    let sp = format.slices_per_brick() as usize;
    let row = layout.row_bytes();
    let (run, rows_per_brick, per_row) = brick_runs(format);
    // The atlas as bands (the rows of one slice that one row of bricks
    // covers), grouped by row of bricks: group (layer, py) holds the bands of
    // its `sp` slices, in slice order.
    let mut groups: Vec<Vec<&mut [u8]>> = Vec::new();
    groups.resize_with(out.len() / (rows_per_brick * row * sp).max(1), Vec::new);
    for (k, band) in out.chunks_exact_mut((rows_per_brick * row).max(1)).enumerate() {
        let (slice, py) = (k / by, k % by);
        if let Some(g) = groups.get_mut((slice / sp) * by + py) {
            g.push(band);
        }
    }
    groups.par_iter_mut().enumerate().for_each(|(g, bands)| {
        let mut buf = [0u8; MAX_BRICK_BYTES];
        let data = &mut buf[..format.brick_bytes()];
        for px in 0..bx {
            let local = g * bx + px;
            if local >= layout.count as usize || !bricks.write(layout.first_brick as usize + local, data) {
                break;
            }
            for (ls, band) in bands.iter_mut().enumerate() {
                for r in 0..rows_per_brick {
                    for c in 0..per_row {
                        let src = ((ls * rows_per_brick + r) * per_row + c) * run;
                        let dst = r * row + (px * per_row + c) * run;
                        if let (Some(d), Some(v)) = (band.get_mut(dst..dst + run), data.get(src..src + run)) {
                            d.copy_from_slice(v);
                        }
                    }
                }
            }
        }
    });
    out
}

/// Reads local brick `i` back out of atlas bytes, in [`EncodedBricks`]' brick order.
pub fn unpack_brick(layout: &AtlasLayout, atlas: &[u8], i: u32) -> Option<Vec<u8>> {
    if !layout.is_valid() || i >= layout.count || atlas.len() < layout.byte_len() {
        return None;
    }
    let [px, py, pz] = layout.position(i).map(|p| p as usize);
    let f = layout.format;
    let mut out = vec![0u8; f.brick_bytes()];
    let (sp, row, slice) = (f.slices_per_brick() as usize, layout.row_bytes(), layout.slice_bytes());
    let (run, rows, per_row) = brick_runs(f);
    // Run j of the encoding is (slice ls, row r, column c), as `pack_atlas` lays it.
    for (j, dst) in out.chunks_exact_mut(run).enumerate() {
        let (ls, r, c) = (j / (rows * per_row), (j / per_row) % rows, j % per_row);
        let src = (pz * sp + ls) * slice + (py * rows + r) * row + (px * per_row + c) * run;
        dst.copy_from_slice(atlas.get(src..src + run)?);
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
    /// Adds the voxels of `mask` (512 bits) of a reference brick and its decoding.
    pub fn add_masked(&mut self, reference: &[f32; BRICK_VOXELS], value: &[f32; BRICK_VOXELS], mask: &[u64; 8]) {
        if mask.iter().all(|&w| w == u64::MAX) {
            // Every voxel: eight fixed lanes the compiler can vectorise.
            let (mut sq, mut mx) = ([0.0f64; 8], [0.0f64; 8]);
            for (r, v) in reference.chunks_exact(8).zip(value.chunks_exact(8)) {
                for k in 0..8 {
                    let d = f64::from(v[k]) - f64::from(r[k]);
                    sq[k] += d * d;
                    mx[k] = mx[k].max(d.abs());
                }
            }
            self.count += BRICK_VOXELS as u64;
            self.sum_sq += sq.iter().sum::<f64>();
            self.max_abs = mx.iter().copied().fold(self.max_abs, f64::max);
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
        let d = encode_brick(Format::F16, &b).decode(0).unwrap();
        for (x, y) in b.iter().zip(d.iter()) {
            assert!((x - y).abs() <= x.abs() * 2f32.powi(-11) + 1e-7, "{x} {y}");
        }
    }

    #[test]
    fn unorm8_within_half_a_step_of_the_brick_range() {
        let mut b = smoke(2.0);
        b[0] = 1e-4; // thin smoke must keep its own range
        let e = encode_brick(Format::Unorm8, &b);
        let [lo, hi] = e.ranges[0];
        let d = e.decode(0).unwrap();
        let step = (hi - lo) / 255.0;
        for (x, y) in b.iter().zip(d.iter()) {
            assert!((x - y).abs() <= step * 0.5 + 1e-6, "{x} {y} step {step}");
        }
        let flat = [0.25f32; BRICK_VOXELS];
        assert_eq!(encode_brick(Format::Unorm8, &flat).decode(0).unwrap(), flat);
    }

    #[test]
    fn atlases_respect_the_texture_limit() {
        let p = plan_atlases(Format::F32, 5, 2048);
        assert_eq!(p, vec![AtlasLayout { format: Format::F32, bricks: [5, 1, 1], first_brick: 0, count: 5 }]);
        let p = plan_atlases(Format::F16, 300, 64); // 8 bricks per axis, 512 per atlas
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].bricks, [8, 8, 5]);
        let p = plan_atlases(Format::Unorm8, 1100, 64);
        assert_eq!(p.iter().map(|a| a.count).collect::<Vec<_>>(), vec![512, 512, 76]);
        assert!(p.iter().all(|a| a.texels().iter().all(|&t| t <= 64)));
        // BC7 packs a brick into two slices: four times as many layers fit.
        let p = plan_atlases(Format::Bc7, 1100, 64);
        assert_eq!(p.iter().map(|a| a.count).collect::<Vec<_>>(), vec![1100]);
        assert!(p[0].texels()[2] <= 64 && p[0].texels()[2].is_multiple_of(2));
        assert!(plan_atlases(Format::Bc4, 0, 2048).is_empty());
        // A single atlas takes the shape with the fewest empty positions:
        // 70,000 bricks fit 250 × 140 × 2 exactly (rows of 256 would leave 144
        // empty), and so do the 268 bricks of a short EmberGen sequence (rows of
        // 256 left 244 of 512 empty) and the 3,115 of arnold-usd/smoke.vdb.
        let p = plan_atlases(Format::F16, 70_000, 2048);
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].bricks, [250, 140, 2]);
        assert_eq!(plan_atlases(Format::Bc7, 268, 2048)[0].bricks, [134, 2, 1]);
        assert_eq!(plan_atlases(Format::Bc7, 3115, 2048)[0].bricks, [89, 35, 1]);
        for count in [1u32, 255, 256, 65_537, 115_230, 1_000_000] {
            for a in plan_atlases(Format::Bc7, count, 2048) {
                let [bx, by, bz] = a.bricks;
                assert!(a.is_valid() && a.texels().iter().all(|&t| t <= 2048), "{count}: {a:?}");
                assert!(bx * by * bz - a.count < bx * bz, "{count}: more than a row per layer empty: {a:?}");
            }
        }
    }

    #[test]
    fn a_single_atlas_wastes_no_more_than_full_rows_did() {
        // Against the previous rule (rows as wide as the limit allows, as many
        // rows and layers as needed) on every count up to 600 and a spread of
        // larger ones, under several limits: never more empty positions, never
        // over the limit, and an exact fit whenever the count has one.
        let full_rows = |n: u32, per: u32| {
            let bx = n.min(per);
            let bz = n.div_ceil(bx * per);
            bx * n.div_ceil(bx * bz) * bz
        };
        let counts = (1u32..=600).chain([1009, 3115, 4096, 65_535, 65_537, 70_001, 115_230]);
        for max_dim in [16u32, 64, 2048] {
            for format in [Format::F16, Format::Bc7] {
                let per = max_dim / 8;
                let cap = per * per * (max_dim / format.slices_per_brick());
                for n in counts.clone().filter(|&n| n <= cap) {
                    let p = plan_atlases(format, n, max_dim);
                    assert_eq!(p.len(), 1, "{n} bricks, limit {max_dim}");
                    let [bx, by, bz] = p[0].bricks;
                    assert!(p[0].is_valid() && p[0].texels().iter().all(|&t| t <= max_dim), "{n}: {:?}", p[0]);
                    assert!(bx * by * bz <= full_rows(n, per), "{n}: {:?} wastes more than full rows", p[0]);
                    let exact = (1..=per).any(|x| (1..=per).any(|y| n % (x * y) == 0 && n / (x * y) <= max_dim / format.slices_per_brick()));
                    assert_eq!(bx * by * bz == n, exact, "{n}: {:?}", p[0]);
                }
            }
        }
    }

    #[test]
    fn every_voxel_lands_at_its_brick_coordinate() {
        // Property: for many brick counts and limits, voxel (x, y, z) of
        // every brick (leaf order) is texel (8·px + x, 8·py + y, 8·pz + z) of
        // its atlas, and reading each brick back gives its encoding.
        // (20, 32): one atlas of 4×3×2 bricks (its layers are not full).
        for (count, max_dim) in [(1u32, 2048u32), (7, 16), (20, 32), (37, 32), (130, 40)] {
            let values: Vec<[f32; BRICK_VOXELS]> = (0..count).map(|i| std::array::from_fn(|v| (i * 1000 + v as u32) as f32)).collect();
            let bricks = encode_all(Format::F32, Quality::Fast, &values, None, &|_| {});
            for layout in plan_atlases(Format::F32, count, max_dim) {
                let atlas = pack_atlas(&layout, &bricks);
                for i in 0..layout.count {
                    let g = layout.first_brick + i;
                    let back = unpack_brick(&layout, &atlas, i).unwrap();
                    assert_eq!(back, bricks.brick(g as usize).unwrap());
                    assert_eq!(decode_brick(Format::F32, [0.0; 2], &back), values[g as usize]);
                    let [px, py, pz] = layout.position(i);
                    for v in 0..BRICK_VOXELS as u32 {
                        let (x, y, z) = (v / 64, (v / 8) % 8, v % 8);
                        let o = layout.texel_offset(px * 8 + x, py * 8 + y, pz * 8 + z);
                        assert_eq!(f32::from_le_bytes(atlas[o..o + 4].try_into().unwrap()), (g * 1000 + v) as f32);
                    }
                }
            }
        }
    }

    #[test]
    fn every_format_keeps_voxel_order() {
        // A brick whose voxels differ along each axis by different steps
        // decodes with each voxel in its place, in every format.
        let ramp: [f32; BRICK_VOXELS] = std::array::from_fn(|i| (((i / 64) * 24 + ((i / 8) % 8) * 6 + i % 8 * 2) as f32) / 255.0);
        for format in Format::ALL {
            let e = encode_brick(format, &ramp);
            let d = e.decode(0).unwrap();
            let worst = ramp.iter().zip(d.iter()).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
            assert!(worst <= 12.0 / 255.0, "{format:?}: worst error {worst}");
        }
    }

    #[test]
    fn made_on_demand_kept_and_subset_encodings_agree() {
        // Uncompressed bricks encoded when asked for give the same bytes,
        // ranges and atlases as bricks encoded up front; a subset renumbers.
        let values: Vec<[f32; BRICK_VOXELS]> = (0..70).map(|i| smoke(i as f32)).collect();
        for format in [Format::F32, Format::F16, Format::Unorm8] {
            let kept = encode_all(format, Quality::Fast, &values, None, &|_| {});
            let lazy = SourceBricks::new(format, &values).unwrap();
            let mut buf = vec![0u8; format.brick_bytes()];
            for i in 0..values.len() {
                assert!(lazy.write(i, &mut buf));
                assert_eq!(Some(&buf[..]), kept.brick(i));
                assert_eq!(lazy.range(i), kept.range(i));
            }
            assert!(!lazy.write(values.len(), &mut buf));
            for layout in plan_atlases(format, 70, 32) {
                assert_eq!(pack_atlas(&layout, &lazy), pack_atlas(&layout, &kept), "{format:?}");
            }
            let keep = [3usize, 4, 60];
            let sub = Subset { inner: &lazy, keep: &keep };
            assert_eq!(sub.len(), 3);
            assert_eq!(sub.decode(2), kept.decode(60));
            assert_eq!(sub.range(1), kept.range(4));
            assert!(sub.decode(3).is_none());
        }
        assert!(SourceBricks::new(Format::Bc7, &values).is_none());
    }

    #[test]
    fn every_block_lands_at_its_brick_position() {
        for format in [Format::Bc4, Format::Bc7] {
            for (count, max_dim) in [(1u32, 2048u32), (9, 16), (70, 32)] {
                let data = (0..count as usize).flat_map(|i| (0..format.brick_bytes()).map(move |b| (i * 7 + b) as u8)).collect();
                let bricks = EncodedBricks { format, ranges: vec![[0.0, 1.0]; count as usize], data };
                for layout in plan_atlases(format, count, max_dim) {
                    let atlas = pack_atlas(&layout, &bricks);
                    assert_eq!(atlas.len(), layout.byte_len());
                    for i in 0..layout.count {
                        let g = (layout.first_brick + i) as usize;
                        assert_eq!(unpack_brick(&layout, &atlas, i).unwrap(), bricks.brick(g).unwrap(), "{format:?} brick {g}");
                        // Block (slice 1, row 1, col 0) of the brick, straight from the texture.
                        let [px, py, pz] = layout.position(i).map(|p| p as usize);
                        let sp = format.slices_per_brick() as usize;
                        let o = (pz * sp + 1) * layout.slice_bytes() + (py * 2 + 1) * layout.row_bytes() + (px * 2) * format.block_bytes();
                        let want = 6 * format.block_bytes();
                        assert_eq!(&atlas[o..o + format.block_bytes()], &bricks.brick(g).unwrap()[want..want + format.block_bytes()]);
                    }
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
