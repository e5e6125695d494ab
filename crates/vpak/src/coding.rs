//! Supercompression (version 8): a body's sections stored zstd-compressed
//! after a filter that lines up what repeats (bytes of equal weight together,
//! differences of neighbouring texels), as KTX2 does for GPU textures. The
//! coding section lists each compressed section with its filter and its
//! restored size and checksum; [`restore`] gives back the exact GPU bytes.

use crate::shown::TileMask;
use crate::{checksum, kind, Error, Format, Metadata, Section};
use rayon::prelude::*;

/// Bytes of one coding record.
pub const RECORD_LEN: usize = 40;
/// Compression scheme 1: a zstd frame.
pub const SCHEME_ZSTD: u32 = 1;
/// Compression scheme 2 (version 11): a `tiles unpredicted` atlas coded
/// with a context model and rANS ([`crate::context`]).
pub const SCHEME_CONTEXT: u32 = 2;
/// Compression scheme 3 (version 14): an L3 array under the `l3 nodes`
/// filter, its sub-masks coded with a context model and rANS
/// ([`crate::masks`]).
pub const SCHEME_MASKS: u32 = 3;
/// Compression scheme 4 (version 15): a `tiles unpredicted` atlas coded as
/// scheme 2 is, leaving out the elements no L3 node shows
/// ([`crate::shown`]), which the decoder takes from the body's restored
/// node arrays and tables.
pub const SCHEME_SHOWN: u32 = 4;
/// A zstd frame decodes to at most this many times its own size (an RLE
/// block of 4 bytes stands for up to 128 KiB): a larger claimed size is a lie.
const MAX_RATIO: u64 = 1 << 15;

/// How an asset's sections are stored on disk: `none`, or `zstd[:LEVEL]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Supercompress {
    #[default]
    None,
    Zstd(i32),
}

impl Supercompress {
    pub const DEFAULT_LEVEL: i32 = 5;
    pub const LEVELS: std::ops::RangeInclusive<i32> = 1..=22;
}

impl std::fmt::Display for Supercompress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Supercompress::None => f.write_str("none"),
            Supercompress::Zstd(l) => write!(f, "zstd:{l}"),
        }
    }
}

impl std::str::FromStr for Supercompress {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("\"{s}\" is not a supercompression (none, zstd or zstd:LEVEL with LEVEL 1 to 22)");
        match s.split_once(':') {
            None if s == "none" => Ok(Supercompress::None),
            None if s == "zstd" => Ok(Supercompress::Zstd(Supercompress::DEFAULT_LEVEL)),
            Some(("zstd", l)) => l.parse().ok().filter(|l| Supercompress::LEVELS.contains(l)).map(Supercompress::Zstd).ok_or_else(bad),
            _ => Err(bad()),
        }
    }
}

/// How a writer stores sections: each as one zstd frame at `level` (after
/// the filter that makes it smallest) and, with `context`, the atlases of
/// level planes (`unorm8`, `unorm16`) context-coded (scheme 2, or 4 over
/// their shown voxels) and the L3 array mask-coded (scheme 3) where that is
/// smaller still: what `--optimize disk` asks for, the smallest file at the
/// cost of some cook time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Schemes {
    pub level: i32,
    pub context: bool,
}

impl Schemes {
    /// The schemes of a setting (`None`: sections stored as they are).
    pub fn of(s: Supercompress, context: bool) -> Option<Schemes> {
        match s {
            Supercompress::None => None,
            Supercompress::Zstd(level) => Some(Schemes { level, context }),
        }
    }
}

/// A manifest writes it as the flag does: "zstd:19".
impl<'de> serde::Deserialize<'de> for Supercompress {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?.parse().map_err(serde::de::Error::custom)
    }
}

/// Recorded as the flag's text; empty when off (as unset settings are).
impl crate::settings::SettingText for Supercompress {
    fn text(&self) -> String {
        match self {
            Supercompress::None => String::new(),
            s => s.to_string(),
        }
    }
}

/// A filter applied before compression (undone after decompression).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    /// The bytes as they are.
    None,
    /// Byte j of every `width`-byte element together, for j = 0, 1, ….
    Shuffle { width: u32 },
    /// Each `width`-byte little-endian element minus the one `stride`
    /// elements before it (wrapping), then shuffled as above.
    Delta { width: u32, stride: u32 },
    /// An atlas of 8×8×8-texel tiles, tile by tile: each tile's divisor,
    /// then its elements divided by it, less their 3D prediction or not ([`Tiles`]).
    Tiles(Tiles),
    /// An L3 array's node records as steps from the record before, by
    /// field and byte weight; its sub-masks as they are (version 12).
    L3Nodes,
}

pub use crate::tiles::Tiles;

impl Filter {
    pub(crate) fn code(self) -> (u32, u32, u32) {
        match self {
            Filter::None => (0, 1, 0),
            Filter::Shuffle { width } => (1, width, 0),
            Filter::Delta { width, stride } => (2, width, stride),
            Filter::Tiles(t) => (if t.predict { 3 } else { 4 }, t.width, t.stride()),
            Filter::L3Nodes => (5, 4, 0),
        }
    }

    fn from_code(filter: u32, width: u32, stride: u32) -> Option<Filter> {
        match (filter, width, stride) {
            (0, 1, 0) => Some(Filter::None),
            (1, 1 | 2 | 4 | 8 | 16, 0) => Some(Filter::Shuffle { width }),
            (2, 1 | 2 | 4, 1..=4096) => Some(Filter::Delta { width, stride }),
            (3 | 4, _, _) => Tiles::from_record(filter == 3, width, stride).map(Filter::Tiles),
            (5, 4, 0) => Some(Filter::L3Nodes),
            _ => None,
        }
    }

    pub fn name(self) -> String {
        match self {
            Filter::None => "none".into(),
            Filter::Shuffle { width } => format!("shuffle {width}"),
            Filter::Delta { width, stride } => format!("delta {width}/{stride}"),
            Filter::Tiles(t) => format!("tiles{} {}/{}x{}", if t.predict { "" } else { " unpredicted" }, t.width, t.x, t.y),
            Filter::L3Nodes => "l3 nodes".into(),
        }
    }

    fn width(self) -> usize {
        self.code().1 as usize
    }

    /// Bytes of the filtered form of `raw` restored bytes, if the filter
    /// applies to that many (a multiple of the width; whole slabs of tiles).
    fn filtered_len(self, raw: usize) -> Option<usize> {
        match self {
            Filter::Tiles(t) => t.filtered_len(raw),
            Filter::L3Nodes => (raw >= 4 && raw.is_multiple_of(4)).then_some(raw),
            _ => raw.is_multiple_of(self.width()).then_some(raw),
        }
    }

