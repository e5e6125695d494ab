//! The `l3 nodes` filter (coding filter 5, version 12): an L3 array's node
//! records made predictable before zstd. A record is (brick, sub-block
//! states, first sub-mask word); the writer numbers bricks nearly in node
//! order and lays the sub-masks out node after node, so the brick's step from
//! the record before and the first word's step from where the record before
//! ends its sub-masks are almost always 1 and 0. zstd sees those fields apart
//! and by byte weight (as the shuffle filter lays them), the sub-masks as
//! they are; the increasing words it otherwise cannot model took half the
//! stored L3 bytes of a dense fog.

use crate::nodes::L3_WORDS;

fn word(b: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]])
}

/// Node records of an L3 array of `len` bytes whose word 0 is `count`, when
/// they fit after it.
fn records(len: usize, count: u32) -> Option<usize> {
    let n = count as usize;
    (len >= 4 && len.is_multiple_of(4) && n.checked_mul(4 * L3_WORDS).is_some_and(|b| b <= len - 4)).then_some(n)
}

/// Whether `raw` is an L3 array the filter applies to: whole words, its
/// records inside it.
pub(crate) fn fits(raw: &[u8]) -> bool {
    raw.len() >= 4 && records(raw.len(), word(raw, 0)).is_some()
}

/// Sub-masks a record with sub-block `states` has (state 2 in each pair).
fn sub_masks(states: u32) -> u32 {
    ((states >> 1) & 0x5555).count_ones()
}

/// The filtered array: word 0 as it is; then the n records' fields as three
/// runs of n words (brick minus the record before's brick, 0 before the
/// first; the states; the first word minus where the record before's
/// sub-masks end, `1 + 3n` before the first), all wrapping, stored byte
/// plane by byte plane; then the sub-masks as they are. `raw` must [`fits`].
pub(crate) fn apply(raw: &[u8]) -> Vec<u8> {
    let mut out = raw.to_vec();
    let Some(n) = fits(raw).then(|| word(raw, 0) as usize) else { return out };
    let mut fields = vec![0u32; 3 * n];
    let (mut brick, mut end) = (0u32, (1 + L3_WORDS * n) as u32);
    for k in 0..n {
        let (b, states, first) = (word(raw, 1 + 3 * k), word(raw, 2 + 3 * k), word(raw, 3 + 3 * k));
        fields[k] = b.wrapping_sub(brick);
        fields[n + k] = states;
        fields[2 * n + k] = first.wrapping_sub(end);
        brick = b;
        end = first.wrapping_add(2 * sub_masks(states));
    }
    let planes = &mut out[4..4 + 12 * n];
    for (i, f) in fields.iter().enumerate() {
        for (j, &byte) in f.to_le_bytes().iter().enumerate() {
            planes[j * 3 * n + i] = byte;
        }
    }
    out
}

/// Undoes [`apply`] on `data` into `out` (as long): refused when word 0
/// counts more records than the array holds.
pub(crate) fn undo(data: &[u8], out: &mut [u8]) -> Result<(), String> {
    let count = if data.len() >= 4 { word(data, 0) } else { 0 };
    let n = records(data.len(), count).ok_or_else(|| format!("counts {count} l3 nodes in {} bytes", data.len()))?;
    out.copy_from_slice(data);
    let planes = &data[4..4 + 12 * n];
    let field = |i: usize| u32::from_le_bytes([planes[i], planes[3 * n + i], planes[6 * n + i], planes[9 * n + i]]);
    let (mut brick, mut end) = (0u32, (1 + L3_WORDS * n) as u32);
    for (k, record) in out[4..4 + 12 * n].chunks_exact_mut(12).enumerate() {
        let (b, states) = (field(k).wrapping_add(brick), field(n + k));
        let first = field(2 * n + k).wrapping_add(end);
        record[..4].copy_from_slice(&b.to_le_bytes());
        record[4..8].copy_from_slice(&states.to_le_bytes());
        record[8..].copy_from_slice(&first.to_le_bytes());
        brick = b;
        end = first.wrapping_add(2 * sub_masks(states));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bytes(words: &[u32]) -> Vec<u8> {
        words.iter().flat_map(|w| w.to_le_bytes()).collect()
    }

    #[test]
    fn a_writers_array_filters_to_steps_of_one_and_zero_and_back() {
        // Three nodes: bricks 0, 1, 5; the first and last with two and one sub-masks.
        let states = [0b10_10_01_00, 0b01_01_01_01, 0b10_00_00_00];
        let words = [3, 0, states[0], 10, 1, states[1], 14, 5, states[2], 14, 7, 8, 9, 10, 11, 12];
        let raw = bytes(&words);
        assert!(fits(&raw));
        let f = apply(&raw);
        let n = 3;
        let field = |i: usize| u32::from_le_bytes([f[4 + i], f[4 + 3 * n + i], f[4 + 6 * n + i], f[4 + 9 * n + i]]);
        assert_eq!((0..9).map(field).collect::<Vec<_>>(), [0, 1, 4, states[0], states[1], states[2], 0, 0, 0]);
        assert_eq!(f[..4], raw[..4]);
        assert_eq!(f[40..], raw[40..], "the sub-masks stay as they are");
        let mut back = vec![0u8; raw.len()];
        undo(&f, &mut back).unwrap();
        assert_eq!(back, raw);
    }

    #[test]
    fn any_words_round_trip_and_a_count_past_the_array_is_refused() {
        // Fields that do not follow the writer's order still come back (wrapping steps).
        let words = [2, u32::MAX, 0xffff_ffff, 3, 7, 0x5555_aaaa, 0, 1, 2];
        let raw = bytes(&words);
        let mut back = vec![0u8; raw.len()];
        undo(&apply(&raw), &mut back).unwrap();
        assert_eq!(back, raw);
        for count in [3, u32::MAX] {
            let mut lie = apply(&raw);
            lie[..4].copy_from_slice(&count.to_le_bytes());
            assert!(undo(&lie, &mut back).unwrap_err().contains(&count.to_string()));
        }
        assert!(!fits(&bytes(&[3, 0, 0, 0])) && !fits(&[1, 0]) && fits(&bytes(&[0])));
    }
}
