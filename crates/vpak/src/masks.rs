//! Coding scheme 3 (version 14): an L3 array under the `l3 nodes` filter
//! with its sub-masks coded by a static context model and rANS instead of
//! zstd. A sub-mask is sixteen rows of four voxels along z; each row is one
//! symbol, coded in a context made of the rows beside it along x and y
//! (decoded before it, in its own sub-block or in the node's sub-blocks
//! below it, whose states the records give). zstd sees the masks as bytes
//! and takes about a fifth more on the fires and level sets, where the L3
//! array is a quarter of a supercompressed file. The records stay with
//! zstd, in the stream's side frame. `docs/format.md`, "Mask coding", is the
//! specification.

use crate::context::{fill_table, quantise, rans_put, RANS_LOW, UNUSED};

/// Rows of a sub-mask, and the symbols a row can be (four voxels).
const ROWS: usize = 16;
const SYMBOLS: usize = 16;
/// Contexts: 81 for the two neighbouring rows (each voxel of the row: how
/// many of its two neighbours are active), 16 + 16 for one of them alone,
/// 1 for neither.
pub(crate) const CONTEXTS: usize = 81 + 16 + 16 + 1;
/// Each used context's frequencies sum to 2^PRECISION, as vdbcook writes them.
const PRECISION: u32 = 9;
const PRECISIONS: std::ops::RangeInclusive<u32> = 9..=12;
/// Bytes of the stream's header: lanes, precision, side frame bytes, words.
const HEAD: usize = 16;
/// Lanes, as vdbcook writes them (sub-masks of 16 nodes decoded side by
/// side, so that their rANS states' chains overlap), and the most allowed.
const LANES: usize = 16;
const MAX_LANES: usize = 64;
/// Bytes of the frequency table in the side frame.
const TABLE: usize = CONTEXTS * SYMBOLS * 2;
/// Sub-block states (two bits each, sub-block b at bits 2b and 2b + 1).
const PARTIAL: u32 = 2;
const FULL: u32 = 1;

/// Row `t` (x = t / 4, y = t % 4 in the sub-block; bits 4t to 4t + 3).
fn row(mask: u64, t: usize) -> u32 {
    (mask >> (4 * t)) as u32 & 15
}

/// The filtered L3 array's parts: its head's bytes (count and records,
/// `4 + 12n`) and its sub-masks, each with its node and sub-block, in the
/// order the array holds them; `None` when it does not have that shape
/// (the sub-masks after the records are exactly those the states name).
struct Shape {
    head: usize,
    /// (node, sub-block) of each sub-mask word.
    owners: Vec<(u32, u8)>,
    /// Each node's sub-block states.
    states: Vec<u32>,
}

fn shape(filtered_len: usize, head: &[u8]) -> Option<Shape> {
    let n = u32::from_le_bytes(head.get(..4)?.try_into().ok()?) as usize;
    let head_len = n.checked_mul(12)?.checked_add(4)?;
    if head_len > filtered_len || head.len() < head_len || !(filtered_len - head_len).is_multiple_of(8) {
        return None;
    }
    // Field n + k (the states), byte j at 4 + j·3n + (n + k).
    let states: Vec<u32> = (0..n).map(|k| (0..4).fold(0u32, |s, j| s | u32::from(head[4 + j * 3 * n + n + k]) << (8 * j))).collect();
    // Sub-blocks in state 2 exactly (binary 10).
    let named: usize = states.iter().map(|&s| ((s >> 1) & !s & 0x5555).count_ones() as usize).sum();
    if named != (filtered_len - head_len) / 8 {
        return None;
    }
    let owners = states.iter().enumerate().flat_map(|(k, &s)| (0..8u8).filter(move |&b| (s >> (2 * b)) & 3 == PARTIAL).map(move |b| (k as u32, b))).collect();
    Some(Shape { head: head_len, owners, states })
}

