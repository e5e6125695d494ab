//! The union of several channels' grids of one frame, as positions (a leaf
//! origin and the union of the channels' active masks there) and what each
//! channel has at each position: its own leaf, a tile's value, or nothing.
//! Bricks are made from the parts straight into the pool: a merged leaf per
//! channel (the channel's values under the union mask, its background where
//! it is inactive) is built only where a channel's mask differs from the
//! union, and a channel with nothing at a position (one stored at another
//! level, or empty there) costs a constant brick.

use crate::{brick_of_leaf, Brick, ChannelMasks, Error};
use std::collections::{BTreeMap, HashMap, HashSet};
use vdbcook_grid::{Coord, Grid, Leaf, LeafMask, LEAF_VOXELS};

/// What one channel has at a position of the union tree.
#[derive(Clone, Copy)]
pub(crate) enum Part<'g> {
    Leaf(&'g Leaf),
    /// An 8³ tile over the position: every voxel active at its value.
    Tile(f32),
    /// Nothing: the channel's background.
    Background,
}

/// A frame's union tree: leaf positions with `channels` parts each (part `c`
/// of position `i` is `parts[i · channels + c]`), and tiles that hold a
/// value per channel.
pub(crate) struct Merged<'g> {
    pub(crate) positions: Vec<(Coord, LeafMask)>,
    pub(crate) parts: Vec<Part<'g>>,
    /// Per position per channel, the channel's own active mask (none with one channel).
    pub(crate) channel_masks: ChannelMasks,
    pub(crate) tiles: Vec<(Coord, u32, Vec<f32>)>,
}

impl<'g> Merged<'g> {
    /// One channel's grid as it is: its non-empty leaves and active tiles.
    pub(crate) fn single(g: &'g Grid) -> Merged<'g> {
        let leaves: Vec<&Leaf> = g.leaves.iter().filter(|l| !l.mask.is_empty()).collect();
        Merged {
            positions: leaves.iter().map(|l| (l.origin, l.mask)).collect(),
            parts: leaves.into_iter().map(Part::Leaf).collect(),
            channel_masks: ChannelMasks::default(),
            tiles: g.tiles.iter().filter(|t| t.active).map(|t| (t.origin, t.dim, vec![t.value])).collect(),
        }
    }
}

impl Part<'_> {
    /// The leaf this part is at a position with union mask `mask`: its
    /// active values (a tile's value everywhere), the background elsewhere.
    fn leaf(&self, origin: Coord, mask: LeafMask, background: f32) -> Leaf {
        let mut values = [background; LEAF_VOXELS];
        match self {
            Part::Leaf(l) => {
                for i in l.mask.iter_on() {
                    values[i] = l.values[i];
                }
            }
            Part::Tile(v) => values = [*v; LEAF_VOXELS],
            Part::Background => {}
        }
        Leaf { origin, mask, values }
    }

    /// `brick_of_leaf` of [`Part::leaf`], built only where needed: a leaf
    /// active where the union is gives its own brick, and the background
    /// under a full mask, or a +0.0 background (whose neighbour averages
    /// are exact), is a constant brick.
    pub(crate) fn brick(&self, origin: Coord, mask: LeafMask, background: f32) -> Brick {
        match (self, self.known_constant(mask, background)) {
            (Part::Leaf(l), _) if l.mask == mask => brick_of_leaf(l),
            (_, Some(bits)) => [f32::from_bits(bits); LEAF_VOXELS],
            _ => brick_of_leaf(&self.leaf(origin, mask, background)),
        }
    }

    /// The bits of the one value of [`Part::brick`] when that is known
    /// without making it (the background's, see there).
    pub(crate) fn known_constant(&self, mask: LeafMask, background: f32) -> Option<u32> {
        match self {
            Part::Background if background.to_bits() == 0 || mask.count_on() as usize == LEAF_VOXELS => Some(background.to_bits()),
            _ => None,
        }
    }

    /// [`Part::range`] from the part's brick `b` ([`Part::brick`]) where
    /// that brick is its own leaf's: its active voxels are the leaf's, taken
    /// in the same order (so the same bits, ±0 included), while the brick is
    /// in cache. `None` for other parts.
    pub(crate) fn range_of_brick(&self, mask: LeafMask, b: &Brick) -> Option<[f32; 2]> {
        match self {
            Part::Leaf(l) if l.mask == mask => Some(vdbcook_grid::active_range_of(&mask, b)),
            _ => None,
        }
    }

    /// The minimum and maximum of [`Part::leaf`]'s active values (`mask` is not empty).
    pub(crate) fn range(&self, origin: Coord, mask: LeafMask, background: f32) -> [f32; 2] {
        match self {
            Part::Leaf(l) if l.mask == mask => vdbcook_grid::active_range(l),
            Part::Leaf(_) => vdbcook_grid::active_range(&self.leaf(origin, mask, background)),
            Part::Tile(v) => [f32::INFINITY.min(*v), f32::NEG_INFINITY.max(*v)],
            Part::Background => [f32::INFINITY.min(background), f32::NEG_INFINITY.max(background)],
        }
    }
}

