//! The planes of a brick pool, encoded: block formats at once and in
//! parallel, uncompressed ones when asked for, per-brick formats from their
//! choices.

use crate::texels::{bc7_texels, encode_texels, levels, quantise, range_of, round_trip};
use crate::{bc, single_plane, Brick, BrickSource, Bricks, Choices, Format, PlaneSpec, Quality, BRICK_VOXELS, MAX_BRICK_BYTES};
use rayon::prelude::*;
use vdbcook_grid::spill::{SpillPolicy, Store, StoreError};

/// The encoded bricks of one plane: kept (block formats, whose encoders are
/// slow), made from the pool whenever asked for (uncompressed formats, so
/// no copy of the pool is kept), or, with per-brick formats, kept for the
/// bricks that chose the plane's format (in [`Chosen`]'s order).
enum PlaneData {
    Kept(Store<u8>),
    OnDemand,
    Chosen(Store<u8>),
}

/// With per-brick formats, per brick channel (`i · channels + c`): the code
/// of the format chosen ([`NOT_STORED`]: the brick is in no plane), and its
/// place among the bricks of its channel that chose it. One table for all
/// the planes, in stores: it grows with the segment.
struct Chosen {
    formats: Store<u8>,
    at: Store<u32>,
}

/// [`Chosen`]'s format code of a brick no plane holds.
const NOT_STORED: u8 = u8::MAX;

/// Every plane of every brick of a pool (`channels` [`Brick`]s per brick),
/// with each brick's channel ranges.
pub struct Encoded<'a> {
    pub specs: Vec<PlaneSpec>,
    bricks: Bricks<'a>,
    channels: usize,
    /// (min, max) per brick per channel.
    ranges: Store<[f32; 2]>,
    planes: Vec<PlaneData>,
    chosen: Option<Chosen>,
    /// Per brick per channel, true when no reader samples the channel in the
    /// brick (a channel at its own voxel size is absent from the levels of
    /// other channels): a plane whose channels are all absent from a brick
    /// gives it one canonical encoding, made once.
    absent: Option<Vec<bool>>,
}

/// Bricks per parallel work item of the block encoders.
const CHUNK: usize = 256;

impl Encoded<'_> {
    /// Bytes of its per-brick tables (ranges, absent channels) beside its
    /// stores, which a spill policy counts itself.
    pub fn table_bytes(&self) -> u64 {
        let ranges = match self.ranges.policy() {
            Some(_) => 0,
            None => self.ranges.capacity() * std::mem::size_of::<[f32; 2]>(),
        };
        (ranges + self.absent.as_ref().map_or(0, Vec::capacity)) as u64
    }
}

