//! Decoder for BloscLZ, blosc's LZ77 codec derived from FastLZ (level 2).
//!
//! Written from the format as c-blosc's `blosclz_decompress` reads it
//! (blosc/blosclz.c), which is the same in BloscLZ 1.x (c-blosc 1.0 - 1.17)
//! and BloscLZ 2.x (c-blosc 1.18+): only the *encoder* changed (minimum match
//! length 3 or 4, hashing, entropy probing), never the stream format, and the
//! `versionlz` header byte stayed 1.
//!
//! A stream is a sequence of instructions, each starting with a control byte
//! `ctrl`:
//!
//! ```text
//! first byte      only its low 5 bits count: the top 3 bits are a marker the
//!                 encoder ORs in (1 << 5), and the first instruction is
//!                 always a literal run.
//!
//! ctrl < 32       literal run: copy the next ctrl + 1 input bytes.
//!
//! ctrl >= 32      match: L = ctrl >> 5 (1..=7), D = (ctrl & 31) << 8.
//!                 if L == 7: add the following bytes to L while they are
//!                            255, then add the first byte that is not.
//!                 code = next byte;
//!                 length   = L + 2
//!                 distance = D + code + 1
//!                 if code == 255 and D == 31 << 8 ("far" match):
//!                     distance = (next byte << 8 | next byte) + 8191 + 1
//!                 copy `length` bytes from `distance` bytes back in the
//!                 output, byte by byte (so overlapping copies repeat;
//!                 distance 1 is a run of the previous byte).
//! ```
//!
//! The stream ends when the input is exhausted after an instruction. The
//! BloscLZ 2.x reader stops *before* performing a match that is the last
//! instruction, the 1.x reader performs it; encoders of both always end with a
//! literal run, so we perform it (the 1.x behaviour) and let the final length
//! check decide.

/// Largest distance of a "near" match; far matches add this to their 16-bit
/// offset (`MAX_DISTANCE` in blosclz.c).
const MAX_DISTANCE: usize = 8191;

/// Reads input bytes, reporting where the stream ran out.
struct Input<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Input<'a> {
    fn byte(&mut self, what: &str) -> Result<usize, String> {
        let b = self.bytes.get(self.pos).ok_or_else(|| format!("blosclz stream ends inside a {what}"))?;
        self.pos = self.pos.saturating_add(1);
        Ok(usize::from(*b))
    }

    fn slice(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        let s = self.pos.checked_add(n).and_then(|end| self.bytes.get(self.pos..end)).ok_or_else(|| format!("blosclz stream ends inside a {what}"))?;
        self.pos = self.pos.saturating_add(n);
        Ok(s)
    }

    fn at_end(&self) -> bool {
        self.pos >= self.bytes.len()
    }
}

/// Decodes `input` into exactly `out.len()` bytes.
pub(crate) fn decompress(input: &[u8], out: &mut [u8]) -> Result<(), String> {
    let mut ip = Input { bytes: input, pos: 0 };
    if ip.at_end() {
        return Err("empty blosclz stream".into());
    }
    // Only the low 5 bits of the first byte count (always a literal run).
    let mut ctrl = ip.byte("control byte")? & 31;
    let mut op: usize = 0;
    let out_len = out.len();

    loop {
        if ctrl >= 32 {
            // Match.
            let mut len = (ctrl >> 5).saturating_sub(1);
            let ofs = (ctrl & 31) << 8;
            if len == 6 {
                loop {
                    let code = ip.byte("match length")?;
                    len = len.saturating_add(code);
                    if code != 255 {
                        break;
                    }
                }
            }
            let code = ip.byte("match distance")?;
            len = len.saturating_add(3);
            let mut distance = ofs.saturating_add(code).saturating_add(1);
            if code == 255 && ofs == 31 << 8 {
                let hi = ip.byte("far match distance")?;
                let lo = ip.byte("far match distance")?;
                distance = (hi << 8 | lo).saturating_add(MAX_DISTANCE + 1);
            }
            op = checked_copy_match(out, op, distance, len)?;
        } else {
            // Literal run.
            let n = ctrl.saturating_add(1);
            let dst = op.checked_add(n).and_then(|end| out.get_mut(op..end)).ok_or_else(|| {
                format!(
                    "literal run of {n} bytes at output offset {op} overflows the \
                         {out_len}-byte output"
                )
            })?;
            dst.copy_from_slice(ip.slice(n, "literal run")?);
            op = op.saturating_add(n);
        }
        if ip.at_end() {
            break;
        }
        ctrl = ip.byte("control byte")?;
    }

    if op != out_len {
        return Err(format!("blosclz stream decodes to {op} bytes, expected {out_len}"));
    }
    Ok(())
}

