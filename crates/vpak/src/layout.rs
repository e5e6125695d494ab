//! Voxel formats, texture planes, atlas shapes and the texel packing of every
//! format: where voxel (x, y, z) of channel c of brick b lives (which texture,
//! texel, lane, block and byte), and how its stored level becomes a value.
//! Specified in `docs/format.md` ("Bricks, planes and atlases").

use serde::{Deserialize, Serialize};

/// Voxels per brick (an 8³ leaf).
pub const BRICK_VOXELS: usize = 512;

/// Voxel formats.  The variant order is the format code (metadata and
/// shaders); the names (manifests, flags) are `f32`, `f16`, `unorm8`, `bc4`,
/// `bc7`, `unorm16` and `constant` (chosen per brick by `cook --max-error`,
/// never for a whole channel).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Format {
    /// 32-bit float texels.
    F32,
    /// IEEE half texels.
    F16,
    /// 8-bit levels over each brick's channel range.
    Unorm8,
    /// BC4: one lane, 8 bytes per 4×4 texels.
    Bc4,
    /// BC7: four lanes (RGBA), 16 bytes per 4×4 texels.
    Bc7,
    /// 16-bit levels over each brick's channel range (the peer of NanoVDB's
    /// Fp16: its error is range / 131070 where f16's grows with the value).
    Unorm16,
    /// No texels: every voxel of the plane brick is its range's minimum.
    #[cfg_attr(feature = "clap", value(skip))]
    Constant,
}

impl Format {
    /// The formats a whole channel may be stored in (every format but `Constant`).
    pub const ALL: [Format; 6] = [Format::F32, Format::F16, Format::Unorm8, Format::Bc4, Format::Bc7, Format::Unorm16];
    /// Every format, in code order.
    pub const CODES: [Format; 7] = [Format::F32, Format::F16, Format::Unorm8, Format::Bc4, Format::Bc7, Format::Unorm16, Format::Constant];
    /// What `cook --max-error` tries for a brick, cheapest first (stored
    /// bytes per voxel: 0, 1/4, 1/2, 1, 2, 2, 4).
    pub const BY_COST: [Format; 7] = [Format::Constant, Format::Bc7, Format::Bc4, Format::Unorm8, Format::Unorm16, Format::F16, Format::F32];

    pub fn code(self) -> u32 {
        self as u32
    }

    pub fn from_code(code: u32) -> Option<Format> {
        Format::CODES.get(code as usize).copied()
    }

    pub fn name(self) -> &'static str {
        match self {
            Format::F32 => "f32",
            Format::F16 => "f16",
            Format::Unorm8 => "unorm8",
            Format::Bc4 => "bc4",
            Format::Bc7 => "bc7",
            Format::Unorm16 => "unorm16",
            Format::Constant => "constant",
        }
    }

    pub fn parse(s: &str) -> Option<Format> {
        Format::CODES.into_iter().find(|f| f.name() == s)
    }

    /// True for the block-compressed formats.
    pub fn is_block(self) -> bool {
        matches!(self, Format::Bc4 | Format::Bc7)
    }

    /// True when texels are levels in [0, 1] over the brick's channel range
    /// (value = min + level · (max − min)); f32 and f16 texels are values.
    pub fn is_ranged(self) -> bool {
        !matches!(self, Format::F32 | Format::F16)
    }

    /// Bytes of one lane of an uncompressed texel (0 for block formats).
    pub fn lane_bytes(self) -> usize {
        match self {
            Format::F32 => 4,
            Format::F16 | Format::Unorm16 => 2,
            Format::Unorm8 => 1,
            Format::Bc4 | Format::Bc7 | Format::Constant => 0,
        }
    }

    /// Bytes of one 4×4 block (block formats; 0 otherwise).
    pub fn block_bytes(self) -> usize {
        match self {
            Format::Bc4 => 8,
            Format::Bc7 => 16,
            _ => 0,
        }
    }

    /// The lane counts a plane of this format may have.
    pub fn allowed_lanes(self) -> &'static [u32] {
        match self {
            Format::Bc4 | Format::Constant => &[1],
            Format::Bc7 => &[4],
            _ => &[1, 2, 4],
        }
    }
}

