//! Header parsing, validation and the walk over blocks and streams.
//!
//! Mirrors `blosc_run_decompression_with_context`, `serial_blosc` and
//! `blosc_d` of c-blosc 1.21 (blosc/blosc.c), with every offset checked.

use crate::{codecs, shuffle, Compressor, Error, Header, Shuffle, BLOSC_VERSION_FORMAT, FLAG_BITSHUFFLE, FLAG_DONT_SPLIT, FLAG_RESERVED, FLAG_SHUFFLE, HEADER_LEN, MAX_BLOCKSIZE, MAX_NBYTES};

/// Blocks are only split when `typesize <= MAX_SPLITS` (c-blosc's `MAX_SPLITS`).
const MAX_SPLITS: usize = 16;
/// ... and when each stream would hold at least this many bytes
/// (c-blosc's `MIN_BUFFERSIZE`).
const MIN_BUFFERSIZE: usize = 128;
/// The only codec format version any c-blosc 1.x writes
/// (`BLOSC_*_VERSION_FORMAT` in blosc.h are all 1).
const CODEC_VERSION_FORMAT: u8 = 1;

/// Parses the 16-byte header at the start of `src`.
///
/// Only fails when `src` is shorter than the header; the fields are not
/// validated (that is [`decompress_into`]'s job), so this also works for
/// looking at buffers this crate would refuse.
pub fn header(src: &[u8]) -> Result<Header, Error> {
    let bytes: [u8; HEADER_LEN] = src.get(..HEADER_LEN).and_then(|h| h.try_into().ok()).ok_or(Error::TruncatedHeader { len: src.len() })?;
    let [version, versionlz, flags, typesize, n0, n1, n2, n3, b0, b1, b2, b3, c0, c1, c2, c3] = bytes;
    let shuffle = if flags & FLAG_SHUFFLE != 0 {
        Shuffle::Byte
    } else if flags & FLAG_BITSHUFFLE != 0 {
        Shuffle::Bit
    } else {
        Shuffle::None
    };
    Ok(Header {
        version,
        versionlz,
        flags,
        typesize,
        nbytes: u32::from_le_bytes([n0, n1, n2, n3]),
        blocksize: u32::from_le_bytes([b0, b1, b2, b3]),
        cbytes: u32::from_le_bytes([c0, c1, c2, c3]),
        compressor: Compressor::from_format(flags >> 5),
        shuffle,
    })
}

/// Decompresses a blosc 1.x buffer into a new vector.
///
/// Fails, before allocating anything, unless the header's uncompressed size
/// is exactly `expected_len`; so the allocation is bounded by the caller, not
/// by the input. Extra memory while decoding is at most one block (never
/// larger than `expected_len`) plus the fixed state of the zlib/zstd decoders.
pub fn decompress(src: &[u8], expected_len: usize) -> Result<Vec<u8>, Error> {
    let h = header(src)?;
    check_nbytes(&h, expected_len)?;
    let mut out = Vec::new();
    out.try_reserve_exact(expected_len).map_err(|_| Error::OutOfMemory { bytes: expected_len })?;
    out.resize(expected_len, 0);
    decompress_into(src, &mut out)?;
    Ok(out)
}

