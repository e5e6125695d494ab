//! A pure-Rust, panic-free decoder for the c-blosc **1.x** buffer format, the
//! one OpenVDB uses for voxel buffers written with `COMPRESS_BLOSC`.
//!
//! Only decoding is implemented. The input is treated as hostile: every
//! offset and size read from it is validated against the input length and
//! the caller's expected output size, nothing read from the input can make the
//! decoder allocate more than the expected output size (plus bounded codec
//! state), and no input can make it panic.
//!
//! # Byte layout
//!
//! ```text
//! offset  size  field
//! ------  ----  -----------------------------------------------------------
//!      0     1  version      blosc format version, 2 for every c-blosc 1.x
//!      1     1  versionlz    format version of the codec below, 1 for all
//!      2     1  flags        bit 0  0x01  byte shuffle
//!                            bit 1  0x02  memcpyed: data stored raw
//!                            bit 2  0x04  bit shuffle
//!                            bit 3  0x08  reserved, must be 0
//!                            bit 4  0x10  dont_split (set by c-blosc >= 1.14
//!                                         when it did not split blocks)
//!                            bits 5-7     codec: 0 blosclz, 1 lz4 and lz4hc,
//!                                         2 snappy, 3 zlib, 4 zstd
//!      3     1  typesize     element size in bytes, 1..=255
//!      4     4  nbytes       u32 LE, uncompressed size
//!      8     4  blocksize    u32 LE, uncompressed bytes per block
//!     12     4  cbytes       u32 LE, total compressed size incl. header
//!
//! memcpyed (flags & 0x02):
//!     16 nbytes raw bytes follow; cbytes == nbytes + 16.
//!
//! otherwise, with nblocks = ceil(nbytes / blocksize) and the last block
//! holding only nbytes % blocksize bytes when that is not 0 (the "leftover
//! block"):
//!     16  4*nblocks  bstarts[i]: i32 LE, offset of block i from byte 0
//!
//!   block i, at bstarts[i]: nsplits streams, one after the other
//!     +--------------+----------------+--------------+----------------+--
//!     | i32 LE csize | csize bytes    | i32 LE csize | csize bytes    | ...
//!     +--------------+----------------+--------------+----------------+--
//!     each stream decodes to neblock = block_len / nsplits bytes; a stream
//!     whose csize == neblock is stored raw (uncompressed).
//!
//!   nsplits = typesize when ALL of these hold, else 1:
//!     * flags bit 4 (dont_split) is clear,
//!     * typesize <= 16 and block_len / typesize >= 128,
//!     * the block is not the leftover block.
//!   (`blosc_d` in c-blosc 1.14 .. 1.21 blosc/blosc.c. Before 1.14 there was
//!   no dont_split flag and the other two conditions alone decided, so the
//!   same rule reads old buffers.)
//!
//!   The concatenated stream outputs form the block in "shuffled" order when
//!   a shuffle flag is set; the block is then un-shuffled:
//!     byte shuffle (bit 0, only when typesize > 1): byte j of element i is
//!       at j * (block_len / typesize) + i; the block_len % typesize tail
//!       bytes are stored unshuffled.
//!     bit shuffle (bit 2, only when bit 0 is not acting and
//!       block_len >= typesize): see [`shuffle`]; when the element count is
//!       not a multiple of 8 the whole block is stored unshuffled.
//! ```
//!
//! # Example
//!
//! ```
//! // A memcpyed frame: 16-byte header followed by the raw bytes.
//! let mut frame = vec![2, 1, 0x02, 1];
//! frame.extend_from_slice(&3u32.to_le_bytes()); // nbytes
//! frame.extend_from_slice(&3u32.to_le_bytes()); // blocksize
//! frame.extend_from_slice(&19u32.to_le_bytes()); // cbytes
//! frame.extend_from_slice(b"abc");
//! assert_eq!(vdbcook_blosc::decompress(&frame, 3).unwrap(), b"abc");
//! assert!(vdbcook_blosc::decompress(&frame, 4).is_err());
//! ```

// Library code must not be able to panic on any input: no indexing, no
// unwrap, no unchecked arithmetic. Tests may do as they like.
#![cfg_attr(
    not(test),
    deny(clippy::indexing_slicing, clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::arithmetic_side_effects, clippy::unreachable, clippy::todo, clippy::unimplemented)
)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

mod blosclz;
mod codecs;
mod frame;
pub mod shuffle;
mod snappy;

pub use frame::{decompress, decompress_into, header};

use std::fmt;

/// Size of the c-blosc 1.x header in bytes.
pub const HEADER_LEN: usize = 16;

/// The only blosc format version written by c-blosc 1.x (`BLOSC_VERSION_FORMAT`).
pub const BLOSC_VERSION_FORMAT: u8 = 2;

/// Largest uncompressed size c-blosc 1.x handles (`nbytes` is an `int32_t` there).
pub const MAX_NBYTES: u32 = i32::MAX as u32;