    /// The filtered bytes (`raw.len()` as [`Filter::filtered_len`] accepts).
    fn apply(self, raw: &[u8]) -> Vec<u8> {
        match self {
            Filter::Tiles(t) => return t.apply(raw),
            Filter::L3Nodes => return crate::l3_filter::apply(raw),
            _ => {}
        }
        let w = self.width();
        let mut src = raw.to_vec();
        // x[i] − x[i − s] from i = s on, wrapping at the width, whole elements at a time.
        if let Filter::Delta { width, stride } = self {
            let s = (stride as usize).min(raw.len() / w);
            match width {
                1 => src[s..].iter_mut().zip(raw).for_each(|(d, &p)| *d = d.wrapping_sub(p)),
                2 => {
                    let (d, p): (&mut [[u8; 2]], &[[u8; 2]]) = (bytemuck::cast_slice_mut(&mut src), bytemuck::cast_slice(raw));
                    d[s..].iter_mut().zip(p).for_each(|(d, p)| *d = u16::from_le_bytes(*d).wrapping_sub(u16::from_le_bytes(*p)).to_le_bytes());
                }
                _ => {
                    let (d, p): (&mut [[u8; 4]], &[[u8; 4]]) = (bytemuck::cast_slice_mut(&mut src), bytemuck::cast_slice(raw));
                    d[s..].iter_mut().zip(p).for_each(|(d, p)| *d = u32::from_le_bytes(*d).wrapping_sub(u32::from_le_bytes(*p)).to_le_bytes());
                }
            }
        }
        if w == 1 {
            return src;
        }
        // Byte j of element i to plane j: out[j·n + i].
        let n = raw.len() / w;
        let mut out = vec![0u8; raw.len()];
        match w {
            2 => {
                let (a, b) = out.split_at_mut(n);
                for ((a, b), e) in a.iter_mut().zip(b).zip(src.chunks_exact(2)) {
                    (*a, *b) = (e[0], e[1]);
                }
            }
            4 => {
                let (a, rest) = out.split_at_mut(n);
                let (b, rest) = rest.split_at_mut(n);
                let (c, d) = rest.split_at_mut(n);
                for ((((a, b), c), d), e) in a.iter_mut().zip(b).zip(c).zip(d).zip(src.chunks_exact(4)) {
                    (*a, *b, *c, *d) = (e[0], e[1], e[2], e[3]);
                }
            }
            _ => {
                for (i, e) in src.chunks_exact(w).enumerate() {
                    for (j, &b) in e.iter().enumerate() {
                        out[j * n + i] = b;
                    }
                }
            }
        }
        out
    }

    /// Undoes [`Filter::apply`] on `data` into `out` (`data` the filtered
    /// length of `out`); refused where the filtered bytes contradict themselves.
    fn undo(self, data: &[u8], out: &mut [u8]) -> Result<(), String> {
        let w = self.width();
        let n = data.len() / w;
        match self {
            Filter::None => out.copy_from_slice(data),
            Filter::Tiles(t) => t.undo(data, out),
            Filter::L3Nodes => crate::l3_filter::undo(data, out)?,
            Filter::Shuffle { .. } => unshuffle(data, out, w),
            Filter::Delta { width, stride } => {
                unshuffle(data, out, w);
                // x[i] = d[i] + x[i − s], in increasing i, wrapping at the width.
                let s = stride as usize;
                match width {
                    1 => (s..n).for_each(|i| out[i] = out[i].wrapping_add(out[i - s])),
                    2 => {
                        let o: &mut [[u8; 2]] = bytemuck::cast_slice_mut(out);
                        (s..n).for_each(|i| o[i] = u16::from_le_bytes(o[i]).wrapping_add(u16::from_le_bytes(o[i - s])).to_le_bytes());
                    }
                    _ => {
                        let o: &mut [[u8; 4]] = bytemuck::cast_slice_mut(out);
                        (s..n).for_each(|i| o[i] = u32::from_le_bytes(o[i]).wrapping_add(u32::from_le_bytes(o[i - s])).to_le_bytes());
                    }
                }
            }
        }
        Ok(())
    }
}

/// Element i of `out` from byte j of every element's plane `data[j·n ..]`:
/// the planes read in step (two and four of them zipped, which compiles to
/// vector shuffles), not a strided gather per byte.
fn unshuffle(data: &[u8], out: &mut [u8], w: usize) {
    let n = data.len() / w;
    match w {
        1 => out.copy_from_slice(data),
        // Whole elements assembled in registers (little-endian), which compiles to byte interleaves.
        2 => {
            let (a, b) = data.split_at(n);
            for ((o, &x), &y) in out.chunks_exact_mut(2).zip(a).zip(b) {
                o.copy_from_slice(&(u16::from(x) | u16::from(y) << 8).to_le_bytes());
            }
        }
        4 => {
            let (a, rest) = data.split_at(n);
            let (b, rest) = rest.split_at(n);
            let (c, d) = rest.split_at(n);
            for ((((o, &x), &y), &z), &t) in out.chunks_exact_mut(4).zip(a).zip(b).zip(c).zip(d) {
                o.copy_from_slice(&u32::from_le_bytes([x, y, z, t]).to_le_bytes());
            }
        }
        _ => {
            // BC blocks (8 or 16 planes): a block of elements at a time, each
            // plane's bytes of it written at their stride into output that
            // stays in the L1 cache, rather than every plane over the whole
            // output (w passes of write traffic over memory).
            const BLOCK: usize = 256;
            for (b, block) in out.chunks_mut(BLOCK * w).enumerate() {
                let first = b * BLOCK;
                for j in 0..w {
                    let plane = &data[j * n + first..j * n + first + block.len() / w];
                    for (o, &x) in block[j..].iter_mut().step_by(w).zip(plane) {
                        *o = x;
                    }
                }
            }
        }
    }
}

/// One record of the coding section: how section (`kind`, `index`) is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Coding {
    pub kind: u32,
    pub index: u32,
    pub scheme: u32,
    pub filter: Filter,
    /// Bytes and XXH3-64 of the restored section.
    pub raw_size: u64,
    pub raw_checksum: u64,
}

impl Coding {
    /// The scheme's name, as `inspect` shows it.
    pub fn scheme_name(&self) -> &'static str {
        match self.scheme {
            SCHEME_CONTEXT => "context",
            SCHEME_MASKS => "masks",
            SCHEME_SHOWN => "context, shown",
            _ => "zstd",
        }
    }

    pub(crate) fn bytes(&self) -> [u8; RECORD_LEN] {
        let (f, w, s) = self.filter.code();
        let mut b = [0u8; RECORD_LEN];
        for (i, v) in [self.kind, self.index, self.scheme, f, w, s].into_iter().enumerate() {
            b[i * 4..i * 4 + 4].copy_from_slice(&v.to_le_bytes());
        }
        b[24..32].copy_from_slice(&self.raw_size.to_le_bytes());
        b[32..40].copy_from_slice(&self.raw_checksum.to_le_bytes());
        b
    }

    /// Parses a coding section.
    pub fn parse_all(b: &[u8]) -> Result<Vec<Coding>, Error> {
        if !b.len().is_multiple_of(RECORD_LEN) {
            return Err(Error::Shape { kind: kind::CODING, size: b.len(), unit: RECORD_LEN });
        }
        b.chunks_exact(RECORD_LEN)
            .map(|r| {
                let u = |i: usize| u32::from_le_bytes(r[i * 4..i * 4 + 4].try_into().unwrap_or([0; 4]));
                let (kind, index, scheme) = (u(0), u(1), u(2));
                if !matches!(scheme, SCHEME_ZSTD | SCHEME_CONTEXT | SCHEME_MASKS | SCHEME_SHOWN) {
                    return Err(Error::Coding { kind, index, problem: format!("unknown scheme {scheme}") });
                }
                let filter = Filter::from_code(u(3), u(4), u(5)).ok_or_else(|| Error::Coding { kind, index, problem: format!("unknown filter {} (width {}, stride {})", u(3), u(4), u(5)) })?;
                if scheme == SCHEME_CONTEXT && !matches!(filter, Filter::Tiles(Tiles { predict: false, .. })) {
                    return Err(Error::Coding { kind, index, problem: format!("codes filter {} with context coding, which takes tiles unpredicted only", filter.name()) });
                }
                if scheme == SCHEME_SHOWN && (!matches!(filter, Filter::Tiles(Tiles { predict: false, .. })) || kind != crate::kind::ATLAS) {
                    return Err(Error::Coding {
                        kind,
                        index,
                        problem: format!("codes filter {} with context coding of shown voxels, which takes an atlas under tiles unpredicted only", filter.name()),
                    });
                }
                if scheme == SCHEME_MASKS && (filter != Filter::L3Nodes || kind != crate::kind::L3_NODES) {
                    return Err(Error::Coding { kind, index, problem: format!("codes filter {} with mask coding, which takes an L3 array under l3 nodes only", filter.name()) });
                }
                let raw_size = u64::from_le_bytes(r[24..32].try_into().unwrap_or([0; 8]));
                let raw_checksum = u64::from_le_bytes(r[32..40].try_into().unwrap_or([0; 8]));
                Ok(Coding { kind, index, scheme, filter, raw_size, raw_checksum })
            })
            .collect()
    }
}