/// One texture per atlas: a format, its lanes (texel components), and how
/// many consecutive z-slices of a brick share a texel (BC7 packs channels ×
/// z-slices into its four lanes; every other plane has 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Plane {
    pub format: Format,
    /// 1, 2 or 4 (R, RG, RGBA); BC4 has 1, BC7 4.
    pub lanes: u32,
    /// 1, 2 or 4; more than 1 only for BC7 (its lanes hold `lanes / z_per_texel` channels).
    pub z_per_texel: u32,
}

/// The largest brick of any plane: 512 RGBA f32 texels.
pub const MAX_BRICK_BYTES: usize = BRICK_VOXELS * 16;

impl Plane {
    /// A plane with one lane per channel (rounded up to 1, 2 or 4), one z-slice per texel.
    pub fn uncompressed(format: Format, channels: u32) -> Plane {
        let lanes = match channels {
            0 | 1 => 1,
            2 => 2,
            _ => 4,
        };
        Plane { format, lanes, z_per_texel: 1 }
    }

    /// True when the combination is one the format defines.
    pub fn is_valid(&self) -> bool {
        let z_ok = match self.format {
            Format::Bc7 => matches!(self.z_per_texel, 1 | 2 | 4),
            _ => self.z_per_texel == 1,
        };
        z_ok && self.format.allowed_lanes().contains(&self.lanes)
    }

    /// Channels one texel holds (the lanes a channel takes: `z_per_texel` each).
    pub fn channel_slots(&self) -> u32 {
        self.lanes / self.z_per_texel.max(1)
    }

    /// Texture slices one brick takes.
    pub fn slices_per_brick(&self) -> u32 {
        8 / self.z_per_texel.clamp(1, 8)
    }

    /// Bytes of one uncompressed texel (all lanes).
    pub fn texel_bytes(&self) -> usize {
        self.format.lane_bytes() * self.lanes as usize
    }

    /// Stored bytes per brick.
    pub fn brick_bytes(&self) -> usize {
        let slices = self.slices_per_brick() as usize;
        if self.format.is_block() {
            slices * 4 * self.format.block_bytes()
        } else {
            slices * 64 * self.texel_bytes()
        }
    }

    /// Where voxel (x, y, z) of the channel whose first lane is `first_lane`
    /// lives in a brick of this plane: texel (x, y, slice) and lane.
    pub fn locate(&self, [x, y, z]: [u32; 3], first_lane: u32) -> ([u32; 3], u32) {
        let zpt = self.z_per_texel.max(1);
        ([x, y, z / zpt], first_lane + z % zpt)
    }