/// The sub-mask words in decoding order, `lanes` at a time: node k's
/// sub-masks go to lane k mod `lanes`, in the array's order; round r takes
/// each lane's r-th sub-mask (the lanes that have one). Lanes are
/// independent (each its own state and run of words): the rounds are how
/// the decoders take them side by side. Gives every round's (lane, word
/// index), round after round, and where each round starts.
fn rounds(s: &Shape, lanes: usize) -> (Vec<(usize, usize)>, Vec<usize>) {
    // Each lane's r-th sub-mask, and how many lanes have one.
    let mut count = vec![0usize; lanes];
    let mut nth = Vec::with_capacity(s.owners.len());
    for &(k, _) in &s.owners {
        let l = k as usize % lanes;
        nth.push(count[l]);
        count[l] += 1;
    }
    // Sub-masks by round (a counting sort; within a round, in the array's order, each lane once).
    let rounds = count.iter().copied().max().unwrap_or(0);
    let mut starts = vec![0usize; rounds + 1];
    nth.iter().for_each(|&r| starts[r + 1] += 1);
    (0..rounds).for_each(|r| starts[r + 1] += starts[r]);
    let mut order = vec![(0usize, 0usize); s.owners.len()];
    let mut fill = starts.clone();
    for (i, (&(k, _), &r)) in s.owners.iter().zip(&nth).enumerate() {
        order[fill[r]] = (k as usize % lanes, i);
        fill[r] += 1;
    }
    (order, starts)
}

/// A row's neighbour rows outside its sub-block: along x (rows of x = 0,
/// by y) from the sub-block below in x, along y (rows of y = 0, by x) from
/// the one below in y; 16 where there is none (outside the node). `known`:
/// the node's sub-block masks (state 0 empty, 1 full, 2 as decoded).
fn outside(known: &[u64], b: usize) -> ([u8; 4], [u8; 4]) {
    let along_x = std::array::from_fn(|y| if b & 4 != 0 { row(known[b - 4], 12 + y) as u8 } else { 16 });
    let along_y = std::array::from_fn(|x| if b & 2 != 0 { row(known[b - 2], 4 * x + 3) as u8 } else { 16 });
    (along_x, along_y)
}

/// Contexts by neighbour rows a and b along x and y (16: outside the
/// node), at `a · 32 + b`.
const fn context_table() -> [u8; 1024] {
    let mut t = [113u8; 1024];
    let mut i = 0;
    while i < 1024 {
        let (a, b) = (i / 32, i % 32);
        if a < 16 && b < 16 {
            let (mut c, mut z, mut w) = (0, 0, 1);
            while z < 4 {
                c += (((a >> z) & 1) + ((b >> z) & 1)) * w;
                w *= 3;
                z += 1;
            }
            t[i] = c as u8;
        } else if a < 16 && b == 16 {
            t[i] = 81 + a as u8;
        } else if a == 16 && b < 16 {
            t[i] = 97 + b as u8;
        }
        i += 1;
    }
    t
}
const CONTEXT: [u8; 1024] = context_table();

/// Row t's context in a sub-mask decided up to row t − 1 (`m`), with its
/// rows outside the sub-block.
#[inline(always)]
fn context_of(m: u64, t: usize, along_x: &[u8; 4], along_y: &[u8; 4]) -> usize {
    let a = if t >= 4 { row(m, t - 4) as usize } else { usize::from(along_x[t & 3]) };
    let b = if t & 3 != 0 { row(m, t - 1) as usize } else { usize::from(along_y[t >> 2]) };
    usize::from(CONTEXT[(a << 5 | b) & 1023])
}

/// A node's sub-block masks as far as its states tell them (full ones all
/// ones, the others 0 until decoded).
fn known_of(states: u32) -> [u64; 8] {
    std::array::from_fn(|b| if (states >> (2 * b)) & 3 == FULL { u64::MAX } else { 0 })
}

/// The `l3 nodes` filter's output `filtered` as a scheme-3 stream (side
/// frame compressed by zstd at `level`); `None` when it is not an L3 array
/// whose sub-masks are those its states name.
pub fn encode(filtered: &[u8], level: i32) -> std::io::Result<Option<Vec<u8>>> {
    encode_lanes(filtered, level, LANES)
}