/// The filters worth trying on a section, by what its bytes are: `u32`
/// tables and node words, `f32` ranges and tiles, and an atlas's texels in
/// its plane's format (lanes interleaved, so a texel's neighbour along x is
/// `lanes` elements back).
fn candidates(s: &Section, meta: &Metadata) -> Vec<Filter> {
    let words = vec![Filter::None, Filter::Shuffle { width: 4 }, Filter::Delta { width: 4, stride: 1 }];
    match s.kind {
        kind::METADATA | kind::CODING => Vec::new(),
        kind::L3_NODES if crate::l3_filter::fits(&s.data) => vec![Filter::L3Nodes],
        kind::ATLAS => atlas_of(meta, s.index).map_or(vec![Filter::None], |(plane, atlas)| texel_filters(plane, atlas.bricks)),
        _ => words,
    }
}

/// The filters for texels of `plane` in an atlas of `bricks`: the plain
/// one first, then those that usually win on smooth volumes (a texel's
/// difference from its neighbour along x, `lanes` elements back; a 1-lane
/// plane's bricks as tiles; BC blocks' bytes by weight).
fn texel_filters(plane: &crate::Plane, bricks: [u32; 3]) -> Vec<Filter> {
    let lanes = plane.lanes;
    let width = plane.format.lane_bytes() as u32;
    let tiled = lanes == 1 && plane.z_per_texel == 1 && matches!(width, 1 | 2) && bricks[0] < 1 << 16 && bricks[1] < 1 << 16;
    let tiles = [false, true].into_iter().filter(|_| tiled).map(|predict| Filter::Tiles(Tiles { width, x: bricks[0], y: bricks[1], predict }));
    let mut filters = match plane.format {
        Format::Bc4 | Format::Bc7 => vec![Filter::None, Filter::Shuffle { width: plane.format.block_bytes() as u32 }],
        Format::F32 => vec![Filter::Shuffle { width: 4 }, Filter::Delta { width: 4, stride: lanes }],
        Format::F16 | Format::Unorm16 => vec![Filter::Shuffle { width: 2 }, Filter::Delta { width: 2, stride: lanes }],
        Format::Unorm8 => vec![Filter::None, Filter::Delta { width: 1, stride: lanes }],
        Format::Constant => vec![Filter::None],
    };
    filters.extend(tiles);
    filters
}

/// A context-coded atlas is kept when it takes at most this share of its
/// zstd frame's bytes (and expands at most [`MAX_RATIO`] times, as every
/// reader allows: a constant atlas codes to almost nothing). A section's
/// restore runs at 0.8–1.8 times zstd's speed with AVX-512, its decoder at
/// about half that with AVX2 alone and a seventh with neither
/// (docs/benchmarks.md): a few percent of bytes are not worth that.
const CONTEXT_GAIN: f64 = 0.92;

/// A context-coded atlas is coded over its shown voxels (scheme 4) when
/// that takes at most this share of the stream over all of them (scheme 2):
/// its reader first works out every node's voxels and lays them out for the
/// decoder, which cost a smooth fog's restore several percent (a tenth on
/// the Arnold smoke at E = 0.01) for 4–6 % of its bytes (docs/benchmarks.md);
/// flames and level sets, whose bricks are mostly hidden, save a fifth.
const SHOWN_GAIN: f64 = 0.93;

/// The `tiles unpredicted` filter among `filters` when section `s` is the
/// atlas of a plane of levels (`unorm8`, `unorm16`), which context coding
/// (scheme 2) is tried on beside zstd: its model predicts levels from their
/// neighbours, which `f16` bit patterns are not.
fn contextual(s: &Section, meta: &Metadata, filters: &[Filter]) -> Option<Tiles> {
    let (plane, _) = atlas_of(meta, s.index).filter(|_| s.kind == kind::ATLAS)?;
    let unpredicted = filters.iter().find_map(|f| match f {
        Filter::Tiles(t) if !t.predict => Some(*t),
        _ => None,
    })?;
    matches!(plane.format, Format::Unorm8 | Format::Unorm16).then_some(unpredicted)
}

fn atlas_of(meta: &Metadata, section: u32) -> Option<(&crate::Plane, &crate::AtlasInfo)> {
    let (p, a) = meta.section_atlas(section)?;
    Some((&meta.planes[p].plane, &meta.planes[p].atlases[a]))
}

/// The tiles filters among `filters` (they share their geometry): the first,
/// and in order whether each predicts; `None` when there are none.
fn tiles_among(filters: &[Filter]) -> Option<(Tiles, Vec<bool>)> {
    let tiles: Vec<Tiles> = filters.iter().filter_map(|f| if let Filter::Tiles(t) = f { Some(*t) } else { None }).collect();
    tiles.first().map(|&t| (t, tiles.iter().map(|t| t.predict).collect()))
}

/// What one brick's texels (`bytes`, in `plane`) cost in a supercompressed
/// file, as an estimate for choosing formats: the order-0 entropy of its
/// bytes after the plane's own filter (tiles for a 1-lane uncompressed
/// plane, the cheaper of predicted and not; [`texel_filters`]' last
/// otherwise), what a coder fitted to the brick would spend (zstd codes a
/// whole section with one table: a brick compressed alone would be charged
/// a table of its own), plus its range pair. A brick of levels (a 1-lane
/// `unorm8` or `unorm16` plane, whose atlas `--optimize disk` may
/// context-code) costs the lesser of that and what the context coder would
/// spend on its quotients, roughly ([`crate::context::tile_bits`]): the
/// zstd view alone missed the coder's prediction and chose several percent
/// larger files on fogs, and a fifth larger on a level set at E = 0.001
/// (docs/benchmarks.md); the coder's alone chose `f16` planes of a few
/// bricks beside `unorm8` ones in a small asset, whose fixed bytes no
/// brick's estimate holds.
pub fn brick_cost(plane: &crate::Plane, bytes: &[u8]) -> usize {
    let filters = texel_filters(plane, [1, 1, 1]);
    let filtered: Vec<Vec<u8>> = match (tiles_among(&filters), filters.last()) {
        (Some((t, predicts)), _) if t.count(bytes.len()).is_some() => t.apply_each(bytes, &predicts),
        (None, Some(f)) if f.filtered_len(bytes.len()).is_some() => vec![f.apply(bytes)],
        _ => vec![bytes.to_vec()],
    };
    let entropy = |filtered: &Vec<u8>| {
        let mut counts = [0u32; 256];
        filtered.iter().for_each(|&b| counts[usize::from(b)] += 1);
        let n = filtered.len() as f64;
        counts.iter().filter(|&&c| c > 0).map(|&c| f64::from(c) * (n / f64::from(c)).log2()).sum::<f64>()
    };
    let zstd = filtered.iter().map(entropy).fold(f64::INFINITY, f64::min);
    let bits = coder_bits(plane, bytes).map_or(zstd, |c| zstd.min(c));
    (bits.min(8.0 * bytes.len() as f64) / 8.0).ceil() as usize + 8
}

