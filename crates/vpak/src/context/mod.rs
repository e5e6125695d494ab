//! Coding scheme 2 (version 11): a tiled atlas's elements, as the `tiles
//! unpredicted` filter lays them out (each tile's divisor, then its 512
//! quotients), coded with a static context model and rANS instead of zstd.
//! Each quotient is predicted from its decoded neighbours in the tile (the
//! mean of the three 2D Lorenzo predictions), and its residual is coded in a
//! context made of the tile's face class and the sum of the neighbours'
//! residual magnitudes, with one frequency table per context for the whole
//! section. zstd sees bytes; this sees levels and their neighbourhood, and
//! takes 10–20 % fewer bytes than zstd:19 on the atlases `--optimize disk`
//! makes. `N` tiles are decoded side by side, each with its own rANS state
//! over one shared word stream, so that a vector decoder ([`avx512`],
//! [`avx2`]) runs `N` tiles in its lanes; the stream is the same for every
//! decoder, and the fastest the CPU has is chosen at run time.
//!
//! Scheme 4 (version 15) is the same stream told which voxels of each tile
//! some L3 node shows ([`crate::shown`]): a tile whose flag is set leaves
//! its other elements out of the stream, each the prediction there, and
//! every prediction is held to the tile's levels `[0, ⌊max / divisor⌋]`. An
//! element left out decodes in a context of its own whose one symbol (0)
//! has all the frequency: the rANS step leaves the state as it was, so the
//! decoders run every lane alike.
//! `docs/format.md`, "Context coding", is the specification.

use crate::shown::TileMask;
use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;

/// Elements of a tile.
const TILE: usize = crate::tiles::TILE;
/// Symbols below it are zigzagged residuals; symbol `ESCAPE + k` is one of
/// `2^k` residuals told apart by `k` raw bits.
const ESCAPE: u32 = 16;
/// The most symbols a context's table row may hold (`ESCAPE` + 32 escapes).
const MAX_SYMBOLS: usize = 48;
/// The largest symbol a decoder takes: the value of `ESCAPE + 31` is at
/// least 2^31 + 15, outside every element (the spec refuses it there), and
/// would overflow 32-bit arithmetic; every decoder refuses it as it meets it.
const LAST_SYMBOL: u32 = ESCAPE + 30;
/// The tile's face classes: whether x, y and z are past the tile's low faces.
const POSITIONS: usize = 8;
/// Buckets of the neighbours' residual magnitudes.
const BUCKETS: usize = 16;
const CONTEXTS: usize = BUCKETS * POSITIONS;
/// The decode tables' context of an element a scheme-4 stream leaves out:
/// one symbol, 0, of frequency 2^precision (a step that changes nothing).
const SKIPPED: usize = CONTEXTS;
/// The rANS states' lower bound; words are 16 bits.
pub(crate) const RANS_LOW: u32 = 1 << 16;
/// Tiles decoded side by side, as vdbcook writes them: four vectors of 16 lanes.
const LANES: usize = 64;
/// Each used context's frequencies sum to 2^PRECISION, as vdbcook writes
/// them: decode tables of 512 entries per context stay in the L2 cache.
const PRECISION: u32 = 9;
/// Allowed precisions and lane counts.
const PRECISIONS: std::ops::RangeInclusive<u32> = 9..=12;
const MAX_LANES: usize = 256;
/// Bytes of the stream's header.
const HEAD: usize = 24;
/// A decode-table entry that no valid stream reaches (rows of contexts
/// the encoder never used): symbol 63, frequency 0.
pub(crate) const UNUSED: u32 = 63;

/// A tile's element `v` (x fastest) in the decoder's padded 9³ block:
/// neighbours below the tile's low faces read as 0.
#[inline(always)]
fn padded(v: usize) -> usize {
    let (x, y, z) = (v & 7, (v >> 3) & 7, v >> 6);
    (z + 1) * 81 + (y + 1) * 9 + (x + 1)
}

/// The face class of element `v`: 4·[z > 0] + 2·[y > 0] + [x > 0].
#[inline(always)]
fn position(v: usize) -> usize {
    let (x, y, z) = (v & 7, (v >> 3) & 7, v >> 6);
    usize::from(z > 0) << 2 | usize::from(y > 0) << 1 | usize::from(x > 0)
}