    /// The brick's texels (`8 · 8 · slices_per_brick`, index `(slice · 8 + y) · 8 + x`),
    /// each as four lanes of stored levels or values (missing lanes 0), from its
    /// encoding (`brick_bytes` bytes in the order [`brick_runs`] gives).  BC4
    /// is decoded in float, BC7 to 8-bit lanes / 255.
    pub fn decode_brick(&self, data: &[u8]) -> Vec<[f32; 4]> {
        let slices = self.slices_per_brick() as usize;
        let mut out = vec![[0.0f32; 4]; slices * 64];
        if self.format.is_block() {
            let bb = self.format.block_bytes();
            for s in 0..slices {
                for br in 0..2 {
                    for bc in 0..2 {
                        let i = ((s * 2 + br) * 2 + bc) * bb;
                        let Some(block) = data.get(i..i + bb) else { continue };
                        let mut texels = [[0.0f32; 4]; 16];
                        if self.format == Format::Bc7 {
                            let mut rgba = [0u8; 64];
                            bcdec_rs::bc7(block, &mut rgba, 16);
                            for (t, px) in texels.iter_mut().enumerate() {
                                *px = std::array::from_fn(|l| f32::from(rgba[t * 4 + l]) / 255.0);
                            }
                        } else {
                            let mut r = [0.0f32; 16];
                            bcdec_rs::bc4_float(block, &mut r, 4, false);
                            for (t, px) in texels.iter_mut().enumerate() {
                                px[0] = r[t];
                            }
                        }
                        for (t, px) in texels.iter().enumerate() {
                            let (x, y) = (bc * 4 + t % 4, br * 4 + t / 4);
                            out[(s * 8 + y) * 8 + x] = *px;
                        }
                    }
                }
            }
            return out;
        }
        let (lanes, lb) = (self.lanes as usize, self.format.lane_bytes());
        for (t, px) in out.iter_mut().enumerate() {
            for (l, v) in px.iter_mut().enumerate().take(lanes) {
                let at = (t * lanes + l) * lb;
                let Some(b) = data.get(at..at + lb) else { continue };
                *v = match self.format {
                    Format::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                    Format::F16 => half::f16::from_bits(u16::from_le_bytes([b[0], b[1]])).to_f32(),
                    Format::Unorm16 => f32::from(u16::from_le_bytes([b[0], b[1]])) / 65535.0,
                    Format::Unorm8 => f32::from(b[0]) / 255.0,
                    // No texels (the value is the range's minimum).
                    _ => 0.0,
                };
            }
        }
        out
    }

    /// One channel's 512 values (leaf order `x·64 + y·8 + z`) from a brick's
    /// decoded texels: its lanes, mapped through `range` for ranged formats.
    pub fn channel_values(&self, texels: &[[f32; 4]], first_lane: u32, [lo, hi]: [f32; 2]) -> [f32; BRICK_VOXELS] {
        let ranged = self.format.is_ranged();
        if self.format == Format::Constant {
            return [lo; BRICK_VOXELS];
        }
        // Each z's slice and lane (which `locate` gives apart from x and y), once per brick.
        let at_z: [(usize, usize); 8] = std::array::from_fn(|z| {
            let ([_, _, s], lane) = self.locate([0, 0, z as u32], first_lane);
            (s as usize, (lane & 3) as usize)
        });
        std::array::from_fn(|i| {
            let (x, y, (s, lane)) = (i / 64, (i / 8) % 8, at_z[i % 8]);
            let t = texels.get((s * 8 + y) * 8 + x).map_or(0.0, |px| px[lane]);
            if ranged {
                from_unit(t, [lo, hi])
            } else {
                t
            }
        })
    }
}

/// A ranged format's stored level `t` (0 to 1) as a value of the brick's
/// range `[lo, hi]` (a range without width: `lo`).
pub fn from_unit(t: f32, [lo, hi]: [f32; 2]) -> f32 {
    if hi > lo {
        lo + t * (hi - lo)
    } else {
        lo
    }
}

/// How a brick's encoding is cut into runs that are contiguous both in it
/// and in an atlas: per slice of the brick, `rows` × `per_row` runs of `run`
/// bytes (8 rows of one run of 8 texels, or 2 × 2 blocks), run `(slice, r, c)` at
/// `((slice · rows + r) · per_row + c) · run` in the encoding.  Returns
/// (run, rows, per_row).
pub fn brick_runs(plane: &Plane) -> (usize, usize, usize) {
    if plane.format.is_block() {
        (plane.format.block_bytes(), 2, 2)
    } else {
        (8 * plane.texel_bytes(), 8, 1)
    }
}

/// Where a run of consecutive bricks lives: one 3D texture per plane.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct AtlasInfo {
    /// Bricks along x, y, z.
    pub bricks: [u32; 3],
    /// Index of the first plane brick in this atlas.
    pub first_brick: u32,
    /// Bricks stored (the last positions may be empty).
    pub count: u32,
}

