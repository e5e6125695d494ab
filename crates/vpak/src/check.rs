//! The one validator every reader calls: an asset whose checksums hold may
//! still be absurd (a hostile or buggy writer), so before anything is
//! sampled, unpacked or uploaded, the metadata and every section are checked
//! against each other.  The first failure is the error.

use crate::layout::{AtlasLayout, Plane};
use crate::nodes::{l3_node_count, Nodes, L1_WORDS, L2_WORDS};
use crate::{kind, Asset, Error, Metadata};

/// Channels an asset may have (a sanity bound, not a format limit).
pub const MAX_CHANNELS: usize = 256;

/// What a shader needs to read one channel (`shaders/vpak.wgsl`'s `VpakChannel`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GpuChannel {
    /// Plane (texture) of the channel.
    pub plane: u32,
    /// First lane of the channel in the plane's texels.
    pub lane: u32,
    /// log2 of the consecutive z-slices per texel (2 or 1 for BC7 planes, else 0).
    pub z_shift: u32,
    /// Slices one brick takes in the plane (8 >> z_shift).
    pub slices: u32,
    /// Format code of the plane.
    pub format: u32,
    /// Lanes of the plane's texels (1, 2 or 4).
    pub lanes: u32,
    /// 1 when texels are levels over the brick's channel range.
    pub ranged: u32,
    /// The channel's background, as f32 bits.
    pub background: u32,
}

impl GpuChannel {
    /// The eight words, in field order, as a storage buffer holds them.
    pub fn words(&self) -> [u32; 8] {
        [self.plane, self.lane, self.z_shift, self.slices, self.format, self.lanes, self.ranged, self.background]
    }
}

/// A validated asset: its metadata and every section, as slices of the file.
pub struct Checked<'a> {
    pub meta: Metadata,
    pub frames: &'a [u32],
    pub l1: &'a [u32],
    pub l1_entries: &'a [u32],
    pub l2: &'a [u32],
    pub l2_entries: &'a [u32],
    pub l3: &'a [u32],
    pub tiles: &'a [u32],
    /// (min, max) per brick per channel: brick b, channel c at `2 · (b · channels + c)`.
    pub ranges: &'a [f32],
    /// Plane p of atlas a at `p · atlases + a`.
    pub atlases: Vec<&'a [u8]>,
}

fn invalid<T>(what: String) -> Result<T, Error> {
    Err(Error::Invalid(what))
}

impl<'a> Checked<'a> {
    /// Checks everything a reader relies on (section checksums are
    /// [`Asset::verify`]'s job, done by [`Asset::open`]).
    pub fn new(asset: &'a Asset) -> Result<Checked<'a>, Error> {
        let meta = asset.metadata()?;
        let channels = meta.channels.len();
        if channels == 0 || channels > MAX_CHANNELS {
            return invalid(format!("{channels} channels (need 1 to {MAX_CHANNELS})"));
        }
        check_planes(&meta)?;
        check_atlases(&meta)?;
        if meta.index_offset.iter().any(|o| o % 128 != 0) {
            return invalid(format!("index offset {:?} is not a multiple of 128", meta.index_offset));
        }
        if meta.frames.len() != meta.frame_count as usize {
            return invalid(format!("{} frame records for {} frames", meta.frames.len(), meta.frame_count));
        }
        if let Some(f) = meta.frames.iter().position(|f| f.source.is_some_and(|s| s as usize >= meta.sources.len())) {
            return invalid(format!("frame {f} names a source the asset does not list"));
        }
        let frames = asset.u32s(kind::FRAMES)?;
        if frames.len() != meta.frame_count as usize {
            return invalid(format!("{} frames in the frame table, {} in the metadata", frames.len(), meta.frame_count));
        }
        let words = |k: u32, unit: usize, what: &str| -> Result<&'a [u32], Error> {
            let w = asset.u32s(k)?;
            if !w.len().is_multiple_of(unit) {
                return invalid(format!("{what} holds {} words, not a multiple of {unit}", w.len()));
            }
            Ok(w)
        };
        let l1 = words(kind::L1_NODES, L1_WORDS, "l1 nodes")?;
        let l2 = words(kind::L2_NODES, L2_WORDS, "l2 nodes")?;
        let tiles = words(kind::TILES, channels, "tiles")?;
        let l3 = asset.u32s(kind::L3_NODES)?;
        if l3_node_count(l3).is_none() {
            return invalid(format!("l3 nodes: {} words cannot hold the {} nodes the section counts", l3.len(), l3.first().copied().unwrap_or(0)));
        }
        let ranges = asset.f32s(kind::BRICK_RANGES)?;
        let want = u64::from(meta.brick_count) * channels as u64 * 2;
        if ranges.len() as u64 != want {
            return invalid(format!("{} brick range values, {} bricks of {channels} channels need {want}", ranges.len(), meta.brick_count));
        }
        let mut atlases = Vec::with_capacity(meta.planes.len() * meta.atlases.len());
        for (p, plane) in meta.planes.iter().enumerate() {
            for (a, info) in meta.atlases.iter().enumerate() {
                let bytes = asset.section(kind::ATLAS, meta.atlas_section(p, a))?;
                let layout = AtlasLayout { plane: *plane, atlas: *info };
                if bytes.len() != layout.byte_len() {
                    return invalid(format!("plane {p} of atlas {a}: {} bytes, its size needs {}", bytes.len(), layout.byte_len()));
                }
                atlases.push(bytes);
            }
        }
        Ok(Checked { frames, l1, l1_entries: asset.u32s(kind::L1_ENTRIES)?, l2, l2_entries: asset.u32s(kind::L2_ENTRIES)?, l3, tiles, ranges, atlases, meta })
    }