/// What the context coder would spend on one brick of levels (`bytes`, in
/// a 1-lane `unorm8` or `unorm16` plane), roughly, in bits
/// ([`crate::context::tile_bits`]); `None` for any other plane.
pub fn coder_bits(plane: &crate::Plane, bytes: &[u8]) -> Option<f64> {
    crate::tiles::level_quotients(plane, bytes).map(|q| crate::context::tile_bits(&q))
}

/// A brick's quotients (its levels over their common step, 512 of them, x
/// fastest), each the value within its `bounds` nearest what the context
/// coder predicts for it (`--optimize disk`: a voxel no reader uses may take
/// any level, a shown one those within the error bound), so that the coder
/// spends the least on them.
pub fn nearest_predicted(quotients: &mut [u16; crate::BRICK_VOXELS], bounds: impl Fn(usize) -> (u16, u16)) {
    crate::context::nearest_predicted(quotients, bounds)
}

/// Sections of more than this many bytes are compressed at most at
/// [`LARGE_LEVEL`] when the level asked for is one of the fast ones (at most
/// [`Supercompress::DEFAULT_LEVEL`]): zstd's greedy levels (5 and up) spend
/// about four times the time of level 1 for a few percent on texels after
/// their filter, and on a plain `f16` or `f32` atlas of tens of MiB that is
/// more than the rest of the cook. Slower levels are a choice for size and
/// are kept.
pub const LARGE_SECTION: usize = 8 << 20;
pub const LARGE_LEVEL: i32 = 1;

/// The zstd level a section of `len` bytes is compressed at, given `level`.
pub fn level_for(level: i32, len: usize) -> i32 {
    match len > LARGE_SECTION && level <= Supercompress::DEFAULT_LEVEL {
        true => level.min(LARGE_LEVEL),
        false => level,
    }
}

/// Sections of more than this many bytes are compressed by zstd's worker
/// threads in jobs of [`JOB`] bytes (each job's window reaching back into
/// the one before): one frame whose bytes depend on the jobs, which depend
/// on the size alone, not on how many workers run them (1 or more; 0, no
/// worker, is another coding), so an asset is the same on any thread count.
const THREADED_SECTION: usize = 2 << 20;
const JOB: u32 = 1 << 20;

/// One zstd frame of `data` at `level`; by [`rayon`]'s number of threads
/// (at least one) of zstd's workers when it is large.
fn compress(data: &[u8], level: i32) -> std::io::Result<Vec<u8>> {
    if data.len() <= THREADED_SECTION {
        return zstd::bulk::compress(data, level);
    }
    let workers = rayon::current_num_threads().max(1) as u32;
    compress_threaded(data, level, workers)
}

fn compress_threaded(data: &[u8], level: i32, workers: u32) -> std::io::Result<Vec<u8>> {
    use zstd::zstd_safe::CParameter;
    let mut c = zstd::bulk::Compressor::new(level)?;
    c.set_parameter(CParameter::NbWorkers(workers.max(1)))?;
    c.set_parameter(CParameter::JobSize(JOB))?;
    c.compress(data)
}