/// The prediction of the element at padded index `p` of class `pos` from
/// the decoded elements `f`: along one axis the neighbour, in a face the 2D
/// Lorenzo prediction, inside the mean of the three 2D ones (rounded down).
#[inline(always)]
fn predict(pos: usize, f: &[i32; 729], p: usize) -> i32 {
    let (a, b, c) = (f[p - 81], f[p - 9], f[p - 1]);
    match pos {
        7 => (2 * (a + b + c) - f[p - 90] - f[p - 82] - f[p - 10] + 1).div_euclid(3),
        3 => b + c - f[p - 10],
        5 => a + c - f[p - 82],
        6 => a + b - f[p - 90],
        1 => c,
        2 => b,
        _ => a,
    }
}

/// What a tile's quotients cost the coder, roughly, in bits: the order-0
/// entropy of their symbols after prediction, and the escape bits.
pub(crate) fn tile_bits(tile: &[u16; TILE]) -> f64 {
    let mut f = [0i32; 729];
    let mut counts = [0u32; MAX_SYMBOLS];
    let mut raw_bits = 0u32;
    for (v, &q) in tile.iter().enumerate() {
        let p = padded(v);
        let (sym, bits, _) = token(i32::from(q) - predict(position(v), &f, p));
        counts[(sym as usize).min(MAX_SYMBOLS - 1)] += 1;
        raw_bits += bits;
        f[p] = i32::from(q);
    }
    let n = TILE as f64;
    counts.iter().filter(|&&c| c > 0).map(|&c| f64::from(c) * (n / f64::from(c)).log2()).sum::<f64>() + f64::from(raw_bits)
}

/// Sets each element of a tile (quotients, x fastest), in order, to the
/// value within its `bounds` (inclusive) nearest the coder's prediction
/// from the elements before it: an element whose bounds hold the
/// prediction costs a residual of 0, and the others the least residual
/// their bounds allow.
pub(crate) fn nearest_predicted(tile: &mut [u16; TILE], bounds: impl Fn(usize) -> (u16, u16)) {
    let mut f = [0i32; 729];
    for (v, q) in tile.iter_mut().enumerate() {
        let p = padded(v);
        let (lo, hi) = bounds(v);
        *q = predict(position(v), &f, p).clamp(i32::from(lo), i32::from(hi)) as u16;
        f[p] = i32::from(*q);
    }
}

/// The bucket of a sum of three residual magnitudes (at most 255).
#[inline(always)]
fn bucket(e: u32) -> u32 {
    match e < 4 {
        true => e,
        false => (e * e).ilog2().min(BUCKETS as u32 - 1),
    }
}

/// A residual as a symbol and its raw bits: (symbol, bit count, bits).
#[inline(always)]
fn token(r: i32) -> (u32, u32, u32) {
    let z = ((r << 1) ^ (r >> 31)) as u32;
    if z < ESCAPE {
        return (z, 0, 0);
    }
    let u = z - ESCAPE + 1;
    let k = u.ilog2();
    (ESCAPE + k, k, u - (1 << k))
}

/// The zigzagged residual of symbol `s` before its raw bits are added, and their count.
#[inline(always)]
fn base(s: u32) -> (u32, u32) {
    match s < ESCAPE {
        true => (s, 0),
        false => (ESCAPE - 1 + (1 << (s - ESCAPE).min(31)), s - ESCAPE),
    }
}

/// One coded residual: its context, symbol and raw bits (the count follows from the symbol).
#[derive(Clone, Copy)]
struct Token {
    ctx: u8,
    sym: u8,
    raw: u32,
}

/// Whether bit `v` (an element of a tile) of `mask` is set.
#[inline(always)]
fn bit(mask: &TileMask, v: usize) -> bool {
    mask[v >> 6] >> (v & 63) & 1 == 1
}

/// A tile's predictions held within `[lo, hi]` (scheme 4: the tile's levels;
/// scheme 2: no bound).
#[derive(Clone, Copy)]
struct Bounds {
    lo: i32,
    hi: i32,
}

const UNBOUNDED: Bounds = Bounds { lo: i32::MIN, hi: i32::MAX };

impl Bounds {
    /// A scheme-4 tile's: its levels, `[0, ⌊(2^(8w) − 1) / divisor⌋]` (`[0, 0]` for divisor 0).
    fn levels(divisor: u16, width: usize) -> Bounds {
        let top = (1i32 << (8 * width)) - 1;
        Bounds { lo: 0, hi: if divisor == 0 { 0 } else { top / i32::from(divisor) } }
    }
}

