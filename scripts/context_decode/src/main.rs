//! Prototype: static-context rANS coder of quantised 8^3 bricks (issue 24 question), and
//! its single-thread decode throughput against zstd's.
//!
//!     context_decode BRICKS.bin [--runs R] [--zst OUT.zst] [--level 19] [--only x] [--no-masks]
//!
//! Model (the one context_floor.py measures as `lmean`, inactive `fill`, contexts `err+pos`):
//! raster order in each brick (x slowest, z fastest); prediction = mean of the three 2D
//! Lorenzo predictions (2D Lorenzo on faces, previous voxel on edges, 0 at the origin),
//! floor((2(a+b+c) - ab - ac - bc + 1) / 3); inactive voxels are not coded and take their
//! prediction (the decoder knows the mask). Residual zigzagged: values < 16 are symbols,
//! larger ones symbol 16 + k plus k raw bits. Context = bucket(|r(x-1)| + |r(y-1)| + |r(z-1)|)
//! (16 buckets: 0..3, then two per octave) * 8 + which low brick faces the voxel is on.
//! Static per-context frequency tables quantised to 2^P; 32-bit rANS state, 16-bit
//! renormalisation, N states interleaved across N bricks decoded side by side (bricks are
//! independent, so each lane's context chain stays within its own brick); all lanes share
//! one word stream; raw escape bits in a separate bit stream. `simd.rs` (AVX-512) and
//! `avx2.rs` decode the same streams with the lanes in vectors.

use std::time::Instant;

mod avx2;
mod simd;

const T: u32 = 16;
const NSYM: usize = 48;
const NPOS: usize = 8;
const NERR: usize = 16;
const NCTX: usize = NERR * NPOS;
const RANS_L: u32 = 1 << 16;
const FAST: bool = true;
/// Zero words after the rANS stream (the AVX2 decoder loads 8 words at a time).
const PAD_WORDS: usize = 8;

struct Input {
    n: usize,
    e: f64,
    bpl: usize,
    masks: Vec<[u8; 64]>,
    kmin: Vec<i32>,
    levels: Vec<u16>, // n * 512
}

/// The bricks of a BRK1 file (`export_bricks.py`, `export_atlas.py`), or what is wrong
/// with it; the sizes it states are checked against its length before anything is sized by them.
fn read_input(path: &str) -> Result<Input, String> {
    let d = std::fs::read(path).map_err(|e| e.to_string())?;
    if d.len() < 20 || &d[0..4] != b"BRK1" {
        return Err("not a BRK1 brick file".into());
    }
    let n = u32::from_le_bytes(d[4..8].try_into().unwrap()) as usize;
    let e = f64::from_le_bytes(d[8..16].try_into().unwrap());
    let bpl = u32::from_le_bytes(d[16..20].try_into().unwrap()) as usize;
    if !(bpl == 1 || bpl == 2) {
        return Err(format!("{bpl} bytes per level (1 or 2 expected)"));
    }
    let rec = 64 + 4 + 512 * bpl;
    if (d.len() - 20) / rec != n || (d.len() - 20) % rec != 0 {
        return Err(format!("{} bytes, not the {n} bricks of {rec} bytes its header states", d.len()));
    }
    let mut masks = Vec::with_capacity(n);
    let mut kmin = Vec::with_capacity(n);
    let mut levels = Vec::with_capacity(n * 512);
    for r in d[20..].chunks_exact(rec) {
        masks.push(r[0..64].try_into().unwrap());
        kmin.push(i32::from_le_bytes(r[64..68].try_into().unwrap()));
        for v in 0..512 {
            levels.push(if bpl == 1 { r[68 + v] as u16 } else { u16::from_le_bytes([r[68 + 2 * v], r[69 + 2 * v]]) });
        }
    }
    Ok(Input { n, e, bpl, masks, kmin, levels })
}

// ---- model (shared by encoder and decoder) ------------------------------------------------

fn bucket_lut() -> [u8; 256] {
    let mut t = [0u8; 256];
    for v in 0..256u32 {
        // context_floor.py: v < 4 ? v : 4 + floor(2 log2(v / 4)) = ilog2(v^2), at most 15
        t[v as usize] = if v < 4 { v as u8 } else { (v * v).ilog2().min(15) as u8 };
    }
    t
}

#[inline(always)]
fn pidx(i: usize, j: usize, k: usize) -> usize {
    (i + 1) * 81 + (j + 1) * 9 + (k + 1)
}

/// lmean prediction from the padded (9^3, zeros on the low sides) decoded levels.
#[inline(always)]
fn predict(pos: usize, f: &[i32; 729], p: usize) -> i32 {
    let a = f[p - 81];
    let b = f[p - 9];
    let c = f[p - 1];
    match pos {
        7 => (2 * (a + b + c) - f[p - 90] - f[p - 82] - f[p - 10] + 1).div_euclid(3),
        3 => b + c - f[p - 10],
        5 => a + c - f[p - 82],
        6 => a + b - f[p - 90],
        1 => c,
        2 => b,
        _ => a, // 4: a; 0: a = 0 (padding)
    }
}

