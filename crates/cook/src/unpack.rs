//! A frame of an asset back to one [`Grid`] per channel.

use crate::Error;
use vdbcook_grid::{Coord, Grid, GridClass, Leaf, LeafMask, MapType, Tile, Transform, LEAF_VOXELS};
use vdbcook_vpak::{Asset, Checked};

/// Memory one decoded leaf takes, per channel: the leaf, and its entry while the tree is walked.
const LEAF_COST: u64 = (std::mem::size_of::<Leaf>() + std::mem::size_of::<([i32; 3], [u64; 8], u32)>()) as u64;

/// Bytes an unpacked frame may take: half of the memory available now (Linux),
/// else 4 GiB.
fn memory_budget() -> u64 {
    let available = std::fs::read_to_string("/proc/meminfo").ok().and_then(|m| {
        let line = m.lines().find(|l| l.starts_with("MemAvailable:"))?;
        line.split_whitespace().nth(1)?.parse::<u64>().ok()
    });
    available.map_or(4 << 30, |kib| kib.saturating_mul(1024) / 2)
}

/// Tiles a frame may decode to (a root tile fills at most 32768 L1 slots;
/// the rest is a bound on corrupt assets).
const MAX_TILES: usize = 1 << 22;

/// Decodes frame `frame` (counted from 0) of an opened asset: one grid per
/// channel, in the metadata's channel order, each active over the frame's
/// active voxels (the union of the channels'), holding the channel's
/// background where its own grid was inactive. Each channel at its first
/// stored level: its own voxels (level 0 unless its voxels are coarser than
/// the asset's, or `cook --max-bytes` left finer levels out).
pub fn unpack_frame(asset: &Asset, frame: usize) -> Result<Vec<Grid>, Error> {
    unpack_near(asset, frame, None)
}

/// Each channel of frame `frame` at its stored level nearest `level` (its
/// first stored level for `None`), on its own transform: the frame's body
/// restored and checked once, one tree walk per level some channel is taken from.
pub fn unpack_near(asset: &Asset, frame: usize, level: Option<u32>) -> Result<Vec<Grid>, Error> {
    in_body(asset, frame, &|checked, frame| {
        let meta = &checked.meta;
        if !meta.is_multi_resolution() {
            return level_of(checked, frame, level.unwrap_or(meta.first_level));
        }
        let want: Vec<u32> = (0..meta.channels.len()).map(|c| meta.channel_level_near(c, level.unwrap_or(0))).collect();
        let mut levels = want.clone();
        levels.sort_unstable();
        levels.dedup();
        let mut out: Vec<Option<Grid>> = vec![None; want.len()];
        for l in levels {
            for (c, g) in level_of(checked, frame, l)?.into_iter().enumerate() {
                if want.get(c) == Some(&l) {
                    out[c] = Some(g);
                }
            }
        }
        out.into_iter().map(|g| g.ok_or_else(|| Error::Corrupt("a channel has no stored level".into()))).collect()
    })
}

/// Frame `frame` at level of detail `level` (0: the frame itself): the
/// grids are in the level's index space, each with its channel's transform
/// there (voxels 2^level times as large, a voxel's centre at its children's
/// centre, moved by the channel's offset). A channel not stored at the level
/// (its own voxels are coarser, or its levels of detail end before) is an
/// empty grid.
pub fn unpack_level(asset: &Asset, frame: usize, level: u32) -> Result<Vec<Grid>, Error> {
    in_body(asset, frame, &|checked, frame| level_of(checked, frame, level))
}

/// Runs `f` on the checked body that holds frame `frame` (its segment's, of
/// a segmented asset) and the frame's number there.
fn in_body<T>(asset: &Asset, frame: usize, f: &dyn Fn(&Checked, usize) -> Result<T, Error>) -> Result<T, Error> {
    if asset.is_segmented() {
        // The frame's segment alone, and the frame within it.
        let Some((s, local)) = asset.locate(frame) else { return Err(Error::NoFrame { frame, count: asset.frame_count()? }) };
        let seg = asset.segment(s)?;
        let r = in_body(&seg, local, f);
        // A long asset is read a segment at a time: the pages read go again.
        seg.release();
        return r.map_err(|e| match e {
            Error::TooBig { leaves, bytes, budget, .. } => Error::TooBig { frame, leaves, bytes, budget },
            e => e,
        });
    }
    f(&Checked::new(asset)?, frame)
}