/// The tokens of one tile's quotients, in element order; the elements of
/// `skip` (which must each be their prediction: [`skippable`]) in the
/// [`SKIPPED`] context.
fn tokens(tile: &[u16], skip: &TileMask, bounds: Bounds) -> Vec<Token> {
    let mut f = [0i32; 729];
    let mut mag = [0u32; 729];
    let mut out = Vec::with_capacity(TILE);
    for (v, &q) in tile.iter().enumerate() {
        let (p, pos) = (padded(v), position(v));
        f[p] = i32::from(q);
        if bit(skip, v) {
            out.push(Token { ctx: SKIPPED as u8, sym: 0, raw: 0 });
            continue;
        }
        let e = (mag[p - 81] + mag[p - 9] + mag[p - 1]).min(255);
        let r = i32::from(q) - predict(pos, &f, p).clamp(bounds.lo, bounds.hi);
        let (sym, _, raw) = token(r);
        out.push(Token { ctx: (bucket(e) as usize * POSITIONS + pos) as u8, sym: sym as u8, raw });
        mag[p] = r.unsigned_abs();
    }
    out
}

/// Whether a scheme-4 tile may leave out the elements `shown` does not
/// hold: there are some, and each is its prediction (within `bounds`)
/// from the elements before it.
fn skippable(tile: &[u16], shown: &TileMask, bounds: Bounds) -> bool {
    if shown.iter().all(|&w| w == u64::MAX) {
        return false;
    }
    let mut f = [0i32; 729];
    tile.iter().enumerate().all(|(v, &q)| {
        let p = padded(v);
        let keep = bit(shown, v) || predict(position(v), &f, p).clamp(bounds.lo, bounds.hi) == i32::from(q);
        f[p] = i32::from(q);
        keep
    })
}

/// Counts per context quantised to a total of 2^`precision` each (every
/// symbol seen at least 1; a context never seen all 0).
pub(crate) fn quantise<const N: usize>(counts: &[[u64; N]], precision: u32) -> Vec<[u32; N]> {
    let total = 1i64 << precision;
    counts
        .iter()
        .map(|c| {
            let n: u64 = c.iter().sum();
            let mut f = [0u32; N];
            if n == 0 {
                return f;
            }
            for (f, &c) in f.iter_mut().zip(c) {
                if c > 0 {
                    *f = ((c as f64 * total as f64 / n as f64 + 0.5).floor() as u32).max(1);
                }
            }
            // The largest takes the difference; if it cannot give all of it, the next largest gives the rest.
            let mut sum: i64 = f.iter().map(|&x| i64::from(x)).sum();
            while sum != total {
                let s = (0..N).max_by_key(|&s| (f[s], std::cmp::Reverse(s))).unwrap_or(0);
                let d = (total - sum).max(1 - i64::from(f[s]));
                f[s] = (i64::from(f[s]) + d) as u32;
                sum += d;
            }
            f
        })
        .collect()
}

/// Encodes a symbol of frequency `f` and cumulative frequency `c` (of
/// 2^`precision`) into rANS state `x`, first pushing its low word when the
/// state would outgrow 32 bits (encoding runs backwards: the words are
/// reversed once all are pushed).
pub(crate) fn rans_put(x: &mut u32, f: u32, c: u32, precision: u32, words: &mut Vec<u16>) {
    if u64::from(*x) >= (u64::from(RANS_LOW >> precision) << 16) * u64::from(f) {
        words.push(*x as u16);
        *x >>= 16;
    }
    *x = ((*x / f) << precision) + *x % f + c;
}

/// The `tiles unpredicted` filter's output `filtered` (`width`-byte elements
/// shuffled by byte: T divisors, then 512·T quotients) as a context-coded
/// stream, its side frame compressed by zstd at `level`: scheme 4 when
/// `shown` gives each tile's shown voxels ([`crate::shown`]), else scheme 2;
/// `None` when it does not hold whole tiles (or `shown` is not one mask per tile).
pub fn encode(filtered: &[u8], width: u32, level: i32, shown: Option<&[TileMask]>) -> std::io::Result<Option<Vec<u8>>> {
    encode_lanes(filtered, width, level, LANES, shown)
}

