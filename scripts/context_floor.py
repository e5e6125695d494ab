#!/usr/bin/python3
"""How far below the zstd floor a context-modelling entropy coder goes (issue 24).

    /usr/bin/python3 scripts/context_floor.py FILE.vdb E [GRID] [--json]

Quantises the grid as scripts/disk_floor.py does (every 8^3 brick of the grid's active
bounding box that holds an active voxel, levels in steps of 2E from the brick's minimum,
so every active voxel decodes within E), except that the minimum is put on the global
lattice of steps of 2E (`k = floor(min / 2E)`, levels relative to `2E k`: still within E,
rint of the same step, and the minimum becomes an integer that codes in a byte or two).
Then it prints the ideal code lengths (sum of -log2 p, no bit coder is run) of:

* the zstd floor, exactly as disk_floor.py (exact f32 minima, inactive voxels 0);
* order-0 static models (one per-file histogram, 12-bit table sent) of the plain levels
  and of the 3D Lorenzo residuals of the active voxels (the baseline near zstd's);
* residual predictors, run voxel by voxel in raster order (x slowest, z fastest, within
  each brick, from already decoded voxels only): `lorenzo` (3D Lorenzo, zero outside the
  brick, as disk_floor.py), `lmean` (the mean of the three 2D Lorenzo predictions, lower
  noise gain; 2D Lorenzo on faces, previous voxel on edges), `prev` (previous voxel
  along z, y, x), and `choice` (the cheapest of the three per brick, 2 bits-ish sent);
  inactive voxels either `zero` (level 0, as disk_floor.py) or `fill` (they take their
  prediction: the decoder knows the mask first, so they cost nothing and only shape the
  neighbours' predictions);
* residual tokens: zigzag values below 16 are symbols, larger ones an Elias-gamma-like
  bucket symbol plus raw bits (counted as bits);
* context models over those tokens, contexts built from already decoded neighbours at
  x-1, y-1, z-1 (and the diagonal ones): `err` a bucket of the sum of their |residual|,
  `grad` a bucket of the level differences among them (LOCO-I style activity), `lev` a
  bucket of their largest level, `pos` which of the brick's low faces the voxel lies on
  (8 classes), `nact` how many of x-1, y-1, z-1 are active, `sign` the sign of their
  residual sum (`sign3`: the three signs), `pred` the brick's predictor, `bscale` a
  per-brick class of mean |residual| sent as side information; every set is tried with
  the predictor and inactive mode of the fewest bytes under `err+pos`;
* each context model twice: *adaptive* (every context's counts start at a Dirichlet
  prior alpha, 1/32..1/2, best kept, updated after every symbol: the cost of an adaptive
  arithmetic/range coder; its total depends only on the final counts, so it is computed
  from them with lgamma) and *static* (two passes: per-context frequency tables sent in
  the file, each quantised to a total of 2^p with p = 4..12 chosen per context and the
  table Elias-gamma coded, or one p of 8, 10, 12 for all and u16 tables through zstd -19,
  whichever totals less: what a table-driven rANS decodes at speed);
* side information: brick occupancy of the brick grid (binary with the three lower
  neighbour bricks as context, or zstd -19 of the bitmap), minima (f32 through zstd -19
  as disk_floor.py, or the lattice integers as deltas from a neighbour brick's, coded as
  order-0 tokens), active masks (zstd -19 of the bits, or a per-brick "full" flag plus,
  for partial bricks, every bit interleaved with the levels and coded with the causal
  neighbour mask bits and optionally the neighbours' or the voxel's predicted absolute
  level as context), the per-brick predictor and scale classes; each adaptive or static
  with its model.

Totals are residuals plus side information; ratios are to `nanovdb_convert --fpN -a E -z`.
`--json` adds one line `RESULT {...}` for collecting rows. Dense: it holds the grid's
bounding box as arrays (the 256^3 fog: ~3 GB, ~5 minutes on one core). A double grid
(which pyopenvdb 10 cannot load) is read through scripts/vdb_values.py (OpenVDB's vdb_tool).
"""

