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


def load(path, name):
    """The grid's 8^3 bricks of its active bounding box that hold an active voxel: (values,
    active masks, which bricks of the box are kept)."""
    try:
        g = vdb.read(path, name)
    except TypeError:  # a double grid, which pyopenvdb 10 cannot load: OpenVDB's vdb_tool reads it
        from vdb_values import active_values
        ijk, v, _ = active_values(path, name)
        lo = ijk.min(0)
        shape = tuple(int(n + 7) // 8 * 8 for n in ijk.max(0) - lo + 1)
        values, active = np.zeros(shape, np.float64), np.zeros(shape, bool)
        values[tuple((ijk - lo).T)], active[tuple((ijk - lo).T)] = v, True
    else:
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
    nb = tuple(s // 8 for s in shape)
    bricks = lambda a: a.reshape(nb[0], 8, nb[1], 8, nb[2], 8).transpose(0, 2, 4, 1, 3, 5).reshape(-1, 8, 8, 8)
    b, m = bricks(values), bricks(active)
    keep = m.reshape(len(m), -1).any(1)
    return b[keep], m[keep], keep.reshape(nb)


def quantised(b, m, e):
    """Each brick in steps of 2E from its smallest active value (inactive voxels 0): (levels, minima)."""
    mins = np.where(m, b, np.inf).reshape(len(b), -1).min(1)
    q = np.rint((b - mins[:, None, None, None]) / (2 * e)).astype(np.int64)
    q[~m] = 0
    return q, mins


def zstd_floor(b, m, e):
    """The floor's parts in bytes: (levels, Lorenzo residuals, minima and masks)."""
    q, mins = quantised(b, m, e)
    p = np.pad(q, ((0, 0), (1, 0), (1, 0), (1, 0)))
    lorenzo = p[:, 1:, 1:, 1:] - (p[:, :-1, 1:, 1:] + p[:, 1:, :-1, 1:] + p[:, 1:, 1:, :-1] - p[:, :-1, :-1, 1:]
                                  - p[:, :-1, 1:, :-1] - p[:, 1:, :-1, :-1] + p[:, :-1, :-1, :-1])
    side = zstd19(mins.astype(np.float32)) + zstd19(np.packbits(m.reshape(len(m), -1), axis=1))
    return zstd19(residual_bytes(q)), zstd19(residual_bytes(lorenzo)), side


def nano_bytes(path, name, e):
    """The bytes of `nanovdb_convert --fpN -a E -z` of the grid."""
    with tempfile.TemporaryDirectory() as work:
        out = os.path.join(work, "g.nvdb")
        subprocess.run(["nanovdb_convert", "-g", name, "--fpN", "-a", str(e), "-z", "-f", path, out], check=True, capture_output=True)
        return os.path.getsize(out)


def main():
    path, e = sys.argv[1], float(sys.argv[2])
    name = sys.argv[3] if len(sys.argv) > 3 else vdb.readAllGridMetadata(path)[0].name
    b, m, _ = load(path, name)
    q, mins = quantised(b, m, e)
    worst = np.abs(q * 2 * e + mins[:, None, None, None] - b)[m].max()
    plain, predicted, side = zstd_floor(b, m, e)
    nano = nano_bytes(path, name, e)
    best = min(plain, predicted) + side
    print(f"{path} {name} E={e}: {len(b)} bricks, {int(m.sum())} active voxels, largest error {worst:.3g}")
    print(f"  levels {plain} B, Lorenzo residuals {predicted} B, minima and masks {side} B")
    print(f"  floor {best} B; nanovdb_convert --fpN -a {e} -z {nano} B; floor / nano {best / nano:.3f}")


if __name__ == "__main__":
    main()