#[derive(Clone, Copy)]
struct Tok {
    ctx: u8,
    sym: u8,
    nb: u8,
    raw: u32,
}

fn zigzag(r: i32) -> u32 {
    ((r << 1) ^ (r >> 31)) as u32
}

fn token(z: u32) -> (u8, u8, u32) {
    if z < T {
        (z as u8, 0, 0)
    } else {
        let u = z - T + 1;
        let k = u.ilog2();
        ((T + k) as u8, k as u8, u - (1 << k))
    }
}

/// Runs the model over one brick with known levels: its tokens (active voxels, raster
/// order) and the reference output (active: level; inactive: the fill prediction, clamped).
fn model_brick(lv: &[u16], mask: &[u8; 64], bl: &[u8; 256], maxv: i32, toks: &mut Vec<Tok>, out: &mut [u16]) {
    let mut f = [0i32; 729];
    let mut ra = [0u32; 729];
    for i in 0..8 {
        for j in 0..8 {
            for k in 0..8 {
                let v = i * 64 + j * 8 + k;
                let p = pidx(i, j, k);
                let pos = ((i > 0) as usize) << 2 | ((j > 0) as usize) << 1 | (k > 0) as usize;
                let pred = predict(pos, &f, p);
                let act = (mask[v >> 3] >> (v & 7)) & 1 == 1;
                if act {
                    let e = (ra[p - 81] + ra[p - 9] + ra[p - 1]).min(255);
                    let ctx = bl[e as usize] as usize * NPOS + pos;
                    let r = lv[v] as i32 - pred;
                    let (sym, nb, raw) = token(zigzag(r));
                    toks.push(Tok { ctx: ctx as u8, sym, nb, raw });
                    ra[p] = r.unsigned_abs();
                    f[p] = lv[v] as i32;
                } else {
                    ra[p] = 0;
                    f[p] = pred;
                }
                out[v] = f[p].clamp(0, maxv) as u16;
            }
        }
    }
}

/// Every brick of `inp` through the model: its tokens, and the reference output of all.
fn model_all(inp: &Input, bl: &[u8; 256]) -> (Vec<Vec<Tok>>, Vec<u16>) {
    let maxv = if inp.bpl == 1 { 255 } else { 65535 };
    let mut refout = vec![0u16; inp.n * 512];
    let toks = (0..inp.n)
        .zip(refout.chunks_exact_mut(512))
        .map(|(b, out)| {
            let mut t = Vec::new();
            model_brick(&inp.levels[b * 512..(b + 1) * 512], &inp.masks[b], bl, maxv, &mut t, out);
            t
        })
        .collect();
    (toks, refout)
}

// ---- tables ---------------------------------------------------------------------------------

/// Frequencies of every context quantised to a total of 2^p, every seen symbol at least 1.
fn quantise(counts: &[[u64; NSYM]], p: u32) -> Vec<[u32; NSYM]> {
    let tot = 1u32 << p;
    counts
        .iter()
        .map(|c| {
            let n: u64 = c.iter().sum();
            let mut f = [0u32; NSYM];
            if n == 0 {
                return f;
            }
            for s in 0..NSYM {
                if c[s] > 0 {
                    f[s] = ((c[s] as f64 * tot as f64 / n as f64 + 0.5).floor() as u32).max(1);
                }
            }
            let mut sum: i64 = f.iter().map(|&x| x as i64).sum();
            while sum != tot as i64 {
                // adjust the largest frequency (that stays >= 1)
                let s = (0..NSYM).max_by_key(|&s| f[s]).unwrap();
                if sum < tot as i64 {
                    f[s] += (tot as i64 - sum) as u32;
                    sum = tot as i64;
                } else {
                    let d = ((sum - tot as i64) as u32).min(f[s] - 1);
                    assert!(d > 0, "cannot quantise");
                    f[s] -= d;
                    sum -= d as i64;
                }
            }
            f
        })
        .collect()
}

fn cums(f: &[[u32; NSYM]]) -> Vec<[u32; NSYM]> {
    f.iter()
        .map(|r| {
            let mut c = [0u32; NSYM];
            let mut a = 0;
            for s in 0..NSYM {
                c[s] = a;
                a += r[s];
            }
            c
        })
        .collect()
}

/// Decode table: entry = sym | freq << 6 | cum << 19 for every slot of every used context.
fn build_lut(f: &[[u32; NSYM]], p: u32, lut: &mut Vec<u32>) {
    let tot = 1usize << p;
    // Rows of contexts no symbol was coded in are never read (the decoder meets only the
    // contexts the encoder did): they are left as they are, not zeroed on every decode.
    if lut.len() != NCTX * tot {
        lut.clear();
        lut.resize(NCTX * tot, 0);
    }
    for ctx in 0..NCTX {
        let mut cum = 0usize;
        let row = &mut lut[ctx * tot..(ctx + 1) * tot];
        for s in 0..NSYM {
            let fr = f[ctx][s] as usize;
            if fr == 0 {
                continue;
            }
            let e = s as u32 | (fr as u32) << 6 | (cum as u32) << 19;
            row[cum..cum + fr].fill(e);
            cum += fr;
        }
    }
}