    /// The node arrays, copied.
    pub fn nodes(&self) -> Nodes {
        Nodes {
            offset: self.meta.index_offset,
            channels: self.meta.channels.len(),
            frames: self.frames.to_vec(),
            l1: self.l1.to_vec(),
            l1_entries: self.l1_entries.to_vec(),
            l2: self.l2.to_vec(),
            l2_entries: self.l2_entries.to_vec(),
            l3: self.l3.to_vec(),
            tiles: self.tiles.to_vec(),
        }
    }

    /// Plane `plane`'s texture of atlas `atlas`, with its layout.
    pub fn atlas(&self, plane: usize, atlas: usize) -> Option<(AtlasLayout, &'a [u8])> {
        let layout = AtlasLayout { plane: *self.meta.planes.get(plane)?, atlas: *self.meta.atlases.get(atlas)? };
        Some((layout, self.atlases.get(self.meta.atlas_section(plane, atlas) as usize)?))
    }

    /// The atlas holding brick `b`, and its local index there.
    pub fn brick_atlas(&self, b: u32) -> Option<(usize, u32)> {
        let a = self.meta.atlases.iter().position(|a| b >= a.first_brick && b - a.first_brick < a.count)?;
        Some((a, b - self.meta.atlases[a].first_brick))
    }

    /// Brick `b`'s range for channel `c`.
    pub fn range(&self, b: u32, c: usize) -> [f32; 2] {
        let i = 2 * (b as usize * self.meta.channels.len() + c);
        [self.ranges.get(i).copied().unwrap_or(0.0), self.ranges.get(i + 1).copied().unwrap_or(0.0)]
    }

    /// Every channel's values of brick `b` (leaf order), decoded plane by plane.
    pub fn decode_brick(&self, b: u32) -> Option<Vec<[f32; crate::BRICK_VOXELS]>> {
        let (a, local) = self.brick_atlas(b)?;
        let texels: Vec<Vec<[f32; 4]>> = (0..self.meta.planes.len())
            .map(|p| {
                let (layout, bytes) = self.atlas(p, a)?;
                Some(layout.plane.decode_brick(&crate::layout::unpack_brick(&layout, bytes, local)?))
            })
            .collect::<Option<_>>()?;
        Some(self.meta.channels.iter().enumerate().map(|(c, ch)| self.meta.planes[ch.plane as usize].channel_values(&texels[ch.plane as usize], ch.lane, self.range(b, c))).collect())
    }

    /// The channel table a shader reads.
    pub fn gpu_channels(&self) -> Vec<GpuChannel> {
        self.meta
            .channels
            .iter()
            .map(|c| {
                let p: Plane = self.meta.planes[c.plane as usize];
                GpuChannel {
                    plane: c.plane,
                    lane: c.lane,
                    z_shift: p.z_per_texel.max(1).trailing_zeros(),
                    slices: p.slices_per_brick(),
                    format: p.format.code(),
                    lanes: p.lanes,
                    ranged: u32::from(p.format.is_ranged()),
                    background: c.background.to_bits(),
                }
            })
            .collect()
    }
}