/// Decompresses a blosc 1.x buffer into `dst`, whose length must equal the
/// header's uncompressed size.
///
/// `src` may be longer than the header's compressed size (the rest is
/// ignored) but not shorter. On error `dst` holds unspecified bytes.
pub fn decompress_into(src: &[u8], dst: &mut [u8]) -> Result<(), Error> {
    let h = header(src)?;
    check_nbytes(&h, dst.len())?;

    let cbytes = to_usize(h.cbytes);
    // Everything past cbytes is ignored; every offset below is checked
    // against this slice.
    let buf = src.get(..cbytes).ok_or(Error::CompressedSizeExceedsInput { cbytes: h.cbytes, available: src.len() })?;
    if cbytes < HEADER_LEN {
        return Err(Error::CompressedSizeTooSmall { cbytes: h.cbytes });
    }
    if dst.is_empty() {
        // c-blosc returns right away for an empty buffer.
        return Ok(());
    }

    if h.typesize == 0 {
        return Err(Error::ZeroTypesize);
    }
    let max_blocksize = h.nbytes.min(MAX_BLOCKSIZE);
    if h.blocksize == 0 || h.blocksize > max_blocksize {
        return Err(Error::InvalidBlockSize { blocksize: h.blocksize, max: max_blocksize });
    }

    if h.memcpyed() {
        let expected = u64::from(h.nbytes).saturating_add(HEADER_LEN as u64);
        if u64::from(h.cbytes) != expected {
            return Err(Error::MemcpySizeMismatch { cbytes: h.cbytes, expected });
        }
        // cbytes == nbytes + 16 and buf.len() == cbytes, so this is the
        // whole payload.
        let raw = buf.get(HEADER_LEN..).ok_or(Error::CompressedSizeTooSmall { cbytes: h.cbytes })?;
        copy_exact(dst, raw);
        return Ok(());
    }

    if let Compressor::Unknown(code) = h.compressor {
        return Err(Error::UnsupportedCodec { code });
    }
    if h.versionlz != CODEC_VERSION_FORMAT {
        return Err(Error::UnsupportedCodecVersion { codec: h.compressor, found: h.versionlz });
    }

    let blocksize = to_usize(h.blocksize);
    // blocksize >= 1 was checked above.
    let nblocks = dst.len().div_ceil(blocksize);
    // The block-start table: one i32 per block right after the header.
    let table = nblocks.checked_mul(4).and_then(|len| buf.get(HEADER_LEN..)?.get(..len)).ok_or(Error::BlockTableTruncated { nblocks: nblocks as u64, cbytes: h.cbytes })?;

    let ctx = Frame { buf, typesize: usize::from(h.typesize), typesize_u8: h.typesize, flags: h.flags, codec: h.compressor, cbytes: h.cbytes };
    // Scratch space for un-shuffling; at most one block, allocated on first
    // use.
    let mut scratch: Vec<u8> = Vec::new();

    // chunks_mut yields exactly nblocks chunks; only the last can be short,
    // and it is short exactly when nbytes % blocksize != 0 (the leftover
    // block).
    for (block, (dst_block, start)) in dst.chunks_mut(blocksize).zip(table.chunks_exact(4)).enumerate() {
        let start = read_i32(start).ok_or(Error::BlockTableTruncated { nblocks: nblocks as u64, cbytes: h.cbytes })?;
        let leftover_block = dst_block.len() < blocksize;
        ctx.block(block, start, leftover_block, dst_block, &mut scratch, blocksize)?;
    }
    Ok(())
}

/// Validated, per-buffer values shared by every block.
struct Frame<'a> {
    /// The compressed buffer, cut to the header's `cbytes`.
    buf: &'a [u8],
    typesize: usize,
    typesize_u8: u8,
    flags: u8,
    codec: Compressor,
    cbytes: u32,
}