/// Largest block size c-blosc 1.x accepts (`BLOSC_MAX_BLOCKSIZE` in blosc.h:
/// `(INT_MAX - BLOSC_MAX_TYPESIZE * sizeof(int32_t)) / 3`).
pub const MAX_BLOCKSIZE: u32 = (i32::MAX as u32 - 255 * 4) / 3;

/// Header flag: byte shuffle.
pub const FLAG_SHUFFLE: u8 = 0x01;
/// Header flag: data is stored raw after the header.
pub const FLAG_MEMCPYED: u8 = 0x02;
/// Header flag: bit shuffle.
pub const FLAG_BITSHUFFLE: u8 = 0x04;
/// Header flag bit that c-blosc 1.x rejects as "from the future".
pub const FLAG_RESERVED: u8 = 0x08;
/// Header flag: blocks are not split into `typesize` streams.
pub const FLAG_DONT_SPLIT: u8 = 0x10;

/// The codec named by bits 5-7 of the header flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Compressor {
    /// BloscLZ, blosc's own FastLZ derivative (format 0).
    BloscLz,
    /// LZ4 block format; both `lz4` and `lz4hc` write it (format 1).
    Lz4,
    /// Snappy raw format (format 2).
    Snappy,
    /// zlib stream, RFC 1950 (format 3).
    Zlib,
    /// Zstandard frames (format 4).
    Zstd,
    /// Formats 5 to 7, which c-blosc 1.x never writes.
    Unknown(u8),
}

impl Compressor {
    /// Maps the 3-bit codec format from the header flags.
    pub fn from_format(code: u8) -> Compressor {
        match code {
            0 => Compressor::BloscLz,
            1 => Compressor::Lz4,
            2 => Compressor::Snappy,
            3 => Compressor::Zlib,
            4 => Compressor::Zstd,
            other => Compressor::Unknown(other),
        }
    }

    /// The 3-bit codec format stored in the header flags.
    pub fn format(self) -> u8 {
        match self {
            Compressor::BloscLz => 0,
            Compressor::Lz4 => 1,
            Compressor::Snappy => 2,
            Compressor::Zlib => 3,
            Compressor::Zstd => 4,
            Compressor::Unknown(code) => code,
        }
    }
}

impl fmt::Display for Compressor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Compressor::BloscLz => f.write_str("blosclz"),
            Compressor::Lz4 => f.write_str("lz4"),
            Compressor::Snappy => f.write_str("snappy"),
            Compressor::Zlib => f.write_str("zlib"),
            Compressor::Zstd => f.write_str("zstd"),
            Compressor::Unknown(code) => write!(f, "unknown codec format {code}"),
        }
    }
}

/// The shuffle filter a buffer was written with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Shuffle {
    /// No filter.
    None,
    /// Byte shuffle (flags bit 0). A no-op for typesize 1.
    Byte,
    /// Bit shuffle (flags bit 2).
    Bit,
}

/// The parsed 16-byte header of a blosc 1.x buffer.
///
/// [`header`] only parses; [`decompress_into`] validates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Header {
    /// Blosc format version (byte 0); 2 for c-blosc 1.x.
    pub version: u8,
    /// Codec format version (byte 1); 1 for every codec in c-blosc 1.x.
    pub versionlz: u8,
    /// Raw flags byte (byte 2).
    pub flags: u8,
    /// Element size in bytes (byte 3).
    pub typesize: u8,
    /// Uncompressed size in bytes.
    pub nbytes: u32,
    /// Uncompressed bytes per block (the last block may be shorter).
    pub blocksize: u32,
    /// Compressed size in bytes, header included.
    pub cbytes: u32,
    /// Codec from flags bits 5-7.
    pub compressor: Compressor,
    /// Shuffle filter from flags bits 0 and 2 (byte shuffle wins when both
    /// are set, as in c-blosc).
    pub shuffle: Shuffle,
}

impl Header {
    /// Whether the data is stored raw right after the header.
    pub fn memcpyed(&self) -> bool {
        self.flags & FLAG_MEMCPYED != 0
    }

    /// Whether the writer marked blocks as not split into streams.
    pub fn dont_split(&self) -> bool {
        self.flags & FLAG_DONT_SPLIT != 0
    }
}

