//! One compressed stream to exactly `out.len()` bytes, per codec.
//!
//! c-blosc's wrappers (`*_wrap_decompress` in blosc/blosc.c) give each codec
//! an output buffer of exactly the stream's uncompressed size and require the
//! codec to fill it completely; so do we. None of these allocate more than a
//! bounded codec state because of the input.

use crate::{blosclz, snappy, Compressor};

/// Decodes one stream of `codec` into exactly `out.len()` bytes.
pub(crate) fn decode(codec: Compressor, input: &[u8], out: &mut [u8]) -> Result<(), String> {
    match codec {
        Compressor::BloscLz => blosclz::decompress(input, out),
        Compressor::Lz4 => lz4(input, out),
        Compressor::Snappy => snappy::decompress(input, out),
        Compressor::Zlib => zlib(input, out),
        Compressor::Zstd => zstd(input, out),
        Compressor::Unknown(code) => Err(format!("codec format {code} is not supported")),
    }
}

/// LZ4 block format (lz4 and lz4hc write the same format).
fn lz4(input: &[u8], out: &mut [u8]) -> Result<(), String> {
    let expected = out.len();
    match lz4_flex::block::decompress_into(input, out) {
        Ok(n) if n == expected => Ok(()),
        Ok(n) => Err(format!("lz4 block decodes to {n} bytes, expected {expected}")),
        Err(e) => Err(format!("lz4: {e}")),
    }
}

/// A zlib (RFC 1950) stream, Adler-32 checked, as zlib's `uncompress` reads.
fn zlib(input: &[u8], out: &mut [u8]) -> Result<(), String> {
    use flate2::{Decompress, FlushDecompress, Status};
    let expected = out.len();
    let mut z = Decompress::new(true);
    let status = z.decompress(input, out, FlushDecompress::Finish).map_err(|e| format!("zlib: {e}"))?;
    let written = z.total_out();
    match status {
        Status::StreamEnd if written == expected as u64 => Ok(()),
        Status::StreamEnd => Err(format!("zlib stream decodes to {written} bytes, expected {expected}")),
        _ if written == expected as u64 => Err(format!("zlib stream decodes to more than {expected} bytes")),
        _ => Err(format!(
            "zlib stream ends early after {} input bytes and {written} of {expected} \
             output bytes",
            z.total_in()
        )),
    }
}

const ZSTD_MAGIC: u32 = 0xFD2F_B528;
/// Window sizes up to this are always accepted; above it only up to the
/// next power of two of the stream's output size (what `ZSTD_compress`
/// chooses for a known source size).
const ZSTD_MIN_WINDOW_LIMIT: u64 = 1 << 20;

/// One or more Zstandard frames (skippable frames allowed), as
/// `ZSTD_decompress` reads them.
///
/// ruzstd keeps up to one window of output buffered and reserves it up
/// front, and the window size comes from the input; so every frame header is
/// checked here first and the output is drained block by block.
fn zstd(input: &[u8], out: &mut [u8]) -> Result<(), String> {
    use ruzstd::decoding::{BlockDecodingStrategy, FrameDecoder};
    use std::io::Read;

    let expected = out.len();
    let window_limit = (expected as u64).checked_next_power_of_two().unwrap_or(u64::MAX).max(ZSTD_MIN_WINDOW_LIMIT);
    let mut decoder = FrameDecoder::new();
    let mut rest = input;
    let mut written: usize = 0;

    while !rest.is_empty() {
        let remaining = expected.saturating_sub(written);
        match peek_zstd_frame(rest, remaining, window_limit)? {
            ZstdFrame::Skippable(total) => {
                rest = rest.get(total..).ok_or_else(|| "zstd skippable frame runs past the stream".to_string())?;
                continue;
            }
            ZstdFrame::Data => {}
        }
        decoder.reset(&mut rest).map_err(|e| format!("zstd frame header: {e}"))?;
        loop {
            decoder.decode_blocks(&mut rest, BlockDecodingStrategy::UptoBlocks(1)).map_err(|e| format!("zstd: {e}"))?;
            let target = out.get_mut(written..).unwrap_or_default();
            let n = decoder.read(target).map_err(|e| format!("zstd: {e}"))?;
            written = written.saturating_add(n);
            if decoder.can_collect() > 0 {
                return Err(format!("zstd data decodes to more than {expected} bytes"));
            }
            if decoder.is_finished() {
                break;
            }
        }
        if let (Some(stored), Some(computed)) = (decoder.get_checksum_from_data(), decoder.get_calculated_checksum()) {
            if stored != computed {
                return Err(format!(
                    "zstd content checksum {computed:#010x} does not match the stored \
                     {stored:#010x}"
                ));
            }
        }
    }
    if written != expected {
        return Err(format!("zstd data decodes to {written} bytes, expected {expected}"));
    }
    Ok(())
}

