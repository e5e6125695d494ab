//! Per-brick formats (`cook --max-error E`): each brick channel takes the
//! cheapest encoding of [`Format::BY_COST`] whose every shown voxel decodes,
//! exactly as a reader decodes it, within E of the source.  NaN and ±∞
//! voxels must decode to themselves (only `f16` and `f32` keep them).

use crate::texels::{bc7_texels, encode_texels, levels, quantise, range_of};
use crate::{bc, group_planes, Brick, Bricks, Format, Optimize, Plane, Quality};
use rayon::prelude::*;
use vdbcook_grid::spill::{SpillPolicy, Store, StoreError};

/// One brick channel's chosen encoding.
#[derive(Clone, Debug, PartialEq)]
pub struct Choice {
    pub format: Format,
    /// The plane brick's range (`[v, v]` for a constant v).
    pub range: [f32; 2],
    /// Its texels or blocks ([`single_plane`]`(format).brick_bytes()` bytes; none for a constant).
    pub bytes: Vec<u8>,
}

/// The plane a channel takes alone in `format` (BC7: four z-slices per texel).
pub fn single_plane(format: Format) -> Plane {
    match format {
        Format::Constant => Plane { format, lanes: 1, z_per_texel: 1 },
        _ => group_planes(format, &[0])[0].plane,
    }
}

pub(crate) fn encode_one(format: Format, quality: Quality, values: &Brick, range: [f32; 2], mask: &[u64; 8]) -> Vec<u8> {
    let plane = single_plane(format);
    let mut out = vec![0u8; plane.brick_bytes()];
    match format {
        Format::Bc4 => bc::encode_bc4(quality, &[levels(values, range, 255.0)], Some(std::slice::from_ref(mask)), &mut out),
        Format::Bc7 => bc::encode_bc7_shown(quality, 4, &bc7_texels(&[vec![quantise(values, range)]], 4), Some(std::slice::from_ref(mask)), &mut out),
        _ => encode_texels(&plane, &[(values, range)], &mut out),
    }
    out
}

/// A single-channel brick's values from its encoding in `format` (as readers decode them).
pub fn decode_one(format: Format, bytes: &[u8], range: [f32; 2]) -> Brick {
    let plane = single_plane(format);
    plane.channel_values(&plane.decode_brick(bytes), 0, range)
}

/// True when every voxel of `mask` decodes within `max_error` of its
/// source value (computed in f64, so no rounding of the difference hides
/// an excess), a NaN to a NaN and ±∞ to itself.
pub fn within(values: &Brick, decoded: &Brick, mask: &[u64; 8], max_error: f32) -> bool {
    let e = f64::from(max_error);
    vdbcook_grid::set_bits(mask).all(|i| {
        let (v, d) = (values[i], decoded[i]);
        if v.is_nan() {
            d.is_nan()
        } else if v.is_infinite() {
            d == v
        } else {
            d.is_finite() && (f64::from(d) - f64::from(v)).abs() <= e
        }
    })
}

/// The constant nearest every shown voxel (the middle of their range), if
/// they are all finite, and their range (`None`: no voxel is shown).
fn constant_of(values: &Brick, mask: &[u64; 8]) -> Option<(f32, Option<[f32; 2]>)> {
    let mut lo_hi: Option<[f32; 2]> = None;
    for i in vdbcook_grid::set_bits(mask) {
        let v = values[i];
        if !v.is_finite() {
            return None;
        }
        lo_hi = Some(lo_hi.map_or([v, v], |[lo, hi]| [lo.min(v), hi.max(v)]));
    }
    // No voxel shown: any value will do; the brick's smallest keeps it in range.
    let [lo, hi] = lo_hi.unwrap_or_else(|| range_of(values));
    // Halves first: the difference of two large values may overflow.
    Some((lo / 2.0 + hi / 2.0, lo_hi))
}