/// Compresses every section worth it (the smallest of its filters' outputs,
/// tried at a fast level, then compressed at `level`, or as [`level_for`]
/// says for a large one; or context-coded when `schemes` allows and that
/// takes at most [`CONTEXT_GAIN`] of zstd's bytes) and adds the coding section; sections that shrink by no more than their record stay
/// as they are. Deterministic: each section is one zstd frame or context
/// stream, the same on any number of threads ([`compress`]).
pub fn supercompress(sections: Vec<Section>, meta: &Metadata, schemes: Schemes) -> Result<Vec<Section>, Error> {
    let level = schemes.level;
    // The shown voxels of each atlas context coding may take (scheme 4 leaves the others out).
    let coder_atlases: Vec<crate::shown::Wanted> = sections
        .iter()
        .filter(|s| schemes.context && s.kind == kind::ATLAS)
        .filter_map(|s| {
            let filters = candidates(s, meta);
            let t = contextual(s, meta, &filters)?;
            Some(crate::shown::Wanted { section: s.index, tiles: s.data.len() / (crate::BRICK_VOXELS * t.width as usize) })
        })
        .collect();
    // From the metadata the body holds, as its readers take it (no scheme 4 without one).
    let find = |k: u32, i: u32| sections.iter().find(|s| (s.kind, s.index) == (k, i)).map(|s| &s.data[..]);
    let coder_atlases = match find(kind::METADATA, 0).map(Metadata::from_bytes) {
        Some(Ok(body)) if !coder_atlases.is_empty() => Some((body, coder_atlases)),
        _ => None,
    };
    let shown = coder_atlases.as_ref().map_or_else(Vec::new, |(body, wanted)| crate::shown::shown_tiles(body, wanted, &find));
    let coder_atlases = coder_atlases.map_or_else(Vec::new, |(_, wanted)| wanted);
    let shown_of = |s: &Section| coder_atlases.iter().position(|w| s.kind == kind::ATLAS && w.section == s.index).map(|j| &shown[j][..]);
    let coded: Vec<(Section, Option<Coding>)> = sections
        .into_par_iter()
        .map(|s| {
            let filters: Vec<Filter> = candidates(&s, meta).into_iter().filter(|f| f.filtered_len(s.data.len()).is_some()).collect();
            if filters.is_empty() || s.data.is_empty() {
                return Ok((s, None));
            }
            let contextual = contextual(&s, meta, &filters).filter(|_| schemes.context);
            // The first of the smallest, with its filtered bytes when they were made whole,
            // and the unpredicted tiles' when context coding is tried on them.
            let (best, filtered, mut unpredicted) = match filters.as_slice() {
                [only] => (*only, None, None),
                _ => {
                    // Tiles span the atlas's rows: every tiles filter made whole in one pass, then
                    // sampled, when the sample is the whole section or context coding needs the
                    // unpredicted tiles whole; else only the tiles the sample shows are filtered.
                    let tiles = tiles_among(&filters);
                    let ranges = tiles.as_ref().and_then(|(t, _)| t.filtered_len(s.data.len())).map(sample_ranges).unwrap_or_default();
                    let make_whole = contextual.is_some() || ranges.len() == 1;
                    let mut tiled: Vec<Vec<u8>> = match &tiles {
                        Some((t, predicts)) if make_whole => t.apply_each(&s.data, predicts),
                        Some((t, predicts)) => t.apply_each_at(&s.data, predicts, &ranges),
                        None => Vec::new(),
                    };
                    let mut next_tiled = 0..tiled.len();
                    // Each filter's sample, and where its whole output is kept.
                    let samples: Vec<(Vec<u8>, Option<usize>)> = filters
                        .iter()
                        .map(|f| match f {
                            Filter::Tiles(_) => {
                                let j = next_tiled.next().unwrap_or(0);
                                match make_whole {
                                    true => (ranges.iter().map(|r| tiled.get(j).map_or(&[][..], |w| &w[r.clone()])).collect::<Vec<_>>().concat(), Some(j)),
                                    // Already the sample.
                                    false => (tiled.get_mut(j).map(std::mem::take).unwrap_or_default(), None),
                                }
                            }
                            _ => (sample(&s.data).map(|chunk| f.apply(chunk)).collect::<Vec<_>>().concat(), None),
                        })
                        .collect();
                    let sizes: Vec<usize> = samples.par_iter().map(|(x, _)| zstd::bulk::compress(x, 1).map(|c| c.len())).collect::<Result<_, _>>()?;
                    let first_smallest = (0..sizes.len()).min_by_key(|&i| (sizes[i], i)).unwrap_or(0);
                    let whole = samples[first_smallest].1.and_then(|j| tiled.get_mut(j).map(std::mem::take));
                    let unpredicted = contextual.and_then(|t| filters.iter().filter(|f| matches!(f, Filter::Tiles(_))).position(|&f| f == Filter::Tiles(t)));
                    let unpredicted = unpredicted.and_then(|j| tiled.get_mut(j).map(std::mem::take)).filter(|u| !u.is_empty());
                    (filters[first_smallest], whole, unpredicted)
                }
            };
            let filtered = filtered.unwrap_or_else(|| best.apply(&s.data));
            let mut data = compress(&filtered, level_for(level, filtered.len()))?;
            let (mut scheme, mut filter) = (SCHEME_ZSTD, best);
            if let Some(t) = contextual {
                let input = match best == Filter::Tiles(t) {
                    true => &filtered,
                    false => unpredicted.get_or_insert_with(|| Filter::Tiles(t).apply(&s.data)),
                };
                let worth = |c: &Vec<u8>| (c.len() as f64) <= CONTEXT_GAIN * data.len() as f64 && input.len() as u64 <= c.len() as u64 * MAX_RATIO;
                // Over the shown voxels where that saves enough of the stream over all of them.
                let over_all = crate::context::encode(input, t.width, level, None)?;
                // Tried only where the nodes leave out a twentieth of the texels or more (a fog's
                // atlas, nearly all shown, is not coded twice).
                let hidden = |shown: &[TileMask]| shown.iter().flatten().map(|w| w.count_zeros() as usize).sum::<usize>();
                let over_shown = match (shown_of(&s).filter(|m| 20 * hidden(m) >= m.len() * crate::BRICK_VOXELS), &over_all) {
                    (Some(shown), Some(all)) => crate::context::encode(input, t.width, level, Some(shown))?.filter(|c| c.len() as f64 <= SHOWN_GAIN * all.len() as f64),
                    _ => None,
                };
                let best = match over_shown {
                    Some(c) => Some((c, SCHEME_SHOWN)),
                    None => over_all.map(|c| (c, SCHEME_CONTEXT)),
                };
                if let Some((coded, coded_as)) = best.filter(|(c, _)| worth(c)) {
                    (data, scheme, filter) = (coded, coded_as, Filter::Tiles(t));
                }
            }
            if schemes.context && best == Filter::L3Nodes {
                let worth = |c: &Vec<u8>| (c.len() as f64) <= CONTEXT_GAIN * data.len() as f64 && filtered.len() as u64 <= c.len() as u64 * MAX_RATIO;
                if let Some(coded) = crate::masks::encode(&filtered, level)?.filter(worth) {
                    (data, scheme) = (coded, SCHEME_MASKS);
                }
            }
            drop((filtered, unpredicted));
            // Stored as it is unless compression saves more than its record costs.
            if data.len() + RECORD_LEN >= s.data.len() {
                return Ok((s, None));
            }
            let c = Coding { kind: s.kind, index: s.index, scheme, filter, raw_size: s.data.len() as u64, raw_checksum: checksum(&s.data) };
            Ok((Section { kind: s.kind, index: s.index, data: data.into() }, Some(c)))
        })
        .collect::<Result<_, std::io::Error>>()?;
    let mut table = Vec::new();
    let mut out = Vec::with_capacity(coded.len() + 1);
    for (s, c) in coded {
        if let Some(c) = c {
            table.extend_from_slice(&c.bytes());
        }
        out.push(s);
    }
    if !table.is_empty() {
        out.push(Section { kind: kind::CODING, index: 0, data: table.into() });
    }
    Ok(out)
}

/// Checks a record against its stored bytes before anything is allocated:
/// a restored size its filter cannot have, or that no zstd frame of that
/// size can reach, is a lie.
fn plausible(c: &Coding, stored: usize) -> Result<usize, Error> {
    let filtered = usize::try_from(c.raw_size).ok().filter(|&n| n <= isize::MAX as usize / 2).and_then(|n| c.filter.filtered_len(n));
    match filtered {
        Some(f) if f as u64 <= (stored as u64).saturating_mul(MAX_RATIO) => Ok(f),
        _ => Err(Error::Coding { kind: c.kind, index: c.index, problem: format!("claims {} restored bytes from {stored} stored", c.raw_size) }),
    }
}

// A thread's buffer for filtered bytes, kept from one restore to the next
// (up to KEEP_SCRATCH bytes): a reader restoring segment after segment then
// decompresses into memory it has touched before, not into fresh pages that
// the kernel must fault in and zero each time.
thread_local! {
    static SCRATCH: std::cell::Cell<Vec<u8>> = const { std::cell::Cell::new(Vec::new()) };
}
const KEEP_SCRATCH: usize = 256 << 20;

// A thread's zstd decompression context, made once: making one allocates
// and clears its tables, which took a quarter of the time of restoring a
// small section.
thread_local! {
    static DECOMPRESSOR: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> = const { std::cell::RefCell::new(None) };
}

/// Decompresses the zstd frame `stored` into `out` (a slice, or a vector's
/// spare capacity), giving the bytes it wrote (an error when they would not
/// fit), with the thread's context.
pub(crate) fn decompress_into<C: zstd::zstd_safe::WriteBuf + ?Sized>(stored: &[u8], out: &mut C) -> std::io::Result<usize> {
    DECOMPRESSOR.with(|cell| {
        let mut cell = cell.borrow_mut();
        let d = match &mut *cell {
            Some(d) => d,
            empty => empty.insert(zstd::bulk::Decompressor::new()?),
        };
        d.decompress_to_buffer(stored, out)
    })
}

