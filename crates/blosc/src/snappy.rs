//! Decoder for the Snappy raw (block) format, as written by
//! `snappy_compress` and read by `snappy_uncompress` (format_description.txt
//! in the snappy sources).
//!
//! ```text
//! preamble   uncompressed length, little-endian base-128 varint (<= 5 bytes)
//! then elements, each starting with a tag byte; tag & 3 selects:
//!   0 literal   len-1 = tag >> 2 when < 60; 60..=63 means len-1 follows in
//!               1..=4 little-endian bytes; then len literal bytes
//!   1 copy      len = 4 + ((tag >> 2) & 7), offset = (tag >> 5) << 8 | next
//!   2 copy      len = (tag >> 2) + 1, offset = next 2 bytes LE
//!   3 copy      len = (tag >> 2) + 1, offset = next 4 bytes LE
//! copies read `offset` bytes back in the output (offset 0 is invalid) and
//! may overlap their own output, byte by byte as in LZ77.
//! ```

use crate::blosclz::checked_copy_match;

/// Decodes `input` into exactly `out.len()` bytes; the preamble must state
/// that length (c-blosc checks the decoded size equals the stream size).
pub(crate) fn decompress(input: &[u8], out: &mut [u8]) -> Result<(), String> {
    let (declared, mut ip) = read_varint(input)?;
    let out_len = out.len();
    if usize::try_from(declared).ok() != Some(out_len) {
        return Err(format!("snappy stream says {declared} uncompressed bytes, expected {out_len}"));
    }
    let mut op: usize = 0;
    let take = |ip: &mut usize, n: usize| -> Result<&[u8], String> {
        let s = ip.checked_add(n).and_then(|end| input.get(*ip..end)).ok_or_else(|| "snappy stream ends inside an element".to_string())?;
        *ip = ip.saturating_add(n);
        Ok(s)
    };
    let le = |bytes: &[u8]| -> usize { bytes.iter().rev().fold(0usize, |acc, &b| acc << 8 | usize::from(b)) };

    while ip < input.len() {
        let tag = usize::from(*take(&mut ip, 1)?.first().unwrap_or(&0));
        let (len, offset) = match tag & 3 {
            0 => {
                let mut len = tag >> 2;
                if len >= 60 {
                    let extra = len.saturating_sub(59);
                    len = le(take(&mut ip, extra)?);
                }
                let len = len.saturating_add(1);
                let dst = op.checked_add(len).and_then(|end| out.get_mut(op..end)).ok_or_else(|| {
                    format!(
                        "literal of {len} bytes at output offset {op} overflows the \
                             {out_len}-byte output"
                    )
                })?;
                dst.copy_from_slice(take(&mut ip, len)?);
                op = op.saturating_add(len);
                continue;
            }
            1 => {
                let lo = le(take(&mut ip, 1)?);
                (4usize.saturating_add((tag >> 2) & 7), (tag >> 5) << 8 | lo)
            }
            2 => ((tag >> 2).saturating_add(1), le(take(&mut ip, 2)?)),
            _ => ((tag >> 2).saturating_add(1), le(take(&mut ip, 4)?)),
        };
        op = checked_copy_match(out, op, offset, len)?;
    }
    if op != out_len {
        return Err(format!("snappy stream decodes to {op} bytes, expected {out_len}"));
    }
    Ok(())
}

/// Reads the preamble varint (at most 32 bits); returns it and the position
/// after it.
fn read_varint(input: &[u8]) -> Result<(u32, usize), String> {
    let mut value: u32 = 0;
    for (i, &b) in input.iter().take(5).enumerate() {
        let shift = 7u32.saturating_mul(i as u32);
        let bits = u32::from(b & 0x7f);
        // The fifth byte may only carry the top 4 bits.
        if i == 4 && b > 0x0f {
            return Err("snappy length preamble exceeds 32 bits".into());
        }
        value |= bits.checked_shl(shift).unwrap_or(0);
        if b & 0x80 == 0 {
            return Ok((value, i.saturating_add(1)));
        }
    }
    Err("snappy stream ends inside its length preamble".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(input: &[u8], n: usize) -> Result<Vec<u8>, String> {
        let mut out = vec![0u8; n];
        decompress(input, &mut out).map(|()| out)
    }

    #[test]
    fn literals_and_copies() {
        // len 9; literal "abc" (tag (3-1)<<2); copy1 len 4 offset 3;
        // copy2 len 2 offset 1.
        let input = [9, 2 << 2, b'a', b'b', b'c', 0b0000_0001, 3, (1 << 2) | 2, 1, 0];
        assert_eq!(decode(&input, 9).unwrap(), b"abcabcaaa");
    }

    #[test]
    fn long_literal_and_copy4() {
        let data: Vec<u8> = (0..100u8).collect();
        let mut input = vec![104];
        input.push(60 << 2);
        input.push(99);
        input.extend_from_slice(&data);
        // copy4: len 4, offset 100
        input.push((3 << 2) | 3);
        input.extend_from_slice(&100u32.to_le_bytes());
        let out = decode(&input, 104).unwrap();
        assert_eq!(&out[..100], &data[..]);
        assert_eq!(&out[100..], &data[..4]);
    }

    #[test]
    fn varint() {
        assert_eq!(read_varint(&[0x80, 0x01]).unwrap(), (128, 2));
        assert_eq!(read_varint(&[0xff, 0xff, 0xff, 0xff, 0x0f]).unwrap(), (u32::MAX, 5));
        assert!(read_varint(&[0xff, 0xff, 0xff, 0xff, 0x1f]).is_err());
        assert!(read_varint(&[0x80]).is_err());
    }

    #[test]
    fn errors() {
        assert!(decode(&[3, 0], 3).is_err()); // literal runs out of input
        assert!(decode(&[4], 3).is_err()); // wrong declared length
        assert!(decode(&[3, 0, b'a', 0b0000_0101, 0], 3).is_err()); // offset 0
        assert!(decode(&[3, 0, b'a', 0b0000_0101, 2], 3).is_err()); // offset beyond
        assert!(decode(&[2, 0, b'a', 0b0001_1101, 1], 2).is_err()); // overflow
        assert!(decode(&[2, 0, b'a'], 2).is_err()); // too short
    }
}
