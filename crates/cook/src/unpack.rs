//! A frame of an asset back to a [`Grid`].

use crate::{Error, Format};
use vdbcook_encode::AtlasLayout;
use vdbcook_flipbook::{Nodes, L1_WORDS, L2_WORDS};
use vdbcook_grid::{Coord, Grid, GridClass, Leaf, LeafMask, MapType, Tile, Transform, LEAF_VOXELS};
use vdbcook_vpak::{kind, Asset, Metadata};

/// Memory one decoded leaf takes: the leaf, and its entry while the tree is walked.
const LEAF_COST: u64 = (std::mem::size_of::<Leaf>() + std::mem::size_of::<(Coord, [u64; 8], u32)>()) as u64;

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

fn need_multiple(name: &str, v: &[u32], unit: usize) -> Result<(), Error> {
    if !v.len().is_multiple_of(unit) {
        return Err(Error::Corrupt(format!("{name} holds {} words, not a multiple of {unit}", v.len())));
    }
    Ok(())
}

/// Copies the node arrays out of an asset.
pub fn load_nodes(asset: &Asset, meta: &Metadata) -> Result<Nodes, Error> {
    let n = Nodes {
        offset: Coord::new(meta.index_offset[0], meta.index_offset[1], meta.index_offset[2]),
        frames: asset.u32s(kind::FRAMES)?.to_vec(),
        l1: asset.u32s(kind::L1_NODES)?.to_vec(),
        l1_entries: asset.u32s(kind::L1_ENTRIES)?.to_vec(),
        l2: asset.u32s(kind::L2_NODES)?.to_vec(),
        l2_entries: asset.u32s(kind::L2_ENTRIES)?.to_vec(),
        l3: asset.u32s(kind::L3_NODES)?.to_vec(),
        tiles: asset.u32s(kind::TILES)?.to_vec(),
    };
    need_multiple("l1 nodes", &n.l1, L1_WORDS)?;
    need_multiple("l2 nodes", &n.l2, L2_WORDS)?;
    if vdbcook_flipbook::l3_node_count(&n.l3).is_none() {
        let l3 = n.l3.first().copied().unwrap_or(0);
        return Err(Error::Corrupt(format!("l3 nodes: {} words cannot hold the {l3} nodes the section counts", n.l3.len())));
    }
    need_multiple("tiles", &n.tiles, 2)?;
    Ok(n)
}

/// Decodes frame `frame` (counted from 0) of an opened asset.
pub fn unpack_frame(asset: &Asset, frame: usize) -> Result<Grid, Error> {
    let meta = asset.metadata()?;
    if frame >= meta.frame_count as usize {
        return Err(Error::NoFrame { frame, count: meta.frame_count as usize });
    }
    let format = Format::parse(&meta.format).ok_or_else(|| Error::Format(meta.format.clone()))?;
    let nodes = load_nodes(asset, &meta)?;
    if nodes.frames.len() != meta.frame_count as usize {
        return Err(Error::Corrupt(format!("{} frames in the frame table, {} in the metadata", nodes.frames.len(), meta.frame_count)));
    }
    if meta.index_offset.iter().any(|o| o % 128 != 0) {
        return Err(Error::Corrupt(format!("index offset {:?} is not a multiple of 128", meta.index_offset)));
    }
    let ranges = asset.f32s(kind::BRICK_RANGES)?;
    // The metadata says how many leaves the frame has: decode no more. Shared
    // nodes let a small asset describe a huge frame (legitimately, for
    // repeated leaves): refuse what would not fit in memory before expanding it.
    let want = meta.frames.get(frame).map_or(0, |f| u64::from(f.leaves));
    let (bytes, budget) = (want.saturating_mul(LEAF_COST), memory_budget());
    if bytes > budget {
        return Err(Error::TooBig { frame, leaves: want, bytes, budget });
    }
    let want = want as usize;
    let (leaves, tiles) =
        nodes.frame_contents(frame, want, MAX_TILES).ok_or_else(|| Error::Corrupt(format!("frame {frame} holds more than the {want} leaves or {MAX_TILES} tiles its metadata allows")))?;
    if leaves.len() != want {
        return Err(Error::Corrupt(format!("frame {frame} holds {} leaves, its metadata says {want}", leaves.len())));
    }
    let mut out = Vec::with_capacity(leaves.len());
    for (origin, mask, brick) in leaves {
        let info = meta.atlases.iter().enumerate().find(|(_, a)| brick >= a.first_brick && brick - a.first_brick < a.count).ok_or_else(|| Error::Corrupt(format!("brick {brick} is in no atlas")))?;
        let layout = AtlasLayout { format, bricks: info.1.bricks, first_brick: info.1.first_brick, count: info.1.count };
        if !layout.is_valid() {
            return Err(Error::Corrupt(format!("atlas {} has an impossible layout {:?} for {} bricks", info.0, layout.bricks, layout.count)));
        }
        let atlas = asset.section(kind::ATLAS, info.0 as u32)?;
        let data = vdbcook_encode::unpack_brick(&layout, atlas, brick - layout.first_brick).ok_or_else(|| Error::Corrupt(format!("atlas {} is too small for its bricks", info.0)))?;
        let b = brick as usize;
        let range = [*ranges.get(2 * b).ok_or_else(|| Error::Corrupt(format!("no range for brick {brick}")))?, ranges.get(2 * b + 1).copied().unwrap_or(0.0)];
        let decoded = vdbcook_encode::decode_brick(format, range, &data);
        let mask = LeafMask(mask);
        let mut values = [meta.background; LEAF_VOXELS];
        for i in mask.iter_on() {
            values[i] = decoded[i];
        }
        out.push(Leaf { origin, mask, values });
    }
    out.sort_by_key(|l| l.origin);
    let map_type = MapType::from_vdb_name(&meta.map_type).unwrap_or(MapType::Affine);
    Ok(Grid {
        name: meta.grid_name.clone(),
        class: GridClass::from_vdb_name(&meta.grid_class),
        background: meta.background,
        transform: Transform { map_type, matrix: meta.transform },
        leaves: out,
        tiles: tiles.into_iter().map(|(origin, dim, value)| Tile { origin, dim, value, active: true }).collect(),
    })
}