impl AtlasInfo {
    /// Brick position (in bricks) of local brick `i`.
    pub fn position(&self, i: u32) -> [u32; 3] {
        let [bx, by, _] = self.bricks.map(|b| u64::from(b.max(1)));
        let i = u64::from(i);
        // Each part is at most i, so fits u32.
        [i % bx, (i / bx) % by, i / (bx * by)].map(|p| p as u32)
    }
}

/// A plane as the metadata records it: its texels, the distinct bricks it
/// stores (each plane deduplicates its own: an L3 node's brick reaches them
/// through the plane's brick table), and the atlases those fill.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct PlaneInfo {
    pub plane: Plane,
    /// Plane bricks (at most the asset's bricks; as many when the plane has no table).
    pub bricks: u32,
    /// Consecutive runs of the plane bricks, one 3D texture each (none for `constant`).
    pub atlases: Vec<AtlasInfo>,
}

impl PlaneInfo {
    /// The atlas holding plane brick `pb`, and its local index there.
    pub fn brick_atlas(&self, pb: u32) -> Option<(usize, u32)> {
        let a = self.atlases.iter().position(|a| pb >= a.first_brick && pb - a.first_brick < a.count)?;
        Some((a, pb - self.atlases[a].first_brick))
    }

    /// Range pairs per plane brick: one per channel slot.
    pub fn range_slots(&self) -> u32 {
        self.plane.channel_slots()
    }
}

/// One plane's texture of one atlas.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AtlasLayout {
    pub plane: Plane,
    pub atlas: AtlasInfo,
}

impl AtlasLayout {
    /// Texture size in texels.
    pub fn texels(&self) -> [u32; 3] {
        let [bx, by, bz] = self.atlas.bricks;
        [bx.saturating_mul(8), by.saturating_mul(8), bz.saturating_mul(self.plane.slices_per_brick())]
    }

    /// True when the layout is self-consistent: no empty axis, and room for its bricks.
    pub fn is_valid(&self) -> bool {
        let [bx, by, bz] = self.atlas.bricks.map(u128::from);
        self.plane.is_valid() && bx > 0 && by > 0 && bz > 0 && u128::from(self.atlas.count) <= bx * by * bz
    }

    /// Bytes of one row in a slice (texels, or one row of blocks): wgpu's `bytes_per_row`.
    pub fn row_bytes(&self) -> usize {
        let w = self.texels()[0] as usize;
        if self.plane.format.is_block() {
            (w / 4).saturating_mul(self.plane.format.block_bytes())
        } else {
            w.saturating_mul(self.plane.texel_bytes())
        }
    }

    /// Rows of one slice (texel rows, or rows of blocks).
    pub fn rows(&self) -> usize {
        let h = self.texels()[1] as usize;
        if self.plane.format.is_block() {
            h / 4
        } else {
            h
        }
    }

    /// Bytes of one texture slice.
    pub fn slice_bytes(&self) -> usize {
        self.row_bytes().saturating_mul(self.rows())
    }

    pub fn byte_len(&self) -> usize {
        self.slice_bytes().saturating_mul(self.texels()[2] as usize)
    }

    /// Byte offset of uncompressed texel (x, y, z).
    pub fn texel_offset(&self, x: u32, y: u32, z: u32) -> usize {
        let [w, h, _] = self.texels().map(|t| t as usize);
        ((z as usize * h + y as usize) * w + x as usize) * self.plane.texel_bytes()
    }
}

