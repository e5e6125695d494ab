//! A bounds-checked little-endian reader over the file's bytes.

use crate::Error;

pub(crate) struct Cursor<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Cursor { data, pos: 0 }
    }

    pub fn at(data: &'a [u8], pos: usize) -> Result<Self, Error> {
        if pos > data.len() {
            return Err(Error::BadOffset { what: "grid data", offset: pos as i64, len: data.len() as u64 });
        }
        Ok(Cursor { data, pos })
    }

    pub fn pos(&self) -> usize {
        self.pos
    }

    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// Fails unless `count` items of at least `min_size` bytes each could still fit.
    pub fn check_count(&self, what: &'static str, count: u64, min_size: u64) -> Result<(), Error> {
        let need = count.saturating_mul(min_size);
        if need > self.remaining() as u64 {
            return Err(Error::Implausible { what, count, offset: self.pos as u64, remaining: self.remaining() as u64 });
        }
        Ok(())
    }

    pub fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], Error> {
        if n > self.remaining() {
            return Err(Error::Truncated { what, offset: self.pos as u64, need: n as u64, have: self.remaining() as u64 });
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    pub fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], Error> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub fn u8(&mut self, what: &'static str) -> Result<u8, Error> {
        Ok(self.array::<1>(what)?[0])
    }
    pub fn u32(&mut self, what: &'static str) -> Result<u32, Error> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
    pub fn i32(&mut self, what: &'static str) -> Result<i32, Error> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }
    pub fn i64(&mut self, what: &'static str) -> Result<i64, Error> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }
    pub fn f64(&mut self, what: &'static str) -> Result<f64, Error> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }

    /// An OpenVDB string: u32 length, then that many bytes (not NUL-terminated).
    pub fn string(&mut self, what: &'static str) -> Result<String, Error> {
        let len = self.u32(what)? as usize;
        let bytes = self.take(len, what)?;
        Ok(String::from_utf8_lossy(bytes).into_owned())
    }

    pub fn vec3d(&mut self, what: &'static str) -> Result<[f64; 3], Error> {
        Ok([self.f64(what)?, self.f64(what)?, self.f64(what)?])
    }

    pub fn coord(&mut self, what: &'static str) -> Result<vdbcook_grid::Coord, Error> {
        Ok(vdbcook_grid::Coord::new(self.i32(what)?, self.i32(what)?, self.i32(what)?))
    }

    /// Reads a node mask of `words` 64-bit words.
    pub fn mask(&mut self, words: usize, what: &'static str) -> Result<Vec<u64>, Error> {
        let bytes = self.take(words * 8, what)?;
        Ok(bytes.chunks_exact(8).map(|c| u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]])).collect())
    }
}

impl<'a> Cursor<'a> {
    /// The whole buffer this cursor reads.
    pub fn data(&self) -> &'a [u8] {
        self.data
    }
}