// ---- encoder ------------------------------------------------------------------------------

struct Coded {
    words: Vec<u16>,    // rANS streams (each: states first, decode order, padding), one after the other
    starts: Vec<usize>, // where each stream starts in `words`
    bits: Vec<u8>,      // raw escape bits, LSB first, padded with 8 bytes
    tables_z: Vec<u8>,
    masks_z: Vec<u8>,
    kmin_z: Vec<u8>,
    nsym: usize,
    ideal_bits: f64,
}

fn encode(inp: &Input, toks: &[Vec<Tok>], n_lanes: usize, streams: usize, p: u32) -> Coded {
    let mut counts = vec![[0u64; NSYM]; NCTX];
    let mut nsym = 0;
    for bt in toks {
        for t in bt {
            counts[t.ctx as usize][t.sym as usize] += 1;
            nsym = nsym.max(t.sym as usize + 1);
        }
    }
    let f = quantise(&counts, p);
    let c = cums(&f);
    let mut ideal = 0.0;
    for ctx in 0..NCTX {
        for s in 0..NSYM {
            if counts[ctx][s] > 0 {
                ideal -= counts[ctx][s] as f64 * (f[ctx][s] as f64 / (1u64 << p) as f64).log2();
            }
        }
    }
    // decode order: group, voxel, lane
    let groups = inp.n.div_ceil(n_lanes);
    let mut order: Vec<(u8, Tok)> = Vec::new();
    let mut next = vec![0usize; inp.n];
    for g in 0..groups {
        for v in 0..512 {
            for l in 0..n_lanes {
                let b = g * n_lanes + l;
                if b < inp.n && (inp.masks[b][v >> 3] >> (v & 7)) & 1 == 1 {
                    order.push((l as u8, toks[b][next[b]]));
                    next[b] += 1;
                }
            }
        }
    }
    // raw bits, forward
    let mut bits = Vec::new();
    let mut acc: u64 = 0;
    let mut nacc = 0u32;
    for (_, t) in &order {
        acc |= (t.raw as u64) << nacc;
        nacc += t.nb as u32;
        while nacc >= 8 {
            bits.push(acc as u8);
            acc >>= 8;
            nacc -= 8;
        }
    }
    if nacc > 0 {
        bits.push(acc as u8);
    }
    bits.extend_from_slice(&[0u8; 8]);
    // rANS, backwards
    // rANS, backwards; the lanes in `streams` contiguous groups, each with a word stream of
    // its own (its states first, then its words in decode order, then padding).
    let per = n_lanes / streams;
    assert_eq!(per * streams, n_lanes);
    let mut st = vec![RANS_L; n_lanes];
    let mut ws: Vec<Vec<u16>> = vec![Vec::new(); streams];
    for (l, t) in order.iter().rev() {
        let w = &mut ws[*l as usize / per];
        let fr = f[t.ctx as usize][t.sym as usize];
        let cu = c[t.ctx as usize][t.sym as usize];
        let mut x = st[*l as usize];
        let xmax = ((RANS_L as u64 >> p) << 16) * fr as u64;
        if x as u64 >= xmax {
            w.push(x as u16);
            x >>= 16;
        }
        x = ((x / fr) << p) + (x % fr) + cu;
        st[*l as usize] = x;
    }
    let mut words = Vec::new();
    let mut starts = Vec::new();
    for (sidx, mut w) in ws.into_iter().enumerate() {
        for l in (sidx * per..(sidx + 1) * per).rev() {
            w.push(st[l] as u16);
            w.push((st[l] >> 16) as u16);
        }
        w.reverse();
        w.extend_from_slice(&[0u16; PAD_WORDS]); // the decoders may read past the end (AVX2: 8 words)
        starts.push(words.len());
        words.extend_from_slice(&w);
    }
    // side information
    let mut tb = Vec::new();
    for ctx in 0..NCTX {
        for s in 0..nsym {
            tb.extend_from_slice(&(f[ctx][s] as u16).to_le_bytes());
        }
    }
    let mut mb = Vec::new();
    for m in &inp.masks {
        mb.extend_from_slice(m);
    }
    let mut kb = Vec::new();
    let mut prev = 0i32;
    for &k in &inp.kmin {
        kb.extend_from_slice(&(k - prev).to_le_bytes());
        prev = k;
    }
    Coded {
        words,
        starts,
        bits,
        tables_z: zstd::bulk::compress(&tb, 19).unwrap(),
        masks_z: zstd::bulk::compress(&mb, 19).unwrap(),
        kmin_z: zstd::bulk::compress(&kb, 19).unwrap(),
        nsym,
        ideal_bits: ideal,
    }
}

// ---- decoder ------------------------------------------------------------------------------

trait Texel: Copy + Default {
    fn from_level(q: i32) -> Self;
    fn level(self) -> u16;
}
impl Texel for u8 {
    #[inline(always)]
    fn from_level(q: i32) -> Self {
        q.clamp(0, 255) as u8
    }
    fn level(self) -> u16 {
        self as u16
    }
}
impl Texel for u16 {
    #[inline(always)]
    fn from_level(q: i32) -> Self {
        q.clamp(0, 65535) as u16
    }
    fn level(self) -> u16 {
        self
    }
}

