//! The `tiles` filters (coding filters 3 and 4): an atlas of 8×8×8-texel
//! tiles of one `w`-byte lane (a 1-lane `unorm8`, `unorm16` or `f16` plane,
//! whose tiles are its bricks) stored tile by tile, each tile's elements
//! divided by their greatest common divisor and (filter 3) predicted from
//! their 3D neighbours in the tile (Lorenzo). Filter 4 leaves the quotients
//! unpredicted: sharp, sparse bricks (flames) compress better as they are.
//! Texels snapped to a step of the error bound (`cook --max-error
//! --supercompress`) are multiples of their brick's step, so what zstd sees
//! is the same small residuals in every brick, whatever its range; without
//! the divisor each brick's step scatters them.
//!
//! All arithmetic is modulo 2^(8w), which 16-bit wrapping arithmetic keeps
//! (for w = 1 the low byte of a 16-bit result is the 8-bit one): a tile is
//! worked on as 512 `u16`s, its Lorenzo residuals being its differences along
//! x, y and z, and their inverse running sums along each axis.

use rayon::prelude::*;

/// Elements of a tile.
pub const TILE: usize = 512;

/// One tile's elements, x fastest, then y, then z.
type Tile = [u16; TILE];

/// The geometry of a tiled section: elements of `width` bytes, `x` × `y`
/// tiles per slab of 8 texels in z; and whether quotients are predicted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tiles {
    pub width: u32,
    pub x: u32,
    pub y: u32,
    pub predict: bool,
}

impl Tiles {
    /// From a coding record's width and stride (`x + 65536·y`).
    pub fn from_record(predict: bool, width: u32, stride: u32) -> Option<Tiles> {
        let (x, y) = (stride & 0xffff, stride >> 16);
        (matches!(width, 1 | 2) && x > 0 && y > 0).then_some(Tiles { width, x, y, predict })
    }

    pub fn stride(self) -> u32 {
        self.x | self.y << 16
    }

    fn slab_bytes(self) -> usize {
        self.x as usize * self.y as usize * TILE * self.width as usize
    }

    /// Tiles in a section of `raw` bytes, if it is a whole number of slabs.
    pub fn count(self, raw: usize) -> Option<usize> {
        raw.is_multiple_of(self.slab_bytes()).then(|| raw / (TILE * self.width as usize))
    }

    /// Bytes of the filtered form of `raw` bytes: one divisor more per tile.
    pub fn filtered_len(self, raw: usize) -> Option<usize> {
        self.count(raw).map(|t| raw + t * self.width as usize)
    }

    /// Where the 64 rows of the `x` tiles of tile row `r` start in the
    /// section, in elements: row q = j + 8k (8·x elements, y = j and z = k
    /// within the tiles) is the section's row 8·(r mod y) + j of layer
    /// 8·⌊r / y⌋ + k.
    fn row_starts(self, r: usize) -> impl Iterator<Item = usize> {
        (0..64).map(move |q| self.row_start(r, q))
    }

    fn row_start(self, r: usize, q: usize) -> usize {
        let (x, y) = (self.x as usize, self.y as usize);
        let (row, layer) = (8 * x, 64 * x * y);
        row * 8 * (r % y) + layer * 8 * (r / y) + row * (q % 8) + layer * (q / 8)
    }

    /// Tile `t`'s elements in a section of `raw` bytes, a row of 8 at a time.
    fn tile(self, raw: &[u8], t: usize) -> Tile {
        let (x, w) = (self.x as usize, self.width as usize);
        let mut e = [0u16; TILE];
        for (q, row) in e.chunks_exact_mut(8).enumerate() {
            let at = self.row_start(t / x, q) + 8 * (t % x);
            match w {
                1 => row.iter_mut().zip(&raw[at..at + 8]).for_each(|(e, &b)| *e = u16::from(b)),
                _ => row.iter_mut().zip(raw[2 * at..2 * (at + 8)].chunks_exact(2)).for_each(|(e, b)| *e = u16::from_le_bytes([b[0], b[1]])),
            }
        }
        e
    }

    /// Element `v` (x fastest) of tile `t` in a section of `raw` bytes.
    fn element(self, raw: &[u8], t: usize, v: usize) -> u16 {
        let x = self.x as usize;
        let at = self.row_start(t / x, v / 8) + 8 * (t % x) + v % 8;
        match self.width {
            1 => u16::from(raw[at]),
            _ => u16::from_le_bytes([raw[2 * at], raw[2 * at + 1]]),
        }
    }

