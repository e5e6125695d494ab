#!/usr/bin/python3
"""Quantise a grid's 8^3 bricks as scripts/context_floor.py does and write them
for the Rust prototype.

    /usr/bin/python3 export_bricks.py FILE.vdb E GRID OUT.bin [--ideal]

Bricks: every 8^3 brick of the grid's active bounding box holding an active voxel
(disk_floor.load). Minimum on the lattice of steps of 2E: k = floor(min / 2E), levels
q = rint((v - 2E k) / 2E), inactive voxels 0 (context_floor.py).

File layout (little endian):
  b"BRK1", u32 nbricks, f64 E, u32 bytes_per_level (1 or 2)
  per brick: 64 bytes active mask (bit (idx & 7) of byte (idx >> 3), idx = x*64 + y*8 + z,
             x slowest as in context_floor.py), i32 kmin, 512 levels (u8 or u16)

--ideal also prints context_floor.py's ideal static and adaptive code lengths of the
residuals alone for lmean / inactive fill / contexts err+pos (what the prototype codes).
"""

import os
import struct
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import context_floor as cf  # noqa: E402
from context_floor import lattice_levels  # noqa: E402
from disk_floor import load  # noqa: E402


def main():
    path, e, grid, out = sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4]
    b, m, keep = load(path, grid)
    _, kmin, q, worst = lattice_levels(b, m, e)
    qmax = int(q.max())
    bpl = 1 if qmax < 256 else 2
    n = len(b)
    print(f"{path} {grid} E={e}: {n} bricks, {int(m.sum())} active voxels, largest level {qmax}, "
          f"largest error {worst:.6g}, {bpl} byte(s) per level")
    masks = np.packbits(m.reshape(n, 512), axis=1, bitorder="little")  # (n, 64)
    lv = q.reshape(n, 512).astype("<u1" if bpl == 1 else "<u2")
    rec = np.dtype([("mask", "u1", 64), ("kmin", "<i4"), ("lv", lv.dtype, 512)])
    arr = np.zeros(n, rec)
    arr["mask"], arr["kmin"], arr["lv"] = masks, kmin.astype(np.int32), lv
    with open(out, "wb") as fh:
        fh.write(b"BRK1" + struct.pack("<IdI", n, e, bpl))
        fh.write(arr.tobytes())
    if "--ideal" in sys.argv:
        r, f = cf.predict(q, m, "lmean", True)
        feats = cf.features(r, f, m, np.zeros(n, np.int64), np.zeros(n, np.int64))
        ctx = cf.context(feats, ("err", "pos"))[m]
        sym, extra = cf.tokens(r)
        sym, extra = sym[m], extra[m]
        c = cf.counts(ctx.ravel(), sym.ravel(), int(sym.max()) + 1)
        code, table = cf.static_bits(c)
        print(f"  ideal (context_floor.py), residuals lmean/fill/err+pos: static {code / 8:.0f} B code + "
              f"{table / 8:.0f} B tables + {extra.sum() / 8:.0f} B raw bits; adaptive "
              f"{(cf.adaptive_bits(c) + extra.sum()) / 8:.0f} B")


if __name__ == "__main__":
    main()