struct Scratch {
    lut: Vec<u32>,
    masks: Vec<u8>,
    kmin: Vec<u8>,
    tables: Vec<u8>,
}

/// The side information (zstd) and the decode table.
fn prepare(cd: &Coded, n: usize, lanes: usize, p: u32, sc: &mut Scratch) {
    sc.masks.clear();
    sc.masks.resize(n.div_ceil(lanes) * lanes * 64, 0);
    let mm = zstd::bulk::decompress_to_buffer(&cd.masks_z, &mut sc.masks[..n * 64]).unwrap();
    assert_eq!(mm, n * 64);
    sc.kmin.resize(n * 4, 0);
    zstd::bulk::decompress_to_buffer(&cd.kmin_z, &mut sc.kmin[..]).unwrap();
    sc.tables.resize(NCTX * cd.nsym * 2, 0);
    zstd::bulk::decompress_to_buffer(&cd.tables_z, &mut sc.tables[..]).unwrap();
    let mut f = vec![[0u32; NSYM]; NCTX];
    for ctx in 0..NCTX {
        for s in 0..cd.nsym {
            let o = (ctx * cd.nsym + s) * 2;
            f[ctx][s] = u16::from_le_bytes([sc.tables[o], sc.tables[o + 1]]) as u32;
        }
    }
    build_lut(&f, p, &mut sc.lut);
}

#[inline(never)]
fn decode_voxels<O: Texel, const N: usize, const P: u32>(cd: &Coded, n: usize, masks: &[u8], lut: &[u32], out: &mut [O], bl: &[u8; 256]) {
    let mut base = [0u32; 64];
    let mut nbt = [0u32; 64];
    for s in 0..64u32 {
        base[s as usize] = if s < T {
            s
        } else if s < 48 {
            T - 1 + (1 << (s - T))
        } else {
            0
        };
        nbt[s as usize] = if s < T { 0 } else { s - T };
    }
    let words = &cd.words[..];
    let bits = &cd.bits[..];
    let mut wp = 0usize;
    let mut st = [0u32; N];
    for l in 0..N {
        st[l] = (words[wp] as u32) << 16 | words[wp + 1] as u32;
        wp += 2;
    }
    let mut bp = 0usize;
    let mut f = [[0i32; 729]; N];
    let mut ra = [[0u32; 729]; N];
    let zero = [0u8; 64];
    let mask_of = |b: usize| -> &[u8] {
        if b < n {
            &masks[b * 64..b * 64 + 64]
        } else {
            &zero[..]
        }
    };
    let groups = n.div_ceil(N);
    let tmask = (1u32 << P) - 1;
    for g in 0..groups {
        let m: [&[u8]; N] = std::array::from_fn(|l| mask_of(g * N + l));
        let nl = (n - g * N).min(N);
        for i in 0..8 {
            for j in 0..8 {
                for k in 0..8 {
                    let v = i * 64 + j * 8 + k;
                    let p = pidx(i, j, k);
                    let pos = ((i > 0) as usize) << 2 | ((j > 0) as usize) << 1 | (k > 0) as usize;
                    for l in 0..N {
                        let act = ((m[l][v >> 3] >> (v & 7)) & 1) as u32;
                        let e = (ra[l][p - 81] + ra[l][p - 9] + ra[l][p - 1]).min(255);
                        let ctx = bl[e as usize] as usize * NPOS + pos;
                        let x = st[l];
                        let slot = x & tmask;
                        let ent = lut[(ctx << P) | slot as usize];
                        let sym = (ent & 63) as usize;
                        let fr = (ent >> 6) & 0x1fff;
                        let cu = ent >> 19;
                        let xn = fr * (x >> P) + slot - cu;
                        let xs = if act != 0 { xn } else { x };
                        let need = xs < RANS_L;
                        let w = words[wp] as u32;
                        st[l] = if need { (xs << 16) | w } else { xs };
                        wp += need as usize;
                        let nb = nbt[sym] & act.wrapping_neg();
                        let peek = u64::from_le_bytes(bits[bp >> 3..(bp >> 3) + 8].try_into().unwrap()) >> (bp & 7);
                        let raw = (peek & ((1u64 << nb) - 1)) as u32;
                        bp += nb as usize;
                        let z = (base[sym] + raw) & act.wrapping_neg();
                        let r = ((z >> 1) as i32) ^ -((z & 1) as i32);
                        ra[l][p] = (z + 1) >> 1;
                        let q = predict(pos, &f[l], p) + r;
                        f[l][p] = q;
                        if l < nl {
                            out[(g * N + l) * 512 + v] = O::from_level(q);
                        }
                    }
                }
            }
        }
    }
}

// ---- the comparison: 3D-delta-filtered levels through zstd ---------------------------------