    /// The filtered bytes: the tiles' divisors, then each tile's residuals,
    /// the elements byte-shuffled as the shuffle filter does. `raw` must be a
    /// whole number of slabs ([`Tiles::count`]).
    pub fn apply(self, raw: &[u8]) -> Vec<u8> {
        self.apply_each(raw, &[self.predict]).pop().unwrap_or_default()
    }

    /// [`Tiles::apply`] with each of `predicts` in turn, in one pass: the
    /// tiles gathered, their divisors found and their elements divided once.
    /// A row of tiles along x at a time (its 64 rows of the section read
    /// whole, not 16 bytes from each per tile), the rows in parallel.
    pub fn apply_each(self, raw: &[u8], predicts: &[bool]) -> Vec<Vec<u8>> {
        let w = self.width as usize;
        let tiles = self.count(raw.len()).unwrap_or(0);
        let m = tiles * (TILE + 1);
        let mut outs: Vec<Vec<u8>> = predicts.iter().map(|_| vec![0u8; m * w]).collect();
        let x = self.x as usize;
        if tiles == 0 {
            return outs;
        }
        // Per tile row, per output: its tiles' low residual bytes and high ones (empty for w = 1).
        let mut rows: Vec<Vec<(&mut [u8], &mut [u8])>> = (0..tiles / x).map(|_| Vec::with_capacity(predicts.len())).collect();
        for out in outs.iter_mut() {
            let (lo, hi) = out.split_at_mut(m);
            let hi_res: Vec<&mut [u8]> = match w {
                1 => (0..rows.len()).map(|_| <&mut [u8]>::default()).collect(),
                _ => hi[tiles..].chunks_mut(x * TILE).collect(),
            };
            for ((row, l), h) in rows.iter_mut().zip(lo[tiles..].chunks_mut(x * TILE)).zip(hi_res) {
                row.push((l, h));
            }
        }
        let len = 8 * x;
        let divisors: Vec<u16> = rows
            .into_par_iter()
            .enumerate()
            .map_init(
                || vec![0u16; 64 * len],
                |block, (r, mut slots)| {
                    for (q, at) in self.row_starts(r).enumerate() {
                        let dst = &mut block[q * len..(q + 1) * len];
                        match w {
                            1 => dst.iter_mut().zip(&raw[at..at + len]).for_each(|(d, &b)| *d = u16::from(b)),
                            _ => dst.iter_mut().zip(raw[2 * at..2 * (at + len)].chunks_exact(2)).for_each(|(d, b)| *d = u16::from_le_bytes([b[0], b[1]])),
                        }
                    }
                    (0..x)
                        .map(|tx| {
                            let mut e = [0u16; TILE];
                            for (q, dst) in e.chunks_exact_mut(8).enumerate() {
                                dst.copy_from_slice(&block[q * len + 8 * tx..q * len + 8 * tx + 8]);
                            }
                            let (g, e) = divided(e);
                            let mut residuals: Option<Tile> = None;
                            for ((lo, hi), &predict) in slots.iter_mut().zip(predicts) {
                                let v: &Tile = match predict {
                                    true => residuals.get_or_insert_with(|| predicted(&e)),
                                    false => &e,
                                };
                                let lo = &mut lo[tx * TILE..(tx + 1) * TILE];
                                lo.iter_mut().zip(v).for_each(|(b, &v)| *b = v as u8);
                                if w == 2 {
                                    hi[tx * TILE..(tx + 1) * TILE].iter_mut().zip(v).for_each(|(b, &v)| *b = (v >> 8) as u8);
                                }
                            }
                            g
                        })
                        .collect::<Vec<u16>>()
                },
            )
            .flatten_iter()
            .collect();
        for out in outs.iter_mut() {
            let (lo, hi) = out.split_at_mut(m);
            lo[..tiles].iter_mut().zip(&divisors).for_each(|(b, &g)| *b = g as u8);
            if w == 2 {
                hi[..tiles].iter_mut().zip(&divisors).for_each(|(b, &g)| *b = (g >> 8) as u8);
            }
        }
        outs
    }