impl<'a> Encoded<'a> {
    /// Encodes the block planes now, in parallel (`progress(n)` after each
    /// chunk of `n` bricks of a plane); uncompressed planes are made when
    /// asked for.  `masks` (512 bits per brick) says which voxels count for
    /// the encoders that can use it (BC4): readers take the others from the
    /// background.
    pub fn new(specs: Vec<PlaneSpec>, quality: Quality, bricks: &'a [Brick], channels: usize, masks: Option<&[[u64; 8]]>, progress: &(dyn Fn(usize) + Sync)) -> Encoded<'a> {
        let in_memory = |len: usize| Ok::<_, std::convert::Infallible>(Store::from(vec![0u8; len]));
        match Self::encode(specs, quality, Bricks::dense(bricks, channels), masks, None, &in_memory, progress) {
            Ok(e) => e,
            Err(never) => match never {},
        }
    }

    /// [`Encoded::new`], told which channels of which bricks no reader
    /// samples (`absent[i · channels + c]`): a block plane encodes one brick
    /// of its channels' backgrounds for all the bricks from which every
    /// channel of the plane is absent, and deduplication finds them equal
    /// without hashing their texels.
    /// Block textures go under `spill` (see `vdbcook_grid::spill`); a
    /// texture that fits neither memory nor the spill file's disk is the error.
    pub fn with_absent(
        specs: Vec<PlaneSpec>,
        quality: Quality,
        bricks: Bricks<'a>,
        masks: Option<&[[u64; 8]]>,
        absent: Option<Vec<bool>>,
        spill: Option<&SpillPolicy>,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Encoded<'a>, StoreError> {
        let texture = |len: usize| {
            let mut s = Store::with_policy(spill.cloned());
            s.extend_zeroed(len, "a block texture")?;
            s.advise_huge_pages();
            Ok(s)
        };
        Self::encode(specs, quality, bricks, masks, absent, &texture, progress)
    }

    /// The encoding of [`Encoded::with_absent`], each block texture's
    /// `len` zeroed bytes from `texture(len)`.
    fn encode<E>(
        specs: Vec<PlaneSpec>,
        quality: Quality,
        bricks: Bricks<'a>,
        masks: Option<&[[u64; 8]]>,
        absent: Option<Vec<bool>>,
        texture: &dyn Fn(usize) -> Result<Store<u8>, E>,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Encoded<'a>, E> {
        let channels = bricks.channels();
        let n = bricks.len();
        // A constant brick held once has one range, taken once.
        let constant_ranges: Vec<[f32; 2]> = bricks.constants().iter().map(range_of).collect();
        let ranges: Vec<[f32; 2]> = (0..n * channels)
            .into_par_iter()
            .map(|j| match bricks.constant_of(j / channels, j % channels) {
                Some(k) => constant_ranges[k],
                None => bricks.range(j / channels, j % channels),
            })
            .collect();
        let mut e = Encoded { specs, bricks, channels, ranges: ranges.into(), planes: Vec::new(), chosen: None, absent: absent.filter(|a| a.len() == n * channels) };
        for p in 0..e.specs.len() {
            let spec = &e.specs[p];
            if !spec.plane.format.is_block() {
                progress(n);
                e.planes.push(PlaneData::OnDemand);
                continue;
            }
            let bb = spec.plane.brick_bytes();
            let mut data = texture(n * bb)?;
            // The canonical encoding of an absent brick: the first one's, made without a mask.
            let canonical = (0..n).find(|&i| e.plane_absent(p, i)).map(|i| {
                let mut out = vec![0u8; bb];
                e.encode_block(spec, quality, &[i], None, &mut out);
                out
            });
            data.par_chunks_mut(CHUNK * bb).enumerate().for_each(|(k, out)| {
                let first = k * CHUNK;
                let count = out.len() / bb;
                let todo: Vec<usize> = (first..first + count).filter(|&i| !e.plane_absent(p, i)).collect();
                if todo.len() == count {
                    e.encode_block(spec, quality, &todo, masks.and_then(|m| m.get(first..first + count)), out);
                } else {
                    let todo_masks: Option<Vec<[u64; 8]>> = masks.map(|m| todo.iter().map(|&i| m.get(i).copied().unwrap_or([u64::MAX; 8])).collect());
                    let mut buf = vec![0u8; todo.len() * bb];
                    e.encode_block(spec, quality, &todo, todo_masks.as_deref(), &mut buf);
                    for (j, &i) in todo.iter().enumerate() {
                        out[(i - first) * bb..(i - first + 1) * bb].copy_from_slice(&buf[j * bb..(j + 1) * bb]);
                    }
                    for (i, o) in out.chunks_exact_mut(bb).enumerate() {
                        if let (true, Some(c)) = (e.plane_absent(p, first + i), &canonical) {
                            o.copy_from_slice(c);
                        }
                    }
                }
                progress(count);
            });
            e.planes.push(PlaneData::Kept(data));
        }
        Ok(e)
    }

    /// Encodes `bricks` in the block plane `spec` into `out`, one after the other.
    fn encode_block(&self, spec: &PlaneSpec, quality: Quality, bricks: &[usize], masks: Option<&[[u64; 8]]>, out: &mut [u8]) {
        let slot = |b: usize, c: usize| (self.bricks.get(b, c), self.ranges[b * self.channels + c]);
        match spec.plane.format {
            Format::Bc4 => {
                let c = spec.channels[0];
                let lv: Vec<Brick> = bricks.iter().map(|&b| levels(slot(b, c).0, slot(b, c).1, 255.0)).collect();
                bc::encode_bc4(quality, &lv, masks, out);
            }
            _ => {
                let lv: Vec<Vec<[u8; BRICK_VOXELS]>> = bricks.iter().map(|&b| spec.channels.iter().map(|&c| quantise(slot(b, c).0, slot(b, c).1)).collect()).collect();
                let zpt = spec.plane.z_per_texel as usize;
                bc::encode_bc7_shown(quality, zpt, &bc7_texels(&lv, zpt), masks, out);
            }
        }
    }

    /// True when every channel of plane `p` is absent from brick `i` (see [`Encoded::with_absent`]).
    pub fn plane_absent(&self, p: usize, i: usize) -> bool {
        match (&self.absent, self.specs.get(p)) {
            (Some(a), Some(spec)) => spec.channels.iter().all(|&c| a.get(i * self.channels + c).copied().unwrap_or(false)),
            _ => false,
        }
    }

    /// Bricks.
    pub fn len(&self) -> usize {
        self.bricks.len()
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
            PlaneData::Chosen(bytes) => {
                let Some(k) = self.chosen_at(p, i) else { return false };
                out.copy_from_slice(&bytes[k * bb..(k + 1) * bb]);
            }
            PlaneData::OnDemand => {
                let slots: Vec<(&Brick, [f32; 2])> = spec.channels.iter().map(|&c| (self.bricks.get(i, c), self.range(i, c))).collect();
                encode_texels(&spec.plane, &slots, out);
            }
        }
        true
    }