/// [`encode`] with `lanes` tiles side by side (vdbcook writes [`LANES`];
/// the tests also make the other counts a reader must take).
fn encode_lanes(filtered: &[u8], width: u32, level: i32, lanes: usize, shown: Option<&[TileMask]>) -> std::io::Result<Option<Vec<u8>>> {
    let w = width as usize;
    let m = filtered.len() / w.max(1);
    if !matches!(w, 1 | 2) || m * w != filtered.len() || m == 0 || !m.is_multiple_of(TILE + 1) {
        return Ok(None);
    }
    let tiles = m / (TILE + 1);
    if shown.is_some_and(|s| s.len() != tiles) {
        return Ok(None);
    }
    let element = |i: usize| match w {
        1 => u16::from(filtered[i]),
        _ => u16::from_le_bytes([filtered[i], filtered[m + i]]),
    };
    // Per tile (scheme 4): whether it leaves out what no node shows, and its tokens.
    let coded: Vec<(bool, Vec<Token>)> = (0..tiles)
        .into_par_iter()
        .map(|t| {
            let tile: Vec<u16> = (tiles + t * TILE..tiles + (t + 1) * TILE).map(element).collect();
            match shown {
                Some(shown) => {
                    let bounds = Bounds::levels(element(t), w);
                    let skips = skippable(&tile, &shown[t], bounds);
                    let skip = match skips {
                        true => shown[t].map(|m| !m),
                        false => [0; 8],
                    };
                    (skips, tokens(&tile, &skip, bounds))
                }
                None => (false, tokens(&tile, &[0; 8], UNBOUNDED)),
            }
        })
        .collect();
    let (flags, toks): (Vec<bool>, Vec<Vec<Token>>) = coded.into_iter().unzip();
    let mut counts = vec![[0u64; MAX_SYMBOLS]; CONTEXTS];
    let mut symbols = 1;
    for t in toks.iter().flatten().filter(|t| usize::from(t.ctx) < CONTEXTS) {
        counts[usize::from(t.ctx)][usize::from(t.sym)] += 1;
        symbols = symbols.max(usize::from(t.sym) + 1);
    }
    let mut freq = quantise(&counts, PRECISION);
    // The left-out elements' context: a step that changes no state.
    let mut null = [0u32; MAX_SYMBOLS];
    null[0] = 1 << PRECISION;
    freq.push(null);
    let cum: Vec<[u32; MAX_SYMBOLS]> = freq
        .iter()
        .map(|row| {
            let mut c = [0u32; MAX_SYMBOLS];
            row.iter().zip(c.iter_mut()).fold(0, |a, (&f, c)| {
                *c = a;
                a + f
            });
            c
        })
        .collect();
    // Decode order: group of `lanes` tiles, element, lane.
    let groups = tiles.div_ceil(lanes);
    let lanes_of = |g: usize| g * lanes..((g + 1) * lanes).min(tiles);
    let toks = &toks;
    let group = |g: usize| (0..TILE).flat_map(move |v| lanes_of(g).map(move |t| toks[t][v]));
    let mut bits = Vec::new();
    let (mut acc, mut held) = (0u64, 0u32);
    for tok in (0..groups).flat_map(group) {
        acc |= u64::from(tok.raw) << held;
        held += base(u32::from(tok.sym)).1;
        while held >= 8 {
            bits.push(acc as u8);
            acc >>= 8;
            held -= 8;
        }
    }
    if held > 0 {
        bits.push(acc as u8);
    }
    // rANS runs backwards: the last symbol decoded is encoded first.
    let mut states = vec![RANS_LOW; lanes];
    let mut words: Vec<u16> = Vec::new();
    for g in (0..groups).rev() {
        for v in (0..TILE).rev() {
            for t in lanes_of(g).rev() {
                let tok = toks[t][v];
                let (ctx, sym) = (usize::from(tok.ctx), usize::from(tok.sym));
                rans_put(&mut states[t % lanes], freq[ctx][sym], cum[ctx][sym], PRECISION, &mut words);
            }
        }
    }
    for x in states.iter().rev() {
        words.push(*x as u16);
        words.push((*x >> 16) as u16);
    }
    words.reverse();
    let mut side = Vec::with_capacity(tiles * w + tiles.div_ceil(8) + CONTEXTS * symbols * 2);
    for t in 0..tiles {
        side.extend_from_slice(&element(t).to_le_bytes()[..w]);
    }
    if shown.is_some() {
        side.extend(flags.chunks(8).map(|c| c.iter().enumerate().fold(0u8, |b, (i, &f)| b | u8::from(f) << i)));
    }
    for row in &freq[..CONTEXTS] {
        row[..symbols].iter().for_each(|&f| side.extend_from_slice(&(f as u16).to_le_bytes()));
    }
    let side = zstd::bulk::compress(&side, level)?;
    let fields = [lanes, PRECISION as usize, symbols, side.len(), bits.len(), words.len()];
    // The header's fields are 32 bits: a section too large for them stays with zstd.
    if fields.iter().any(|&v| u32::try_from(v).is_err()) {
        return Ok(None);
    }
    let mut out = Vec::with_capacity(HEAD + side.len() + bits.len() + 2 * words.len());
    for v in fields {
        out.extend_from_slice(&(v as u32).to_le_bytes());
    }
    out.extend_from_slice(&side);
    out.extend_from_slice(&bits);
    words.iter().for_each(|w| out.extend_from_slice(&w.to_le_bytes()));
    Ok(Some(out))
}