    /// The bytes at `ranges` of each of [`Tiles::apply_each`]'s outputs
    /// (byte ranges of the filtered form, within it), one after another per
    /// output, with only the tiles they show filtered: a sample of a large
    /// section, which the coder judges filters on, costs what it holds, not
    /// the whole section. The divisors a range shows are found each from
    /// its tile's elements up to the first that makes it 1.
    pub fn apply_each_at(self, raw: &[u8], predicts: &[bool], ranges: &[std::ops::Range<usize>]) -> Vec<Vec<u8>> {
        let w = self.width as usize;
        let tiles = self.count(raw.len()).unwrap_or(0);
        let m = tiles * (TILE + 1);
        // Each range as runs of elements, byte plane by byte plane (low bytes first, as stored).
        let runs: Vec<(std::ops::Range<usize>, usize)> =
            ranges.iter().flat_map(|r| (0..w).map(move |p| (r.start.clamp(p * m, (p + 1) * m) - p * m..r.end.clamp(p * m, (p + 1) * m) - p * m, p))).filter(|(r, _)| !r.is_empty()).collect();
        let divisors_to = runs.iter().map(|(r, _)| r.end.min(tiles)).max().unwrap_or(0);
        let divisors: Vec<u16> = (0..divisors_to).into_par_iter().map(|t| gcd_of((0..TILE).map(|v| self.element(raw, t, v)))).collect();
        let mut shown: Vec<usize> = runs.iter().filter(|(r, _)| r.end > tiles).flat_map(|(r, _)| (r.start.max(tiles) - tiles) / TILE..(r.end - tiles).div_ceil(TILE)).collect();
        shown.sort_unstable();
        shown.dedup();
        // Per tile shown, its residuals for each of `predicts`.
        let filtered: Vec<Vec<Tile>> = shown
            .par_iter()
            .map(|&t| {
                let (_, e) = divided(self.tile(raw, t));
                predicts.iter().map(|&p| if p { predicted(&e) } else { e }).collect()
            })
            .collect();
        let byte = |v: u16, p: usize| (v >> (8 * p)) as u8;
        (0..predicts.len())
            .map(|i| {
                let mut out = Vec::with_capacity(ranges.iter().map(|r| r.len()).sum());
                for (r, p) in &runs {
                    out.extend(divisors[r.start.min(tiles)..r.end.min(tiles)].iter().map(|&g| byte(g, *p)));
                    let mut e = r.start.max(tiles);
                    while e < r.end {
                        let (t, v) = ((e - tiles) / TILE, (e - tiles) % TILE);
                        let end = (r.end - tiles - t * TILE).min(TILE);
                        let tile = shown.binary_search(&t).map_or(&[0u16; TILE], |k| &filtered[k][i]);
                        out.extend(tile[v..end].iter().map(|&x| byte(x, *p)));
                        e += end - v;
                    }
                }
                out
            })
            .collect()
    }

    /// Undoes [`Tiles::apply`]: `data` is the filtered form of `out`.
    ///
    /// A row of tiles along x at a time, in a buffer laid out as `out` is (8
    /// layers of 8 rows of `8·x` elements): each tile's residuals multiplied
    /// by its divisor (which commutes with the sums, modulo 2^16) and summed
    /// along x, then the running sums along y and z over whole rows and
    /// layers, then 64 contiguous rows written to `out`. Writing tile by tile
    /// would scatter 64 rows of 16 bytes each across the atlas.
    pub fn undo(self, data: &[u8], out: &mut [u8]) {
        let w = self.width as usize;
        let tiles = self.count(out.len()).unwrap_or(0);
        let m = tiles * (TILE + 1);
        if data.len() != m * w || tiles == 0 {
            return;
        }
        let (lo, hi) = data.split_at(m);
        let x = self.x as usize;
        let len = 8 * x;
        let mut block = vec![0u16; 64 * len];
        let mut u = [0u16; TILE];
        for r in 0..tiles / x {
            for tx in 0..x {
                let t = r * x + tx;
                let first = tiles + t * TILE;
                let lo_res: &[u8; TILE] = lo[first..first + TILE].try_into().unwrap_or(&[0; TILE]);
                let g = match w {
                    1 => {
                        u.iter_mut().zip(lo_res).for_each(|(u, &l)| *u = u16::from(l));
                        u16::from(lo[t])
                    }
                    _ => {
                        let hi_res: &[u8; TILE] = hi[first..first + TILE].try_into().unwrap_or(&[0; TILE]);
                        u.iter_mut().zip(lo_res.iter().zip(hi_res)).for_each(|(u, (&l, &h))| *u = u16::from_le_bytes([l, h]));
                        u16::from_le_bytes([lo[t], hi[t]])
                    }
                };
                if g != 1 {
                    u.iter_mut().for_each(|v| *v = v.wrapping_mul(g));
                }
                for (q, src) in u.chunks_exact(8).enumerate() {
                    let r: [u16; 8] = src.try_into().unwrap_or_default();
                    let dst = &mut block[q * len + 8 * tx..q * len + 8 * tx + 8];
                    dst.copy_from_slice(&if self.predict { row_sums(r) } else { r });
                }
            }
            if self.predict {
                // Along y within each layer, then along z.
                let rows_y = (1..64).filter(|q| q % 8 != 0).map(|q| (q, q - 1));
                for (q, from) in rows_y.chain((8..64).map(|q| (q, q - 8))) {
                    let (before, here) = block.split_at_mut(q * len);
                    let prev = &before[from * len..from * len + len];
                    here[..len].iter_mut().zip(prev).for_each(|(v, &p)| *v = v.wrapping_add(p));
                }
            }
            for (src, at) in block.chunks_exact(len).zip(self.row_starts(r)) {
                match w {
                    1 => out[at..at + len].iter_mut().zip(src).for_each(|(o, &v)| *o = v as u8),
                    _ => out[2 * at..2 * (at + len)].chunks_exact_mut(2).zip(src).for_each(|(o, &v)| o.copy_from_slice(&v.to_le_bytes())),
                }
            }
        }
    }
}