import json
import math
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pyopenvdb as vdb  # noqa: E402
from disk_floor import load, nano_bytes, zstd19, zstd_floor  # noqa: E402  (the grid and the zstd floor, as disk_floor.py measures them)

T = 16  # zigzag values below T are symbols of their own; larger ones escape
LN2 = math.log(2)
PREDICTORS = ("lorenzo", "lmean", "prev")
LGAMMA = np.vectorize(math.lgamma, otypes=[np.float64])


# ---- code lengths ----------------------------------------------------------------------

def lattice_levels(b, m, e):
    """Each brick's levels in steps of 2E relative to 2E floor(min / 2E), its minimum on
    the lattice (inactive voxels level 0): (the bricks' minima, their lattice minima k,
    the levels, the largest error of an active voxel decoded as (k + level) 2E in f32)."""
    step = 2 * e
    mins = np.where(m, b, np.inf).reshape(len(b), -1).min(1).astype(np.float64)
    kmin = np.floor(mins / step).astype(np.int64)
    q = np.rint((b - (kmin * step)[:, None, None, None]) / step).astype(np.int64)
    q[~m] = 0
    dec = (kmin[:, None, None, None] + q) * step
    worst = float(np.abs(dec.astype(np.float32).astype(np.float64) - b.astype(np.float64))[m].max())
    return mins, kmin, q, worst


def unsigned_tokens(z):
    """Integers >= 0 -> (symbol, raw bits): z below T, else bucket T + floor(log2(z - T + 1))
    followed by that many raw bits."""
    z = z.astype(np.int64)
    u = np.maximum(z - T + 1, 1)
    k = np.floor(np.log2(u)).astype(np.int64)
    k += (u >> (k + 1)) > 0  # guard float rounding of log2 at powers of two
    k -= (u >> k) == 0
    big = z >= T
    return np.where(big, T + k, z), np.where(big, k, 0)


def tokens(v):
    """Signed integers -> tokens of their zigzag values."""
    v = v.astype(np.int64)
    return unsigned_tokens((v << 1) ^ (v >> 63))


def counts(ctx, sym, nsym):
    nctx = int(ctx.max()) + 1 if len(ctx) else 1
    return np.bincount(ctx * nsym + sym, minlength=nctx * nsym).reshape(nctx, nsym)


def adaptive_bits(c, alphas=(1 / 32, 1 / 8, 1 / 2)):
    """Bits of an adaptive coder over the count table c[ctx, sym] (Dirichlet(alpha) start,
    counts updated after every symbol: independent of order), the best alpha."""
    nsym = c.shape[1]
    rows = c.sum(1)
    rows = rows[rows > 0]
    nz = c[c > 0]
    best = math.inf
    for a in alphas:
        bits = (LGAMMA(rows + nsym * a).sum() - len(rows) * math.lgamma(nsym * a)
                - LGAMMA(nz + a).sum() + len(nz) * math.lgamma(a)) / LN2
        best = min(best, bits)
    return best


def gamma_bits(x):
    """Elias-gamma length of integers x >= 1."""
    return 2 * np.floor(np.log2(np.maximum(x, 1))) + 1