/// A stream's parts, checked against each other and the section's shape.
struct Stream {
    lanes: usize,
    precision: u32,
    tiles: usize,
    /// The escape bits, then 8 zero bytes (a decoder reads 8 at a time).
    bits: Vec<u8>,
    bits_len: usize,
    /// The rANS words, then zeros: as many as a row of 8 elements can take in
    /// every lane, and the 8 a vector decoder loads past the last it takes.
    words: Vec<u16>,
    words_len: usize,
    /// The decode table: per context 2^precision entries `symbol | freq << 6 | cum << 19`,
    /// the last context [`SKIPPED`]'s.
    table: Vec<u32>,
    /// Scheme 4: the elements left out, as the vector decoders take them: byte
    /// `(64·g + row)·N + l` is row `row` (y + 8z) of lane l's tile of group g,
    /// bit x set when element x of the row is left out; and each tile's
    /// predictions' bounds (both empty for scheme 2: none left out, no bounds).
    skip: Vec<u8>,
    bounds: Vec<Bounds>,
}

/// The left-out elements of the tiles whose flag is set (those `shown`
/// does not hold) laid out for the decoders ([`Stream::skip`]): per group
/// of `lanes` tiles, row by row, each lane's byte. By 8×8 byte transposes:
/// eight tiles' words `r` (their rows 8r to 8r + 7) become rows 8r to 8r + 7
/// of those eight lanes.
/// A flag must leave something out: one on a tile whose every voxel is
/// shown is refused (a writer never sets it).
// Word r of eight tiles' masks at once: the loop index is the word, not one mask's position.
#[allow(clippy::needless_range_loop)]
fn skip_layout(shown: &[TileMask], flagged: impl Fn(usize) -> bool, lanes: usize) -> Result<Vec<u8>, String> {
    let mut out = vec![0u8; shown.len().div_ceil(lanes) * 64 * lanes];
    // Runs of at most 8 lanes within each group (a group of 12 lanes: 8, then 4).
    let runs = (0..shown.len()).step_by(lanes).flat_map(|g0| (g0..(g0 + lanes).min(shown.len())).step_by(8).map(move |t0| (t0, 8.min(g0 + lanes - t0))));
    for (t0, run) in runs {
        let width = run.min(shown.len() - t0);
        let (g, l0) = (t0 / lanes, t0 % lanes);
        let on: [bool; 8] = std::array::from_fn(|i| i < width && flagged(t0 + i));
        let mut hidden = [0u64; 8];
        for r in 0..8 {
            let mut m: [u64; 8] = std::array::from_fn(|i| if on[i] { !shown[t0 + i][r] } else { 0 });
            hidden.iter_mut().zip(m).for_each(|(h, m)| *h |= m);
            if m.iter().all(|&w| w == 0) {
                continue;
            }
            transpose8(&mut m);
            for (k, row) in m.iter().enumerate() {
                let at = (g * 64 + 8 * r + k) * lanes + l0;
                match width {
                    8 => out[at..at + 8].copy_from_slice(&row.to_le_bytes()),
                    _ => out[at..at + width].copy_from_slice(&row.to_le_bytes()[..width]),
                }
            }
        }
        if let Some(i) = (0..8).find(|&i| on[i] && hidden[i] == 0) {
            return Err(format!("has tile {}'s flag set, but its every voxel is shown", t0 + i));
        }
    }
    Ok(out)
}

/// An 8×8 matrix of bytes (byte j of word i) transposed in place: byte i of word j.
fn transpose8(m: &mut [u64; 8]) {
    // Swap the off-diagonal 4×4, 2×2 and 1×1 blocks of bytes.
    for (half, mask) in [(4usize, 0x0000_0000_ffff_ffffu64), (2, 0x0000_ffff_0000_ffff), (1, 0x00ff_00ff_00ff_00ff)] {
        let shift = 8 * half as u32;
        for i in (0..8).filter(|i| i & half == 0) {
            let (a, b) = (m[i], m[i + half]);
            let t = ((a >> shift) ^ b) & mask;
            m[i] = a ^ (t << shift);
            m[i + half] = b ^ t;
        }
    }
}