/// [`encode`] with `lanes` lanes (vdbcook writes [`LANES`]; the tests also
/// make the other counts a reader must take).
fn encode_lanes(filtered: &[u8], level: i32, lanes: usize) -> std::io::Result<Option<Vec<u8>>> {
    let Some(s) = shape(filtered.len(), filtered) else { return Ok(None) };
    let mask = |i: usize| u64::from_le_bytes(filtered[s.head + 8 * i..s.head + 8 * i + 8].try_into().unwrap_or_default());
    let known: Vec<u64> = s.owners.iter().enumerate().fold(s.states.iter().flat_map(|&st| known_of(st)).collect(), |mut known, (i, &(k, b))| {
        known[8 * k as usize + usize::from(b)] = mask(i);
        known
    });
    // (lane, context, symbol) of every row, in decoding order.
    let mut tokens: Vec<(u8, u8, u8)> = Vec::with_capacity(16 * s.owners.len());
    let (order, starts) = rounds(&s, lanes);
    for round in starts.windows(2).map(|w| &order[w[0]..w[1]]) {
        // Each sub-mask of the round with its rows outside it.
        let subs: Vec<(u8, u64, [u8; 4], [u8; 4])> = round
            .iter()
            .map(|&(lane, i)| {
                let (along_x, along_y) = outside(&known[8 * s.owners[i].0 as usize..][..8], usize::from(s.owners[i].1));
                (lane as u8, mask(i), along_x, along_y)
            })
            .collect();
        for t in 0..ROWS {
            for (lane, m, along_x, along_y) in &subs {
                tokens.push((*lane, context_of(*m, t, along_x, along_y) as u8, row(*m, t) as u8));
            }
        }
    }
    let mut counts = vec![[0u64; SYMBOLS]; CONTEXTS];
    tokens.iter().for_each(|&(_, c, s)| counts[usize::from(c)][usize::from(s)] += 1);
    let freq = quantise(&counts, PRECISION);
    let cum: Vec<[u32; SYMBOLS]> = freq.iter().map(|f| std::array::from_fn(|s| f[..s].iter().sum())).collect();
    // Each lane's own run of words, so that no lane waits on another's reads.
    let mut states = vec![RANS_LOW; lanes];
    let mut runs: Vec<Vec<u16>> = vec![Vec::new(); lanes];
    for &(lane, c, sym) in tokens.iter().rev() {
        let (l, c, sym) = (usize::from(lane), usize::from(c), usize::from(sym));
        rans_put(&mut states[l], freq[c][sym], cum[c][sym], PRECISION, &mut runs[l]);
    }
    for (run, x) in runs.iter_mut().zip(&states) {
        run.push(*x as u16);
        run.push((*x >> 16) as u16);
        run.reverse();
    }
    let mut side = Vec::with_capacity(s.head + TABLE + 4 * lanes);
    side.extend_from_slice(&filtered[..s.head]);
    freq.iter().flatten().for_each(|&f| side.extend_from_slice(&(f as u16).to_le_bytes()));
    runs.iter().for_each(|r| side.extend_from_slice(&(r.len() as u32).to_le_bytes()));
    let side = zstd::bulk::compress(&side, level)?;
    let words: Vec<u16> = runs.concat();
    let (Ok(a), Ok(w)) = (u32::try_from(side.len()), u32::try_from(words.len())) else { return Ok(None) };
    let mut out = Vec::with_capacity(HEAD + side.len() + 2 * words.len());
    [lanes as u32, PRECISION, a, w].iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    out.extend_from_slice(&side);
    words.iter().for_each(|w| out.extend_from_slice(&w.to_le_bytes()));
    Ok(Some(out))
}