/// The union of several channels' grids of one frame: a position wherever
/// any channel has a leaf (each channel's leaf there, under the union's
/// mask), and tiles that hold a value per channel.  A tile of one channel
/// over finer content of another (a leaf, or a smaller tile) is split into
/// its children until none overlaps: an 8³ tile over another channel's leaf
/// becomes that channel's part of the position.
pub(crate) fn merge_channels<'g>(grids: &[Option<&'g Grid>], backgrounds: &[f32]) -> Result<Merged<'g>, Error> {
    let c = grids.len();
    let present = || grids.iter().enumerate().filter_map(|(k, g)| g.map(|g| (k, g)));
    // Leaf origins of every channel, and the coarser regions that hold finer content.
    let mut leaf_at: HashMap<Coord, Vec<Option<usize>>> = HashMap::new();
    for (k, g) in present() {
        for (i, l) in g.leaves.iter().enumerate().filter(|(_, l)| !l.mask.is_empty()) {
            leaf_at.entry(l.origin).or_insert_with(|| vec![None; c])[k] = Some(i);
        }
    }
    let align = |o: Coord, d: i32| Coord::new(o.x & !(d - 1), o.y & !(d - 1), o.z & !(d - 1));
    let mut finer128: HashSet<Coord> = leaf_at.keys().map(|&o| align(o, 128)).collect();
    let mut finer4096: HashSet<Coord> = leaf_at.keys().map(|&o| align(o, 4096)).collect();
    for (_, g) in present() {
        for t in g.tiles.iter().filter(|t| t.active) {
            if t.dim == 8 {
                finer128.insert(align(t.origin, 128));
            }
            if t.dim <= 128 {
                finer4096.insert(align(t.origin, 4096));
            }
        }
    }
    // Tiles by (origin, edge), one value per channel; 8³ tiles that fall on a leaf.
    let mut tiles: BTreeMap<(Coord, u32), Vec<Option<f32>>> = BTreeMap::new();
    let mut tile_leaves: HashMap<Coord, Vec<Option<f32>>> = HashMap::new();
    let mut work: Vec<(usize, Coord, u32, f32)> = present().flat_map(|(k, g)| g.tiles.iter().filter(|t| t.active).map(move |t| (k, t.origin, t.dim, t.value))).collect();
    while let Some((k, o, dim, v)) = work.pop() {
        let split = match dim {
            8 => {
                if leaf_at.contains_key(&o) {
                    tile_leaves.entry(o).or_insert_with(|| vec![None; c])[k] = Some(v);
                    continue;
                }
                false
            }
            128 => finer128.contains(&o),
            _ => dim > 128 && finer4096.contains(&align(o, 4096)),
        };
        if !split {
            tiles.entry((o, dim)).or_insert_with(|| vec![None; c])[k] = Some(v);
            continue;
        }
        // Children: 16³ tiles of 8 in a 128 tile, 32³ tiles of 128 in a larger one.
        let child = if dim == 128 { 8 } else { 128 };
        let n = (dim / child) as i32;
        for x in 0..n {
            for y in 0..n {
                for z in 0..n {
                    let d = child as i32;
                    work.push((k, o.offset(x * d, y * d, z * d), child, v));
                }
            }
        }
    }
    let mut origins: Vec<Coord> = leaf_at.keys().copied().collect();
    origins.sort_unstable();
    let mut m = Merged { positions: Vec::with_capacity(origins.len()), parts: Vec::with_capacity(origins.len() * c), channel_masks: ChannelMasks::new(c), tiles: Vec::new() };
    m.channel_masks.reserve(origins.len());
    let mut masks = Vec::with_capacity(c);
    for o in origins {
        let own = &leaf_at[&o];
        let tiled = tile_leaves.get(&o);
        let mut union = [0u64; 8];
        masks.clear();
        for k in 0..c {
            let leaf = own[k].and_then(|i| grids[k].and_then(|g| g.leaves.get(i)));
            // A tile's value wins over a leaf's values; the leaf's mask over the tile's.
            let (part, mask) = match (leaf, tiled.and_then(|t| t[k])) {
                (Some(l), Some(v)) => (Part::Tile(v), l.mask),
                (Some(l), None) => (Part::Leaf(l), l.mask),
                (None, Some(v)) => (Part::Tile(v), LeafMask([u64::MAX; 8])),
                (None, None) => (Part::Background, LeafMask::default()),
            };
            for (u, w) in union.iter_mut().zip(mask.0) {
                *u |= w;
            }
            m.parts.push(part);
            masks.push(mask.0);
        }
        m.channel_masks.push(&masks, &union)?;
        m.positions.push((o, LeafMask(union)));
    }
    m.tiles = tiles.into_iter().map(|((o, dim), v)| (o, dim, v.iter().zip(backgrounds).map(|(v, &bg)| v.unwrap_or(bg)).collect())).collect();
    Ok(m)
}