impl Frame<'_> {
    /// Decodes one block (`blosc_d`).
    fn block(&self, block: usize, start: i32, leftover_block: bool, dst: &mut [u8], scratch: &mut Vec<u8>, blocksize: usize) -> Result<(), Error> {
        let len = dst.len();
        let ts = self.typesize;
        // Byte shuffle only acts for typesize > 1; otherwise a set bit-shuffle
        // flag acts, but only on blocks holding at least one element. (Exactly
        // the `doshuffle` / `dobitshuffle` conditions of `blosc_d`.)
        let byte_shuffle = self.flags & FLAG_SHUFFLE != 0 && ts > 1;
        let bit_shuffle = !byte_shuffle && self.flags & FLAG_BITSHUFFLE != 0 && len >= ts;

        // The split rule of `blosc_d`. c-blosc >= 1.14 writes the dont_split
        // flag whenever it did not split; the typesize and size conditions
        // are what older versions decided on alone, and 1.14+ still checks
        // them when reading. (A 1.14+ writer forced to BLOSC_ALWAYS_SPLIT
        // outside those conditions writes buffers c-blosc itself cannot read;
        // we refuse them the same way.)
        let split = self.flags & FLAG_DONT_SPLIT == 0 && ts <= MAX_SPLITS && len.checked_div(ts).unwrap_or(0) >= MIN_BUFFERSIZE && !leftover_block;
        let nsplits = if split { ts } else { 1 };
        if len.checked_rem(nsplits) != Some(0) {
            return Err(Error::UnevenSplit { block, len, typesize: self.typesize_u8 });
        }
        // len >= 1, and nsplits <= len / 128 when splitting, so neblock >= 1.
        let neblock = len.checked_div(nsplits).unwrap_or(0).max(1);

        let max_start = self.buf.len().saturating_sub(4);
        let offset = usize::try_from(start).ok().filter(|&o| o <= max_start).ok_or(Error::BadBlockStart { block, offset: start, max: max_start })?;

        if byte_shuffle || bit_shuffle {
            if scratch.capacity() < blocksize {
                scratch.try_reserve_exact(blocksize).map_err(|_| Error::OutOfMemory { bytes: blocksize })?;
            }
            scratch.resize(len, 0);
            self.streams(block, offset, neblock, scratch)?;
            if byte_shuffle {
                shuffle::unshuffle(ts, scratch, dst);
            } else {
                shuffle::bitunshuffle(ts, scratch, dst);
            }
        } else {
            self.streams(block, offset, neblock, dst)?;
        }
        Ok(())
    }

    /// Decodes the `out.len() / neblock` consecutive streams of one block,
    /// starting at `offset` in the compressed buffer, into `out`.
    fn streams(&self, block: usize, mut offset: usize, neblock: usize, out: &mut [u8]) -> Result<(), Error> {
        for (stream, out) in out.chunks_exact_mut(neblock).enumerate() {
            let size_field = offset.checked_add(4).and_then(|end| self.buf.get(offset..end)).and_then(read_i32).ok_or(Error::TruncatedStreamHeader { block, stream, offset, cbytes: self.cbytes })?;
            // offset + 4 <= buf.len() was just checked.
            let data_start = offset.saturating_add(4);
            let rest = self.buf.get(data_start..).unwrap_or_default();
            let csize = usize::try_from(size_field).ok().filter(|&s| s <= rest.len()).ok_or(Error::BadStreamSize { block, stream, size: size_field, available: rest.len() })?;
            let data = rest.get(..csize).unwrap_or_default();
            if csize == neblock {
                // Stored raw: the writer could not compress this stream.
                copy_exact(out, data);
            } else {
                codecs::decode(self.codec, data, out).map_err(|reason| Error::CorruptStream { block, stream, codec: self.codec, reason })?;
            }
            offset = data_start.saturating_add(csize);
        }
        Ok(())
    }
}

/// Checks the header fields every buffer must get right, and that the
/// uncompressed size is what the caller expects.
fn check_nbytes(h: &Header, expected: usize) -> Result<(), Error> {
    if h.version != BLOSC_VERSION_FORMAT {
        return Err(Error::UnsupportedVersion { found: h.version });
    }
    if h.flags & FLAG_RESERVED != 0 {
        return Err(Error::ReservedFlag { flags: h.flags });
    }
    if h.nbytes > MAX_NBYTES {
        return Err(Error::TooLarge { found: h.nbytes });
    }
    if usize::try_from(h.nbytes).ok() != Some(expected) {
        return Err(Error::SizeMismatch { found: h.nbytes, expected });
    }
    Ok(())
}

/// u32 to usize; saturates on (hypothetical) 16-bit targets, where every
/// later bounds check then fails cleanly.
fn to_usize(v: u32) -> usize {
    usize::try_from(v).unwrap_or(usize::MAX)
}

fn read_i32(bytes: &[u8]) -> Option<i32> {
    Some(i32::from_le_bytes(bytes.try_into().ok()?))
}

/// Copies `src` into `dst`; both have the same length at every call site
/// (the fallback only exists so that a mistake cannot panic).
pub(crate) fn copy_exact(dst: &mut [u8], src: &[u8]) {
    if dst.len() == src.len() {
        dst.copy_from_slice(src);
    } else {
        for (d, s) in dst.iter_mut().zip(src) {
            *d = *s;
        }
    }
}
