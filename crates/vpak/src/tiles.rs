//! The `tiles` filters (coding filters 3 and 4): an atlas of 8×8×8-texel
//! tiles of one `w`-byte lane (a 1-lane `unorm8`, `unorm16` or `f16` plane,
//! whose tiles are its bricks) stored tile by tile, each tile's elements
//! divided by their greatest common divisor and (filter 3) predicted from
//! their 3D neighbours in the tile (Lorenzo). Filter 4 leaves the quotients
//! unpredicted: sharp, sparse bricks (flames) compress better as they are. Texels snapped to a step of the error bound
//! (`cook --max-error --supercompress`) are multiples of their brick's step,
//! so what zstd sees is the same small residuals in every brick, whatever
//! its range; without the divisor each brick's step scatters them.

/// Elements of a tile.
pub const TILE: usize = 512;

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

    /// Element index in the section of element (x, y, z) of tile t.
    fn places(self, t: usize) -> impl Iterator<Item = usize> {
        let (w, h) = (8 * self.x as usize, 8 * self.y as usize);
        let per_slab = self.x as usize * self.y as usize;
        let (tx, ty, tz) = (t % self.x as usize, t / self.x as usize % self.y as usize, t / per_slab);
        let base = 8 * tx + w * (8 * ty + h * 8 * tz);
        (0..8).flat_map(move |z| (0..8).flat_map(move |y| (0..8).map(move |x| base + x + w * (y + h * z))))
    }

    /// The filtered bytes: the tiles' divisors, then each tile's residuals,
    /// the elements byte-shuffled as the shuffle filter does. `raw` must be a
    /// whole number of slabs ([`Tiles::count`]).
    pub fn apply(self, raw: &[u8]) -> Vec<u8> {
        let w = self.width as usize;
        let tiles = self.count(raw.len()).unwrap_or(0);
        let get = |i: usize| if w == 1 { u32::from(raw[i]) } else { u32::from(u16::from_le_bytes([raw[2 * i], raw[2 * i + 1]])) };
        let mut out = vec![0u32; tiles * (TILE + 1)];
        let (divisors, residuals) = out.split_at_mut(tiles);
        for (t, (g, r)) in divisors.iter_mut().zip(residuals.chunks_exact_mut(TILE)).enumerate() {
            let e: Vec<u32> = self.places(t).map(get).collect();
            *g = e.iter().fold(0, |g, &v| gcd(g, v));
            let n: Vec<u32> = e.iter().map(|&v| v.checked_div(*g).unwrap_or(0)).collect();
            let mut cube = [0u32; 729];
            for (i, r) in r.iter_mut().enumerate() {
                let at = padded(i);
                cube[at] = n[i];
                *r = if self.predict { n[i].wrapping_sub(predict(&cube, at)) } else { n[i] };
            }
        }
        // Little-endian bytes, shuffled: all low bytes, then all high ones.
        let m = out.len();
        let mut bytes = vec![0u8; m * w];
        for (i, v) in out.iter().enumerate() {
            for j in 0..w {
                bytes[j * m + i] = (v >> (8 * j)) as u8;
            }
        }
        bytes
    }

    /// Undoes [`Tiles::apply`]: `data` is the filtered form of `out`.
    pub fn undo(self, data: &[u8], out: &mut [u8]) {
        let w = self.width as usize;
        let tiles = self.count(out.len()).unwrap_or(0);
        let m = tiles * (TILE + 1);
        if data.len() != m * w {
            return;
        }
        let element = |i: usize| if w == 1 { u32::from(data[i]) } else { u32::from(data[i]) | u32::from(data[m + i]) << 8 };
        let mask = if w == 1 { 0xff } else { 0xffff };
        let mut cube = [0u32; 729];
        for t in 0..tiles {
            let g = element(t);
            let first = tiles + t * TILE;
            for (i, place) in self.places(t).enumerate() {
                let at = padded(i);
                let n = if self.predict { element(first + i).wrapping_add(predict(&cube, at)) & mask } else { element(first + i) };
                cube[at] = n;
                let v = n.wrapping_mul(g);
                if w == 1 {
                    out[place] = v as u8;
                } else {
                    out[2 * place..2 * place + 2].copy_from_slice(&(v as u16).to_le_bytes());
                }
            }
        }
    }
}

/// Index in a 9×9×9 cube (a zero border at 0 on each axis) of tile element i.
fn padded(i: usize) -> usize {
    let (x, y, z) = (i % 8 + 1, i / 8 % 8 + 1, i / 64 + 1);
    x + 9 * (y + 9 * z)
}

/// The Lorenzo prediction of the element at `at` from its seven neighbours
/// before it (0 outside the tile), wrapping.
fn predict(c: &[u32; 729], at: usize) -> u32 {
    let (dx, dy, dz) = (1, 9, 81);
    c[at - dx].wrapping_add(c[at - dy]).wrapping_add(c[at - dz]).wrapping_sub(c[at - dx - dy]).wrapping_sub(c[at - dx - dz]).wrapping_sub(c[at - dy - dz]).wrapping_add(c[at - dx - dy - dz])
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

    #[test]
    fn tiles_undo_what_they_do() {
        for (t, slabs) in [
            (Tiles { width: 1, x: 3, y: 2, predict: true }, 2),
            (Tiles { width: 2, x: 1, y: 4, predict: true }, 1),
            (Tiles { width: 2, x: 5, y: 1, predict: true }, 3),
            (Tiles { width: 1, x: 2, y: 3, predict: false }, 2),
            (Tiles { width: 2, x: 3, y: 1, predict: false }, 1),
        ] {
            for raw in [atlas(t, slabs, |i| (i * 7 % 251 + i / 64) as u32 * 3), atlas(t, slabs, |i| (i * 2654435761) as u32 >> 7), atlas(t, slabs, |_| 0)] {
                let f = t.apply(&raw);
                assert_eq!(Some(f.len()), t.filtered_len(raw.len()));
                let mut back = vec![0u8; raw.len()];
                t.undo(&f, &mut back);
                assert_eq!(back, raw, "{t:?}");
            }
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