/// Restores a scheme-3 stream `stored` into `out`, the `l3 nodes` filter's
/// output, or says what is wrong with it. Never reads or writes outside
/// what it was given, whatever the stream holds.
pub fn decode(stored: &[u8], out: &mut [u8]) -> Result<(), String> {
    if stored.len() < HEAD {
        return Err(format!("is {} bytes, shorter than a mask stream's {HEAD}-byte header", stored.len()));
    }
    let field = |i: usize| u32::from_le_bytes([stored[4 * i], stored[4 * i + 1], stored[4 * i + 2], stored[4 * i + 3]]);
    let (lanes, precision, side_len, words_len) = (field(0) as usize, field(1), field(2) as usize, field(3) as usize);
    if !(1..=MAX_LANES).contains(&lanes) || !PRECISIONS.contains(&precision) {
        return Err(format!("has {lanes} lanes and precision {precision} (1 to {MAX_LANES} and 9 to 12 allowed)"));
    }
    let body = (stored.len() - HEAD) as u64;
    if side_len as u64 + 2 * words_len as u64 != body {
        return Err(format!("states {side_len} + 2·{words_len} bytes of parts, but {body} follow its header"));
    }
    let frame = &stored[HEAD..HEAD + side_len];
    if zstd::zstd_safe::find_frame_compressed_size(frame) != Ok(frame.len()) {
        return Err("has a side part that is not one zstd frame".into());
    }
    // The side frame holds the array's head (at most all of it), the table and the lanes' runs of words.
    let most = out.len() + TABLE + 4 * lanes;
    match zstd::zstd_safe::get_frame_content_size(frame) {
        Ok(Some(size)) if size <= most as u64 => {}
        _ => return Err(format!("has a side frame that does not state a content size of at most {most} bytes")),
    }
    let mut side = Vec::new();
    side.try_reserve_exact(most).map_err(|_| format!("has a side frame of {most} bytes, more than memory allows"))?;
    let got = crate::coding::decompress_into(frame, &mut side).map_err(|e| format!("has a side frame that does not decompress to at most {most} bytes ({e})"))?;
    let s = shape(out.len(), &side)
        .filter(|s| s.head + TABLE + 4 * lanes == got)
        .ok_or_else(|| format!("has a side frame of {got} bytes that is not the head of an L3 array of {} bytes whose states name its sub-masks, a table and {lanes} run lengths", out.len()))?;
    let runs: Vec<usize> = side[s.head + TABLE..].chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize).collect();
    // A row takes at most one word: a lane's run is its state and at most 16 words per sub-mask.
    let mut most_words = vec![2u64; lanes];
    s.owners.iter().for_each(|&(k, _)| most_words[k as usize % lanes] += ROWS as u64);
    if runs.iter().zip(&most_words).any(|(&r, &most)| r < 2 || r as u64 > most) || runs.iter().map(|&r| r as u64).sum::<u64>() != words_len as u64 {
        return Err(format!("has runs of {runs:?} words (each its lane's state, 2 words, and at most 16 per sub-mask of the lane) for its {words_len} words"));
    }
    // Per context 2^precision entries `symbol | freq << 6 | cum << 19` (unused contexts' of frequency 0),
    // in the thread's table from the decode before: memory touched already, not fresh pages to fault in.
    let mut table = TABLES.take();
    table.clear();
    table.resize(128 << precision, UNUSED);
    let result = fill_table(&mut table, &side[s.head..s.head + TABLE], SYMBOLS, precision).and_then(|()| {
        out[..s.head].copy_from_slice(&side[..s.head]);
        let words = &stored[HEAD + side_len..];
        match precision {
            9 => rows::<9>(&s, &table, words, &runs, out),
            10 => rows::<10>(&s, &table, words, &runs, out),
            11 => rows::<11>(&s, &table, words, &runs, out),
            _ => rows::<12>(&s, &table, words, &runs, out),
        }
    });
    TABLES.set(table);
    result
}

thread_local! {
    static TABLES: std::cell::Cell<Vec<u32>> = const { std::cell::Cell::new(Vec::new()) };
    /// The decoder rows take, once asked (the tests set it to compare).
    static DECODER: std::cell::Cell<Option<Decoder>> = const { std::cell::Cell::new(None) };
}

/// The decoders, fastest first; each gives the scalar one's output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Decoder {
    Avx2,
    Scalar,
}

impl Decoder {
    const ALL: [Decoder; 2] = [Decoder::Avx2, Decoder::Scalar];

    /// Whether this CPU runs it.
    fn usable(self) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            Decoder::Avx2 => avx2::usable(),
            Decoder::Scalar => true,
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The fastest this CPU runs.
    fn best() -> Decoder {
        Decoder::ALL.into_iter().find(|d| d.usable()).unwrap_or(Decoder::Scalar)
    }
}

/// One lane's decoding: its rANS state, next word and the end of its run,
/// and the sub-mask it is decoding with that sub-mask's rows outside it.
#[derive(Clone, Copy, Default)]
struct Lane {
    x: u32,
    at: usize,
    end: usize,
    m: u64,
    along_x: [u8; 4],
    along_y: [u8; 4],
}

/// Decodes row `t` of the lane's sub-mask (table of precision `P`, every
/// index inside it: `table.len() == 128 << P`); a context the table
/// leaves unused, or a word past the lane's run (the last is read again),
/// sets `bad`.
#[inline(always)]
fn step<const P: u32>(l: &mut Lane, t: usize, table: &[u32], words: &[u16], bad: &mut bool) {
    let a = if t >= 4 { row(l.m, t - 4) } else { u32::from(l.along_x[t & 3]) };
    let b = if t & 3 != 0 { row(l.m, t - 1) } else { u32::from(l.along_y[t >> 2]) };
    let ctx = CONTEXT[((a << 5 | b) & 1023) as usize] as usize;
    let slot = l.x & ((1 << P) - 1);
    let e = table[(ctx << P) | slot as usize];
    let f = e >> 6 & 0x1fff;
    let x = (f * (l.x >> P) + slot).wrapping_sub(e >> 19);
    let renormalise = x < RANS_LOW;
    *bad |= (f == 0) | (renormalise & (l.at == l.end));
    let w = u32::from(words[l.at.min(l.end - 1)]);
    l.x = if renormalise { x << 16 | w } else { x };
    l.at += usize::from(renormalise);
    l.m |= u64::from(e & 15) << (4 * t);
}