/// Restores one section's GPU bytes from its stored bytes into `out` (its
/// restored size): decompressed in place when it has no filter, else into
/// `scratch` (when it has room, else the thread's own buffer) and
/// unfiltered from there; then checked against its checksum.
/// A scheme-4 section takes `shown`, its tiles' shown voxels ([`shown_of`]).
fn restore_into(c: &Coding, stored: &[u8], out: &mut [u8], scratch: &mut Vec<u8>, shown: Option<&[TileMask]>) -> Result<(), Error> {
    let err = |problem: String| Error::Coding { kind: c.kind, index: c.index, problem };
    let n = c.filter.filtered_len(out.len()).ok_or_else(|| err(format!("restores {} bytes, which its filter cannot", out.len())))?;
    // Exactly the n bytes the record implies.
    let check = |r: std::io::Result<usize>| match r {
        Ok(got) if got == n => Ok(()),
        Ok(got) => Err(err(format!("decompresses to {got} bytes, the coding table says {n}"))),
        Err(e) => Err(err(format!("does not decompress to the {n} bytes the coding table says ({e})"))),
    };
    // One zstd frame and nothing after it (the decompressor would take a second frame on).
    if c.scheme == SCHEME_ZSTD && zstd::zstd_safe::find_frame_compressed_size(stored) != Ok(stored.len()) {
        return Err(err("is not one zstd frame with nothing after it".into()));
    }
    if c.filter == Filter::None && c.scheme == SCHEME_ZSTD {
        check(decompress_into(stored, out))?;
    } else {
        let own = scratch.capacity() < n;
        let mut buf = if own { SCRATCH.take() } else { std::mem::take(scratch) };
        // The context decoders write every byte: memory an earlier restore left need not be zeroed again.
        if !matches!(c.scheme, SCHEME_CONTEXT | SCHEME_SHOWN) {
            buf.clear();
        }
        buf.truncate(n);
        let undone = buf.try_reserve_exact(n - buf.len()).map_err(|_| err(format!("no memory for its {n} filtered bytes"))).and_then(|()| {
            match c.scheme {
                SCHEME_CONTEXT | SCHEME_SHOWN => {
                    let shown = match c.scheme {
                        SCHEME_SHOWN => Some(shown.ok_or_else(|| err("is coded over its shown voxels, which it was not given".into()))?),
                        _ => None,
                    };
                    buf.resize(n, 0);
                    crate::context::decode(stored, c.filter.width() as u32, &mut buf, shown).map_err(err)?;
                }
                SCHEME_MASKS => {
                    buf.resize(n, 0);
                    crate::masks::decode(stored, &mut buf).map_err(err)?;
                }
                _ => check(decompress_into(stored, &mut buf))?,
            }
            c.filter.undo(&buf, out).map_err(err)
        });
        match own {
            true if buf.capacity() <= KEEP_SCRATCH => SCRATCH.set(buf),
            true => {}
            false => *scratch = buf,
        }
        undone?;
    }
    let computed = checksum(out);
    if computed != c.raw_checksum {
        return Err(err(format!("restored checksum mismatch (stored {:#018x}, computed {computed:#018x})", c.raw_checksum)));
    }
    Ok(())
}

/// Section `c`'s restored bytes as one zstd frame at `level` after the
/// record's filter: what scheme 1 would store in place of a context-coded
/// section (benchmarks time `zstd -d` on it).
pub fn zstd_frame(c: &Coding, restored: &[u8], level: i32) -> std::io::Result<Vec<u8>> {
    compress(&c.filter.apply(restored), level)
}

/// What a filter is judged on: a section of up to 1 MiB whole, a larger one
/// by 16 chunks of 64 KiB spread over it (a multiple of every filter's width).
fn sample(data: &[u8]) -> impl Iterator<Item = &[u8]> {
    sample_ranges(data.len()).into_iter().map(move |r| &data[r])
}

/// The byte ranges [`sample`] takes of `len` bytes.
fn sample_ranges(len: usize) -> Vec<std::ops::Range<usize>> {
    const CHUNK: usize = 64 << 10;
    match len <= 1 << 20 {
        true => std::iter::once(0..len).collect(),
        false => {
            let step = (len - CHUNK) / 15 / CHUNK * CHUNK;
            (0..16).map(|k| k * step..k * step + CHUNK).collect()
        }
    }
}

/// `n` zeroed items from the allocator's zeroed memory (fresh pages are not
/// touched until written: a restored size that lies costs address space, not
/// memory, until its frame fails to fill it), or `None` when it has none.
pub(crate) fn zeroed<T: bytemuck::Zeroable>(n: usize) -> Option<Vec<T>> {
    let layout = std::alloc::Layout::array::<T>(n).ok()?;
    if layout.size() == 0 {
        return Some(Vec::new());
    }
    // SAFETY: the layout's size is not zero; a null pointer is handled; all-zero
    // bits are a valid T (Zeroable), and the Vec takes the allocation with this layout.
    unsafe {
        let p = std::alloc::alloc_zeroed(layout) as *mut T;
        (!p.is_null()).then(|| Vec::from_raw_parts(p, n, n))
    }
}

/// Restores one section's GPU bytes from its stored bytes (a scheme-4
/// section needs its body's: [`restore_body`]).
pub fn restore(c: &Coding, stored: &[u8]) -> Result<Vec<u8>, Error> {
    plausible(c, stored.len())?;
    let mut out = Vec::new();
    out.try_reserve_exact(c.raw_size as usize).map_err(|_| Error::Coding { kind: c.kind, index: c.index, problem: format!("no memory for its {} restored bytes", c.raw_size) })?;
    out.resize(c.raw_size as usize, 0);
    restore_into(c, stored, &mut out, &mut Vec::new(), None)?;
    Ok(out)
}

/// The shown voxels of the scheme-4 atlases `coded` (one list of tile
/// masks each, in order) from a body's restored sections (`section`): its
/// metadata (`meta`, or parsed from the body's), L3 array and tables.
pub(crate) fn shown_of<'a>(coded: &[Coding], meta: Option<&Metadata>, section: &dyn Fn(u32, u32) -> Option<&'a [u8]>) -> Result<Vec<Vec<TileMask>>, Error> {
    if coded.is_empty() {
        return Ok(Vec::new());
    }
    let parsed;
    let meta = match meta {
        Some(m) => m,
        None => {
            parsed = Metadata::from_bytes(section(kind::METADATA, 0).ok_or(Error::Missing { kind: kind::METADATA, index: 0 })?)?;
            &parsed
        }
    };
    let wanted: Vec<crate::shown::Wanted> = coded.iter().map(|c| crate::shown::Wanted { section: c.index, tiles: c.raw_size as usize / (crate::BRICK_VOXELS * c.filter.width()) }).collect();
    Ok(crate::shown::shown_tiles(meta, &wanted, section))
}

/// How a body's sections are restored: the restored body's header and
/// section table, its length, and per stored section (in table order, the
/// coding section left out) its record and place there.
pub(crate) struct Plan {
    pub head: Vec<u8>,
    pub len: usize,
    pub parts: Vec<Part>,
}

/// One section of a [`Plan`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Part {
    /// As stored.
    pub stored: crate::SectionEntry,
    /// Its record, if it is stored compressed.
    pub coding: Option<Coding>,
    /// Its offset and size in the restored body.
    pub offset: usize,
    pub size: usize,
}

impl Part {
    /// Whether restoring it takes the body's other sections (scheme 4).
    pub fn needs_shown(&self) -> bool {
        self.coding.is_some_and(|c| c.scheme == SCHEME_SHOWN)
    }

    /// The restored section's checksum.
    pub fn checksum(&self) -> u64 {
        self.coding.map_or(self.stored.checksum, |c| c.raw_checksum)
    }
}

