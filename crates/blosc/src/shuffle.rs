//! The byte- and bit-shuffle filters of c-blosc 1.x, applied per block.
//!
//! **Byte shuffle** (`blosc/shuffle-generic.c`): a block of `len` bytes holds
//! `n = len / typesize` whole elements. Shuffled, byte `j` of element `i` is at
//! `j * n + i` (all first bytes, then all second bytes, ...). The
//! `len % typesize` bytes after the last whole element are stored as they are.
//!
//! **Bit shuffle** (`blosc/shuffle.c` `blosc_internal_bitunshuffle`, which
//! calls bitshuffle's `bshuf_untrans_bit_elem`): only done when the element
//! count `n` is a multiple of 8; otherwise the *whole block* is stored as it
//! is. When done, the shuffled block holds `8 * typesize` rows of `n / 8`
//! bytes: row `8 * j + k` holds bit `k` (0 = least significant) of byte `j`
//! of every element, element `e` at bit `e % 8` of the row's byte `e / 8`.
//! The `len % typesize` tail bytes are stored as they are (c-blosc >= 1.17
//! copies them explicitly; earlier versions left them unwritten on both
//! sides, so no valid buffer depends on them).
//!
//! All functions work on `min(src.len(), dst.len())` bytes and never panic.

/// Undoes the byte shuffle of one block.
pub fn unshuffle(typesize: usize, src: &[u8], dst: &mut [u8]) {
    let Some((src_body, src_tail, dst_body, dst_tail, n)) = split(typesize, src, dst) else {
        return;
    };
    copy(dst_tail, src_tail);
    if typesize <= 1 || n == 0 {
        copy(dst_body, src_body);
        return;
    }
    // Halves and floats element by element over zipped planes (a loop the
    // compiler vectorises), other sizes plane by plane.
    match typesize {
        2 => unshuffle2(src_body, dst_body, n),
        4 => unshuffle4(src_body, dst_body, n),
        _ => {
            // Plane j holds byte j of every element.
            for (j, plane) in src_body.chunks_exact(n).enumerate() {
                for (elem, &b) in dst_body.chunks_exact_mut(typesize).zip(plane) {
                    if let Some(d) = elem.get_mut(j) {
                        *d = b;
                    }
                }
            }
        }
    }
}

/// [`unshuffle`]'s whole 2-byte elements: element `i` is byte `i` of each
/// of the two planes of `n` bytes.
fn unshuffle2(src: &[u8], dst: &mut [u8], n: usize) {
    if n == 0 {
        return;
    }
    let mut planes = src.chunks_exact(n);
    let (Some(p0), Some(p1)) = (planes.next(), planes.next()) else { return };
    for ((elem, &a), &b) in dst.chunks_exact_mut(2).zip(p0).zip(p1) {
        elem.copy_from_slice(&[a, b]);
    }
}

/// [`unshuffle`]'s whole 4-byte elements (floats), as [`unshuffle2`].
fn unshuffle4(src: &[u8], dst: &mut [u8], n: usize) {
    if n == 0 {
        return;
    }
    let mut planes = src.chunks_exact(n);
    let (Some(p0), Some(p1), Some(p2), Some(p3)) = (planes.next(), planes.next(), planes.next(), planes.next()) else { return };
    for ((((elem, &a), &b), &c), &d) in dst.chunks_exact_mut(4).zip(p0).zip(p1).zip(p2).zip(p3) {
        elem.copy_from_slice(&[a, b, c, d]);
    }
}

/// Applies the byte shuffle to one block (the inverse of [`unshuffle`]).
pub fn shuffle(typesize: usize, src: &[u8], dst: &mut [u8]) {
    let Some((src_body, src_tail, dst_body, dst_tail, n)) = split(typesize, src, dst) else {
        return;
    };
    copy(dst_tail, src_tail);
    if typesize <= 1 || n == 0 {
        copy(dst_body, src_body);
        return;
    }
    for (j, plane) in dst_body.chunks_exact_mut(n).enumerate() {
        for (d, elem) in plane.iter_mut().zip(src_body.chunks_exact(typesize)) {
            if let Some(&b) = elem.get(j) {
                *d = b;
            }
        }
    }
}