/// Everything that can go wrong while decoding. Messages are lowercase and
/// state the value found and what was expected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The input cannot even hold the header.
    #[error("blosc buffer is {len} bytes, expected at least the 16-byte header")]
    TruncatedHeader {
        /// Input length.
        len: usize,
    },
    /// Header byte 0 is not 2.
    #[error("blosc format version {found} is not supported, expected {BLOSC_VERSION_FORMAT}")]
    UnsupportedVersion {
        /// Version found.
        found: u8,
    },
    /// Flag bit 3 is set, which c-blosc 1.x rejects.
    #[error("blosc header flags {flags:#04x} set reserved bit 3, expected it clear")]
    ReservedFlag {
        /// Flags byte.
        flags: u8,
    },
    /// The header's uncompressed size is not what the caller expected.
    #[error("blosc header says {found} uncompressed bytes, expected {expected}")]
    SizeMismatch {
        /// `nbytes` from the header.
        found: u32,
        /// Size the caller expects (or the output buffer length).
        expected: usize,
    },
    /// The header's uncompressed size is beyond what c-blosc 1.x handles.
    #[error("blosc header says {found} uncompressed bytes, expected at most {MAX_NBYTES}")]
    TooLarge {
        /// `nbytes` from the header.
        found: u32,
    },
    /// The header claims more compressed bytes than the input holds.
    #[error("blosc header says {cbytes} compressed bytes, but the input holds only {available}")]
    CompressedSizeExceedsInput {
        /// `cbytes` from the header.
        cbytes: u32,
        /// Input length.
        available: usize,
    },
    /// The header's compressed size cannot even hold the header.
    #[error("blosc header says {cbytes} compressed bytes, expected at least 16")]
    CompressedSizeTooSmall {
        /// `cbytes` from the header.
        cbytes: u32,
    },
    /// Typesize 0.
    #[error("blosc header says typesize 0, expected 1 to 255")]
    ZeroTypesize,
    /// Block size 0, above the uncompressed size, or above c-blosc's limit.
    #[error("blosc header says block size {blocksize}, expected 1 to {max}")]
    InvalidBlockSize {
        /// `blocksize` from the header.
        blocksize: u32,
        /// The largest acceptable block size here.
        max: u32,
    },
    /// Codec formats 5 to 7.
    #[error(
        "blosc header says codec format {code}, expected 0 (blosclz), 1 (lz4/lz4hc), \
         2 (snappy), 3 (zlib) or 4 (zstd)"
    )]
    UnsupportedCodec {
        /// The 3-bit codec format.
        code: u8,
    },
    /// Header byte 1 is not 1 for a compressed buffer.
    #[error("blosc {codec} format version {found} is not supported, expected 1")]
    UnsupportedCodecVersion {
        /// The codec.
        codec: Compressor,
        /// `versionlz` from the header.
        found: u8,
    },
    /// A memcpyed buffer whose compressed size is not `nbytes + 16`.
    #[error(
        "blosc memcpyed buffer says {cbytes} compressed bytes, expected {expected} \
         (uncompressed size plus the 16-byte header)"
    )]
    MemcpySizeMismatch {
        /// `cbytes` from the header.
        cbytes: u32,
        /// `nbytes + 16`.
        expected: u64,
    },
    /// The block-start table does not fit in the compressed size.
    #[error("blosc block-start table for {nblocks} blocks does not fit in {cbytes} compressed bytes")]
    BlockTableTruncated {
        /// Number of blocks implied by `nbytes` and `blocksize`.
        nblocks: u64,
        /// `cbytes` from the header.
        cbytes: u32,
    },
    /// A block start outside the compressed buffer.
    #[error("blosc block {block} starts at offset {offset}, expected 0 to {max}")]
    BadBlockStart {
        /// Block index.
        block: usize,
        /// Offset read from the table.
        offset: i32,
        /// Largest offset that leaves room for a stream size field.
        max: usize,
    },
    /// A stream-size field that runs past the compressed buffer.
    #[error(
        "blosc block {block} stream {stream}: size field at offset {offset} runs past \
         the {cbytes} compressed bytes"
    )]
    TruncatedStreamHeader {
        /// Block index.
        block: usize,
        /// Stream index within the block.
        stream: usize,
        /// Offset of the 4-byte size field.
        offset: usize,
        /// `cbytes` from the header.
        cbytes: u32,
    },
    /// A stream size that is negative or runs past the compressed buffer.
    #[error(
        "blosc block {block} stream {stream} says {size} compressed bytes, expected 0 to \
         {available} (the bytes left in the buffer)"
    )]
    BadStreamSize {
        /// Block index.
        block: usize,
        /// Stream index within the block.
        stream: usize,
        /// Size read from the stream header.
        size: i32,
        /// Bytes left in the compressed buffer after the size field.
        available: usize,
    },
    /// A split block whose length is not a multiple of the typesize, which a
    /// valid writer never produces (c-blosc would leave bytes unwritten).
    #[error(
        "blosc block {block} is {len} bytes, expected a multiple of typesize {typesize} \
         for a block split into streams"
    )]
    UnevenSplit {
        /// Block index.
        block: usize,
        /// Block length.
        len: usize,
        /// Typesize (the number of streams).
        typesize: u8,
    },
    /// A codec stream that does not decode to exactly its expected size.
    #[error("blosc block {block} stream {stream}: corrupt {codec} data: {reason}")]
    CorruptStream {
        /// Block index.
        block: usize,
        /// Stream index within the block.
        stream: usize,
        /// The codec.
        codec: Compressor,
        /// What the codec decoder found.
        reason: String,
    },
    /// The output buffer could not be allocated.
    #[error("could not allocate {bytes} bytes for the blosc output")]
    OutOfMemory {
        /// Requested size.
        bytes: usize,
    },
}