/// `stored` parsed as a scheme-2 stream, or as a scheme-4 one when `shown`
/// gives each tile's shown voxels; the divisors written to `divisors` (the
/// filtered bytes' first `width`·T).
fn parse(stored: &[u8], width: usize, tiles: usize, divisors: &mut [u8], shown: Option<&[TileMask]>) -> Result<Stream, String> {
    if stored.len() < HEAD {
        return Err(format!("is {} bytes, shorter than a context stream's {HEAD}-byte header", stored.len()));
    }
    let field = |i: usize| u32::from_le_bytes([stored[4 * i], stored[4 * i + 1], stored[4 * i + 2], stored[4 * i + 3]]) as usize;
    let (lanes, precision, symbols, side_len, bits_len, words_len) = (field(0), field(1) as u32, field(2), field(3), field(4), field(5));
    if !(1..=MAX_LANES).contains(&lanes) || !PRECISIONS.contains(&precision) || !(1..=MAX_SYMBOLS).contains(&symbols) {
        return Err(format!("has {lanes} lanes, precision {precision} and {symbols} symbols (1 to {MAX_LANES}, 9 to 12 and 1 to {MAX_SYMBOLS} allowed)"));
    }
    let body = stored.len() - HEAD;
    if side_len as u64 + bits_len as u64 + 2 * words_len as u64 != body as u64 {
        return Err(format!("states {side_len} + {bits_len} + 2·{words_len} bytes of parts, but {body} follow its header"));
    }
    if words_len < 2 * lanes {
        return Err(format!("has {words_len} words, fewer than its {lanes} lanes' states"));
    }
    let flag_bytes = if shown.is_some() { tiles.div_ceil(8) } else { 0 };
    let side_want = tiles * width + flag_bytes + CONTEXTS * symbols * 2;
    let frame = &stored[HEAD..HEAD + side_len];
    if zstd::zstd_safe::find_frame_compressed_size(frame) != Ok(frame.len()) {
        return Err("has a side part that is not one zstd frame".into());
    }
    let mut side = Vec::with_capacity(side_want);
    let got = crate::coding::decompress_into(frame, &mut side).map_err(|e| format!("has a side frame that does not decompress to {side_want} bytes ({e})"))?;
    if got != side_want {
        return Err(format!("has a side frame of {got} bytes, not {side_want}"));
    }
    let (div, rest) = side.split_at(tiles * width);
    let (flags, freqs) = rest.split_at(flag_bytes);
    let m = divisors.len() / width.max(1);
    for (t, d) in div.chunks_exact(width).enumerate() {
        divisors[t] = d[0];
        if width == 2 {
            divisors[m + t] = d[1];
        }
    }
    let (mut skip, mut bounds) = (Vec::new(), Vec::new());
    if let Some(shown) = shown {
        // Every state stays at 2^16 or more, so a left-out element's step (the state as it is) never takes a word.
        if let Some(l) = (0..lanes).find(|&l| stored[HEAD + side_len + bits_len + 4 * l..][..2] == [0, 0]) {
            return Err(format!("has lane {l}'s first state below 2^16"));
        }
        if shown.len() != tiles {
            return Err(format!("is given {} tiles' shown voxels for its {tiles} tiles", shown.len()));
        }
        if !tiles.is_multiple_of(8) && flags.last().is_some_and(|&b| b >> (tiles % 8) != 0) {
            return Err("has a flag set past its last tile".into());
        }
        skip = skip_layout(shown, |t| flags[t / 8] >> (t % 8) & 1 == 1, lanes)?;
        bounds = div.chunks_exact(width).map(|d| Bounds::levels(if width == 2 { u16::from_le_bytes([d[0], d[1]]) } else { u16::from(d[0]) }, width)).collect();
    }
    let mut table = vec![UNUSED; (CONTEXTS + 1) << precision];
    fill_table(&mut table, freqs, symbols, precision)?;
    table[SKIPPED << precision..].fill(1 << (6 + precision));
    let at = HEAD + side_len;
    let mut bits = Vec::with_capacity(bits_len + 8);
    bits.extend_from_slice(&stored[at..at + bits_len]);
    bits.resize(bits_len + 8, 0);
    let mut words = vec![0u16; words_len + 8 * lanes + 8];
    bytemuck::cast_slice_mut::<u16, u8>(&mut words[..words_len]).copy_from_slice(&stored[at + bits_len..]);
    if cfg!(target_endian = "big") {
        words.iter_mut().for_each(|w| *w = u16::from_le(*w));
    }
    Ok(Stream { lanes, precision, tiles, bits, bits_len, words, words_len, table, skip, bounds })
}

