//! The one validator every reader calls: an asset whose checksums hold may
//! still be absurd (a hostile or buggy writer), so before anything is
//! sampled, unpacked or uploaded, the metadata and every section are checked
//! against each other.  The first failure is the error.

use crate::layout::{AtlasLayout, Format, PlaneInfo};
use crate::nodes::{l1_records, l3_node_count, Nodes, L2_WORDS};
use crate::{kind, Asset, Error, Metadata, CHOICE_SHIFT, MAX_ALTERNATES, MAX_LEVELS, PLANE_BRICK_MASK};

/// Channels an asset may have (a sanity bound, not a format limit).
pub const MAX_CHANNELS: usize = 256;

/// What a shader needs to read one channel (`shaders/vpak.wgsl`'s
/// `VpakChannel`): its place in its plane, and the plane's brick table,
/// ranges and atlases, as offsets into the buffers [`Checked::gpu_tables`]
/// and [`Checked::gpu_ranges`] make and the texture slots (atlas sections).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GpuChannel {
    /// Texture slot (atlas section index) of the plane's first atlas.
    pub slot: u32,
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
    /// First word of the plane's brick table in the tables buffer, or `u32::MAX` (no table).
    pub table: u32,
    /// First (min, max) pair of the plane in the ranges buffer.
    pub range_base: u32,
    /// Pairs per plane brick (the plane's channel slots).
    pub range_slots: u32,
    /// The plane.
    pub plane: u32,
    /// The plane's first atlas: size in bricks (x, y, z) and bricks per full atlas.
    pub atlas_bricks: [u32; 4],
    /// The plane's last atlas: its number and its own size in bricks along x and y.
    pub last_atlas: [u32; 3],
    /// For a channel stored in several planes: the record of its first
    /// alternate plane (records past the channels'; alternate j at
    /// `alternates + j − 1`), and `table` is its channel table; else `u32::MAX`.
    pub alternates: u32,
}

/// Words of one [`GpuChannel`].
pub const GPU_CHANNEL_WORDS: usize = 20;