/// masks, kmin (i32), then per brick the levels (u8 or u16, wrapping) after a difference
/// along x, then y, then z inside the brick (undone by running sums along z, y, x).
fn filtered_bytes(inp: &Input) -> Vec<u8> {
    let mut out = Vec::new();
    for m in &inp.masks {
        out.extend_from_slice(m);
    }
    for &k in &inp.kmin {
        out.extend_from_slice(&k.to_le_bytes());
    }
    for b in 0..inp.n {
        let mut a: Vec<i32> = inp.levels[b * 512..(b + 1) * 512].iter().map(|&x| x as i32).collect();
        for (s, st) in [(64usize, 0usize), (8, 1), (1, 2)] {
            let _ = st;
            for v in (0..512).rev() {
                let c = (v / s) % 8;
                if c > 0 {
                    a[v] -= a[v - s];
                }
            }
        }
        for v in 0..512 {
            if inp.bpl == 1 {
                out.push(a[v] as u8);
            } else {
                out.extend_from_slice(&(a[v] as u16).to_le_bytes());
            }
        }
    }
    out
}

fn unfilter(d: &mut [u8], n: usize, bpl: usize) {
    let off = n * 68;
    for b in 0..n {
        let s0 = off + b * 512 * bpl;
        if bpl == 1 {
            let a = &mut d[s0..s0 + 512];
            for v in 0..512 {
                if v % 8 > 0 {
                    a[v] = a[v].wrapping_add(a[v - 1]);
                }
            }
            for v in 0..512 {
                if (v / 8) % 8 > 0 {
                    a[v] = a[v].wrapping_add(a[v - 8]);
                }
            }
            for v in 64..512 {
                a[v] = a[v].wrapping_add(a[v - 64]);
            }
        } else {
            let a = &mut d[s0..s0 + 1024];
            let g = |a: &[u8], v: usize| u16::from_le_bytes([a[2 * v], a[2 * v + 1]]);
            for (s, c) in [(1usize, 8usize), (8, 64), (64, 512)] {
                for v in 0..512 {
                    if (v % c) >= s {
                        let x = g(a, v).wrapping_add(g(a, v - s));
                        a[2 * v..2 * v + 2].copy_from_slice(&x.to_le_bytes());
                    }
                }
            }
        }
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

/// The file's bytes: the rANS words, escape bits, tables, masks and minima (no padding).
fn coded_bytes(cd: &Coded) -> usize {
    (cd.words.len() - PAD_WORDS * cd.starts.len()) * 2 + cd.bits.len() - 8 + cd.tables_z.len() + cd.masks_z.len() + cd.kmin_z.len()
}

/// Times `decode` over `runs` runs after a first one checked texel for texel: the medians
/// of the voxel loop and of everything (side information, tables, voxels), and the
/// scratch (side information and decode table) of the last run.
#[allow(clippy::too_many_arguments)]
fn time_decoder<O: Texel>(cd: &Coded, n: usize, lanes: usize, p: u32, refout: &[u16], runs: usize, out: &mut [O], decode: impl Fn(&Coded, &Scratch, &mut [O])) -> (f64, f64, Scratch) {
    let mut sc = Scratch { lut: Vec::new(), masks: Vec::new(), kmin: Vec::new(), tables: Vec::new() };
    let (mut tv, mut tt) = (Vec::new(), Vec::new());
    for r in 0..runs + 1 {
        let t0 = Instant::now();
        prepare(cd, n, lanes, p, &mut sc);
        let t1 = Instant::now();
        decode(cd, &sc, out);
        let (tvox, tall) = (t1.elapsed().as_secs_f64(), t0.elapsed().as_secs_f64());
        if r == 0 {
            for i in 0..n * 512 {
                assert_eq!(out[i].level(), refout[i], "decode ({lanes} lanes) mismatch at brick {} voxel {}", i / 512, i % 512);
            }
        } else {
            tv.push(tvox);
            tt.push(tall);
        }
    }
    (median(tv), median(tt), sc)
}

fn run_proto<O: Texel, const N: usize, const P: u32>(inp: &Input, toks: &[Vec<Tok>], refout: &[u16], runs: usize, bl: &[u8; 256]) -> (usize, f64, f64) {
    let n = inp.n;
    let cd = encode(inp, toks, N, 1, P);
    let mut out = vec![O::default(); n.div_ceil(N) * N * 512];
    let (tv, tt, sc) = time_decoder(&cd, n, N, P, refout, runs, &mut out, |cd, sc, out| {
        if FAST {
            decode_voxels_fast::<O, N, P, true>(cd, n, &sc.masks, &sc.lut, out, bl);
        } else {
            decode_voxels::<O, N, P>(cd, n, &sc.masks, &sc.lut, out, bl);
        }
    });
    let mut te = Vec::new();
    for r in 0..runs + 1 {
        let t0 = Instant::now();
        decode_voxels_fast::<O, N, P, false>(&cd, n, &sc.masks, &sc.lut, &mut out, bl);
        if r > 0 {
            te.push(t0.elapsed().as_secs_f64());
        }
    }
    let te = median(te);
    eprintln!(
        "    N={N} P={P}: entropy decode alone (no prediction) {:.1} Mvox/s ({:.2} ns/voxel) against {:.2} ns/voxel with it",
        (n * 512) as f64 / te / 1e6,
        te * 1e9 / (n * 512) as f64,
        tv * 1e9 / (n * 512) as f64
    );
    eprintln!(
        "    N={N} P={P}: rANS words {} B + raw bits {} B (ideal static {:.0} B) + tables {} B + masks {} B + kmin {} B",
        (cd.words.len() - PAD_WORDS) * 2,
        cd.bits.len() - 8,
        cd.ideal_bits / 8.0,
        cd.tables_z.len(),
        cd.masks_z.len(),
        cd.kmin_z.len()
    );
    (coded_bytes(&cd), tv, tt)
}

/// A vector decoder over `lanes` lanes (`streams` word streams): bytes, and the medians
/// of the voxel loop and of everything.
#[allow(clippy::too_many_arguments)]
fn run_vector<O: Texel>(inp: &Input, toks: &[Vec<Tok>], refout: &[u16], runs: usize, lanes: usize, streams: usize, p: u32, decode: impl Fn(&Coded, &Scratch, &mut [O])) -> (usize, f64, f64) {
    let cd = encode(inp, toks, lanes, streams, p);
    let mut out = vec![O::default(); inp.n * 512];
    let (tv, tt, _) = time_decoder(&cd, inp.n, lanes, p, refout, runs, &mut out, decode);
    (coded_bytes(&cd), tv, tt)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = &args[1];
    let get = |k: &str| args.iter().position(|a| a == k).map(|i| args[i + 1].clone());
    let runs: usize = get("--runs").map(|s| s.parse().unwrap()).unwrap_or(7);
    let level: i32 = get("--level").map(|s| s.parse().unwrap()).unwrap_or(19);
    let mut inp = read_input(path).unwrap_or_else(|e| {
        eprintln!("error: {path}: {e}");
        std::process::exit(1)
    });
    let bl = bucket_lut();
    let (mut toks, mut refout) = model_all(&inp, &bl);
    let active: usize = toks.iter().map(|t| t.len()).sum();
    let vox = inp.n * 512;
    let out_bytes = vox * inp.bpl;
    println!("{path}: E={} {} bricks, {} voxels ({} active), {} B per texel, output {} B", inp.e, inp.n, vox, active, inp.bpl, out_bytes);

    // zstd comparison
    let raw = filtered_bytes(&inp);
    let z = zstd::bulk::compress(&raw, level).unwrap();
    if let Some(zp) = get("--zst") {
        std::fs::write(zp, &z).unwrap();
    }
    let mut buf = vec![0u8; raw.len()];
    let mut dec = zstd::bulk::Decompressor::new().unwrap();
    let mut tz = Vec::new();
    let mut tzu = Vec::new();
    for r in 0..runs + 1 {
        let t0 = Instant::now();
        let k = dec.decompress_to_buffer(&z, &mut buf[..]).unwrap();
        let t1 = t0.elapsed().as_secs_f64();
        unfilter(&mut buf, inp.n, inp.bpl);
        let t2 = t0.elapsed().as_secs_f64();
        assert_eq!(k, raw.len());
        if r == 0 {
            // check the unfilter restores the levels
            let off = inp.n * 68;
            for i in 0..vox {
                let q = if inp.bpl == 1 { buf[off + i] as u16 } else { u16::from_le_bytes([buf[off + 2 * i], buf[off + 2 * i + 1]]) };
                assert_eq!(q, inp.levels[i]);
            }
        } else {
            tz.push(t1);
            tzu.push(t2);
        }
    }
    let (tz, tzu) = (median(tz), median(tzu));
    println!(
        "  zstd -{level} of masks + kmin + 3D-delta levels: {} B ({:.3} bits/voxel) of {} B; decompress (crate, 1 thread) {:.1} MB/s of its output = {:.1} Mvox/s; + unfilter {:.1} Mvox/s",
        z.len(),
        z.len() as f64 * 8.0 / vox as f64,
        raw.len(),
        raw.len() as f64 / tz / 1e6,
        vox as f64 / tz / 1e6,
        vox as f64 / tzu / 1e6
    );

    if args.iter().any(|a| a == "--no-masks") {
        // Every voxel coded: the inactive ones take the level they decode to with masks
        // (their prediction), so the stream needs no masks and restores alone. After the
        // zstd comparison, which keeps the bricks as they are (masks, inactive voxels 0).
        inp.levels.copy_from_slice(&refout);
        for m in inp.masks.iter_mut() {
            *m = [0xff; 64];
        }
        (toks, refout) = model_all(&inp, &bl);
        println!("  --no-masks: every voxel coded, masks all set ({} B through zstd)", zstd::bulk::compress(&vec![0xffu8; inp.n * 64], 19).unwrap().len());
    }
    macro_rules! one {
        ($o:ty, $n:expr, $p:expr) => {{
            let (bytes, tv, tt) = run_proto::<$o, $n, $p>(&inp, &toks, &refout, runs, &bl);
            println!(
                "  rANS N={:<2} P={}: {} B ({:.3} bits/voxel, {:.3} per active; {:.3}x zstd's) voxel loop {:.1} MB/s = {:.1} Mvox/s ({:.2} ns/voxel, {:.2} ns/active); with side info + tables {:.1} MB/s; loop / zstd crate {:.3} (MB/s) {:.3} (vox/s)",
                $n,
                $p,
                bytes,
                bytes as f64 * 8.0 / vox as f64,
                bytes as f64 * 8.0 / active as f64,
                bytes as f64 / z.len() as f64,
                out_bytes as f64 / tv / 1e6,
                vox as f64 / tv / 1e6,
                tv * 1e9 / vox as f64,
                tv * 1e9 / active as f64,
                out_bytes as f64 / tt / 1e6,
                (out_bytes as f64 / tv) / (raw.len() as f64 / tz),
                tz / tv
            );
        }};
    }
    macro_rules! vector {
        ($name:expr, $o:ty, $lanes:expr, $streams:expr, $p:expr, $dec:expr) => {{
            let (bytes, tv, tt) = run_vector::<$o>(&inp, &toks, &refout, runs, $lanes, $streams, $p, $dec);
            println!(
                "  {} rANS N={:<2} streams={} P={}: {} B ({:.3}x zstd's) voxel loop {:.1} MB/s = {:.1} Mvox/s ({:.2} ns/voxel); with side info + tables {:.1} MB/s; loop / zstd crate {:.3}, all / zstd crate {:.3} (MB/s)",
                $name,
                $lanes,
                $streams,
                $p,
                bytes,
                bytes as f64 / z.len() as f64,
                out_bytes as f64 / tv / 1e6,
                vox as f64 / tv / 1e6,
                tv * 1e9 / vox as f64,
                out_bytes as f64 / tt / 1e6,
                (out_bytes as f64 / tv) / (raw.len() as f64 / tz),
                (out_bytes as f64 / tt) / (raw.len() as f64 / tz)
            );
        }};
    }
    macro_rules! vectors {
        ($o:ty) => {{
            let n = inp.n;
            if std::is_x86_feature_detected!("avx512f")
                && std::is_x86_feature_detected!("avx512vl")
                && std::is_x86_feature_detected!("avx512bw")
                && std::is_x86_feature_detected!("avx512cd")
                && std::is_x86_feature_detected!("avx512vbmi")
                && std::is_x86_feature_detected!("avx512vbmi2")
            {
                // SAFETY: the features are checked just above.
                vector!("AVX-512", $o, 16, 1, 11, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { simd::decode::<$o, 1, 11>(cd, n, &sc.masks, &sc.lut, out) });
                vector!("AVX-512", $o, 32, 1, 11, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { simd::decode::<$o, 2, 11>(cd, n, &sc.masks, &sc.lut, out) });
                vector!("AVX-512", $o, 64, 1, 11, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { simd::decode::<$o, 4, 11>(cd, n, &sc.masks, &sc.lut, out) });
                vector!("AVX-512", $o, 64, 4, 11, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { simd::decode::<$o, 4, 11>(cd, n, &sc.masks, &sc.lut, out) });
                vector!("AVX-512", $o, 64, 1, 9, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { simd::decode::<$o, 4, 9>(cd, n, &sc.masks, &sc.lut, out) });
            }
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                vector!("AVX2", $o, 16, 1, 11, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { avx2::decode::<$o, 2, 11>(cd, n, &sc.masks, &sc.lut, out) });
                vector!("AVX2", $o, 32, 1, 11, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { avx2::decode::<$o, 4, 11>(cd, n, &sc.masks, &sc.lut, out) });
                vector!("AVX2", $o, 32, 4, 11, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { avx2::decode::<$o, 4, 11>(cd, n, &sc.masks, &sc.lut, out) });
                vector!("AVX2", $o, 16, 1, 9, |cd: &Coded, sc: &Scratch, out: &mut [$o]| unsafe { avx2::decode::<$o, 2, 9>(cd, n, &sc.masks, &sc.lut, out) });
            }
        }};
    }
    if inp.bpl == 1 {
        vectors!(u8);
    } else {
        vectors!(u16);
    }
    let only: Option<String> = get("--only");
    macro_rules! all {
        ($o:ty) => {{
            if only.is_none() {
                one!($o, 1, 12);
                one!($o, 2, 12);
                one!($o, 4, 11);
                one!($o, 8, 12);
            }
            one!($o, 4, 12);
        }};
    }
    if inp.bpl == 1 {
        all!(u8);
    } else {
        all!(u16);
    }
}

// ---- the same decoder without bounds checks, the face class hoisted out of the voxel --------

struct Syms {
    base: [u32; 64],
    nbt: [u32; 64],
}

#[inline(always)]
unsafe fn predict_raw<const POS: usize>(f: *const i32, p: usize) -> i32 {
    unsafe {
        let a = *f.add(p - 81);
        let b = *f.add(p - 9);
        let c = *f.add(p - 1);
        match POS {
            7 => (2 * (a + b + c) - *f.add(p - 90) - *f.add(p - 82) - *f.add(p - 10) + 1).div_euclid(3),
            3 => b + c - *f.add(p - 10),
            5 => a + c - *f.add(p - 82),
            6 => a + b - *f.add(p - 90),
            1 => c,
            2 => b,
            _ => a,
        }
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn step<O: Texel, const P: u32, const POS: usize, const PRED: bool>(
    act: u32,
    f: *mut i32,
    ra: *mut u32,
    p: usize,
    st: &mut u32,
    wp: &mut *const u16,
    bits: *const u8,
    bp: &mut usize,
    lut: *const u32,
    bl: *const u8,
    sy: &Syms,
    out: *mut O,
) {
    unsafe {
        let e = (*ra.add(p - 81) + *ra.add(p - 9) + *ra.add(p - 1)).min(255);
        let ctx = *bl.add(e as usize) as usize * NPOS + POS;
        let x = *st;
        let slot = x & ((1u32 << P) - 1);
        let ent = *lut.add((ctx << P) | slot as usize);
        let sym = (ent & 63) as usize;
        let fr = (ent >> 6) & 0x1fff;
        let cu = ent >> 19;
        let xn = fr * (x >> P) + slot - cu;
        let xs = if act != 0 { xn } else { x };
        let need = xs < RANS_L;
        let w = **wp as u32;
        *st = if need { (xs << 16) | w } else { xs };
        *wp = wp.add(need as usize);
        let am = act.wrapping_neg();
        let nb = *sy.nbt.get_unchecked(sym) & am;
        let peek = std::ptr::read_unaligned(bits.add(*bp >> 3) as *const u64) >> (*bp & 7);
        let raw = (peek & ((1u64 << nb) - 1)) as u32;
        *bp += nb as usize;
        let z = (*sy.base.get_unchecked(sym) + raw) & am;
        let r = ((z >> 1) as i32) ^ -((z & 1) as i32);
        *ra.add(p) = (z + 1) >> 1;
        let q = if PRED { predict_raw::<POS>(f, p) + r } else { r };
        if PRED {
            *f.add(p) = q;
        }
        *out = O::from_level(q);
    }
}

#[inline(never)]
fn decode_voxels_fast<O: Texel, const N: usize, const P: u32, const PRED: bool>(cd: &Coded, n: usize, masks: &[u8], lut: &[u32], out: &mut [O], bl: &[u8; 256]) {
    let mut sy = Syms { base: [0; 64], nbt: [0; 64] };
    for s in 0..64u32 {
        sy.base[s as usize] = if s < T {
            s
        } else if s < 48 {
            T - 1 + (1 << (s - T))
        } else {
            0
        };
        sy.nbt[s as usize] = if s < T { 0 } else { s - T };
    }
    let groups = n.div_ceil(N);
    assert!(out.len() >= groups * N * 512 && masks.len() >= groups * N * 64 && lut.len() >= NCTX << P);
    let mut st = [0u32; N];
    let words = cd.words.as_ptr();
    for l in 0..N {
        st[l] = (cd.words[2 * l] as u32) << 16 | cd.words[2 * l + 1] as u32;
    }
    let mut wp = unsafe { words.add(2 * N) };
    let mut bp = 0usize;
    let bits = cd.bits.as_ptr();
    let mut f = [[0i32; 729]; N];
    let mut ra = [[0u32; 729]; N];
    let lut = lut.as_ptr();
    let blp = bl.as_ptr();
    let outp = out.as_mut_ptr();
    let mp = masks.as_ptr();
    for g in 0..groups {
        for i in 0..8 {
            for j in 0..8 {
                let mb: [u32; N] = std::array::from_fn(|l| unsafe { *mp.add((g * N + l) * 64 + i * 8 + j) } as u32);
                macro_rules! lanes {
                    ($pos:expr, $k:expr) => {
                        for l in 0..N {
                            let v = i * 64 + j * 8 + $k;
                            unsafe {
                                step::<O, P, { $pos }, PRED>(
                                    (mb[l] >> $k) & 1,
                                    f[l].as_mut_ptr(),
                                    ra[l].as_mut_ptr(),
                                    pidx(i, j, $k),
                                    &mut st[l],
                                    &mut wp,
                                    bits,
                                    &mut bp,
                                    lut,
                                    blp,
                                    &sy,
                                    outp.add((g * N + l) * 512 + v),
                                )
                            }
                        }
                    };
                }
                match (i > 0, j > 0) {
                    (true, true) => {
                        lanes!(6, 0);
                        for k in 1..8 {
                            lanes!(7, k);
                        }
                    }
                    (false, true) => {
                        lanes!(2, 0);
                        for k in 1..8 {
                            lanes!(3, k);
                        }
                    }
                    (true, false) => {
                        lanes!(4, 0);
                        for k in 1..8 {
                            lanes!(5, k);
                        }
                    }
                    (false, false) => {
                        lanes!(0, 0);
                        for k in 1..8 {
                            lanes!(1, k);
                        }
                    }
                }
            }
        }
    }
}