/// Fills a decode table (2^`precision` entries per context, `symbol | freq
/// << 6 | cum << 19`) from `freqs`, one row of `symbols` `u16` frequencies
/// per context; a row summing to 0 (an unused context) leaves its entries as
/// they were ([`UNUSED`] where the caller filled them so), and one summing
/// to neither 0 nor 2^`precision` is refused. Shared by schemes 2 and 3.
pub(crate) fn fill_table(table: &mut [u32], freqs: &[u8], symbols: usize, precision: u32) -> Result<(), String> {
    let size = 1usize << precision;
    for (ctx, row) in freqs.chunks_exact(2 * symbols).enumerate() {
        let freq: Vec<usize> = row.chunks_exact(2).map(|b| usize::from(u16::from_le_bytes([b[0], b[1]]))).collect();
        let sum: usize = freq.iter().sum();
        if sum == 0 {
            continue;
        }
        if sum != size {
            return Err(format!("has context {ctx}'s frequencies summing to {sum}, not 0 or {size}"));
        }
        let mut cum = 0;
        for (s, &f) in freq.iter().enumerate() {
            table[(ctx << precision) + cum..(ctx << precision) + cum + f].fill(s as u32 | (f as u32) << 6 | (cum as u32) << 19);
            cum += f;
        }
    }
    Ok(())
}

/// Restores a scheme-2 stream `stored` (or scheme 4, given each tile's
/// shown voxels) into `out`, the `tiles unpredicted` filter's output for
/// `width`-byte elements (shuffled by byte), or says what is wrong with it.
/// Never reads or writes outside what it was given, whatever the stream holds.
pub fn decode(stored: &[u8], width: u32, out: &mut [u8], shown: Option<&[TileMask]>) -> Result<(), String> {
    let w = width as usize;
    let m = out.len() / w.max(1);
    if !matches!(w, 1 | 2) || m * w != out.len() || !m.is_multiple_of(TILE + 1) {
        return Err(format!("cannot restore {} bytes of {w}-byte tiles", out.len()));
    }
    let tiles = m / (TILE + 1);
    let s = parse(stored, w, tiles, out, shown)?;
    let decoder = Decoder::ALL.into_iter().find(|d| d.usable(s.lanes)).unwrap_or(Decoder::Scalar);
    decoder.run(&s, w, out)
}

/// The decoders, fastest first; each gives the scalar one's output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Decoder {
    Avx512,
    Avx2,
    Scalar,
}

impl Decoder {
    const ALL: [Decoder; 3] = [Decoder::Avx512, Decoder::Avx2, Decoder::Scalar];

    /// Whether this CPU runs it on a stream of `lanes` lanes.
    fn usable(self, lanes: usize) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            Decoder::Avx512 => avx512::usable(lanes),
            #[cfg(target_arch = "x86_64")]
            Decoder::Avx2 => avx2::usable(lanes),
            Decoder::Scalar => true,
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// Decodes `s` into `out` (`usable` must hold: it falls back to the scalar decoder otherwise).
    fn run(self, s: &Stream, w: usize, out: &mut [u8]) -> Result<(), String> {
        match self {
            // SAFETY: `usable` checked the CPU's features.
            #[cfg(target_arch = "x86_64")]
            Decoder::Avx512 if avx512::usable(s.lanes) => unsafe { avx512::decode(s, w, out) },
            #[cfg(target_arch = "x86_64")]
            Decoder::Avx2 if avx2::usable(s.lanes) => unsafe { avx2::decode(s, w, out) },
            _ => decode_scalar(s, w, out),
        }
    }
}

impl Stream {
    /// Each lane's first state, from the front of the words.
    fn initial_states(&self) -> Vec<u32> {
        (0..self.lanes).map(|l| u32::from(self.words[2 * l]) << 16 | u32::from(self.words[2 * l + 1])).collect()
    }

    fn escapes(&self) -> Escapes<'_> {
        Escapes { bits: &self.bits, len: self.bits_len, at: 0 }
    }

    /// Group `g`'s left-out elements (64 rows of N lanes' bytes), or 64·N zeros.
    #[inline(always)]
    fn skip_rows<'a>(&'a self, g: usize, zeros: &'a [u8]) -> &'a [u8] {
        let n = 64 * self.lanes;
        self.skip.get(g * n..(g + 1) * n).unwrap_or(zeros)
    }

    /// Tile `t`'s prediction bounds.
    #[inline(always)]
    fn bounds_of(&self, t: usize) -> Bounds {
        self.bounds.get(t).copied().unwrap_or(UNBOUNDED)
    }
}

