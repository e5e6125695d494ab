//! Levels of detail: a grid filtered to voxels twice as large.
//!
//! Coarse voxel `i` (per axis) covers fine voxels `2i` and `2i + 1`, so a
//! coarse leaf covers 2×2×2 fine leaves and every coarse voxel's eight
//! children lie in one fine leaf or tile.  A coarse voxel is active when any
//! child is.  Its value depends on the [`Filter`]:
//!
//! - [`Filter::Mean`] (fog volumes and every other class but level sets):
//!   the mean of the eight children, an inactive child counting as the
//!   background.  A region's integral (the sum of its values times the voxel
//!   volume, so the optical depth through it) is kept exactly, up to f32
//!   rounding; a constant region stays the same constant.
//! - [`Filter::ActiveMean`] (level sets): the mean of the active children
//!   only.  A level set's inactive voxels carry no sign in a cooked asset
//!   (they read the positive background), so mixing them in would move the
//!   surface; the active children's mean keeps the distances (in world
//!   units) where the band is, and the band, as wide in world units, gets
//!   half as many voxels across per level.
//!
//! Constant regions stay constant: a fine tile becomes tiles (or, for an 8³
//! tile, a fully active 4³ block of a coarse leaf, and a coarse leaf made
//! only of such blocks of one value becomes an 8³ tile).  Inactive tiles
//! are dropped, as the cooker drops them (their voxels read the background).
//!
//! [`coarsen_transform`] gives the coarse grid's index-to-world map: the
//! fine one with voxels twice as large, shifted so a coarse voxel's centre
//! sits at the centre of its eight children (fine index `2i + 1/2`).

use crate::{Coord, Grid, GridClass, Leaf, LeafMask, MapType, Tile, Transform, LEAF_VOXELS};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// How a coarse voxel is made from its eight children.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Filter {
    /// Mean of the eight children, inactive ones counting as the background.
    Mean,
    /// Mean of the active children.
    ActiveMean,
}

impl Filter {
    /// The filter a grid class gets: [`Filter::ActiveMean`] for level sets, else [`Filter::Mean`].
    pub fn for_class(class: GridClass) -> Filter {
        match class {
            GridClass::LevelSet => Filter::ActiveMean,
            _ => Filter::Mean,
        }
    }
}

/// The transform of a grid coarsened once: index `i` of the coarse grid is
/// at fine index `2i + 1/2` (each axis).
pub fn coarsen_transform(t: &Transform) -> Transform {
    let m = &t.matrix;
    let mut c = *m;
    for a in 0..3 {
        for (col, v) in c[a].iter_mut().enumerate() {
            *v = 2.0 * m[a][col];
        }
    }
    for col in 0..4 {
        c[3][col] = m[3][col] + 0.5 * (m[0][col] + m[1][col] + m[2][col]);
    }
    // The shift adds a translation; doubling keeps a scale's kind.
    let map_type = match t.map_type {
        MapType::UniformScale | MapType::UniformScaleTranslate | MapType::Translation => MapType::UniformScaleTranslate,
        MapType::Scale | MapType::ScaleTranslate => MapType::ScaleTranslate,
        MapType::Affine | MapType::Unitary => MapType::Affine,
    };
    Transform { map_type, matrix: c }
}

/// A fine item that feeds one coarse leaf.
#[derive(Clone, Copy)]
enum Part<'a> {
    Leaf(&'a Leaf),
    /// An active 8³ tile's value.
    Tile(f32),
}

/// Origin of the coarse leaf holding fine 8³ block `o`, and the block's
/// corner (0 or 4 per axis) inside it.
fn coarse_place(o: Coord) -> (Coord, [usize; 3]) {
    let c = Coord::new(o.x >> 1, o.y >> 1, o.z >> 1);
    (c.leaf_origin(), [(c.x & 4) as usize, (c.y & 4) as usize, (c.z & 4) as usize])
}