/// The cheapest encoding of one brick channel whose voxels of `mask`
/// decode within `max_error` of `values` (`f32` always does). For a
/// supercompressed asset (`disk`), texels (and a ranged format's range) are
/// moved to the coarsest grid within the bound (`snap`: steps of about 2E),
/// and with [`Optimize::Disk`] "cheapest" is the fewest bytes in the file
/// (the entropy of each format's filtered texels,
/// `vdbcook_vpak::coding::brick_cost`) rather than on the GPU.
pub fn cheapest(values: &Brick, mask: &[u64; 8], max_error: f32, quality: Quality, disk: Option<Optimize>) -> Choice {
    constant_within(values, mask, max_error, disk.is_some()).unwrap_or_else(|| cheapest_ranged(values, range_of(values), mask, max_error, quality, disk, None))
}

/// The constant choice (the first of [`Format::BY_COST`]) when it holds
/// every voxel of `mask` within `max_error`; for a supercompressed asset
/// (`disk`) its value is the float of fewest mantissa bits that does.
fn constant_within(values: &Brick, mask: &[u64; 8], max_error: f32, disk: bool) -> Option<Choice> {
    let (mut v, shown) = constant_of(values, mask)?;
    if disk {
        // For the disk: the value of fewest mantissa bits that holds them all.
        let e = f64::from(max_error);
        let [lo, hi] = shown.map_or_else(|| range_of(values), |[lo, hi]| [(f64::from(hi) - e) as f32, (f64::from(lo) + e) as f32]);
        let c = crate::snap::fewest_bits(lo.min(v), hi.max(v));
        if shown.is_none_or(|[lo, hi]| (f64::from(c) - f64::from(lo)).abs() <= e && (f64::from(hi) - f64::from(c)).abs() <= e) {
            v = c;
        }
    }
    // It decodes to v everywhere, and the shown voxels (all finite) farthest
    // from v are their smallest and largest ([`within`]'s test, there).
    let e = f64::from(max_error);
    let holds = shown.is_none_or(|[lo, hi]| (f64::from(v) - f64::from(lo)).abs() <= e && (f64::from(hi) - f64::from(v)).abs() <= e);
    holds.then_some(Choice { format: Format::Constant, range: [v, v], bytes: Vec::new() })
}

/// [`cheapest`] among the ranged formats (the constant does not hold), of
/// `values` whose [`range_of`] is `range`; `bc7`: the brick channel's BC7
/// candidate, when it was encoded with others ([`bc7_candidates`]).
#[allow(clippy::too_many_arguments)]
fn cheapest_ranged(values: &Brick, range: [f32; 2], mask: &[u64; 8], max_error: f32, quality: Quality, disk: Option<Optimize>, mut bc7: Option<Vec<u8>>) -> Choice {
    // Texels (and a ranged format's range) moved to the coarsest grid within the bound.
    let snap = |format: Format, bytes: Vec<u8>, range: [f32; 2]| match disk {
        Some(o) => {
            let coder = if o == Optimize::Disk { crate::snap::Coder::Context } else { crate::snap::Coder::Zstd };
            crate::snap::coarsest(format, values, range, mask, max_error, coder).unwrap_or((bytes, range))
        }
        None => (bytes, range),
    };
    // Smallest file: every format within the bound, the one of fewest compressed bytes (the first of equals).
    let mut smallest: Option<(usize, Choice)> = None;
    for format in Format::BY_COST.into_iter().filter(|&f| f != Format::F32 && f != Format::Constant) {
        let bytes = match format {
            Format::Bc7 => bc7.take().unwrap_or_else(|| encode_one(format, quality, values, range, mask)),
            _ => encode_one(format, quality, values, range, mask),
        };
        if within(values, &decode_one(format, &bytes, range), mask, max_error) {
            let (bytes, range) = snap(format, bytes, range);
            let choice = Choice { format, range, bytes };
            if disk != Some(Optimize::Disk) {
                return choice;
            }
            let cost = vdbcook_vpak::coding::brick_cost(&single_plane(format), &choice.bytes);
            if smallest.as_ref().is_none_or(|(c, _)| cost < *c) {
                smallest = Some((cost, choice));
            }
        }
    }
    if let Some((_, c)) = smallest {
        return c;
    }
    // Exact, NaN and ±∞ included.
    let (bytes, range) = snap(Format::F32, encode_one(Format::F32, quality, values, range, mask), range);
    Choice { format: Format::F32, range, bytes }
}