/// Checks an LZ77 match (`1 <= distance <= op`, `op + len <= out.len()`),
/// copies it with [`copy_match`], and returns the new output offset.
pub(crate) fn checked_copy_match(out: &mut [u8], op: usize, distance: usize, len: usize) -> Result<usize, String> {
    if distance == 0 {
        return Err(format!("match distance 0 is invalid at output offset {op}"));
    }
    if distance > op {
        return Err(format!("match distance {distance} reaches before the start of the output ({op} bytes written)"));
    }
    let out_len = out.len();
    let end = op.checked_add(len).filter(|&end| end <= out_len).ok_or_else(|| format!("match of {len} bytes at output offset {op} overflows the {out_len}-byte output"))?;
    copy_match(out, op, distance, len);
    Ok(end)
}

/// LZ77 copy of `len` bytes from `distance` back to `op`, with the
/// byte-by-byte semantics for overlapping ranges. The caller has checked
/// `1 <= distance <= op` and `op + len <= out.len()`.
pub(crate) fn copy_match(out: &mut [u8], op: usize, distance: usize, len: usize) {
    let Some(start) = op.checked_sub(distance) else {
        return;
    };
    if distance == 0 {
        return;
    }
    if distance == 1 {
        // A run of the previous byte.
        let Some(&b) = out.get(start) else { return };
        if let Some(dst) = op.checked_add(len).and_then(|end| out.get_mut(op..end)) {
            dst.fill(b);
        }
        return;
    }
    // Copy in pieces no longer than `distance`: each piece's source lies
    // entirely before its destination, so a plain (memmove) copy gives the
    // same result as the byte-by-byte loop.
    let mut done = 0;
    while done < len {
        let piece = distance.min(len.saturating_sub(done));
        let src = start.saturating_add(done);
        let (Some(src_end), Some(dst)) = (src.checked_add(piece), op.checked_add(done)) else {
            return;
        };
        if src_end > out.len() || dst.saturating_add(piece) > out.len() {
            return;
        }
        out.copy_within(src..src_end, dst);
        done = done.saturating_add(piece);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(input: &[u8], n: usize) -> Result<Vec<u8>, String> {
        let mut out = vec![0u8; n];
        decompress(input, &mut out).map(|()| out)
    }

    #[test]
    fn literal_only() {
        // First byte: marker bit 5 set, literal run of 3 bytes.
        assert_eq!(decode(&[0x20 | 2, b'a', b'b', b'c'], 3).unwrap(), b"abc");
        // Several literal runs back to back.
        assert_eq!(decode(&[0x21, b'a', b'b', 0, b'c'], 3).unwrap(), b"abc");
    }

    #[test]
    fn short_match_and_run() {
        // "ab", then match L=2 (length 4), distance 0*256 + 1 + 1 = 2 -> "abab",
        // then literal "z".
        let input = [0x21, b'a', b'b', 2 << 5, 1, 0, b'z'];
        assert_eq!(decode(&input, 7).unwrap(), b"abababz");
        // Distance 1 is a run: "x" then length 1+2=3 of x.
        let input = [0x20, b'x', 1 << 5, 0, 0, b'.'];
        assert_eq!(decode(&input, 5).unwrap(), b"xxxx.");
    }

    #[test]
    fn long_match_length_extension() {
        // L = 7 with extension bytes 255, 10: length = 6 + 255 + 10 + 3 = 274.
        let mut input = vec![0x20, b'q', 7 << 5, 255, 10, 0, 0, b'!'];
        let out = decode(&input, 1 + 274 + 1).unwrap();
        assert!(out[..275].iter().all(|&b| b == b'q'));
        assert_eq!(out[275], b'!');
        // Truncated inside the extension.
        input.truncate(4);
        assert!(decode(&input, 276).unwrap_err().contains("ends inside"));
    }

    #[test]
    fn far_match() {
        // 10000 literal bytes (pattern), then a far match of length 5 at
        // distance 10000 = (hi<<8|lo) + 8192 -> hi<<8|lo = 1808.
        let data: Vec<u8> = (0..10000u32).map(|i| (i * 7 % 251) as u8).collect();
        let mut input = Vec::new();
        for (i, chunk) in data.chunks(32).enumerate() {
            input.push(((chunk.len() - 1) as u8) | if i == 0 { 0x20 } else { 0 });
            input.extend_from_slice(chunk);
        }
        let far = 10000 - 8192;
        input.extend_from_slice(&[(3 << 5) | 31, 255, (far >> 8) as u8, (far & 255) as u8]);
        input.extend_from_slice(&[0, b'E']);
        let out = decode(&input, 10000 + 5 + 1).unwrap();
        assert_eq!(&out[..10000], &data[..]);
        assert_eq!(&out[10000..10005], &data[..5]);
        assert_eq!(out[10005], b'E');
    }

    #[test]
    fn near_match_with_high_offset_bits() {
        // Distance (3 << 8) + 4 + 1 = 773, length 3.
        let data: Vec<u8> = (0..800u32).map(|i| (i % 200) as u8 ^ (i / 200) as u8).collect();
        let mut input = Vec::new();
        for (i, chunk) in data.chunks(32).enumerate() {
            input.push(((chunk.len() - 1) as u8) | if i == 0 { 0x20 } else { 0 });
            input.extend_from_slice(chunk);
        }
        input.extend_from_slice(&[(1 << 5) | 3, 4, 0, 0]);
        let out = decode(&input, 804).unwrap();
        assert_eq!(&out[800..803], &data[800 - 773..800 - 773 + 3]);
    }

    #[test]
    fn errors_instead_of_panics() {
        // Empty input.
        assert!(decode(&[], 0).is_err());
        // Match reaching before the output start.
        assert!(decode(&[0x20, b'a', 1 << 5, 5, 0, b'b'], 6).unwrap_err().contains("before the start"));
        // Literal overflowing the output.
        assert!(decode(&[0x20 | 4, 1, 2, 3, 4, 5], 3).unwrap_err().contains("overflows"));
        // Literal running past the input.
        assert!(decode(&[0x20 | 4, 1, 2], 5).unwrap_err().contains("ends inside"));
        // Match overflowing the output.
        assert!(decode(&[0x20, b'a', 6 << 5, 0, 0, b'b'], 4).unwrap_err().contains("overflows"));
        // Too short.
        assert!(decode(&[0x20, b'a'], 2).unwrap_err().contains("expected 2"));
        // A trailing match is performed (BloscLZ 1.x reading).
        assert_eq!(decode(&[0x20, b'a', 1 << 5, 0], 4).unwrap(), b"aaaa");
    }

    #[test]
    fn overlapping_copy_matches_bytewise_semantics() {
        for distance in 1..12usize {
            for len in 0..40usize {
                let mut a: Vec<u8> = (0..(distance + len) as u8).collect();
                let mut b = a.clone();
                copy_match(&mut a, distance, distance, len);
                for i in 0..len {
                    b[distance + i] = b[i];
                }
                assert_eq!(a, b, "distance {distance} len {len}");
            }
        }
    }
}