    /// True when plane `p` stores brick `i` (with per-brick formats, the
    /// planes of the formats it did not choose do not).
    pub fn holds(&self, p: usize, i: usize) -> bool {
        match self.planes.get(p) {
            Some(PlaneData::Chosen(_)) => self.chosen_at(p, i).is_some(),
            Some(_) => i < self.len(),
            None => false,
        }
    }

    /// With per-brick formats, brick `i`'s place among the bricks of plane
    /// `p` (one channel, one format), if it chose that plane.
    fn chosen_at(&self, p: usize, i: usize) -> Option<usize> {
        let (chosen, spec) = (self.chosen.as_ref()?, self.specs.get(p)?);
        let j = i * self.channels + *spec.channels.first()?;
        (*chosen.formats.get(j)? == spec.plane.format.code() as u8).then(|| chosen.at.get(j).map(|&k| k as usize)).flatten()
    }

    /// The families of planes: each brick is in at most one plane of a
    /// family.  With per-brick formats, a channel's planes (one per format
    /// its bricks chose, in spec order); otherwise each plane alone.
    pub fn families(&self) -> Vec<Vec<usize>> {
        match self.chosen {
            Some(_) => (0..self.channels).map(|c| (0..self.specs.len()).filter(|&p| self.specs[p].channels == [c]).collect()).filter(|f: &Vec<usize>| !f.is_empty()).collect(),
            None => (0..self.specs.len()).map(|p| vec![p]).collect(),
        }
    }

    /// Brick `i` decoded back to values, one [`Brick`] per channel.
    pub fn decode(&self, i: usize) -> Option<Vec<Brick>> {
        self.decode_wanted(i, &[]).map(|d| d.into_iter().map(|b| b.unwrap_or([0.0; BRICK_VOXELS])).collect())
    }