/// The grid with voxels twice as large (see the module documentation).
/// Leaves are built in parallel and collected in origin order, so the result
/// does not depend on the thread count.
pub fn coarsen(g: &Grid, filter: Filter) -> Grid {
    let bg = g.background;
    // Fine leaves and 8³ tiles, by the coarse leaf they feed.
    let mut parts: Vec<(Coord, [usize; 3], Part)> = Vec::with_capacity(g.leaves.len());
    for l in g.leaves.iter().filter(|l| !l.mask.is_empty()) {
        let (c, at) = coarse_place(l.origin);
        parts.push((c, at, Part::Leaf(l)));
    }
    // Larger tiles: constant cubes of the coarse grid, by the 128³ region holding them.
    let mut cubes: BTreeMap<Coord, Vec<(Coord, u32, f32)>> = BTreeMap::new();
    let mut big: Vec<(Coord, u32, f32)> = Vec::new();
    for t in g.tiles.iter().filter(|t| t.active) {
        if t.dim <= 8 {
            let (c, at) = coarse_place(t.origin);
            parts.push((c, at, Part::Tile(t.value)));
            continue;
        }
        let (o, d) = (Coord::new(t.origin.x >> 1, t.origin.y >> 1, t.origin.z >> 1), t.dim / 2);
        if d >= 128 {
            big.push((o, d, t.value));
        } else {
            let region = Coord::new(o.x & !127, o.y & !127, o.z & !127);
            cubes.entry(region).or_default().push((o, d, t.value));
        }
    }
    parts.sort_by_key(|p| p.0);
    let groups: Vec<&[(Coord, [usize; 3], Part)]> = parts.chunk_by(|a, b| a.0 == b.0).collect();
    let built: Vec<Result<Leaf, Tile>> = groups.par_iter().map(|grp| coarse_leaf(grp, bg, filter)).collect();
    let mut leaves = Vec::with_capacity(built.len());
    let mut tiles = Vec::new();
    for b in built {
        match b {
            Ok(l) => leaves.push(l),
            Err(t) => tiles.push(t),
        }
    }
    for (o, d, v) in big {
        // 128³ tiles filling the cube (d is a multiple of 128).
        fill_cube(&mut tiles, o, d, 128, v);
    }
    for (region, cs) in cubes {
        // Cubes of one value filling their 128³ region are one tile; else 8³ tiles.
        let volume: u64 = cs.iter().map(|c| u64::from(c.1).pow(3)).sum();
        let first = cs[0].2.to_bits();
        if volume == 128 * 128 * 128 && cs.iter().all(|c| c.2.to_bits() == first) {
            tiles.push(Tile { origin: region, dim: 128, value: cs[0].2, active: true });
            continue;
        }
        for (o, d, v) in cs {
            fill_cube(&mut tiles, o, d, 8, v);
        }
    }
    tiles.sort_by_key(|t| (t.origin, t.dim));
    Grid { name: g.name.clone(), class: g.class, background: bg, transform: coarsen_transform(&g.transform), leaves, tiles }
}

/// Active tiles of edge `dim` filling the cube of edge `d` (a multiple of `dim`) at `o`.
fn fill_cube(tiles: &mut Vec<Tile>, o: Coord, d: u32, dim: u32, value: f32) {
    let (n, step) = ((d / dim) as i32, dim as i32);
    for x in 0..n {
        for y in 0..n {
            for z in 0..n {
                tiles.push(Tile { origin: o.offset(x * step, y * step, z * step), dim, value, active: true });
            }
        }
    }
}

/// One coarse leaf from the fine leaves and 8³ tiles that feed it; a leaf
/// made of eight tiles of one value is an 8³ tile.
fn coarse_leaf(parts: &[(Coord, [usize; 3], Part)], bg: f32, filter: Filter) -> Result<Leaf, Tile> {
    let origin = parts[0].0;
    if parts.len() == 8 {
        if let Part::Tile(v) = parts[0].2 {
            if parts.iter().all(|p| matches!(p.2, Part::Tile(w) if w.to_bits() == v.to_bits())) {
                return Err(Tile { origin, dim: 8, value: v, active: true });
            }
        }
    }
    let mut values = [bg; LEAF_VOXELS];
    let mut mask = LeafMask::default();
    for &(_, at, part) in parts {
        for x in 0..4 {
            for y in 0..4 {
                for z in 0..4 {
                    let i = crate::leaf_offset((at[0] + x) as i32, (at[1] + y) as i32, (at[2] + z) as i32);
                    let v = match part {
                        Part::Tile(v) => Some(v),
                        Part::Leaf(l) => children_mean(l, [2 * x, 2 * y, 2 * z], bg, filter),
                    };
                    if let Some(v) = v {
                        values[i] = v;
                        mask.set(i, true);
                    }
                }
            }
        }
    }
    Ok(Leaf { origin, mask, values })
}

/// The coarse value of the 2×2×2 children of `leaf` from local corner `c`,
/// or `None` when none of them is active.
#[inline]
fn children_mean(leaf: &Leaf, c: [usize; 3], bg: f32, filter: Filter) -> Option<f32> {
    let (mut sum, mut active) = (0.0f64, 0u32);
    for dx in 0..2 {
        for dy in 0..2 {
            for dz in 0..2 {
                let i = crate::leaf_offset((c[0] + dx) as i32, (c[1] + dy) as i32, (c[2] + dz) as i32);
                if leaf.mask.is_on(i) {
                    sum += f64::from(leaf.values[i]);
                    active += 1;
                } else if filter == Filter::Mean {
                    sum += f64::from(bg);
                }
            }
        }
    }
    match (active, filter) {
        (0, _) => None,
        (_, Filter::Mean) => Some((sum / 8.0) as f32),
        (n, Filter::ActiveMean) => Some((sum / f64::from(n)) as f32),
    }
}

#[cfg(test)]
mod tests;