impl GpuChannel {
    /// The words, in field order, as a storage buffer holds them.
    pub fn words(&self) -> [u32; GPU_CHANNEL_WORDS] {
        let head = [self.slot, self.lane, self.z_shift, self.slices, self.format, self.lanes, self.ranged, self.background, self.table, self.range_base, self.range_slots, self.plane];
        std::array::from_fn(|i| match i {
            0..12 => head[i],
            12..16 => self.atlas_bricks[i - 12],
            16..19 => self.last_atlas[i - 16],
            _ => self.alternates,
        })
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
    /// Per plane, (min, max) per plane brick per channel slot: plane brick k, slot s at `2 · (k · slots + s)`.
    pub ranges: Vec<&'a [f32]>,
    /// Per plane, its brick table (the plane brick of each brick), or `None`:
    /// brick b is plane brick b, unless a channel table addresses the plane.
    pub tables: Vec<Option<&'a [u32]>>,
    /// Per channel, its channel table when it is stored in several planes.
    pub channel_tables: Vec<Option<&'a [u32]>>,
    /// Atlas textures in section order (plane 0's atlases, then plane 1's, …).
    pub atlases: Vec<&'a [u8]>,
}

/// A section's bytes as 4-byte items, without copying.
fn cast<T: bytemuck::Pod>(kind: u32, b: &[u8]) -> Result<&[T], Error> {
    bytemuck::try_cast_slice(b).map_err(|_| Error::Shape { kind, size: b.len(), unit: std::mem::size_of::<T>() })
}

fn invalid<T>(what: String) -> Result<T, Error> {
    Err(Error::Invalid(what))
}

impl<'a> Checked<'a> {
    /// Checks everything a reader relies on (section checksums are
    /// [`Asset::verify`]'s job, done by [`Asset::open`]).
    pub fn new(asset: &'a Asset) -> Result<Checked<'a>, Error> {
        Checked::from_sections(asset.metadata()?, |k, i| asset.section(k, i))
    }

    /// [`Checked::new`] of a body given as its metadata and its sections,
    /// found by (kind, index) (buffers a runtime reader filled, say; each
    /// section of 4-byte items must start at a multiple of 4 bytes).
    pub fn from_sections(meta: Metadata, section: impl Fn(u32, u32) -> Result<&'a [u8], Error>) -> Result<Checked<'a>, Error> {
        let words = |k: u32, i: u32| -> Result<&'a [u32], Error> { cast(k, section(k, i)?) };
        let channels = meta.channels.len();
        if channels == 0 || channels > MAX_CHANNELS {
            return invalid(format!("{channels} channels (need 1 to {MAX_CHANNELS})"));
        }
        check_planes(&meta)?;
        for (p, plane) in meta.planes.iter().enumerate() {
            check_atlases(p, plane)?;
        }
        if meta.index_offset.iter().any(|o| o % 128 != 0) {
            return invalid(format!("index offset {:?} is not a multiple of 128", meta.index_offset));
        }
        if meta.frames.len() != meta.frame_count as usize {
            return invalid(format!("{} frame records for {} frames", meta.frames.len(), meta.frame_count));
        }
        if let Some(f) = meta.frames.iter().position(|f| f.source.is_some_and(|s| s as usize >= meta.sources.len())) {
            return invalid(format!("frame {f} names a source the asset does not list"));
        }
        if meta.levels == 0 || meta.levels > MAX_LEVELS {
            return invalid(format!("{} levels of detail (need 1 to {MAX_LEVELS})", meta.levels));
        }
        let filters = if meta.levels > 1 { channels } else { 0 };
        if meta.level_filters.len() != filters {
            return invalid(format!("{} level filters for {channels} channels and {} levels (need {filters})", meta.level_filters.len(), meta.levels));
        }
        if let Some(f) = meta.frames.iter().position(|f| f.coarse.len() + 1 != meta.levels as usize) {
            return invalid(format!("frame {f} has figures for {} levels, the asset has {}", meta.frames[f].coarse.len() + 1, meta.levels));
        }
        if meta.first_level >= meta.levels {
            return invalid(format!("first stored level {} of {} levels", meta.first_level, meta.levels));
        }
        let stored = meta.levels - meta.first_level;
        let frames = words(kind::FRAMES, 0)?;
        if frames.len() as u64 != u64::from(meta.frame_count) * u64::from(stored) {
            return invalid(format!("{} trees in the frame table, {} frames × {stored} stored levels in the metadata", frames.len(), meta.frame_count));
        }
        let whole = |k: u32, unit: usize, what: &str| -> Result<&'a [u32], Error> {
            let w = words(k, 0)?;
            if !w.len().is_multiple_of(unit) {
                return invalid(format!("{what} holds {} words, not a multiple of {unit}", w.len()));
            }
            Ok(w)
        };
        let l1 = words(kind::L1_NODES, 0)?;
        // L1 nodes differ in size: the array must be whole nodes, and every
        // tree must start at one (samplers read its L from the frame entry).
        let Some(starts) = l1_records(l1) else { return invalid(format!("l1 nodes: {} words are not a sequence of whole L1 nodes", l1.len())) };
        if let Some(t) = frames.iter().position(|f| starts.binary_search(f).is_err()) {
            return invalid(format!("tree {t} of the frame table points at word {} of the l1 nodes, where no node starts", frames[t]));
        }
        let l2 = whole(kind::L2_NODES, L2_WORDS, "l2 nodes")?;
        let tiles = whole(kind::TILES, channels, "tiles")?;
        let l3 = words(kind::L3_NODES, 0)?;
        let Some(l3_nodes) = l3_node_count(l3) else {
            return invalid(format!("l3 nodes: {} words cannot hold the {} nodes the section counts", l3.len(), l3.first().copied().unwrap_or(0)));
        };
        // Every L3 node's brick exists (samplers index tables and ranges with it).
        if let Some(k) = (0..l3_nodes).find(|&k| l3[1 + k * crate::nodes::L3_WORDS] >= meta.brick_count) {
            return invalid(format!("l3 node {k} points at brick {}, the asset has {}", l3[1 + k * crate::nodes::L3_WORDS], meta.brick_count));
        }
        let (mut ranges, mut tables) = (Vec::with_capacity(meta.planes.len()), Vec::with_capacity(meta.planes.len()));
        for (p, info) in meta.planes.iter().enumerate() {
            let r: &[f32] = cast(kind::BRICK_RANGES, section(kind::BRICK_RANGES, p as u32)?)?;
            let want = u64::from(info.bricks) * u64::from(info.range_slots()) * 2;
            if r.len() as u64 != want {
                return invalid(format!("plane {p}: {} brick range values, {} plane bricks of {} slots need {want}", r.len(), info.bricks, info.range_slots()));
            }
            // Samplers compute min + t·(max − min): a range must be ordered.
            if let Some(k) = r.chunks_exact(2).position(|m| m[0].partial_cmp(&m[1]).is_none_or(|o| o == std::cmp::Ordering::Greater)) {
                return invalid(format!("plane {p}: brick range {k} is [{}, {}]", r[2 * k], r[2 * k + 1]));
            }
            ranges.push(r);
            let has_table = meta.plane_has_table(p);
            let table = match words(kind::BRICK_TABLE, p as u32) {
                Err(Error::Missing { .. }) if !has_table => None,
                Ok(_) if !has_table => return invalid(format!("plane {p} has a brick table it must not have (it stores every brick, or a channel table addresses it)")),
                Ok(t) if t.len() as u64 != u64::from(meta.brick_count) => return invalid(format!("plane {p}: a brick table of {} entries for {} bricks", t.len(), meta.brick_count)),
                Ok(t) => match t.iter().position(|&pb| pb >= info.bricks) {
                    Some(b) => return invalid(format!("plane {p}: brick {b} maps to plane brick {}, the plane has {}", t[b], info.bricks)),
                    None => Some(t),
                },
                Err(e) => return Err(e),
            };
            tables.push(table);
            if info.plane.format == Format::Constant {
                if let Some(k) = r.chunks_exact(2).position(|m| m[0] != m[1]) {
                    return invalid(format!("plane {p} is constant, but its brick range {k} is [{}, {}]", r[2 * k], r[2 * k + 1]));
                }
            }
        }
        let mut channel_tables = Vec::with_capacity(channels);
        for (c, ch) in meta.channels.iter().enumerate() {
            let table = match words(kind::CHANNEL_TABLE, c as u32) {
                Err(Error::Missing { .. }) if ch.alternates.is_empty() => None,
                Ok(_) if ch.alternates.is_empty() => return invalid(format!("channel {c} ({}) is in one plane but has a channel table", ch.name)),
                Ok(t) if t.len() as u64 != u64::from(meta.brick_count) => return invalid(format!("channel {c} ({}): a channel table of {} entries for {} bricks", ch.name, t.len(), meta.brick_count)),
                Ok(t) => {
                    let planes = meta.channel_planes(c);
                    let bad = t.iter().position(|&e| planes.get((e >> CHOICE_SHIFT) as usize).is_none_or(|&p| e & PLANE_BRICK_MASK >= meta.planes[p as usize].bricks));
                    if let Some(b) = bad {
                        return invalid(format!("channel {c} ({}): brick {b}'s entry {:#010x} names no plane brick of the channel's {} planes", ch.name, t[b], planes.len()));
                    }
                    Some(t)
                }
                Err(e) => return Err(e),
            };
            channel_tables.push(table);
        }
        let mut atlases = Vec::with_capacity(meta.texture_count());
        for (p, info) in meta.planes.iter().enumerate() {
            for (a, atlas) in info.atlases.iter().enumerate() {
                let bytes = section(kind::ATLAS, meta.atlas_section(p, a))?;
                let layout = AtlasLayout { plane: info.plane, atlas: *atlas };
                if bytes.len() != layout.byte_len() {
                    return invalid(format!("atlas {a} of plane {p}: {} bytes, its size needs {}", bytes.len(), layout.byte_len()));
                }
                atlases.push(bytes);
            }
        }
        Ok(Checked { frames, l1, l1_entries: words(kind::L1_ENTRIES, 0)?, l2, l2_entries: words(kind::L2_ENTRIES, 0)?, l3, tiles, ranges, tables, channel_tables, atlases, meta })
    }

    /// The L1 node of frame `frame` at level `level`.
    pub fn tree(&self, frame: usize, level: u32) -> Option<u32> {
        self.frames.get(self.meta.tree_index(frame, level)?).copied()
    }

    /// Bytes level `level` needs on its own: the node arrays of its trees
    /// (every frame's) and, in every plane, its distinct plane bricks with
    /// their ranges, each counted once (what an engine that loads only this
    /// level uploads; levels share what they have in common, so the levels'
    /// figures add up to more than the asset).
    pub fn level_bytes(&self, level: u32) -> u64 {
        let roots: Vec<u32> = (0..self.meta.frame_count as usize).filter_map(|f| self.tree(f, level)).collect();
        let usage = self.nodes().usage(&roots);
        let mut bytes = usage.tree_bytes(self.meta.channels.len());
        // Every channel's plane bricks (per-brick formats spread a channel over
        // several planes), each counted once, and the channel tables' entries.
        let channels = self.meta.channels.len();
        let mut plane_bricks: Vec<(usize, u32)> = usage.bricks.iter().flat_map(|&b| (0..channels).filter_map(move |c| self.channel_brick(c, b))).collect();
        plane_bricks.sort_unstable();
        plane_bricks.dedup();
        for (p, _) in plane_bricks {
            let info = &self.meta.planes[p];
            bytes += info.plane.brick_bytes() as u64 + 8 * u64::from(info.range_slots());
        }
        let tables = self.channel_tables.iter().filter(|t| t.is_some()).count() as u64;
        bytes + 4 * tables * usage.bricks.len() as u64
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

    /// Atlas `atlas` of plane `plane`, with its layout.
    pub fn atlas(&self, plane: usize, atlas: usize) -> Option<(AtlasLayout, &'a [u8])> {
        let info = self.meta.planes.get(plane)?;
        let layout = AtlasLayout { plane: info.plane, atlas: *info.atlases.get(atlas)? };
        Some((layout, self.atlases.get(self.meta.atlas_section(plane, atlas) as usize)?))
    }

    /// Where channel `c` of brick `b` is stored: the plane, and the plane brick there.
    pub fn channel_brick(&self, c: usize, b: u32) -> Option<(usize, u32)> {
        let ch = self.meta.channels.get(c)?;
        if b >= self.meta.brick_count {
            return None;
        }
        if let Some(t) = self.channel_tables.get(c)? {
            let e = *t.get(b as usize)?;
            let p = match (e >> CHOICE_SHIFT) as usize {
                0 => ch.plane,
                j => *ch.alternates.get(j - 1)?,
            };
            return Some((p as usize, e & PLANE_BRICK_MASK));
        }
        let p = ch.plane as usize;
        match self.tables.get(p)? {
            Some(t) => Some((p, *t.get(b as usize)?)),
            None => Some((p, b)),
        }
    }

    /// Plane `p`'s range of plane brick `pb` in channel slot `slot`.
    pub fn plane_range(&self, p: usize, pb: u32, slot: u32) -> [f32; 2] {
        let (Some(r), Some(info)) = (self.ranges.get(p), self.meta.planes.get(p)) else { return [0.0; 2] };
        let i = 2 * (pb as usize * info.range_slots() as usize + slot as usize);
        [r.get(i).copied().unwrap_or(0.0), r.get(i + 1).copied().unwrap_or(0.0)]
    }

    /// Channel `c`'s first lane in plane `p` (0 in a channel's alternate planes).
    fn lane_in(&self, c: usize, p: usize) -> u32 {
        self.meta.channels.get(c).map_or(0, |ch| if ch.plane as usize == p { ch.lane } else { 0 })
    }

    /// Brick `b`'s range for channel `c`.
    pub fn range(&self, b: u32, c: usize) -> [f32; 2] {
        let Some((p, pb)) = self.channel_brick(c, b) else { return [0.0; 2] };
        let zpt = self.meta.planes.get(p).map_or(1, |i| i.plane.z_per_texel.max(1));
        self.plane_range(p, pb, self.lane_in(c, p) / zpt)
    }

    /// Every channel's values of brick `b` (leaf order), each decoded from its plane brick.
    pub fn decode_brick(&self, b: u32) -> Option<Vec<[f32; crate::BRICK_VOXELS]>> {
        // Each plane holds one plane brick of a brick: decode it once for all its channels.
        let mut texels: Vec<Option<Vec<[f32; 4]>>> = vec![None; self.meta.planes.len()];
        (0..self.meta.channels.len())
            .map(|c| {
                let (p, pb) = self.channel_brick(c, b)?;
                let plane = self.meta.planes.get(p)?.plane;
                if texels[p].is_none() && plane.format != Format::Constant {
                    let (a, local) = self.meta.planes[p].brick_atlas(pb)?;
                    let (layout, bytes) = self.atlas(p, a)?;
                    texels[p] = Some(plane.decode_brick(&crate::layout::unpack_brick(&layout, bytes, local)?));
                }
                Some(plane.channel_values(texels[p].as_deref().unwrap_or(&[]), self.lane_in(c, p), self.range(b, c)))
            })
            .collect()
    }

    /// The brick tables of the planes that have one, then the channel tables,
    /// back to back (what [`GpuChannel::table`] indexes).
    pub fn gpu_tables(&self) -> Vec<u32> {
        self.tables.iter().chain(&self.channel_tables).flatten().flat_map(|t| t.iter().copied()).collect()
    }

    /// Every plane's ranges, back to back (what [`GpuChannel::range_base`] indexes, in pairs).
    pub fn gpu_ranges(&self) -> Vec<f32> {
        self.ranges.iter().flat_map(|r| r.iter().copied()).collect()
    }

    /// The channel table a shader reads ([`Metadata::gpu_channels`]).
    pub fn gpu_channels(&self) -> Vec<GpuChannel> {
        self.meta.gpu_channels()
    }
}

impl Metadata {
    /// The channel table a shader reads: one record per channel, then one
    /// per alternate plane of the channels stored in several planes. Of a
    /// body this metadata describes once it is validated ([`Checked`]: its
    /// brick tables are the planes' [`Metadata::plane_has_table`], its
    /// channel tables the channels' with alternates), which is what
    /// [`Checked::gpu_tables`] and [`Checked::gpu_ranges`] lay out.
    pub fn gpu_channels(&self) -> Vec<GpuChannel> {
        // Per plane: its table's first word, its first range pair, its first texture slot.
        let mut bases = Vec::with_capacity(self.planes.len());
        let (mut table, mut range) = (0u32, 0u32);
        for (p, info) in self.planes.iter().enumerate() {
            let has = self.plane_has_table(p);
            bases.push((if has { table } else { u32::MAX }, range, self.atlas_section(p, 0)));
            table = table.saturating_add(if has { self.brick_count } else { 0 });
            range = range.saturating_add(info.bricks.saturating_mul(info.range_slots()));
        }
        // Channel tables follow the planes' tables.
        let mut channel_table = Vec::with_capacity(self.channels.len());
        for ch in &self.channels {
            let has = !ch.alternates.is_empty();
            channel_table.push(if has { table } else { u32::MAX });
            table = table.saturating_add(if has { self.brick_count } else { 0 });
        }
        let record = |p: usize, lane: u32, background: f32, table: u32, alternates: u32| {
            let info = &self.planes[p];
            let plane = info.plane;
            let (plane_table, range_base, slot) = bases[p];
            let atlas_bricks = info.atlases.first().map_or([1, 1, 1, 1], |a| {
                let [x, y, z] = a.bricks.map(|b| b.max(1));
                [x, y, z, x.saturating_mul(y).saturating_mul(z)]
            });
            let last_atlas = info.atlases.last().map_or([0, 1, 1], |a| [(info.atlases.len() - 1) as u32, a.bricks[0].max(1), a.bricks[1].max(1)]);
            GpuChannel {
                slot,
                lane,
                z_shift: plane.z_per_texel.max(1).trailing_zeros(),
                slices: plane.slices_per_brick(),
                format: plane.format.code(),
                lanes: plane.lanes,
                ranged: u32::from(plane.format.is_ranged()),
                background: background.to_bits(),
                table: if table == u32::MAX { plane_table } else { table },
                range_base,
                range_slots: info.range_slots(),
                plane: p as u32,
                atlas_bricks,
                last_atlas,
                alternates,
            }
        };
        let channels = &self.channels;
        let mut out: Vec<GpuChannel> = Vec::with_capacity(channels.len());
        let mut next = channels.len() as u32;
        for (c, ch) in channels.iter().enumerate() {
            let alternates = if ch.alternates.is_empty() { u32::MAX } else { next };
            next = next.saturating_add(ch.alternates.len() as u32);
            out.push(record(ch.plane as usize, ch.lane, ch.background, channel_table[c], alternates));
        }
        for ch in channels {
            // An alternate's plane brick comes from the channel table.
            out.extend(ch.alternates.iter().map(|&p| GpuChannel { table: u32::MAX, ..record(p as usize, 0, ch.background, u32::MAX, u32::MAX) }));
        }
        out
    }
}

/// Every plane is one the format defines; every channel sits in a plane, on
/// lanes no other channel uses; every plane holds some channel.
fn check_planes(meta: &Metadata) -> Result<(), Error> {
    if meta.planes.is_empty() || meta.planes.len() > MAX_CHANNELS {
        return invalid(format!("{} planes (need 1 to {MAX_CHANNELS})", meta.planes.len()));
    }
    if let Some((p, plane)) = meta.planes.iter().enumerate().map(|(p, i)| (p, i.plane)).find(|(_, p)| !p.is_valid()) {
        return invalid(format!("plane {p}: {} with {} lanes and {} z-slices per texel is not a plane the format defines", plane.format.name(), plane.lanes, plane.z_per_texel));
    }
    // Every brick has a plane brick in every plane.
    if let Some((p, info)) = meta.planes.iter().enumerate().find(|(_, i)| i.bricks > meta.brick_count || (i.bricks == 0) != (meta.brick_count == 0)) {
        return invalid(format!("plane {p} stores {} bricks for the asset's {}", info.bricks, meta.brick_count));
    }
    let mut used = vec![0u32; meta.planes.len()];
    for (c, ch) in meta.channels.iter().enumerate() {
        if !ch.alternates.is_empty() {
            // A channel in several planes has each of them to itself, from lane 0.
            let planes = meta.channel_planes(c);
            if ch.alternates.len() > MAX_ALTERNATES || ch.lane != 0 {
                return invalid(format!("channel {c} ({}) has {} alternate planes and starts at lane {} (at most {MAX_ALTERNATES}, from lane 0)", ch.name, ch.alternates.len(), ch.lane));
            }
            for &p in &planes {
                match used.get_mut(p as usize) {
                    None => return invalid(format!("channel {c} ({}) is in plane {p}, the asset has {}", ch.name, meta.planes.len())),
                    Some(u) if *u != 0 => return invalid(format!("channel {c} ({}) is in several planes, but shares plane {p}", ch.name)),
                    Some(u) => *u = u32::MAX,
                }
            }
            continue;
        }
        let Some(plane) = meta.planes.get(ch.plane as usize).map(|i| i.plane) else {
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

/// Atlas records describe consecutive runs of every plane brick, and every
/// atlas but the last has the first one's shape, the last holding every
/// position that shape gives its bricks (samplers place bricks with the
/// first shape).
fn check_atlases(p: usize, plane: &PlaneInfo) -> Result<(), Error> {
    if plane.plane.format == Format::Constant {
        if !plane.atlases.is_empty() {
            return invalid(format!("plane {p} is constant but has {} atlases", plane.atlases.len()));
        }
        return Ok(());
    }
    let first = plane.atlases.first();
    let mut next_brick = 0u64;
    for (i, a) in plane.atlases.iter().enumerate() {
        let bad = |what: String| invalid(format!("atlas {i} of plane {p}: {what}"));
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
            // And it holds no more than the first (samplers find a brick's atlas by the first's capacity).
            let first_capacity = f.bricks.iter().map(|&b| u128::from(b)).product::<u128>();
            let fits = if i + 1 < plane.atlases.len() {
                a.bricks == f.bricks && u128::from(a.count) == capacity
            } else {
                same_places && u128::from(n) <= first_capacity && (0..3).all(|k| u64::from(a.bricks[k]) >= need[k])
            };
            if !fits || u64::from(a.first_brick) != next_brick {
                return bad("its layout does not follow the first atlas's".into());
            }
        }
        // Texture sizes must be representable (a sampler computes texel coordinates in u32).
        let slices = u64::from(plane.plane.slices_per_brick());
        if bx * 8 > u64::from(u32::MAX) || by * 8 > u64::from(u32::MAX) || bz * slices > u64::from(u32::MAX) {
            return bad(format!("{:?} bricks is too large a texture", a.bricks));
        }
        next_brick += u64::from(a.count);
    }
    if next_brick != u64::from(plane.bricks) {
        return invalid(format!("the atlases of plane {p} hold {next_brick} bricks, the metadata counts {}", plane.bricks));
    }
    Ok(())
}