/// [`unpack_level`] of a checked body.
fn level_of(checked: &Checked, frame: usize, level: u32) -> Result<Vec<Grid>, Error> {
    let meta = &checked.meta;
    if frame >= meta.frame_count as usize {
        return Err(Error::NoFrame { frame, count: meta.frame_count as usize });
    }
    if let Some(why) = meta.missing_level(level) {
        return Err(Error::NoLevel(why));
    }
    let channels = meta.channels.len();
    // The metadata says how many leaves the frame has: decode no more. Shared
    // nodes let a small asset describe a huge frame (legitimately, for
    // repeated leaves): refuse what would not fit in memory before expanding it.
    let want = u64::from(meta.level_leaves(frame, level));
    let (bytes, budget) = (want.saturating_mul(LEAF_COST).saturating_mul(channels as u64), memory_budget());
    if bytes > budget {
        return Err(Error::TooBig { frame, leaves: want, bytes, budget });
    }
    let want = want as usize;
    let nodes = checked.nodes();
    let tree = meta.tree_index(frame, level).ok_or_else(|| Error::Corrupt(format!("frame {frame} has no tree at level {level}")))?;
    let (leaves, tiles) = nodes
        .tree_contents(tree, meta.level_offset(level), want, MAX_TILES)
        .ok_or_else(|| Error::Corrupt(format!("frame {frame} holds more than the {want} leaves or {MAX_TILES} tiles its metadata allows")))?;
    if leaves.len() != want {
        return Err(Error::Corrupt(format!("frame {frame} holds {} leaves, its metadata says {want}", leaves.len())));
    }
    let mut out: Vec<Vec<Leaf>> = vec![Vec::with_capacity(leaves.len()); channels];
    for (origin, mask, brick) in leaves {
        let decoded = checked.decode_brick(brick).ok_or_else(|| Error::Corrupt(format!("brick {brick} is in no atlas, or its atlas is too small")))?;
        let mask = LeafMask(mask);
        for (c, values) in decoded.iter().enumerate() {
            let mut v = [meta.channels[c].background; LEAF_VOXELS];
            for i in mask.iter_on() {
                v[i] = values[i];
            }
            out[c].push(Leaf { origin: Coord::new(origin[0], origin[1], origin[2]), mask, values: v });
        }
    }
    let tile_values: Vec<Vec<f32>> = tiles.iter().map(|&(_, _, t)| nodes.tile(t).ok_or_else(|| Error::Corrupt(format!("tile {t} is past the end of the tiles")))).collect::<Result<_, _>>()?;
    let map_type = MapType::from_vdb_name(&meta.map_type).unwrap_or(MapType::Affine);
    Ok(meta
        .channels
        .iter()
        .zip(out)
        .enumerate()
        .map(|(c, (ch, mut leaves))| {
            let stored = meta.channel_levels(c).contains(&level);
            leaves.sort_by_key(|l| l.origin);
            let transform = match (level, meta.resolution(c).half_offset) {
                (0, [0, 0, 0]) => Transform { map_type, matrix: meta.transform },
                // The map type a coarsened (or moved) transform takes; the matrix straight from the metadata.
                _ => Transform { map_type: vdbcook_grid::lod::coarsen_transform(&Transform { map_type, matrix: meta.transform }).map_type, matrix: meta.channel_transform(c, level) },
            };
            Grid {
                name: ch.name.clone(),
                class: GridClass::from_vdb_name(&ch.class),
                background: ch.background,
                transform,
                leaves: if stored { leaves } else { Vec::new() },
                tiles: match stored {
                    true => tiles.iter().zip(&tile_values).map(|(&(o, dim, _), v)| Tile { origin: Coord::new(o[0], o[1], o[2]), dim, value: v[c], active: true }).collect(),
                    false => Vec::new(),
                },
            }
        })
        .collect())
}