def static_bits(c):
    """Bits of a two-pass static coder over c[ctx, sym]: every used context's frequencies
    quantised to a total of 2^p (p = 4..12 chosen per context, 4 bits sent; a rANS with
    one 12-bit total shifts them up), code lengths against them, plus the tables: per
    context the gaps between nonzero symbols and their frequencies, Elias-gamma coded
    (the last frequency follows from the total), and a bitmap of the used contexts
    through zstd -19. Also tried: one p in {8, 10, 12} for all, tables as u16 through
    zstd -19. The cheaper. Returns (code bits, table bits)."""
    used = c.sum(1) > 0
    cu = c[used].astype(np.float64)
    n = cu.sum(1, keepdims=True)
    bitmap = 8 * zstd19(np.packbits(used))

    def quantise(p):
        tot = 2.0 ** p
        f = np.where(cu > 0, np.maximum(1, np.floor(cu * tot / n + 0.5)), 0)
        f[np.arange(len(f)), f.argmax(1)] += tot - f.sum(1)
        ok = ((f >= 1) | (cu == 0)).all(1)
        code = -(cu * np.log2(np.maximum(f, 1) / tot)).sum(1)
        return f, ok, code

    best = (math.inf, 0.0)
    for p in (8, 10, 12):  # one precision, u16 tables through zstd
        f, ok, code = quantise(p)
        if ok.all():
            table = 8 * zstd19(f.astype("<u2")) + bitmap
            if code.sum() + table < sum(best):
                best = (code.sum(), table)
    # per-context precision, gamma-coded tables
    nz = cu > 0
    idx = np.where(nz, np.arange(cu.shape[1])[None, :], -1)
    last = np.maximum.accumulate(idx, axis=1)
    prev_nz = np.concatenate([np.full((len(cu), 1), -1), last[:, :-1]], axis=1)
    gaps = np.where(nz, gamma_bits(np.arange(cu.shape[1])[None, :] - prev_nz), 0).sum(1)
    row_best = np.full(len(cu), np.inf)
    row_code = np.zeros(len(cu))
    for p in range(4, 13):
        f, ok, code = quantise(p)
        table = 4 + gaps + np.where(nz, gamma_bits(np.maximum(f, 1)), 0).sum(1) \
            - gamma_bits(f[np.arange(len(f)), last[:, -1]])
        tot = np.where(ok, code + table, np.inf)
        better = tot < row_best
        row_best[better], row_code[better] = tot[better], code[better]
    if np.isfinite(row_best).all() and row_best.sum() + bitmap < sum(best):
        best = (row_code.sum(), row_best.sum() - row_code.sum() + bitmap)
    return best


def entropy_bits(sym, extra, ctx=None, static=False):
    """Adaptive or static bits of symbols (with raw extra bits) in contexts ctx."""
    sym = sym.ravel()
    ctx = np.zeros_like(sym) if ctx is None else ctx.ravel()
    c = counts(ctx, sym, int(sym.max()) + 1 if len(sym) else 1)
    raw = float(extra.sum())
    return (sum(static_bits(c)) if static else adaptive_bits(c)) + raw


# ---- predictors, run voxel by voxel ----------------------------------------------------

def predict(q, m, kind, fill):
    """Residuals (0 where inactive) and decoded levels of predictor `kind` run in raster
    order inside every brick; inactive voxels take 0 or (fill) their prediction."""
    n = len(q)
    f = np.zeros((n, 9, 9, 9), np.int32)  # decoded levels, padded with 0 on the low sides
    r = np.zeros((n, 8, 8, 8), np.int32)
    for i in range(8):
        for j in range(8):
            for k in range(8):
                a, b, c = f[:, i, j + 1, k + 1], f[:, i + 1, j, k + 1], f[:, i + 1, j + 1, k]
                ab, ac, bc = f[:, i, j, k + 1], f[:, i, j + 1, k], f[:, i + 1, j, k]
                if kind == "lorenzo":
                    p = a + b + c - ab - ac - bc + f[:, i, j, k]
                elif kind == "prev":
                    p = c if k else b if j else a
                elif kind == "lmean":
                    faces = (i > 0) + (j > 0) + (k > 0)
                    if faces == 3:
                        p = (2 * (a + b + c) - ab - ac - bc + 1) // 3
                    elif faces == 2:
                        p = (b + c - bc) if not i else (a + c - ac) if not j else (a + b - ab)
                    else:
                        p = c if k else b if j else a
                cur, act = q[:, i, j, k], m[:, i, j, k]
                r[:, i, j, k] = np.where(act, cur - p, 0)
                f[:, i + 1, j + 1, k + 1] = np.where(act, cur, p if fill else 0)
    return r, f[:, 1:, 1:, 1:]


