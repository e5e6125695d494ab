#!/usr/bin/python3
"""The bytes of the plainest error-bounded coding of a grid, against NanoVDB's zipped FpN.

    /usr/bin/python3 scripts/disk_floor.py FILE.vdb E [GRID]

What docs/benchmarks.md ("Bytes on disk", "Where the limit is") calls the zstd floor:
every 8^3 brick of the grid's active bounding box that holds an active voxel, quantised
in steps of 2E from its smallest active value (inactive voxels 0), all bricks through
one `zstd -19`, with and without a 3D Lorenzo prediction inside each brick (the residuals
as 16-bit zigzag numbers, byte planes apart, when they do not fit a byte), plus the
bricks' minima (f32) and active masks, each through `zstd -19`. Prints those sizes and
their ratio to `nanovdb_convert --fpN -a E -z`. Dense: it holds the grid's bounding box
as one float array.
"""

import os
import subprocess
import sys
import tempfile

import numpy as np
import pyopenvdb as vdb
import zstandard


def zstd19(a):
    return len(zstandard.ZstdCompressor(level=19).compress(np.ascontiguousarray(a).tobytes()))


def residual_bytes(r):
    """Signed residuals as bytes: int8 when they fit, else zigzag u16 with its byte planes apart."""
    if np.abs(r).max() < 128:
        return r.astype(np.int8)
    z = ((r.astype(np.int64) << 1) ^ (r.astype(np.int64) >> 63)).astype("<u2")
    return np.frombuffer(z.tobytes(), np.uint8).reshape(-1, 2).T


def main():
    path, e = sys.argv[1], float(sys.argv[2])
    name = sys.argv[3] if len(sys.argv) > 3 else vdb.readAllGridMetadata(path)[0].name
    g = vdb.read(path, name)
    lo, hi = g.evalActiveVoxelBoundingBox()
    shape = tuple((int(h - l + 1) + 7) // 8 * 8 for l, h in zip(lo, hi))
    values = np.zeros(shape, np.float32)
    g.copyToArray(values, ijk=lo)
    ones = g.deepCopy()
    for it in ones.iterOnValues():
        it.value = 1.0
    active = np.zeros(shape, np.float32)
    ones.copyToArray(active, ijk=lo)
    active = active > 0.5
    nx, ny, nz = (s // 8 for s in shape)
    bricks = lambda a: a.reshape(nx, 8, ny, 8, nz, 8).transpose(0, 2, 4, 1, 3, 5).reshape(-1, 8, 8, 8)
    b, m = bricks(values), bricks(active)
    keep = m.reshape(len(m), -1).any(1)
    b, m = b[keep], m[keep]
    mins = np.where(m, b, np.inf).reshape(len(b), -1).min(1)
    q = np.rint((b - mins[:, None, None, None]) / (2 * e)).astype(np.int64)
    q[~m] = 0
    worst = np.abs(q * 2 * e + mins[:, None, None, None] - b)[m].max()
    p = np.pad(q, ((0, 0), (1, 0), (1, 0), (1, 0)))
    lorenzo = p[:, 1:, 1:, 1:] - (p[:, :-1, 1:, 1:] + p[:, 1:, :-1, 1:] + p[:, 1:, 1:, :-1] - p[:, :-1, :-1, 1:]
                                  - p[:, :-1, 1:, :-1] - p[:, 1:, :-1, :-1] + p[:, :-1, :-1, :-1])
    side = zstd19(mins.astype(np.float32)) + zstd19(np.packbits(m.reshape(len(m), -1), axis=1))
    plain, predicted = zstd19(residual_bytes(q)), zstd19(residual_bytes(lorenzo))
    with tempfile.TemporaryDirectory() as work:
        out = os.path.join(work, "g.nvdb")
        subprocess.run(["nanovdb_convert", "-g", name, "--fpN", "-a", str(e), "-z", "-f", path, out], check=True, capture_output=True)
        nano = os.path.getsize(out)
    best = min(plain, predicted) + side
    print(f"{path} {name} E={e}: {len(b)} bricks, {int(m.sum())} active voxels, largest error {worst:.3g}")
    print(f"  levels {plain} B, Lorenzo residuals {predicted} B, minima and masks {side} B")
    print(f"  floor {best} B; nanovdb_convert --fpN -a {e} -z {nano} B; floor / nano {best / nano:.3f}")


if __name__ == "__main__":
    main()