/// The escape bits as the decoders read them, from the start.
struct Escapes<'a> {
    /// The bits, then 8 zero bytes.
    bits: &'a [u8],
    len: usize,
    /// Bits read so far.
    at: usize,
}

impl Escapes<'_> {
    /// Whether a read `ahead` bits on from the position starts past the
    /// bits' end (the 8 zero bytes after them hold what one read takes).
    #[inline(always)]
    fn past_end(&self, ahead: usize) -> bool {
        (self.at + ahead) >> 3 > self.len
    }

    /// The next `nb` bits (least significant first; at most 47 are taken,
    /// more than any valid symbol has, so that a damaged stream's read stays
    /// in one 64-bit window), or `None` when the position is past the end.
    #[inline(always)]
    fn read(&mut self, nb: u32) -> Option<u32> {
        if self.past_end(0) {
            return None;
        }
        let byte = self.at >> 3;
        let nb = nb.min(47);
        let peek = u64::from_le_bytes(self.bits[byte..byte + 8].try_into().unwrap_or_default()) >> (self.at & 7);
        self.at += nb as usize;
        Some((peek & ((1u64 << nb) - 1)) as u32)
    }
}

/// The reference decoder: one lane at a time.
fn decode_scalar(s: &Stream, w: usize, out: &mut [u8]) -> Result<(), String> {
    let m = out.len() / w;
    let n = s.lanes;
    let mask = (1u32 << s.precision) - 1;
    let max = (1i32 << (8 * w)) - 1;
    let mut states = s.initial_states();
    let (mut wp, mut escapes) = (2 * n, s.escapes());
    let mut f = vec![[0i32; 729]; n];
    let mut mag = vec![[0u32; 729]; n];
    let zeros = vec![0u8; 64 * n];
    for g in 0..s.tiles.div_ceil(n) {
        let present = n.min(s.tiles - g * n);
        let skip = s.skip_rows(g, &zeros);
        for v in 0..TILE {
            // A row of 8 elements takes at most 8 words per lane, which the padding holds.
            if v % 8 == 0 && wp > s.words_len {
                return Err("runs past the end of its words".into());
            }
            let (p, pos) = (padded(v), position(v));
            for l in 0..present {
                let (f, mag) = (&mut f[l], &mut mag[l]);
                let t = g * n + l;
                let e = (mag[p - 81] + mag[p - 9] + mag[p - 1]).min(255);
                let ctx = match skip[(v >> 3) * n + l] >> (v & 7) & 1 {
                    1 => SKIPPED,
                    _ => bucket(e) as usize * POSITIONS + pos,
                };
                let x = states[l];
                let slot = x & mask;
                let ent = s.table[(ctx << s.precision) | slot as usize];
                let sym = ent & 63;
                if sym > LAST_SYMBOL {
                    return Err(format!("decodes symbol {sym} in context {ctx}: an empty context, or a value no element holds"));
                }
                let mut x = ((ent >> 6) & 0x1fff) * (x >> s.precision) + slot - (ent >> 19);
                if x < RANS_LOW {
                    x = x << 16 | u32::from(s.words[wp]);
                    wp += 1;
                }
                states[l] = x;
                let (mut z, nb) = base(sym);
                if nb > 0 {
                    z += escapes.read(nb).ok_or("runs past the end of its escape bits")?;
                }
                let r = ((z >> 1) as i32) ^ -((z & 1) as i32);
                let b = s.bounds_of(t);
                let q = predict(pos, f, p).clamp(b.lo, b.hi).wrapping_add(r);
                if !(0..=max).contains(&q) {
                    return Err(format!("decodes to {q}, outside the {w}-byte element"));
                }
                mag[p] = r.unsigned_abs();
                f[p] = q;
                let i = m / (TILE + 1) + (g * n + l) * TILE + v;
                out[i] = q as u8;
                if w == 2 {
                    out[m + i] = (q >> 8) as u8;
                }
            }
        }
    }
    finish(s, &states, wp, &escapes)
}

/// A stream decoded to its end: every word read, every state back at its start, no bit past the end.
fn finish(s: &Stream, states: &[u32], wp: usize, escapes: &Escapes) -> Result<(), String> {
    if wp != s.words_len || states.iter().any(|&x| x != RANS_LOW) || escapes.at > 8 * s.bits_len {
        return Err("does not end where its coder does (damaged)".into());
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests;