/// One brick of a plane of levels (1 lane, `unorm8` or `unorm16`; `bytes`
/// its 512 texels, x fastest, little-endian) as the tiles filters see it:
/// its texels over their greatest common divisor. `None` for any other
/// plane or size.
pub(crate) fn level_quotients(plane: &crate::Plane, bytes: &[u8]) -> Option<Tile> {
    let one_lane = plane.lanes == 1 && plane.z_per_texel == 1;
    match plane.format {
        crate::Format::Unorm8 if one_lane && bytes.len() == TILE => Some(divided(std::array::from_fn(|v| u16::from(bytes[v]))).1),
        crate::Format::Unorm16 if one_lane && bytes.len() == 2 * TILE => Some(divided(std::array::from_fn(|v| u16::from_le_bytes([bytes[2 * v], bytes[2 * v + 1]]))).1),
        _ => None,
    }
}

/// A tile's elements over their greatest common divisor, and the divisor
/// (0, the elements all 0, when they are).
fn divided(mut e: Tile) -> (u16, Tile) {
    let g = tile_gcd(&e);
    divide(&mut e, g);
    (g, e)
}

/// A tile's quotients as the predicting `tiles` filter stores them: their
/// Lorenzo residuals.
fn predicted(e: &Tile) -> Tile {
    let mut d = *e;
    difference(&mut d);
    d
}

/// The greatest common divisor of a tile's elements (0 when all are 0):
/// each element only checked against the divisor so far (a multiply by its
/// reciprocal), which changes at most 16 times.
fn tile_gcd(e: &Tile) -> u16 {
    gcd_of(e.iter().copied())
}

/// [`tile_gcd`] of elements in order, taking none past the first that makes it 1.
fn gcd_of(elements: impl IntoIterator<Item = u16>) -> u16 {
    let mut g = 0u32;
    let mut recip = 0u64;
    for v in elements {
        let v = u32::from(v);
        if g == 1 {
            break;
        }
        if g == 0 || quotient(v, recip) * g != v {
            g = gcd(g, v);
            recip = reciprocal(g);
        }
    }
    g as u16
}

/// ⌈2^32 / g⌉: for v and g below 2^16, `quotient(v, reciprocal(g))` is ⌊v / g⌋
/// (its error, below g, times v stays below 2^32).
fn reciprocal(g: u32) -> u64 {
    if g == 0 {
        0
    } else {
        (1u64 << 32).div_ceil(u64::from(g))
    }
}

fn quotient(v: u32, recip: u64) -> u32 {
    ((u64::from(v) * recip) >> 32) as u32
}

/// Each element divided by `g` (0 when `g` is: every element is then 0).
fn divide(e: &mut Tile, g: u16) {
    match g {
        1 => {}
        g if g.is_power_of_two() => e.iter_mut().for_each(|v| *v >>= g.trailing_zeros()),
        g => {
            let r = reciprocal(u32::from(g));
            e.iter_mut().for_each(|v| *v = quotient(u32::from(*v), r) as u16);
        }
    }
}