/// Every plane is one the format defines; every channel sits in a plane, on
/// lanes no other channel uses; every plane holds some channel.
fn check_planes(meta: &Metadata) -> Result<(), Error> {
    if meta.planes.is_empty() || meta.planes.len() > MAX_CHANNELS {
        return invalid(format!("{} planes (need 1 to {MAX_CHANNELS})", meta.planes.len()));
    }
    if let Some((p, plane)) = meta.planes.iter().enumerate().find(|(_, p)| !p.is_valid()) {
        return invalid(format!("plane {p}: {} with {} lanes and {} z-slices per texel is not a plane the format defines", plane.format.name(), plane.lanes, plane.z_per_texel));
    }
    let mut used = vec![0u32; meta.planes.len()];
    for (c, ch) in meta.channels.iter().enumerate() {
        let Some(plane) = meta.planes.get(ch.plane as usize) else {
            return invalid(format!("channel {c} ({}) is in plane {}, the asset has {}", ch.name, ch.plane, meta.planes.len()));
        };
        let z = plane.z_per_texel;
        if !ch.lane.is_multiple_of(z) || ch.lane.saturating_add(z) > plane.lanes {
            return invalid(format!("channel {c} ({}) starts at lane {} of a plane of {} lanes, {z} per channel", ch.name, ch.lane, plane.lanes));
        }
        let bits = ((1u32 << z) - 1) << ch.lane;
        if used[ch.plane as usize] & bits != 0 {
            return invalid(format!("channel {c} ({}) shares lanes of plane {} with another channel", ch.name, ch.plane));
        }
        used[ch.plane as usize] |= bits;
    }
    if let Some(p) = used.iter().position(|&u| u == 0) {
        return invalid(format!("plane {p} holds no channel"));
    }
    Ok(())
}

/// Atlas records describe consecutive runs of every brick, and every atlas
/// but the last has the first one's shape, the last holding every position
/// that shape gives its bricks (samplers place bricks with the first shape).
fn check_atlases(meta: &Metadata) -> Result<(), Error> {
    let first = meta.atlases.first();
    let mut next_brick = 0u64;
    for (i, a) in meta.atlases.iter().enumerate() {
        let bad = |what: String| invalid(format!("atlas {i}: {what}"));
        let [bx, by, bz] = a.bricks.map(u64::from);
        let capacity = u128::from(bx) * u128::from(by) * u128::from(bz);
        if bx == 0 || by == 0 || bz == 0 || u128::from(a.count) > capacity {
            return bad(format!("{:?} bricks cannot hold {}", a.bricks, a.count));
        }
        if let Some(f) = first {
            let [fx, fy, _] = f.bricks.map(|b| u64::from(b).max(1));
            let n = u64::from(a.count);
            let need = [n.min(fx), n.div_ceil(fx).min(fy), n.div_ceil(fx * fy)];
            // The last atlas must put brick i where the first atlas's shape does
            // (samplers use that shape throughout): one short row, or rows as
            // wide as the first's, and layers as tall when there are several.
            let same_places = (n <= bx && n <= fx) || (bx == fx && (n.div_ceil(fx) <= by.min(fy) || by == fy));
            let fits = if i + 1 < meta.atlases.len() { a.bricks == f.bricks && u128::from(a.count) == capacity } else { same_places && (0..3).all(|k| u64::from(a.bricks[k]) >= need[k]) };
            if !fits || u64::from(a.first_brick) != next_brick {
                return bad("its layout does not follow the first atlas's".into());
            }
        }
        // Texture sizes must be representable (a sampler computes texel coordinates in u32).
        let slices = u64::from(meta.max_slices());
        if bx * 8 > u64::from(u32::MAX) || by * 8 > u64::from(u32::MAX) || bz * slices > u64::from(u32::MAX) {
            return bad(format!("{:?} bricks is too large a texture", a.bricks));
        }
        next_brick += u64::from(a.count);
    }
    if next_brick != u64::from(meta.brick_count) {
        return invalid(format!("the atlases hold {next_brick} bricks, the metadata counts {}", meta.brick_count));
    }
    Ok(())
}