/// Splits `count` bricks over as few atlases as fit a `max_dim`³ texture
/// limit, for planes of at most `slices` slices per brick.
pub fn plan_atlases(slices: u32, count: u32, max_dim: u32) -> Vec<AtlasInfo> {
    let per = (max_dim / 8).max(1);
    let per_z = (max_dim / slices.max(1)).max(1);
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
        out.push(AtlasInfo { bricks, first_brick: first, count: n });
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

/// Encoded bricks of one plane, by plane brick index.
pub trait BrickSource: Sync {
    /// Writes brick `i`'s encoding (`plane.brick_bytes()` bytes) to `out`; false past the end.
    fn write_brick(&self, i: usize, out: &mut [u8]) -> bool;
}

/// Lays the bricks of one atlas out as texture bytes (plane brick
/// `first_brick + i` of `bricks` at local position `i`), in parallel over
/// rows of bricks; each brick's encoding is fetched once.
pub fn pack_atlas(layout: &AtlasLayout, bricks: &dyn BrickSource) -> Vec<u8> {
    let mut out = vec![0u8; layout.byte_len()];
    pack_atlas_into(layout, bricks, &mut out);
    out
}

/// [`pack_atlas`] into `out` (`layout.byte_len()` zeroed bytes, which the
/// caller allocates: a cook keeps large atlases in a spill file).
pub fn pack_atlas_into(layout: &AtlasLayout, bricks: &dyn BrickSource, out: &mut [u8]) {
    use rayon::prelude::*;
    if !layout.is_valid() || out.len() != layout.byte_len() {
        return;
    }
    let plane = layout.plane;
    let [bx, by, _] = layout.atlas.bricks.map(|b| b as usize);
    let sp = plane.slices_per_brick() as usize;
    let row = layout.row_bytes();
    let (run, rows_per_brick, per_row) = brick_runs(&plane);
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
    let count = layout.atlas.count as usize;
    let first = layout.atlas.first_brick as usize;
    groups.par_iter_mut().enumerate().for_each(|(g, bands)| {
        let mut buf = vec![0u8; plane.brick_bytes()];
        for px in 0..bx {
            let local = g * bx + px;
            if local >= count || !bricks.write_brick(first + local, &mut buf) {
                break;
            }
            for (ls, band) in bands.iter_mut().enumerate() {
                for r in 0..rows_per_brick {
                    for c in 0..per_row {
                        let src = ((ls * rows_per_brick + r) * per_row + c) * run;
                        let dst = r * row + (px * per_row + c) * run;
                        if let (Some(d), Some(v)) = (band.get_mut(dst..dst + run), buf.get(src..src + run)) {
                            d.copy_from_slice(v);
                        }
                    }
                }
            }
        }
    });
}

/// Reads local brick `i` back out of atlas bytes, in the encoding's order.
pub fn unpack_brick(layout: &AtlasLayout, atlas: &[u8], i: u32) -> Option<Vec<u8>> {
    if !layout.is_valid() || i >= layout.atlas.count || atlas.len() < layout.byte_len() {
        return None;
    }
    let [px, py, pz] = layout.atlas.position(i).map(|p| p as usize);
    let plane = layout.plane;
    let mut out = vec![0u8; plane.brick_bytes()];
    let (sp, row, slice) = (plane.slices_per_brick() as usize, layout.row_bytes(), layout.slice_bytes());
    let (run, rows, per_row) = brick_runs(&plane);
    // Run j of the encoding is (slice ls, row r, column c), as `pack_atlas` lays it.
    for (j, dst) in out.chunks_exact_mut(run).enumerate() {
        let (ls, r, c) = (j / (rows * per_row), (j / per_row) % rows, j % per_row);
        let src = (pz * sp + ls) * slice + (py * rows + r) * row + (px * per_row + c) * run;
        dst.copy_from_slice(atlas.get(src..src + run)?);
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Pattern(Plane);
    impl BrickSource for Pattern {
        fn write_brick(&self, i: usize, out: &mut [u8]) -> bool {
            for (b, o) in out.iter_mut().enumerate() {
                *o = (i * 7 + b * 3) as u8;
            }
            out.len() == self.0.brick_bytes()
        }
    }

    #[test]
    fn planes_are_what_the_format_allows() {
        assert!(Plane { format: Format::Bc7, lanes: 4, z_per_texel: 4 }.is_valid());
        assert!(Plane { format: Format::Bc7, lanes: 4, z_per_texel: 2 }.is_valid());
        assert!(!Plane { format: Format::Bc7, lanes: 2, z_per_texel: 1 }.is_valid());
        assert!(!Plane { format: Format::Bc4, lanes: 1, z_per_texel: 2 }.is_valid());
        assert!(!Plane { format: Format::F16, lanes: 3, z_per_texel: 1 }.is_valid());
        assert_eq!(Plane { format: Format::Bc7, lanes: 4, z_per_texel: 4 }.brick_bytes(), 128);
        assert_eq!(Plane { format: Format::Bc7, lanes: 4, z_per_texel: 2 }.brick_bytes(), 256);
        assert_eq!(Plane { format: Format::Bc4, lanes: 1, z_per_texel: 1 }.brick_bytes(), 256);
        assert_eq!(Plane::uncompressed(Format::F16, 3).brick_bytes(), 512 * 8);
        assert_eq!(Plane { format: Format::Unorm16, lanes: 2, z_per_texel: 1 }.brick_bytes(), 512 * 4);
        assert_eq!(Plane { format: Format::Constant, lanes: 1, z_per_texel: 1 }.brick_bytes(), 0);
        assert!(!Plane { format: Format::Constant, lanes: 2, z_per_texel: 1 }.is_valid());
        for code in 0..7 {
            assert_eq!(Format::from_code(code).map(Format::code), Some(code));
        }
        assert_eq!(Format::from_code(7), None);
    }

    #[test]
    fn atlases_respect_the_texture_limit() {
        assert_eq!(plan_atlases(8, 5, 2048), vec![AtlasInfo { bricks: [5, 1, 1], first_brick: 0, count: 5 }]);
        let p = plan_atlases(8, 300, 64); // 8 bricks per axis, 512 per atlas
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].bricks, [8, 8, 5]);
        let p = plan_atlases(8, 1100, 64);
        assert_eq!(p.iter().map(|a| a.count).collect::<Vec<_>>(), vec![512, 512, 76]);
        // Two slices a brick: four times as many layers fit.
        let p = plan_atlases(2, 1100, 64);
        assert_eq!(p.iter().map(|a| a.count).collect::<Vec<_>>(), vec![1100]);
        assert!(plan_atlases(8, 0, 2048).is_empty());
        // Exact fits where they exist (a short EmberGen sequence, arnold smoke).
        assert_eq!(plan_atlases(8, 70_000, 2048)[0].bricks, [250, 140, 2]);
        assert_eq!(plan_atlases(2, 268, 2048)[0].bricks, [134, 2, 1]);
        assert_eq!(plan_atlases(2, 3115, 2048)[0].bricks, [89, 35, 1]);
        for count in [1u32, 255, 256, 65_537, 115_230, 1_000_000] {
            for a in plan_atlases(2, count, 2048) {
                let l = AtlasLayout { plane: Plane { format: Format::Bc7, lanes: 4, z_per_texel: 4 }, atlas: a };
                let [bx, by, bz] = a.bricks;
                assert!(l.is_valid() && l.texels().iter().all(|&t| t <= 2048), "{count}: {a:?}");
                assert!(bx * by * bz - a.count < bx * bz, "{count}: more than a row per layer empty: {a:?}");
            }
        }
    }

    #[test]
    fn a_single_atlas_wastes_no_more_than_full_rows_did() {
        // Against rows as wide as the limit allows, on every count up to 600
        // and a spread of larger ones: never more empty positions, never over
        // the limit, and an exact fit whenever the count has one.
        let full_rows = |n: u32, per: u32| {
            let bx = n.min(per);
            let bz = n.div_ceil(bx * per);
            bx * n.div_ceil(bx * bz) * bz
        };
        let counts = (1u32..=600).chain([1009, 3115, 4096, 65_535, 65_537, 70_001, 115_230]);
        for max_dim in [16u32, 64, 2048] {
            for slices in [8u32, 2] {
                let per = max_dim / 8;
                let cap = per * per * (max_dim / slices);
                for n in counts.clone().filter(|&n| n <= cap) {
                    let p = plan_atlases(slices, n, max_dim);
                    assert_eq!(p.len(), 1, "{n} bricks, limit {max_dim}");
                    let [bx, by, bz] = p[0].bricks;
                    assert!(bx <= per && by <= per && bz * slices <= max_dim, "{n}: {:?}", p[0]);
                    assert!(bx * by * bz <= full_rows(n, per), "{n}: {:?} wastes more than full rows", p[0]);
                    let exact = (1..=per).any(|x| (1..=per).any(|y| n % (x * y) == 0 && n / (x * y) <= max_dim / slices));
                    assert_eq!(bx * by * bz == n, exact, "{n}: {:?}", p[0]);
                }
            }
        }
    }

    #[test]
    fn every_run_lands_at_its_brick_position_in_every_plane() {
        let planes = [
            Plane::uncompressed(Format::F32, 1),
            Plane::uncompressed(Format::F16, 2),
            Plane::uncompressed(Format::Unorm8, 4),
            Plane { format: Format::Bc4, lanes: 1, z_per_texel: 1 },
            Plane { format: Format::Bc7, lanes: 4, z_per_texel: 4 },
            Plane { format: Format::Bc7, lanes: 4, z_per_texel: 2 },
            Plane { format: Format::Bc7, lanes: 4, z_per_texel: 1 },
        ];
        for plane in planes {
            for (count, max_dim) in [(1u32, 2048u32), (9, 16), (70, 32), (130, 40)] {
                let src = Pattern(plane);
                for atlas in plan_atlases(8, count, max_dim) {
                    let layout = AtlasLayout { plane, atlas };
                    let bytes = pack_atlas(&layout, &src);
                    assert_eq!(bytes.len(), layout.byte_len());
                    for i in 0..atlas.count {
                        let g = (atlas.first_brick + i) as usize;
                        let mut want = vec![0u8; plane.brick_bytes()];
                        src.write_brick(g, &mut want);
                        assert_eq!(unpack_brick(&layout, &bytes, i).unwrap(), want, "{plane:?} brick {g}");
                        // The first run of slice 1, straight from the texture.
                        let [px, py, pz] = atlas.position(i).map(|p| p as usize);
                        let (run, rows, per_row) = brick_runs(&plane);
                        let sp = plane.slices_per_brick() as usize;
                        let o = (pz * sp + 1) * layout.slice_bytes() + (py * rows) * layout.row_bytes() + px * per_row * run;
                        let w = rows * per_row * run;
                        assert_eq!(&bytes[o..o + run], &want[w..w + run]);
                    }
                }
            }
        }
    }

    #[test]
    fn uncompressed_texels_decode_lane_by_lane() {
        let plane = Plane::uncompressed(Format::F32, 2);
        let data: Vec<u8> = (0..512 * 2).flat_map(|k| (k as f32).to_le_bytes()).collect();
        let texels = plane.decode_brick(&data);
        // Texel t holds lanes 2t and 2t + 1; voxel (x, y, z) is texel (z·8 + y)·8 + x.
        let c1 = plane.channel_values(&texels, 1, [0.0, 1.0]);
        for (i, &v) in c1.iter().enumerate() {
            let (x, y, z) = (i / 64, (i / 8) % 8, i % 8);
            assert_eq!(v, (((z * 8 + y) * 8 + x) * 2 + 1) as f32);
        }
        let bc7 = Plane { format: Format::Bc7, lanes: 4, z_per_texel: 2 };
        assert_eq!(bc7.locate([3, 4, 5], 2), ([3, 4, 2], 3));
        assert_eq!(Plane { format: Format::Bc7, lanes: 4, z_per_texel: 4 }.locate([0, 0, 7], 0), ([0, 0, 1], 3));
    }
}