/// Undoes the bit shuffle of one block.
pub fn bitunshuffle(typesize: usize, src: &[u8], dst: &mut [u8]) {
    let Some((src_body, src_tail, dst_body, dst_tail, n)) = split(typesize, src, dst) else {
        return;
    };
    if typesize == 0 || n % 8 != 0 {
        // Not bit-shuffled at all.
        copy(dst_body, src_body);
        copy(dst_tail, src_tail);
        return;
    }
    copy(dst_tail, src_tail);
    let row_len = n / 8;
    if row_len == 0 {
        return;
    }
    let Some(group_len) = typesize.checked_mul(8) else {
        return;
    };
    // Rows 8j .. 8j+7 are consecutive: together they give byte j of every
    // element. Byte x of those 8 rows is an 8x8 bit matrix whose transpose is
    // byte j of elements 8x .. 8x+7.
    let Some(rows8_len) = row_len.checked_mul(8) else {
        return;
    };
    for (j, rows8) in src_body.chunks_exact(rows8_len).enumerate() {
        let mut rows: [std::slice::Iter<'_, u8>; 8] = Default::default();
        for (row, chunk) in rows.iter_mut().zip(rows8.chunks_exact(row_len)) {
            *row = chunk.iter();
        }
        for group in dst_body.chunks_exact_mut(group_len) {
            let mut word = [0u8; 8];
            for (w, row) in word.iter_mut().zip(rows.iter_mut()) {
                *w = row.next().copied().unwrap_or(0);
            }
            let t = transpose8x8(u64::from_le_bytes(word)).to_le_bytes();
            for (elem, v) in group.chunks_exact_mut(typesize).zip(t) {
                if let Some(d) = elem.get_mut(j) {
                    *d = v;
                }
            }
        }
    }
}

/// Applies the bit shuffle to one block (the inverse of [`bitunshuffle`]).
pub fn bitshuffle(typesize: usize, src: &[u8], dst: &mut [u8]) {
    let Some((src_body, src_tail, dst_body, dst_tail, n)) = split(typesize, src, dst) else {
        return;
    };
    if typesize == 0 || n % 8 != 0 {
        copy(dst_body, src_body);
        copy(dst_tail, src_tail);
        return;
    }
    copy(dst_tail, src_tail);
    let row_len = n / 8;
    let (Some(group_len), Some(rows8_len)) = (typesize.checked_mul(8), row_len.checked_mul(8)) else {
        return;
    };
    if row_len == 0 {
        return;
    }
    for (j, rows8) in dst_body.chunks_exact_mut(rows8_len).enumerate() {
        for (x, group) in src_body.chunks_exact(group_len).enumerate() {
            let mut word = [0u8; 8];
            for (w, elem) in word.iter_mut().zip(group.chunks_exact(typesize)) {
                *w = elem.get(j).copied().unwrap_or(0);
            }
            let t = transpose8x8(u64::from_le_bytes(word)).to_le_bytes();
            for (row, v) in rows8.chunks_exact_mut(row_len).zip(t) {
                if let Some(d) = row.get_mut(x) {
                    *d = v;
                }
            }
        }
    }
}

/// Transposes an 8x8 bit matrix held in a u64 whose byte `r` is row `r` and
/// whose bit `c` within a byte is column `c`: bit (r, c) moves to (c, r).
/// Same operation as bitshuffle's `TRANS_BIT_8X8` macro.
pub fn transpose8x8(mut x: u64) -> u64 {
    let mut t = (x ^ (x >> 7)) & 0x00AA_00AA_00AA_00AA;
    x = x ^ t ^ (t << 7);
    t = (x ^ (x >> 14)) & 0x0000_CCCC_0000_CCCC;
    x = x ^ t ^ (t << 14);
    t = (x ^ (x >> 28)) & 0x0000_0000_F0F0_F0F0;
    x ^ t ^ (t << 28)
}

type Parts<'s, 'd> = (&'s [u8], &'s [u8], &'d mut [u8], &'d mut [u8], usize);

/// Cuts both buffers to a common length and splits each into the whole
/// elements and the tail; also returns the element count.
fn split<'s, 'd>(typesize: usize, src: &'s [u8], dst: &'d mut [u8]) -> Option<Parts<'s, 'd>> {
    let len = src.len().min(dst.len());
    let src = src.get(..len)?;
    let dst = dst.get_mut(..len)?;
    let n = len.checked_div(typesize).unwrap_or(0);
    let body = n.checked_mul(typesize).unwrap_or(0);
    let (src_body, src_tail) = src.split_at_checked(body)?;
    let (dst_body, dst_tail) = dst.split_at_mut_checked(body)?;
    Some((src_body, src_tail, dst_body, dst_tail, n))
}

fn copy(dst: &mut [u8], src: &[u8]) {
    crate::frame::copy_exact(dst, src);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bit `b` of byte `j` of element `e`, straight from the layout
    /// description in the module docs.
    fn reference_bitshuffle(typesize: usize, src: &[u8]) -> Vec<u8> {
        let n = src.len() / typesize;
        let mut out = src.to_vec();
        if !n.is_multiple_of(8) {
            return out;
        }
        let row_len = n / 8;
        for b in out[..n * typesize].iter_mut() {
            *b = 0;
        }
        for e in 0..n {
            for j in 0..typesize {
                for k in 0..8 {
                    let bit = (src[e * typesize + j] >> k) & 1;
                    let row = 8 * j + k;
                    out[row * row_len + e / 8] |= bit << (e % 8);
                }
            }
        }
        out
    }

    fn pseudo_random(len: usize, seed: u32) -> Vec<u8> {
        vdbcook_testkit::Rng::new(u64::from(seed)).bytes(len)
    }

    #[test]
    fn transpose_moves_bit_r_c_to_c_r() {
        for r in 0..8 {
            for c in 0..8 {
                let x = 1u64 << (8 * r + c);
                assert_eq!(transpose8x8(x), 1u64 << (8 * c + r));
            }
        }
        let x = 0x0123_4567_89ab_cdef;
        assert_eq!(transpose8x8(transpose8x8(x)), x);
    }

    #[test]
    fn byte_shuffle_layout() {
        // Three 2-byte elements plus one tail byte.
        let src = [0x10, 0x11, 0x20, 0x21, 0x30, 0x31, 0x99];
        let mut shuffled = [0u8; 7];
        shuffle(2, &src, &mut shuffled);
        assert_eq!(shuffled, [0x10, 0x20, 0x30, 0x11, 0x21, 0x31, 0x99]);
        let mut back = [0u8; 7];
        unshuffle(2, &shuffled, &mut back);
        assert_eq!(back, src);
    }

    #[test]
    fn bit_shuffle_known_layout() {
        // Eight 1-byte elements: element e = 1 << e. Row k (bit k of byte 0)
        // then has only element k's bit set: byte value 1 << k.
        let src: Vec<u8> = (0..8).map(|e| 1u8 << e).collect();
        let mut out = vec![0u8; 8];
        bitshuffle(1, &src, &mut out);
        assert_eq!(out, src);
        // Eight 2-byte elements all 0x0001: row 0 (byte 0, bit 0) is 0xff,
        // everything else 0.
        let src: Vec<u8> = (0..8).flat_map(|_| [1u8, 0]).collect();
        let mut out = vec![0u8; 16];
        bitshuffle(2, &src, &mut out);
        let mut expected = vec![0u8; 16];
        expected[0] = 0xff;
        assert_eq!(out, expected);
    }

    #[test]
    fn bit_shuffle_matches_reference_and_round_trips() {
        for typesize in [1usize, 2, 3, 4, 8, 16, 17] {
            for n in [0usize, 1, 7, 8, 9, 16, 24, 64, 100, 128] {
                for tail in [0usize, 1] {
                    let tail = tail.min(typesize.saturating_sub(1));
                    let len = n * typesize + tail;
                    let src = pseudo_random(len, (typesize * 1000 + n * 10 + tail) as u32);
                    let expected = reference_bitshuffle(typesize, &src);
                    let mut shuffled = vec![0u8; len];
                    bitshuffle(typesize, &src, &mut shuffled);
                    assert_eq!(shuffled, expected, "typesize {typesize} n {n} tail {tail}");
                    let mut back = vec![0u8; len];
                    bitunshuffle(typesize, &shuffled, &mut back);
                    assert_eq!(back, src, "typesize {typesize} n {n} tail {tail}");
                }
            }
        }
    }

    #[test]
    fn byte_shuffle_round_trips() {
        for typesize in [1usize, 2, 3, 4, 8, 16, 255] {
            for len in [0usize, 1, 2, 15, 16, 17, 1000, 1024] {
                let src = pseudo_random(len, (typesize + len) as u32);
                let mut shuffled = vec![0u8; len];
                shuffle(typesize, &src, &mut shuffled);
                let mut back = vec![0u8; len];
                unshuffle(typesize, &shuffled, &mut back);
                assert_eq!(back, src, "typesize {typesize} len {len}");
                if typesize > 1 && len >= typesize {
                    let n = len / typesize;
                    assert_eq!(shuffled[n], src[1]);
                }
            }
        }
    }

    #[test]
    fn mismatched_lengths_do_not_panic() {
        let src = pseudo_random(100, 1);
        let mut dst = vec![0u8; 37];
        unshuffle(4, &src, &mut dst);
        bitunshuffle(4, &src, &mut dst);
        unshuffle(0, &src, &mut dst);
        bitunshuffle(0, &src, &mut dst);
        bitunshuffle(usize::MAX, &src, &mut dst);
    }
}