    /// [`Encoded::decode`] of the channels `c` with `want[c]` (every
    /// channel when `want` is empty); the others are `None` (not made: a
    /// channel stored at another level is not wanted in most bricks).
    pub fn decode_wanted(&self, i: usize, want: &[bool]) -> Option<Vec<Option<Brick>>> {
        let mut out: Vec<Option<Brick>> = vec![None; self.channels];
        let mut buf = Vec::new();
        for (p, spec) in self.specs.iter().enumerate() {
            if !self.holds(p, i) || !(want.is_empty() || spec.channels.iter().any(|&c| want.get(c).copied().unwrap_or(false))) {
                continue;
            }
            // Encoded on demand: decoded value by value, without the texels.
            if matches!(self.planes.get(p), Some(PlaneData::OnDemand))
                && i < self.len()
                && spec.channels.iter().all(|&c| round_trip(spec.plane.format, self.bricks.get(i, c), self.range(i, c), out[c].insert([0.0; BRICK_VOXELS])))
            {
                continue;
            }
            buf.resize(MAX_BRICK_BYTES, 0);
            let data = &mut buf[..spec.plane.brick_bytes()];
            if !self.write(p, i, data) {
                return None;
            }
            let texels = spec.plane.decode_brick(data);
            for (slot, &c) in spec.channels.iter().enumerate() {
                out[c] = Some(spec.plane.channel_values(&texels, slot as u32 * spec.plane.z_per_texel, self.range(i, c)));
            }
        }
        Some(out)
    }

    /// Plane `p` of the bricks `keep[0]`, `keep[1]`, …, renumbered from 0, for `vdbcook_vpak::layout::pack_atlas`.
    pub fn plane<'s>(&'s self, p: usize, keep: &'s [u32]) -> PlaneBricks<'s> {
        PlaneBricks { encoded: self, plane: p, keep }
    }
}

impl<'a> Encoded<'a> {
    /// Per-brick formats: `choices` holds channel c of brick i at
    /// `i · channels + c` ([`cheapest`]); each channel is stored in one plane
    /// of its own per format its bricks chose, in [`Format::BY_COST`] order.
    /// Bricks not `used` are in no plane.
    pub fn from_choices(bricks: Bricks<'a>, mut choices: Choices, used: &[bool]) -> Encoded<'a> {
        let (channels, n) = (bricks.channels(), bricks.len());
        // Which formats each channel's used bricks chose.
        let mut chose = vec![[false; Format::CODES.len()]; channels];
        for (j, f) in choices.formats.iter_mut().enumerate().take(n * channels) {
            if !used.get(j / channels).copied().unwrap_or(true) {
                *f = NOT_STORED;
            } else if let Some(c) = chose[j % channels].get_mut(usize::from(*f)) {
                *c = true;
            }
        }
        let (mut specs, mut planes) = (Vec::new(), Vec::new());
        for (c, chose) in chose.iter().enumerate() {
            for format in Format::BY_COST.into_iter().filter(|f| chose[f.code() as usize]) {
                specs.push(PlaneSpec { plane: single_plane(format), channels: vec![c] });
                planes.push(PlaneData::Chosen(choices.take_store(c, format)));
            }
        }
        let chosen = Chosen { formats: std::mem::take(&mut choices.formats), at: std::mem::take(&mut choices.at) };
        Encoded { specs, bricks, channels, ranges: std::mem::take(&mut choices.ranges), planes, chosen: Some(chosen), absent: None }
    }
}

/// One plane of a subset of an [`Encoded`] pool.
pub struct PlaneBricks<'s> {
    encoded: &'s Encoded<'s>,
    plane: usize,
    keep: &'s [u32],
}

impl BrickSource for PlaneBricks<'_> {
    fn write_brick(&self, i: usize, out: &mut [u8]) -> bool {
        // The brick's channels (or its kept encoding) read, the atlas written: both may be spilled.
        let channels = self.encoded.specs.get(self.plane).map_or(0, |s| s.channels.len());
        vdbcook_grid::spill::scanned(2 * out.len() + channels * std::mem::size_of::<Brick>());
        self.keep.get(i).is_some_and(|&k| self.encoded.write(self.plane, k as usize, out))
    }
}