def bucket(v, top):
    """0,1,2,3 then two buckets per octave, at most top - 1."""
    v = v.astype(np.float64)
    b = np.where(v < 4, v, 4 + np.floor(2 * np.log2(np.maximum(v, 4) / 4)))
    return np.minimum(b, top - 1).astype(np.int64)


def features(r, f, m, pred_id, bscale):
    """Context features of every voxel from already decoded neighbours: name -> (array, classes)."""
    n = len(r)
    pad = lambda a, v=0: np.pad(a, ((0, 0), (1, 0), (1, 0), (1, 0)), constant_values=v)
    ra, fa, ma = pad(np.abs(r)), pad(f), pad(m.astype(np.int64))
    sh = lambda a, dx, dy, dz: a[:, 1 - dx:9 - dx, 1 - dy:9 - dy, 1 - dz:9 - dz]
    err = sh(ra, 1, 0, 0) + sh(ra, 0, 1, 0) + sh(ra, 0, 0, 1)
    A, B, C = sh(fa, 1, 0, 0), sh(fa, 0, 1, 0), sh(fa, 0, 0, 1)
    AB, AC, BC = sh(fa, 1, 1, 0), sh(fa, 1, 0, 1), sh(fa, 0, 1, 1)
    grad = (np.abs(A - AB) + np.abs(B - AB) + np.abs(A - AC) + np.abs(C - AC) + np.abs(B - BC) + np.abs(C - BC)) // 2
    rs = pad(r)
    s = sh(rs, 1, 0, 0) + sh(rs, 0, 1, 0) + sh(rs, 0, 0, 1)
    i, j, k = np.meshgrid(np.arange(8), np.arange(8), np.arange(8), indexing="ij")
    pos = np.broadcast_to(((i > 0) * 4 + (j > 0) * 2 + (k > 0)), r.shape)
    lev = np.maximum(np.maximum(A, B), C)
    nact = sh(ma, 1, 0, 0) + sh(ma, 0, 1, 0) + sh(ma, 0, 0, 1)
    one = lambda v: np.broadcast_to(v[:, None, None, None], r.shape)
    return {
        "err": (bucket(err, 16), 16),
        "grad": (bucket(grad, 12), 12),
        "pos": (pos, 8),
        "lev": (bucket(lev, 12), 12),  # the largest neighbour level
        "nact": (nact, 4),
        "sign": (np.sign(s) + 1, 3),
        "sign3": ((np.sign(sh(rs, 1, 0, 0)) + 1) * 9 + (np.sign(sh(rs, 0, 1, 0)) + 1) * 3 + np.sign(sh(rs, 0, 0, 1)) + 1, 27),
        "pred": (one(pred_id), len(PREDICTORS)),
        "bscale": (one(bscale), 8),
    }


def context(feats, names):
    ctx = np.zeros(feats["pos"][0].shape, np.int64)
    for nm in names:
        a, k = feats[nm]
        ctx = ctx * k + a
    return ctx


# ---- side information --------------------------------------------------------------------

def topology_bits(keep, static):
    """Which bricks of the brick grid exist: binary, context the 3 lower neighbours."""
    p = np.pad(keep.astype(np.int64), ((1, 0), (1, 0), (1, 0)))
    ctx = p[:-1, 1:, 1:] * 4 + p[1:, :-1, 1:] * 2 + p[1:, 1:, :-1]
    model = entropy_bits(keep.astype(np.int64), np.zeros(1), ctx, static)
    return min(model, 8 * zstd19(np.packbits(keep.ravel())))