/// The plan of a body of stored sections `sections` (in table order) whose
/// coding section (kind 13, index 0), if any, holds `coding`: the coding
/// records checked (one section of index 0 with at least one record, each
/// naming a section of the body once, none the metadata, each restored size
/// plausible for its stored size) and the restored body laid out as the
/// writer lays out a plain one. Nothing is read or allocated by the records' claims.
pub(crate) fn plan(sections: &[crate::SectionEntry], coding: Option<&[u8]>) -> Result<Plan, Error> {
    if let Some(e) = sections.iter().find(|e| e.kind == kind::CODING && (e.index != 0 || e.size == 0)) {
        return Err(Error::Coding { kind: e.kind, index: e.index, problem: "is a coding section other than one of index 0 with at least one record".into() });
    }
    let coding = match sections.iter().any(|e| e.kind == kind::CODING) {
        true => Coding::parse_all(coding.unwrap_or_default())?,
        false => Vec::new(),
    };
    let mut seen = std::collections::HashSet::new();
    for c in &coding {
        let stored = sections.iter().find(|e| (e.kind, e.index) == (c.kind, c.index)).map(|e| e.size as usize);
        match stored {
            Some(len) if !matches!(c.kind, kind::METADATA | kind::CODING) && seen.insert((c.kind, c.index)) => {
                plausible(c, len)?;
            }
            _ => return Err(Error::Coding { kind: c.kind, index: c.index, problem: "is not a section the coding table may name once".into() }),
        }
    }
    let parts: Vec<(crate::SectionEntry, Option<Coding>)> =
        sections.iter().filter(|e| e.kind != kind::CODING).map(|e| (*e, coding.iter().find(|c| (c.kind, c.index) == (e.kind, e.index)).copied())).collect();
    // The restored table: each section at its restored size, with its restored checksum.
    let entries: Vec<crate::Entry> = parts.iter().map(|(e, c)| (e.kind, e.index, c.map_or(e.size as usize, |c| c.raw_size as usize), c.map_or(e.checksum, |c| c.raw_checksum), crate::ALIGN)).collect();
    let (head, offsets, len) = crate::head_of(&entries);
    let parts = parts.into_iter().zip(offsets.iter().zip(&entries)).map(|((stored, coding), (&offset, e))| Part { stored, coding, offset, size: e.2 }).collect();
    Ok(Plan { head, len, parts })
}

/// Restores `part`'s section from its stored bytes into `out` (its restored
/// size): decompressed and unfiltered (through `scratch`), or copied.
/// A scheme-4 section takes `shown`, its tiles' shown voxels ([`shown_of`]).
pub(crate) fn restore_part(part: &Part, stored: &[u8], out: &mut [u8], scratch: &mut Vec<u8>, shown: Option<&[TileMask]>) -> Result<(), Error> {
    match &part.coding {
        Some(c) => restore_into(c, stored, out, scratch, shown),
        None => {
            out.copy_from_slice(stored);
            Ok(())
        }
    }
}

/// A body's sections (as stored, in table order) restored into one new body
/// laid out as the writer lays out a plain one (the coding section left
/// out): its bytes in 8-byte words, in `buf` when it is large enough (its
/// old bytes overwritten), and its length. Each section is decompressed
/// straight into its place, the sections in parallel.
pub(crate) fn restore_body(sections: &[(crate::SectionEntry, &[u8])], buf: Vec<u64>) -> Result<(Vec<u64>, usize), Error> {
    let entries: Vec<crate::SectionEntry> = sections.iter().map(|(e, _)| *e).collect();
    let coding = sections.iter().find(|(e, _)| (e.kind, e.index) == (kind::CODING, 0)).map(|(_, b)| *b);
    let plan = plan(&entries, coding)?;
    let len = plan.len;
    let mut words = reuse_words(buf, len.div_ceil(8)).ok_or_else(|| Error::Invalid(format!("no memory for the {len} bytes of a restored segment")))?;
    let bytes = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..len];
    bytes[..plan.head.len()].copy_from_slice(&plan.head);
    // Disjoint places, in offset order; the padding between them zero.
    let stored = sections.iter().filter(|(e, _)| e.kind != kind::CODING).map(|(_, b)| *b);
    let mut slots = Vec::with_capacity(plan.parts.len());
    let mut rest = &mut bytes[plan.head.len()..];
    let mut at = plan.head.len();
    for (part, stored) in plan.parts.iter().zip(stored) {
        let (gap, tail) = std::mem::take(&mut rest).split_at_mut(part.offset - at);
        gap.fill(0);
        let (slot, tail) = tail.split_at_mut(part.size);
        slots.push((part, slot, stored));
        rest = tail;
        at = part.offset + part.size;
    }
    rest.fill(0);
    restore_parts(slots, None, Vec::new, |scratch, part, slot, stored, shown| restore_part(part, stored, slot, scratch, shown))?;
    Ok((words, len))
}

/// Restores each of a body's `parts` (its plan entry, its restored place and
/// what `restore` needs of it) in parallel, with `restore` and a state per
/// worker that `init` makes; scheme-4 atlases last, given the shown voxels
/// ([`shown_of`], the body's metadata `meta` or its own) that the other
/// sections say once restored. Shared by [`restore_body`] and the runtime reader.
pub(crate) fn restore_parts<P: Sync + Send, S>(
    parts: Vec<(&Part, &mut [u8], P)>,
    meta: Option<&Metadata>,
    init: impl Fn() -> S + Sync + Send,
    restore: impl Fn(&mut S, &Part, &mut [u8], &P, Option<&[TileMask]>) -> Result<(), Error> + Sync + Send,
) -> Result<(), Error> {
    let (later, mut first): (Vec<_>, Vec<_>) = parts.into_iter().partition(|(part, _, _)| part.needs_shown());
    first.par_iter_mut().try_for_each_init(&init, |state, (part, out, p)| restore(state, part, out, p, None))?;
    if later.is_empty() {
        return Ok(());
    }
    let done: Vec<(&Part, &[u8])> = first.into_iter().map(|(part, out, _)| (part, &*out)).collect();
    let find = |k: u32, i: u32| done.iter().find(|(p, _)| (p.stored.kind, p.stored.index) == (k, i)).map(|(_, b)| *b);
    let coded: Vec<Coding> = later.iter().filter_map(|(part, _, _)| part.coding).collect();
    let shown = shown_of(&coded, meta, &find)?;
    later.into_par_iter().zip(shown).try_for_each_init(&init, |state, ((part, out, p), shown)| restore(state, part, out, &p, Some(&shown)))
}

/// `buf` made `n` words long when it has room for them (its contents left
/// for the caller to overwrite), else fresh zeroed words ([`zeroed`]).
pub(crate) fn reuse_words<T: bytemuck::Zeroable + Clone>(mut buf: Vec<T>, n: usize) -> Option<Vec<T>> {
    if buf.capacity() >= n {
        buf.resize(n, T::zeroed());
        buf.truncate(n);
        return Some(buf);
    }
    drop(buf);
    zeroed(n)
}