/// The Lorenzo residuals of a tile: its differences along z, then y, then x
/// (0 before the tile's first element on each axis), wrapping.
fn difference(e: &mut Tile) {
    for k in (1..8).rev() {
        let (before, here) = e.split_at_mut(64 * k);
        here[..64].iter_mut().zip(&before[64 * (k - 1)..]).for_each(|(v, &p)| *v = v.wrapping_sub(p));
    }
    for layer in e.chunks_exact_mut(64) {
        for j in (1..8).rev() {
            let (before, here) = layer.split_at_mut(8 * j);
            here[..8].iter_mut().zip(&before[8 * (j - 1)..]).for_each(|(v, &p)| *v = v.wrapping_sub(p));
        }
    }
    for row in e.chunks_exact_mut(8) {
        for i in (1..8).rev() {
            row[i] = row[i].wrapping_sub(row[i - 1]);
        }
    }
}

/// A row's running sums, on x86-64 in one SSE2 register (three shifted
/// adds), which the compiler does not find from the portable form.
#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
fn row_sums(r: [u16; 8]) -> [u16; 8] {
    use std::arch::x86_64::{__m128i, _mm_add_epi16, _mm_slli_si128};
    let v: __m128i = bytemuck::cast(r);
    // SAFETY: the target has SSE2 (the cfg above); the intrinsics touch no memory.
    let v = unsafe {
        let v = _mm_add_epi16(v, _mm_slli_si128::<2>(v));
        let v = _mm_add_epi16(v, _mm_slli_si128::<4>(v));
        _mm_add_epi16(v, _mm_slli_si128::<8>(v))
    };
    bytemuck::cast(v)
}

#[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
fn row_sums(r: [u16; 8]) -> [u16; 8] {
    let r = add(r, shifted::<1>(r));
    let r = add(r, shifted::<2>(r));
    add(r, shifted::<4>(r))
}

/// A row moved `S` elements along, zeros coming in.
#[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
fn shifted<const S: usize>(r: [u16; 8]) -> [u16; 8] {
    std::array::from_fn(|i| if i >= S { r[i - S] } else { 0 })
}

#[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
fn add(a: [u16; 8], b: [u16; 8]) -> [u16; 8] {
    std::array::from_fn(|i| a[i].wrapping_add(b[i]))
}