enum ZstdFrame {
    /// A skippable frame of this many bytes in total.
    Skippable(usize),
    /// A data frame whose header passed the checks.
    Data,
}

/// Checks a frame header before ruzstd sees it: the window size must not
/// exceed `window_limit`, and a declared content size must fit in the
/// `remaining` output. (Frame layout: RFC 8878 section 3.1.1.)
fn peek_zstd_frame(frame: &[u8], remaining: usize, window_limit: u64) -> Result<ZstdFrame, String> {
    let byte = |i: usize| -> Result<u64, String> { frame.get(i).map(|&b| u64::from(b)).ok_or_else(|| "zstd stream ends inside a frame header".to_string()) };
    let le = |from: usize, n: usize| -> Result<u64, String> {
        let mut v = 0u64;
        for i in (0..n).rev() {
            v = v << 8 | byte(from.saturating_add(i))?;
        }
        Ok(v)
    };
    let magic = le(0, 4)?;
    if (0x184D_2A50..=0x184D_2A5F).contains(&magic) {
        let len = le(4, 4)?;
        let total = usize::try_from(len.saturating_add(8)).unwrap_or(usize::MAX);
        return Ok(ZstdFrame::Skippable(total));
    }
    if magic != u64::from(ZSTD_MAGIC) {
        return Err(format!("zstd frame magic {magic:#010x}, expected {ZSTD_MAGIC:#010x}"));
    }
    let descriptor = byte(4)?;
    let single_segment = descriptor & 0x20 != 0;
    let dict_id_len: usize = match descriptor & 3 {
        0 => 0,
        1 => 1,
        2 => 2,
        _ => 4,
    };
    let fcs_len: usize = match descriptor >> 6 {
        0 if single_segment => 1,
        0 => 0,
        1 => 2,
        2 => 4,
        _ => 8,
    };
    let mut pos: usize = 5;
    let mut window: Option<u64> = None;
    if !single_segment {
        let wd = byte(pos)?;
        pos = pos.saturating_add(1);
        let exponent = wd >> 3;
        let mantissa = wd & 7;
        // exponent <= 31, so this cannot overflow.
        let base = 1024u64.checked_shl(exponent as u32).unwrap_or(u64::MAX);
        window = Some(base.saturating_add((base / 8).saturating_mul(mantissa)));
    }
    pos = pos.saturating_add(dict_id_len);
    let content_size = if fcs_len == 0 {
        None
    } else {
        let v = le(pos, fcs_len)?;
        Some(if fcs_len == 2 { v.saturating_add(256) } else { v })
    };
    if let Some(size) = content_size {
        if size > remaining as u64 {
            return Err(format!("zstd frame says {size} content bytes, but only {remaining} output bytes remain"));
        }
    }
    // A single-segment frame's window is its content size.
    let window = window.or(content_size).unwrap_or(0);
    if window > window_limit {
        return Err(format!(
            "zstd frame window of {window} bytes exceeds the {window_limit}-byte limit for \
             {remaining} output bytes"
        ));
    }
    Ok(ZstdFrame::Data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zstd_rejects_huge_window_before_allocating() {
        // Magic, descriptor without single segment, window descriptor with
        // exponent 31 (2 TiB window).
        let mut frame = ZSTD_MAGIC.to_le_bytes().to_vec();
        frame.extend_from_slice(&[0x00, 31 << 3, 0, 0, 0]);
        let mut out = [0u8; 16];
        let err = zstd(&frame, &mut out).unwrap_err();
        assert!(err.contains("window"), "{err}");
    }

    #[test]
    fn zstd_rejects_large_content_size() {
        // Single segment, 4-byte content size of 1000 with a 16-byte output.
        let mut frame = ZSTD_MAGIC.to_le_bytes().to_vec();
        frame.push(0x20 | (2 << 6));
        frame.extend_from_slice(&1000u32.to_le_bytes());
        let mut out = [0u8; 16];
        let err = zstd(&frame, &mut out).unwrap_err();
        assert!(err.contains("content bytes"), "{err}");
    }

    #[test]
    fn zstd_raw_block_frame() {
        // Hand-made frame: single segment, 1-byte content size 5, one raw
        // last block (header: last=1, type=0 raw, size=5).
        let mut frame = ZSTD_MAGIC.to_le_bytes().to_vec();
        frame.extend_from_slice(&[0x20, 5]);
        let block_header: u32 = 1 | (5 << 3);
        frame.extend_from_slice(&block_header.to_le_bytes()[..3]);
        frame.extend_from_slice(b"hello");
        let mut out = [0u8; 5];
        zstd(&frame, &mut out).unwrap();
        assert_eq!(&out, b"hello");
        // Too small an output.
        let mut small = [0u8; 4];
        assert!(zstd(&frame, &mut small).is_err());
        // Two frames back to back, with a skippable frame between them.
        let mut two = frame.clone();
        two.extend_from_slice(&0x184D_2A50u32.to_le_bytes());
        two.extend_from_slice(&3u32.to_le_bytes());
        two.extend_from_slice(b"xyz");
        two.extend_from_slice(&frame);
        let mut out = [0u8; 10];
        zstd(&two, &mut out).unwrap();
        assert_eq!(&out, b"hellohello");
    }

    #[test]
    fn zstd_rle_bomb_stops_at_the_output_size() {
        // Window 1 KiB, no content size, 1000 RLE blocks of 1000 bytes each
        // (1 MB from 4 KB of input) into a 16-byte output.
        let mut frame = ZSTD_MAGIC.to_le_bytes().to_vec();
        frame.extend_from_slice(&[0x00, 0x00]);
        for i in 0..1000u32 {
            let last = u32::from(i == 999);
            let header = last | (1 << 1) | (1000 << 3);
            frame.extend_from_slice(&header.to_le_bytes()[..3]);
            frame.push(b'x');
        }
        let mut out = [0u8; 16];
        let err = zstd(&frame, &mut out).unwrap_err();
        assert!(err.contains("more than 16"), "{err}");
        // The same frame into an exactly sized output decodes.
        let mut out = vec![0u8; 1_000_000];
        zstd(&frame, &mut out).unwrap();
        assert!(out.iter().all(|&b| b == b'x'));
    }

    #[test]
    fn zlib_round_trip_and_errors() {
        use flate2::{write::ZlibEncoder, Compression};
        use std::io::Write;
        let data: Vec<u8> = (0..5000u32).map(|i| (i % 97) as u8).collect();
        let mut enc = ZlibEncoder::new(Vec::new(), Compression::default());
        enc.write_all(&data).unwrap();
        let z = enc.finish().unwrap();
        let mut out = vec![0u8; data.len()];
        zlib(&z, &mut out).unwrap();
        assert_eq!(out, data);
        let mut short = vec![0u8; data.len() - 1];
        assert!(zlib(&z, &mut short).unwrap_err().contains("more than"));
        let mut long = vec![0u8; data.len() + 1];
        assert!(zlib(&z, &mut long).is_err());
        assert!(zlib(&z[..z.len() / 2], &mut out).unwrap_err().contains("early"));
    }

    #[test]
    fn lz4_round_trip_and_errors() {
        let data: Vec<u8> = (0..5000u32).map(|i| (i % 97) as u8).collect();
        let c = lz4_flex::block::compress(&data);
        let mut out = vec![0u8; data.len()];
        lz4(&c, &mut out).unwrap();
        assert_eq!(out, data);
        let mut long = vec![0u8; data.len() + 1];
        assert!(lz4(&c, &mut long).is_err());
        let mut short = vec![0u8; data.len() - 1];
        assert!(lz4(&c, &mut short).is_err());
    }
}