def minima_bits(kmin, keep, static):
    """Lattice minima as deltas from the nearest lower neighbour brick's (z, y, x), else the
    previous brick's, through order-0 tokens; or the int32 deltas through zstd -19."""
    grid = np.full(keep.shape, np.iinfo(np.int64).min, np.int64)
    grid[keep] = kmin
    order = np.flatnonzero(keep.ravel())
    prev = np.concatenate([[0], kmin[:-1]])
    pred = prev.copy()
    x, y, z = np.unravel_index(order, keep.shape)
    for dx, dy, dz in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):  # the last one found wins: z first
        ok = (x >= dx) & (y >= dy) & (z >= dz)
        nb = np.full(len(order), np.iinfo(np.int64).min)
        nb[ok] = grid[x[ok] - dx, y[ok] - dy, z[ok] - dz]
        pred = np.where(nb != np.iinfo(np.int64).min, nb, pred)
    d = kmin - pred
    sym, extra = tokens(d)
    return min(entropy_bits(sym, extra, None, static), 8 * zstd19(d.astype(np.int32)))


def mask_bits(m, level, predicted, static):
    """Per-brick 'full' flag; for partial bricks every bit in raster order, interleaved with
    the levels (so already decoded neighbours and the voxel's prediction are known),
    context the 3 or 6 causal neighbour mask bits (0, 1, or 2 outside the brick) and
    optionally either a bucket of the largest |absolute level| (lattice minimum + level)
    among the active ones of x-1, y-1, z-1, or a fine bucket of the voxel's own predicted
    |absolute level| (lmean with inactive voxels filled by their prediction: the mask edge
    of a fog is where values near 0, of a level set where |phi| nears the background).
    The cheapest of the six context sets."""
    full = m.reshape(len(m), -1).all(1)
    bits = entropy_bits(full.astype(np.int64), np.zeros(1), None, static)
    part = m[~full].astype(np.int64)
    if not len(part):
        return bits
    p = np.pad(part, ((0, 0), (1, 0), (1, 0), (1, 0)), constant_values=2)
    sh = lambda a, dx, dy, dz: a[:, 1 - dx:9 - dx, 1 - dy:9 - dy, 1 - dz:9 - dz]
    ctx3 = np.zeros(part.shape, np.int64)
    for d in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
        ctx3 = ctx3 * 3 + sh(p, *d)
    ctx6 = ctx3
    for d in ((1, 1, 0), (1, 0, 1), (0, 1, 1)):
        ctx6 = ctx6 * 3 + sh(p, *d)
    lv = np.pad(np.where(part > 0, np.abs(level[~full]), -1), ((0, 0), (1, 0), (1, 0), (1, 0)), constant_values=-1)
    top = np.maximum(np.maximum(sh(lv, 1, 0, 0), sh(lv, 0, 1, 0)), sh(lv, 0, 0, 1))
    lev = np.where(top < 0, 12, bucket(np.maximum(top, 0), 12))
    v = np.abs(predicted[~full]).astype(np.float64)
    fine = np.minimum(np.where(v < 16, v, 16 + np.floor(8 * np.log2(np.maximum(v, 16) / 16))), 63).astype(np.int64)
    return bits + min(entropy_bits(part, np.zeros(1), c, static)
                      for c in (ctx3, ctx6, ctx3 * 13 + lev, ctx6 * 13 + lev, ctx3 * 64 + fine, ctx6 * 64 + fine))


def brick_class_bits(cls, nclass, static):
    """Per-brick classes (predictor, scale), context the previous brick's class."""
    if len(cls) == 0 or cls.max() == cls.min():
        return 8.0
    prev = np.concatenate([[0], cls[:-1]])
    return entropy_bits(cls, np.zeros(1), prev, static)


# ---- the measurement ---------------------------------------------------------------------