fn gcd(mut a: u32, mut b: u32) -> u32 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    fn atlas(t: Tiles, slabs: usize, f: impl Fn(usize) -> u32) -> Vec<u8> {
        let n = slabs * t.slab_bytes() / t.width as usize;
        (0..n).flat_map(|i| f(i).to_le_bytes().into_iter().take(t.width as usize)).collect()
    }

    /// The filter as the format page words it, element by element with the
    /// 7-term predictor over a zero-bordered cube: what the fast one must match.
    fn reference(t: Tiles, raw: &[u8]) -> Vec<u8> {
        let w = t.width as usize;
        let tiles = t.count(raw.len()).unwrap();
        let get = |i: usize| if w == 1 { u32::from(raw[i]) } else { u32::from(u16::from_le_bytes([raw[2 * i], raw[2 * i + 1]])) };
        let (row, h) = (8 * t.x as usize, 8 * t.y as usize);
        let mut out = vec![0u32; tiles * (TILE + 1)];
        let (divisors, residuals) = out.split_at_mut(tiles);
        for (k, (g, r)) in divisors.iter_mut().zip(residuals.chunks_exact_mut(TILE)).enumerate() {
            let (a, b, c) = (k % t.x as usize, k / t.x as usize % t.y as usize, k / (t.x as usize * t.y as usize));
            let e: Vec<u32> = (0..TILE).map(|i| get(8 * a + i % 8 + row * (8 * b + i / 8 % 8 + h * (8 * c + i / 64)))).collect();
            *g = e.iter().fold(0, |g, &v| gcd(g, v));
            let mut cube = [0u32; 729];
            for (i, r) in r.iter_mut().enumerate() {
                let at = i % 8 + 1 + 9 * (i / 8 % 8 + 1 + 9 * (i / 64 + 1));
                cube[at] = e[i].checked_div(*g).unwrap_or(0);
                let c = |d: usize| cube[at - d];
                let p = c(1).wrapping_add(c(9)).wrapping_add(c(81)).wrapping_sub(c(10)).wrapping_sub(c(82)).wrapping_sub(c(90)).wrapping_add(c(91));
                *r = if t.predict { cube[at].wrapping_sub(p) } else { cube[at] };
            }
        }
        let m = out.len();
        let mut bytes = vec![0u8; m * w];
        for (i, v) in out.iter().enumerate() {
            for j in 0..w {
                bytes[j * m + i] = (v >> (8 * j)) as u8;
            }
        }
        bytes
    }

    #[test]
    fn tiles_undo_what_they_do() {
        for (t, slabs) in [
            (Tiles { width: 1, x: 3, y: 2, predict: true }, 2),
            (Tiles { width: 2, x: 1, y: 4, predict: true }, 1),
            (Tiles { width: 2, x: 5, y: 1, predict: true }, 3),
            (Tiles { width: 1, x: 2, y: 3, predict: false }, 2),
            (Tiles { width: 2, x: 3, y: 1, predict: false }, 1),
        ] {
            let steps = |i: usize| [1u32, 2, 3, 6, 7, 64, 255, 1000, 4097][i / 512 % 9];
            for raw in [
                atlas(t, slabs, |i| (i * 7 % 251 + i / 64) as u32 * 3),
                atlas(t, slabs, |i| (i * 2654435761) as u32 >> 7),
                atlas(t, slabs, |i| ((i * 2654435761) as u32 >> 20 & 0xf) * steps(i)),
                atlas(t, slabs, |i| (i as u32 % 13) * steps(i)),
                atlas(t, slabs, |_| 0),
            ] {
                let f = t.apply(&raw);
                assert_eq!(Some(f.len()), t.filtered_len(raw.len()));
                assert!(f == reference(t, &raw), "{t:?}: not the bytes the format page gives");
                let each = t.apply_each(&raw, &[false, true]);
                for (f, predict) in each.iter().zip([false, true]) {
                    assert!(*f == reference(Tiles { predict, ..t }, &raw), "{t:?}: one pass for both differs (predict {predict})");
                }
                // Samples: the divisors' start, across tiles and across the byte planes, the end.
                let m = f.len() / t.width as usize;
                let ranges = [0..3, 5..600, m - 700..m + 9, f.len() - 513..f.len()].map(|r| r.start.min(f.len())..r.end.min(f.len()));
                for (at, (f, predict)) in t.apply_each_at(&raw, &[false, true], &ranges).iter().zip(each.iter().zip([false, true])) {
                    let want: Vec<u8> = ranges.iter().flat_map(|r| &f[r.clone()]).copied().collect();
                    assert!(*at == want, "{t:?}: the sample's bytes differ (predict {predict})");
                }
                let mut back = vec![0u8; raw.len()];
                t.undo(&f, &mut back);
                assert_eq!(back, raw, "{t:?}");
            }
        }
    }

    #[test]
    fn tile_divisors_are_greatest() {
        let mut e = [0u16; TILE];
        assert_eq!(tile_gcd(&e), 0);
        for (vals, g) in [(&[12u16, 18, 30][..], 6), (&[65535, 21845], 21845), (&[4096, 6144, 0], 2048), (&[7, 0, 14, 5], 1), (&[0, 0, 65534], 65534)] {
            e = [0; TILE];
            e[TILE - vals.len()..].copy_from_slice(vals);
            assert_eq!(tile_gcd(&e), g, "{vals:?}");
            divide(&mut e, g);
            assert!(e[TILE - vals.len()..].iter().zip(vals).all(|(&q, &v)| u32::from(q) * u32::from(g) == u32::from(v)), "{vals:?}");
        }
    }

    #[test]
    fn a_ramp_on_a_step_leaves_its_divisor_and_little_else() {
        // Every element a multiple of 6 along a linear ramp: divisor 6, residuals 0 past the tile's edges.
        let t = Tiles { width: 1, x: 2, y: 1, predict: true };
        let w = 16;
        let raw = atlas(t, 1, |i| 6 * ((i % w) % 8 + (i / w % 8) + (i / (w * 8))) as u32);
        let f = t.apply(&raw);
        assert_eq!(&f[..2], &[6, 6]);
        let nonzero = f[2..].iter().filter(|&&b| b != 0).count();
        // Only elements on the tile's three faces through its first corner predict from zeros.
        assert!(nonzero <= 2 * 3 * 8, "{nonzero} non-zero residuals");
    }

    #[test]
    fn sections_that_are_not_whole_slabs_are_not_tiles() {
        let t = Tiles { width: 2, x: 2, y: 2, predict: true };
        assert_eq!(t.count(2 * 2 * 512 * 2), Some(4));
        assert_eq!(t.count(2 * 2 * 512 * 2 + 2), None);
        assert_eq!(Tiles::from_record(false, 1, 3 | 4 << 16), Some(Tiles { width: 1, x: 3, y: 4, predict: false }));
        assert_eq!(Tiles::from_record(true, 4, 3 | 4 << 16), None);
        assert_eq!(Tiles::from_record(true, 1, 3), None);
    }
}