/// Brick channels whose BC7 candidates go to intel_tex_2 in one call: its
/// kernels work across the blocks of a row (16 lanes with AVX-512), which a
/// brick's eight blocks at most half fill.
const BC7_BATCH: usize = 16;

/// A brick channel being chosen for: its values, their [`range_of`] and the voxels shown.
#[derive(Clone, Copy)]
struct Item<'b> {
    values: &'b Brick,
    range: [f32; 2],
    mask: [u64; 8],
}

/// The BC7 candidates ([`encode_one`]) of `items`, one after the other.
fn bc7_candidates(quality: Quality, items: &[Item]) -> Vec<u8> {
    let lv: Vec<Vec<[u8; crate::BRICK_VOXELS]>> = items.iter().map(|i| vec![quantise(i.values, i.range)]).collect();
    let masks: Vec<[u64; 8]> = items.iter().map(|i| i.mask).collect();
    let mut out = vec![0u8; items.len() * single_plane(Format::Bc7).brick_bytes()];
    bc::encode_bc7_shown(quality, 4, &bc7_texels(&lv, 4), Some(&masks), &mut out);
    out
}

/// Every brick channel's choice, in order (brick channel `i · channels + c`),
/// its texels or blocks appended to one store per channel and format as they
/// are chosen (under a spill policy: see `vdbcook_grid::spill`), so that a
/// cook holds the chosen bytes once, out of memory past the policy's size.
/// The per-brick tables (13 bytes a brick channel) are stores too: they
/// grow with the segment.
pub struct Choices {
    channels: usize,
    /// Per brick channel: its format's code, its range, and its place among
    /// the bricks of its channel that chose that format.
    pub(crate) formats: Store<u8>,
    pub(crate) ranges: Store<[f32; 2]>,
    pub(crate) at: Store<u32>,
    /// Per (channel, format): the chosen bytes, and how many chose it.
    stores: Vec<(usize, Format, Store<u8>, u32)>,
    spill: Option<SpillPolicy>,
}

/// A brick channel's format and range, and its place among the bricks of
/// its channel that chose that format.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pick {
    pub format: Format,
    /// The plane brick's range (`[v, v]` for a constant v).
    pub range: [f32; 2],
    pub at: u32,
}

/// Bricks chosen in parallel before their bytes are stored.
const CHOICE_CHUNK: usize = 1024;

impl Choices {
    pub fn new(channels: usize, spill: Option<SpillPolicy>) -> Choices {
        let (formats, ranges, at) = (Store::with_policy(spill.clone()), Store::with_policy(spill.clone()), Store::with_policy(spill.clone()));
        Choices { channels: channels.max(1), formats, ranges, at, stores: Vec::new(), spill }
    }

    /// Brick channels chosen for.
    pub fn len(&self) -> usize {
        self.formats.len()
    }

    pub fn is_empty(&self) -> bool {
        self.formats.is_empty()
    }

    /// Brick channel `j`'s choice.
    pub fn pick(&self, j: usize) -> Option<Pick> {
        let format = Format::from_code(u32::from(*self.formats.get(j)?))?;
        Some(Pick { format, range: *self.ranges.get(j)?, at: *self.at.get(j)? })
    }