FEATURE_SETS = [
    (), ("pos",), ("err",), ("err", "pos"), ("err", "grad"), ("err", "grad", "pos"),
    ("err", "pos", "sign"), ("err", "pos", "nact"), ("err", "grad", "pos", "nact"), ("err", "lev"),
    ("err", "lev", "pos"), ("err", "grad", "lev"), ("err", "grad", "lev", "pos"), ("err", "sign"),
    ("err", "grad", "sign"), ("err", "lev", "sign"), ("err", "grad", "pos", "sign"), ("err", "grad", "lev", "pos", "sign"),
    ("err", "pos", "sign3"), ("err", "grad", "pos", "sign3"),
    ("bscale", "err", "pos"), ("bscale", "err", "grad", "pos"), ("pred", "err", "pos"),
    ("pred", "bscale", "err", "grad", "pos"),
]


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    if len(args) < 2:
        sys.exit("usage: context_floor.py FILE.vdb E [GRID] [--json]")
    path, e = args[0], float(args[1])
    name = args[2] if len(args) > 2 else vdb.readAllGridMetadata(path)[0].name
    b, m, keep = load(path, name)
    nano = nano_bytes(path, name, e)
    zp, zl, zside = zstd_floor(b, m, e)
    zfloor = min(zp, zl) + zside
    out = {"file": path, "grid": name, "E": e, "bricks": len(b), "active": int(m.sum()), "nano": nano,
           "zstd_floor": zfloor, "zstd_levels": zp, "zstd_lorenzo": zl, "zstd_side": zside}
    print(f"{path} {name} E={e}: {len(b)} bricks, {int(m.sum())} active voxels; nanovdb -z {nano} B")
    print(f"  zstd floor (disk_floor.py) {zfloor} B = {zfloor / nano:.3f}x "
          f"(levels {zp}, Lorenzo {zl}, minima and masks {zside})")

    mins, kmin, q, worst = lattice_levels(b, m, e)
    out["largest_error"] = worst
    print(f"  lattice minima: largest error {worst:.6g} (bound {e}), largest level {int(q[m].max())}")

    runs = {(kind, fill): predict(q, m, kind, fill) for fill in (False, True) for kind in PREDICTORS}
    r, f = runs["lmean", True]
    predicted = kmin[:, None, None, None] + f - r  # lmean's prediction of every voxel, inactive ones filled
    side = {}
    for st in (False, True):
        tag = "static" if st else "adaptive"
        side[tag] = {"topology": topology_bits(keep, st) / 8, "minima": minima_bits(kmin, keep, st) / 8,
                     "masks": mask_bits(m, kmin[:, None, None, None] + q, predicted, st) / 8}
    out["side"] = side
    print(f"  side information, bytes: f32 minima zstd {zstd19(mins.astype(np.float32))}, "
          f"mask bits zstd {zstd19(np.packbits(m.reshape(len(m), -1), axis=1))}; "
          + "; ".join(f"{t}: " + ", ".join(f"{k} {v:.0f}" for k, v in s.items()) for t, s in side.items()))

    # order-0 static baselines over the active voxels
    base_side = side["static"]["topology"] + side["static"]["minima"] + side["static"]["masks"]
    sym, extra = unsigned_tokens(q[m])
    o0_levels = entropy_bits(sym, extra, None, True) / 8 + base_side
    sym, extra = tokens(runs["lorenzo", False][0][m])
    o0_lor = entropy_bits(sym, extra, None, True) / 8 + base_side
    out["o0_levels"], out["o0_lorenzo"] = o0_levels, o0_lor
    print(f"  order-0 static: levels {o0_levels:.0f} B = {o0_levels / nano:.3f}x, "
          f"Lorenzo residuals {o0_lor:.0f} B = {o0_lor / nano:.3f}x (incl. side {base_side:.0f} B)")

    # per brick, the predictor of the fewest order-0 bits
    for fill in (False, True):
        per_brick = []
        for kind in PREDICTORS:
            sym, extra = tokens(runs[kind, fill][0])
            c = np.bincount(sym[m], minlength=T + 64).astype(np.float64)
            length = -np.log2(np.maximum(c, 0.5) / c.sum())  # order-0 code length per symbol
            per_brick.append(np.where(m, length[sym] + extra, 0).reshape(len(q), -1).sum(1))
        choice = np.argmin(np.stack(per_brick), 0)
        runs["choice", fill] = tuple(np.choose(choice[:, None, None, None], [runs[k, fill][i] for k in PREDICTORS])
                                     for i in (0, 1)) + (choice,)

    results = {}

    def evaluate(kind, fill, sets):
        r, f = runs[kind, fill][:2]
        choice = runs[kind, fill][2] if kind == "choice" else np.zeros(len(r), np.int64)
        mean_abs = np.where(m, np.abs(r), 0).reshape(len(r), -1).sum(1) / m.reshape(len(m), -1).sum(1)
        bscale = np.minimum(np.floor(2 * np.log2(1 + mean_abs)), 7).astype(np.int64)
        feats = features(r, f, m, choice, bscale)
        sym, extra = tokens(r)
        sym, extra = sym[m], extra[m]
        for names in sets:
            if "pred" in names and kind != "choice":
                continue
            ctx = context(feats, names)[m]
            for tag in ("adaptive", "static"):
                st = tag == "static"
                resid = entropy_bits(sym, extra, ctx, st) / 8
                extra_side = brick_class_bits(choice, 3, st) / 8 if kind == "choice" else 0.0
                if "bscale" in names:
                    extra_side += brick_class_bits(bscale, 8, st) / 8
                total = resid + sum(side[tag].values()) + extra_side
                results[kind, "fill" if fill else "zero", "+".join(names) or "o0", tag] = (total, resid)

    for fill in (False, True):
        for kind in PREDICTORS + ("choice",):
            evaluate(kind, fill, [(), ("err", "pos")])
    print("  predictors (inactive zero / fill), bytes / ratio, adaptive then static: order-0 | contexts err+pos")
    for kind in PREDICTORS + ("choice",):
        cells = []
        for inact in ("zero", "fill"):
            cells.append(" | ".join(" ".join(f"{results[kind, inact, cs, t][0]:9.0f} {results[kind, inact, cs, t][0] / nano:.3f}"
                                             for t in ("adaptive", "static")) for cs in ("o0", "err+pos")))
        print(f"    {kind:8s} zero {cells[0]}\n    {'':8s} fill {cells[1]}")
    top = min(((kind, inact) for kind, inact, cs, t in results if cs == "err+pos" and t == "adaptive"),
              key=lambda k: results[k + ("err+pos", "adaptive")][0])
    evaluate(top[0], top[1] == "fill", FEATURE_SETS)
    print(f"  context sets with {top[0]}, inactive {top[1]}: adaptive B ratio, static B ratio (residual share)")
    for names in FEATURE_SETS:
        key = top + ("+".join(names) or "o0",)
        if key + ("adaptive",) not in results:
            continue
        ad, stt = results[key + ("adaptive",)], results[key + ("static",)]
        print(f"    {key[2]:28s} {ad[0]:10.0f} {ad[0] / nano:6.3f} ({ad[1] / ad[0]:.2f})"
              f" {stt[0]:10.0f} {stt[0] / nano:6.3f} ({stt[1] / stt[0]:.2f})")
    for tag in ("adaptive", "static"):
        best = min((v[0], k) for k, v in results.items() if k[3] == tag)
        out["best_" + tag] = {"bytes": best[0], "model": list(best[1][:3]), "resid": results[best[1]][1]}
        print(f"  best {tag}: {best[0]:.0f} B = {best[0] / nano:.3f}x NanoVDB, {best[0] / zfloor:.3f}x the zstd floor "
              f"({' '.join(best[1][:3])}; residuals {results[best[1]][1]:.0f} B)")
    out["models"] = {"/".join(k): v for k, v in results.items()}
    if "--json" in sys.argv:
        print("RESULT " + json.dumps(out))


if __name__ == "__main__":
    main()
