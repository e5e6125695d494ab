//! Integer index-space coordinates and inclusive boxes.

/// An index-space voxel coordinate.  Ordered like OpenVDB's `Coord`: by x, then y, then z.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Coord {
    pub x: i32,
    pub y: i32,
    pub z: i32,
}

impl Coord {
    pub const fn new(x: i32, y: i32, z: i32) -> Coord {
        Coord { x, y, z }
    }
    /// Wrapping offset: callers only offset inside nodes whose origin was validated.
    #[inline]
    pub fn offset(self, dx: i32, dy: i32, dz: i32) -> Coord {
        Coord::new(self.x.wrapping_add(dx), self.y.wrapping_add(dy), self.z.wrapping_add(dz))
    }
    /// Origin of the 8³ leaf that contains this voxel.
    #[inline]
    pub fn leaf_origin(self) -> Coord {
        Coord::new(self.x & !7, self.y & !7, self.z & !7)
    }
    /// True when every component is a multiple of `dim` (a power of two).
    pub fn is_aligned(self, dim: i32) -> bool {
        let m = dim - 1;
        self.x & m == 0 && self.y & m == 0 && self.z & m == 0
    }
    pub fn to_array(self) -> [i32; 3] {
        [self.x, self.y, self.z]
    }
}

/// An inclusive, non-empty index-space box.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Bbox {
    pub min: Coord,
    pub max: Coord,
}

impl Bbox {
    pub fn new(min: Coord, max: Coord) -> Bbox {
        Bbox { min, max }
    }
    pub fn point(c: Coord) -> Bbox {
        Bbox { min: c, max: c }
    }
    pub fn expanded(self, c: Coord) -> Bbox {
        self.union(Bbox::point(c))
    }
    pub fn union(self, o: Bbox) -> Bbox {
        Bbox { min: Coord::new(self.min.x.min(o.min.x), self.min.y.min(o.min.y), self.min.z.min(o.min.z)), max: Coord::new(self.max.x.max(o.max.x), self.max.y.max(o.max.y), self.max.z.max(o.max.z)) }
    }
    pub fn contains(self, c: Coord) -> bool {
        (self.min.x..=self.max.x).contains(&c.x) && (self.min.y..=self.max.y).contains(&c.y) && (self.min.z..=self.max.z).contains(&c.z)
    }
    /// Edge lengths in voxels (as i64, since a box may span the whole i32 range).
    pub fn extent(self) -> [i64; 3] {
        [i64::from(self.max.x) - i64::from(self.min.x) + 1, i64::from(self.max.y) - i64::from(self.min.y) + 1, i64::from(self.max.z) - i64::from(self.min.z) + 1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leaf_origin_floors_negative_coordinates() {
        assert_eq!(Coord::new(-1, -8, -9).leaf_origin(), Coord::new(-8, -8, -16));
        assert_eq!(Coord::new(7, 8, 15).leaf_origin(), Coord::new(0, 8, 8));
    }

    #[test]
    fn ordering_is_lexicographic() {
        let mut v = vec![Coord::new(1, 0, 0), Coord::new(0, 5, 0), Coord::new(0, 0, 9), Coord::new(-1, 9, 9)];
        v.sort();
        assert_eq!(v, vec![Coord::new(-1, 9, 9), Coord::new(0, 0, 9), Coord::new(0, 5, 0), Coord::new(1, 0, 0)]);
    }

    #[test]
    fn bbox_union_and_extent() {
        let b = Bbox::point(Coord::new(0, 0, 0)).expanded(Coord::new(-3, 4, 1));
        assert_eq!(b, Bbox::new(Coord::new(-3, 0, 0), Coord::new(0, 4, 1)));
        assert_eq!(b.extent(), [4, 5, 2]);
        assert!(b.contains(Coord::new(-3, 4, 1)));
        assert!(!b.contains(Coord::new(1, 0, 0)));
    }
}