/// Writes `asset` again with its sections stored as `to` says (each segment
/// restored, then supercompressed or not), its recorded `supercompress`
/// setting changed to match; nodes, bricks and every other byte the GPU
/// sees stay as they are. A segment at a time: memory holds one.
pub fn recompress<W: std::io::Write + std::io::Seek>(asset: &crate::Asset, to: Supercompress, out: W) -> Result<W, Error> {
    let table = asset.segments()?;
    let mut w = crate::Writer::new(out, table.len() as u32)?;
    for (s, e) in table.iter().enumerate() {
        let stored = asset.stored_segment(s)?;
        let restored = stored.restored().map_err(|err| Error::InSegment(s, Box::new(err)))?;
        stored.release();
        let mut sections = restored.to_sections();
        drop(restored);
        let meta = sections.iter_mut().find(|x| x.kind == kind::METADATA).ok_or(Error::Missing { kind: kind::METADATA, index: 0 })?;
        let mut m = Metadata::from_bytes(&meta.data)?;
        let text = crate::settings::SettingText::text(&to);
        match m.settings.iter_mut().find(|(k, _)| k == "supercompress") {
            Some((_, v)) => *v = text,
            None => m.settings.push(("supercompress".into(), text)),
        }
        // An asset older than version 9 records no time: its frames' indices and the default rate, said outright.
        let first = i64::from(e.first_frame);
        m.time.get_or_insert_with(|| crate::Time { fps: crate::DEFAULT_FPS, numbers: (first..first + i64::from(e.frame_count)).collect() });
        meta.data = m.to_bytes()?.into();
        // An asset cooked for the smallest file stays so: context coding where it is smaller.
        let disk = m.settings.iter().any(|(k, v)| k == "optimize" && v == "disk");
        if let Some(schemes) = Schemes::of(to, disk) {
            sections = supercompress(sections, &m, schemes)?;
        }
        w.add(e.frame_count, &sections)?;
    }
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filters_undo_what_they_do() {
        let raw: Vec<u8> = (0..48_000u32).map(|i| (i * 7 % 251 + i / 64) as u8).collect();
        for f in [
            Filter::None,
            Filter::Shuffle { width: 2 },
            Filter::Shuffle { width: 4 },
            Filter::Shuffle { width: 8 },
            Filter::Shuffle { width: 16 },
            Filter::Delta { width: 1, stride: 1 },
            Filter::Delta { width: 1, stride: 4 },
            Filter::Delta { width: 2, stride: 2 },
            Filter::Delta { width: 2, stride: 1 },
            Filter::Delta { width: 4, stride: 1 },
            Filter::Delta { width: 4, stride: 4096 },
        ] {
            let filtered = f.apply(&raw);
            assert_eq!(filtered.len(), raw.len());
            let mut back = vec![0u8; raw.len()];
            f.undo(&filtered, &mut back).unwrap();
            assert_eq!(back, raw, "{f:?}");
            if f != Filter::None {
                assert_ne!(filtered, raw, "{f:?} changed nothing");
            }
        }
    }

    #[test]
    fn a_level_brick_costs_what_the_context_coder_spends_on_it() {
        // Smooth, smooth with a little noise, noisy: 8-bit levels on a step of 3 and 16-bit ones
        // on a step of 300, x fastest.
        let mut rng = 12345u32;
        let mut noise = move |a: u32| {
            rng = rng.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            (rng >> 16) % (2 * a + 1)
        };
        for (format, width, step, top) in [(Format::Unorm8, 1usize, 3u32, 85u32), (Format::Unorm16, 2, 300, 218)] {
            let brick = |amp: u32, noise: &mut dyn FnMut(u32) -> u32| -> Vec<u8> {
                (0..512u32).flat_map(|v| (step * ((v % 8) * 4 + (v / 8 % 8) * 3 + (v / 64) * 2 + noise(amp)).min(top)).to_le_bytes().into_iter().take(width)).collect()
            };
            let plane = crate::Plane { format, lanes: 1, z_per_texel: 1 };
            let mut last = 0;
            for amp in [0, 2, 12] {
                let b = brick(amp, &mut noise);
                let cost = brick_cost(&plane, &b);
                assert!(cost > last, "{format:?}, amplitude {amp}: {cost} bytes, not more than {last}");
                last = cost;
                // Both formats are bricks of levels, which the coder's estimate covers.
                assert!(crate::tiles::level_quotients(&plane, &b).is_some(), "{format:?}: not costed by the coder");
                // 64 such bricks (other noise) side by side in an atlas (texel (8a + i, j, k) of brick a at
                // 8a + i + 512·j + 4096·k), context-coded: the estimate, less its range pair, within a
                // factor of 2 (and 16 bytes) of the coded bytes per brick.
                let mut texture = vec![0u8; 64 * 512 * width];
                for a in 0..64 {
                    for (v, x) in brick(amp, &mut noise).chunks(width).enumerate() {
                        let t = 8 * a + v % 8 + 512 * (v / 8 % 8) + 4096 * (v / 64);
                        texture[t * width..(t + 1) * width].copy_from_slice(x);
                    }
                }
                let t = Tiles { width: width as u32, x: 64, y: 1, predict: false };
                let coded = crate::context::encode(&t.apply(&texture), width as u32, 5, None).unwrap().map_or(usize::MAX, |c| c.len()) / 64;
                let texels = cost - 8;
                assert!(texels <= 2 * coded + 16 && coded <= 2 * texels + 16, "{format:?}, amplitude {amp}: estimated {texels} bytes a brick, coded {coded}");
            }
        }
    }

    #[test]
    fn a_delta_of_a_ramp_is_constant() {
        let raw: Vec<u8> = (0..256u32).flat_map(|i| ((i * 3) as u16).to_le_bytes()).collect();
        let f = Filter::Delta { width: 2, stride: 1 }.apply(&raw);
        // Low bytes: 0 then all 3; high bytes: all 0.
        assert_eq!(f[0], 0);
        assert!(f[1..256].iter().all(|&b| b == 3));
        assert!(f[256..].iter().all(|&b| b == 0));
    }

    #[test]
    fn threaded_frames_do_not_depend_on_the_workers() {
        // Jobs of 1 MiB over 5 MiB of half-predictable bytes: one frame, the same from 1, 2 or 4 workers.
        let raw: Vec<u8> = (0..5u32 << 20).map(|i| ((i / 3) ^ (i.wrapping_mul(2654435761) >> 29)) as u8).collect();
        let one = compress_threaded(&raw, 5, 1).unwrap();
        assert_eq!(zstd::bulk::decompress(&one, raw.len()).unwrap(), raw);
        for workers in [2, 4] {
            assert!(compress_threaded(&raw, 5, workers).unwrap() == one, "{workers} workers");
        }
    }

    #[test]
    fn supercompress_parses() {
        for (s, want) in [("none", Supercompress::None), ("zstd", Supercompress::Zstd(Supercompress::DEFAULT_LEVEL)), ("zstd:19", Supercompress::Zstd(19))] {
            assert_eq!(s.parse::<Supercompress>(), Ok(want));
            assert_eq!(want.to_string().parse::<Supercompress>(), Ok(want));
        }
        for bad in ["zstd:0", "zstd:23", "zstd:x", "gzip", "zstd:"] {
            assert!(bad.parse::<Supercompress>().unwrap_err().contains(bad));
        }
    }

    #[test]
    fn lying_sizes_and_bad_frames_are_refused() {
        let raw = vec![5u8; 10_000];
        let stored = zstd::bulk::compress(&raw, 3).unwrap();
        let good = Coding { kind: kind::TILES, index: 0, scheme: SCHEME_ZSTD, filter: Filter::None, raw_size: raw.len() as u64, raw_checksum: checksum(&raw) };
        assert_eq!(restore(&good, &stored).unwrap(), raw);
        for (c, b) in [
            (Coding { raw_size: 9_999, ..good }, stored.clone()),
            (Coding { raw_size: 10_001, ..good }, stored.clone()),
            (Coding { raw_size: 1 << 40, ..good }, stored.clone()),
            (Coding { raw_checksum: 1, ..good }, stored.clone()),
            (good, stored[..stored.len() - 1].to_vec()),
            // Two frames that decode to the record's bytes together, and a frame with an empty one after it.
            (good, [zstd::bulk::compress(&raw[..4_000], 3).unwrap(), zstd::bulk::compress(&raw[4_000..], 3).unwrap()].concat()),
            (good, [stored.clone(), zstd::bulk::compress(&[], 3).unwrap()].concat()),
        ] {
            assert!(matches!(restore(&c, &b), Err(Error::Coding { .. })), "{c:?}");
        }
    }
}