    /// Appends [`cheapest`] for every channel of every brick of `bricks`
    /// (`masks[i]`: the voxels brick i shows), chosen in parallel a chunk
    /// at a time; `progress(n)` after each `n` bricks.
    #[allow(clippy::too_many_arguments)]
    pub fn choose(&mut self, bricks: Bricks, masks: &[[u64; 8]], max_error: f32, quality: Quality, disk: Option<Optimize>, progress: &(dyn Fn(usize) + Sync)) -> Result<(), StoreError> {
        for first in (0..bricks.len()).step_by(CHOICE_CHUNK) {
            let ids = first..(first + CHOICE_CHUNK).min(bricks.len());
            // Each brick channel with the range the pool recorded as it was made.
            let items: Vec<Item> = ids
                .clone()
                .flat_map(|i| {
                    let mask = masks.get(i).copied().unwrap_or([u64::MAX; 8]);
                    (0..bricks.channels()).filter_map(move |c| Some(Item { values: bricks.try_get(i, c)?, range: bricks.range(i, c), mask }))
                })
                .collect();
            // Constants first; the others' BC7 candidates (the next format
            // tried) encoded a batch at a time, then the rest brick by brick.
            let constant: Vec<Option<Choice>> = items.par_iter().map(|i| constant_within(i.values, &i.mask, max_error, disk.is_some())).collect();
            let ranged: Vec<usize> = (0..items.len()).filter(|&j| constant[j].is_none()).collect();
            let bb = single_plane(Format::Bc7).brick_bytes();
            let encoded: Vec<Vec<u8>> = ranged.par_chunks(BC7_BATCH).map(|js| bc7_candidates(quality, &js.iter().map(|&j| items[j]).collect::<Vec<_>>())).collect();
            let mut bc7: Vec<Option<Vec<u8>>> = vec![None; items.len()];
            for (js, blocks) in ranged.chunks(BC7_BATCH).zip(&encoded) {
                for (&j, b) in js.iter().zip(blocks.chunks_exact(bb)) {
                    bc7[j] = Some(b.to_vec());
                }
            }
            let chunk: Vec<Choice> =
                items.par_iter().zip(constant).zip(bc7).map(|((i, constant), bc7)| constant.unwrap_or_else(|| cheapest_ranged(i.values, i.range, &i.mask, max_error, quality, disk, bc7))).collect();
            progress(ids.len());
            for choice in chunk {
                self.push(choice)?;
            }
        }
        Ok(())
    }

    /// Appends the next brick channel's choice.
    pub fn push(&mut self, choice: Choice) -> Result<(), StoreError> {
        let c = self.len() % self.channels;
        let k = match self.stores.iter().position(|s| s.0 == c && s.1 == choice.format) {
            Some(k) => k,
            None => {
                self.stores.push((c, choice.format, Store::with_policy(self.spill.clone()), 0));
                self.stores.len() - 1
            }
        };
        let (_, _, store, count) = &mut self.stores[k];
        store.extend_from_slice(&choice.bytes, "the chosen bricks")?;
        self.formats.push(choice.format.code() as u8, "the chosen formats")?;
        self.ranges.push(choice.range, "the chosen ranges")?;
        self.at.push(*count, "the chosen bricks' places")?;
        *count += 1;
        Ok(())
    }

    /// The texels or blocks of brick channel `j`.
    pub fn bytes(&self, j: usize) -> &[u8] {
        let Some(p) = self.pick(j) else { return &[] };
        let bb = single_plane(p.format).brick_bytes();
        let at = p.at as usize * bb;
        self.stores.iter().find(|s| s.0 == j % self.channels && s.1 == p.format).and_then(|s| s.2.get(at..at + bb)).unwrap_or(&[])
    }

    /// The bytes of channel `c`'s bricks that chose `format`, taken out.
    pub(crate) fn take_store(&mut self, c: usize, format: Format) -> Store<u8> {
        self.stores.iter_mut().find(|s| s.0 == c && s.1 == format).map(|s| std::mem::take(&mut s.2)).unwrap_or_default()
    }
}
