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
/// bricks that chose the plane's format (`at[i]`: brick i's place among
/// them, or `u32::MAX`).
enum PlaneData {
    Kept(Store<u8>),
    OnDemand,
    Chosen { bytes: Store<u8>, at: Vec<u32> },
}

/// Every plane of every brick of a pool (`channels` [`Brick`]s per brick),
/// with each brick's channel ranges.
pub struct Encoded<'a> {
    pub specs: Vec<PlaneSpec>,
    bricks: Bricks<'a>,
    channels: usize,
    /// (min, max) per brick per channel.
    ranges: Vec<[f32; 2]>,
    planes: Vec<PlaneData>,
    /// Per brick per channel, true when no reader samples the channel in the
    /// brick (a channel at its own voxel size is absent from the levels of
    /// other channels): a plane whose channels are all absent from a brick
    /// gives it one canonical encoding, made once.
    absent: Option<Vec<bool>>,
}

/// Bricks per parallel work item of the block encoders.
const CHUNK: usize = 256;

impl Encoded<'_> {
    /// Bytes of its per-brick tables (ranges, absent channels), beside its planes' stores.
    pub fn table_bytes(&self) -> u64 {
        (self.ranges.capacity() * std::mem::size_of::<[f32; 2]>() + self.absent.as_ref().map_or(0, Vec::capacity)) as u64
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
        let mut e = Encoded { specs, bricks, channels, ranges, planes: Vec::new(), absent: absent.filter(|a| a.len() == n * channels) };
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
            PlaneData::Chosen { bytes, at } => match at[i] {
                u32::MAX => return false,
                k => out.copy_from_slice(&bytes[k as usize * bb..(k as usize + 1) * bb]),
            },
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
            Some(PlaneData::Chosen { at, .. }) => at.get(i).is_some_and(|&k| k != u32::MAX),
            Some(_) => i < self.len(),
            None => false,
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
    /// Per-brick formats: `choices[i · channels + c]` is channel c of brick
    /// i ([`cheapest`]); each channel is stored in one plane of its own per
    /// format its bricks chose, in [`Format::BY_COST`] order.  Bricks not
    /// `used` are in no plane.
    pub fn from_choices(bricks: Bricks<'a>, mut choices: Choices, used: &[bool]) -> Encoded<'a> {
        let (channels, n) = (bricks.channels(), bricks.len());
        let ranges = choices.picks.iter().map(|p| p.range).collect();
        let (mut specs, mut planes) = (Vec::new(), Vec::new());
        for c in 0..channels {
            for format in Format::BY_COST {
                let pick = |i: usize| choices.picks[i * channels + c];
                let members: Vec<usize> = (0..n).filter(|&i| used.get(i).copied().unwrap_or(true) && pick(i).format == format).collect();
                if members.is_empty() {
                    continue;
                }
                let mut at = vec![u32::MAX; n];
                for &i in &members {
                    at[i] = pick(i).at;
                }
                specs.push(PlaneSpec { plane: single_plane(format), channels: vec![c] });
                planes.push(PlaneData::Chosen { bytes: choices.take_store(c, format), at });
            }
        }
        Encoded { specs, bricks, channels, ranges, planes, absent: None }
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