/// The rANS decoding of every sub-mask into `out` (after its head), with
/// the decode `table` of precision `P`, lane l reading the `runs[l]` words
/// after the runs before it. The lanes are independent; the decoder takes
/// each round's in fours, whose dependency chains then overlap.
fn rows<const P: u32>(s: &Shape, table: &[u32], bytes: &[u8], runs: &[usize], out: &mut [u8]) -> Result<(), String> {
    // One word more than any run reaches: the vector decoder's gathers read 32 bits.
    let mut words = vec![0u16; bytes.len() / 2 + 1];
    words.iter_mut().zip(bytes.chunks_exact(2)).for_each(|(w, b)| *w = u16::from_le_bytes([b[0], b[1]]));
    let decoder = DECODER.get().unwrap_or_else(|| {
        DECODER.set(Some(Decoder::best()));
        Decoder::best()
    });
    // The vector decoders' gather indices are 32-bit.
    let decoder = if words.len() < 1 << 30 { decoder } else { Decoder::Scalar };
    let mut lanes = vec![Lane::default(); runs.len()];
    let mut start = 0;
    for (l, &r) in lanes.iter_mut().zip(runs) {
        (l.x, l.at, l.end) = (u32::from(words[start]) << 16 | u32::from(words[start + 1]), start + 2, start + r);
        start += r;
    }
    // Each lane's node and that node's sub-block masks so far (a node's sub-masks are its lane's, one after the other).
    let mut known = vec![(usize::MAX, [0u64; 8]); runs.len()];
    let mut bad = false;
    let (order, starts) = rounds(s, runs.len());
    for round in starts.windows(2).map(|w| &order[w[0]..w[1]]) {
        for group in round.chunks(16) {
            let mut g = [Lane::default(); 16];
            for (lane, &(l, i)) in g.iter_mut().zip(group) {
                let (k, b) = (s.owners[i].0 as usize, usize::from(s.owners[i].1));
                if known[l].0 != k {
                    known[l] = (k, known_of(s.states[k]));
                }
                *lane = Lane { m: 0, ..lanes[l] };
                (lane.along_x, lane.along_y) = outside(&known[l].1, b);
            }
            match decoder {
                // SAFETY: `Decoder::best` (or a test) checked the CPU; the table holds 128 << P
                // entries, `words` one past every run, every run ends below 2^30.
                #[cfg(target_arch = "x86_64")]
                Decoder::Avx2 => unsafe { avx2::group(&mut g[..group.len()], P, table, &words, &mut bad) },
                _ => {
                    for t in 0..ROWS {
                        let mut quads = g[..group.len()].chunks_exact_mut(4);
                        for q in &mut quads {
                            if let [g0, g1, g2, g3] = q {
                                step::<P>(g0, t, table, &words, &mut bad);
                                step::<P>(g1, t, table, &words, &mut bad);
                                step::<P>(g2, t, table, &words, &mut bad);
                                step::<P>(g3, t, table, &words, &mut bad);
                            }
                        }
                        quads.into_remainder().iter_mut().for_each(|l| step::<P>(l, t, table, &words, &mut bad));
                    }
                }
            }
            for (lane, &(l, i)) in g.iter().zip(group) {
                lanes[l] = *lane;
                known[l].1[usize::from(s.owners[i].1)] = lane.m;
                out[s.head + 8 * i..s.head + 8 * i + 8].copy_from_slice(&lane.m.to_le_bytes());
            }
        }
    }
    if bad {
        return Err("reaches a context its table leaves unused, or reads past a lane's run of words".into());
    }
    if lanes.iter().any(|l| l.x != RANS_LOW || l.at != l.end) {
        return Err("ends with a lane's state other than 2^16, or words left in its run".into());
    }
    Ok(())
}

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(test)]
mod tests;
