#!/usr/bin/python3
"""The least voxel RMSE any BC7 encoder can reach with vdbcook's brick packing.

    /usr/bin/python3 scripts/bc7_floor.py [FILE[:GRID] ...]

vdbcook's bc7 format puts four consecutive z-slices of a brick into the RGBA
channels of one texel, so one BC7 block holds a 4x4x4 cube of voxels: 16 texels
(x along a row, y down the rows), each a point in 4D. Whatever the encoder does, a
decoded block lies on few lines in that 4D space:

* mode 6: all 16 texels on one line in RGBA;
* mode 7: each of two subsets (one of BC7's 64 two-subset partitions) on its own line;
* modes 4 and 5: three channels on one line, the fourth (picked by the rotation
  field) free;
* modes 0 to 3: alpha is the same constant for every texel of the block.

Per-brick ranges and the decoder's arithmetic are affine, so they keep lines lines.
The script fits, per block and per mode, the best line (or constant) with no limit
on the precision of endpoints or indices, over the texels whose four voxels are all
active (dropping terms can only lower the figure), and takes the best mode per block.
The result is a floor: no BC7 encoder, however slow, decodes these bricks with a
lower RMSE over the active voxels. The script checks that against vdbcook's own bc7
cook (the floor must not exceed it) and prints NanoVDB's `--fp4` RMSE beside it,
measured as `bench_size.py` does.

It also gives the floor for the other two stacking axes and for the best axis chosen
block by block, which bounds any packing of four voxels in a line along x, y or z.
"""

import json
import os
import re
import subprocess
import sys

import numpy as np

from bench_size import EXE, INPUTS, OUT, ROOT, grid_args, nanovdb, run
from vdb_values import dense


def partitions2():
    """BC7's 64 two-subset partitions (bit t: texel t's subset), from the WGSL decoder
    that crates/validate/tests/bcdec.rs checks against bcdec_rs."""
    src = open(os.path.join(ROOT, "shaders", "bcdec.wgsl")).read()
    body = re.search(r"bcdec_partition2[^=]*=\s*array<u32, 64>\((.*?)\);", src, re.S).group(1)
    words = [int(w, 16) & 0xFFFF for w in re.findall(r"0x([0-9a-fA-F]+)u", body)]
    assert len(words) == 64, "expected 64 partitions, found %d" % len(words)
    return np.array([[(w >> t) & 1 for t in range(16)] for w in words], float)


def blocks(a):
    """(blocks, 4 x, 4 y, 4 z) in one fixed block order."""
    nx, ny, nz = (n // 4 for n in a.shape)
    return a.reshape(nx, 4, ny, 4, nz, 4).transpose(0, 2, 4, 1, 3, 5).reshape(-1, 4, 4, 4)


def line_residual(P, w, cols):
    """Weighted squared distance of the rows of P (blocks, 16, 4) to their best line
    over the given channels; rows of weight 0 do not count."""
    Y = P[..., cols]
    n = w.sum(axis=1, keepdims=True)
    mu = (Y * w[..., None]).sum(axis=1, keepdims=True) / np.maximum(n, 1)[..., None]
    D = (Y - mu) * w[..., None]
    ev = np.linalg.eigvalsh(np.einsum("bij,bik->bjk", D, D))
    return np.clip(ev[:, :-1].sum(axis=1), 0, None)  # all but the largest eigenvalue


def floor_sse(X, M, parts):
    """Per block, the least squared error over active voxels of any BC7 decoding.
    X, M: (blocks, 16 texels, 4 channels)."""
    full = M.all(axis=2).astype(float)  # texels whose four voxels are active
    mode6 = line_residual(X, full, [0, 1, 2, 3])
    mode45 = np.minimum.reduce([line_residual(X, full, [c for c in range(4) if c != k]) for k in range(4)])
    mode7 = np.full(len(X), np.inf)
    for s in parts:
        mode7 = np.minimum(mode7, line_residual(X, full * s, [0, 1, 2, 3]) + line_residual(X, full * (1 - s), [0, 1, 2, 3]))
    w3 = M[..., 3].astype(float)  # modes 0-3: one alpha for the block
    m3 = (X[..., 3] * w3).sum(axis=1) / np.maximum(w3.sum(axis=1), 1)
    const_alpha = (((X[..., 3] - m3[:, None]) ** 2) * w3).sum(axis=1)
    return np.minimum.reduce([mode6, mode45, mode7, const_alpha])


def texels(B, axis):
    """Blocks (n, x, y, z) as (n, 16 texels, 4 channels) stacked along `axis`: texel
    t = 4·row + column, the column running along the first remaining axis."""
    order = {"z": (0, 2, 1, 3), "y": (0, 3, 1, 2), "x": (0, 3, 2, 1)}[axis]
    return B.transpose(order).reshape(len(B), 16, 4)


def measured(path, grid):
    """(our bc7 cook's RMSE, nanovdb --fp4's RMSE) on the same grid."""
    os.makedirs(OUT, exist_ok=True)
    r = json.loads(run([EXE, "cook", "--json", "--force", "--format", "bc7", "--grid", grid, "-o", os.path.join(OUT, "floor.vpak"), path]))
    return r["voxel_rmse"], nanovdb(path, grid, ["--fp4"], stem="floor")[1]


def main():
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "vdbcook"], cwd=ROOT, check=True)
    # The size table's inputs but the 24M-voxel fog_300 (this script holds the
    # volume densely in NumPy and walks OpenVDB's iterator in Python).
    inputs = sys.argv[1:] or [p + ":" + (grid_args(p) or ["", "density"])[1] for p in INPUTS if "fog_300" not in p]
    parts = partitions2()
    print("%-28s %10s %10s %10s %10s %10s %9s %9s" % (
        "input", "active", "floor z", "floor y", "floor x", "best axis", "our bc7", "fp4"))
    failed = False
    for arg in inputs:
        path, _, grid = arg.partition(":")
        grid = grid or "density"
        vals, act = dense(path, grid)
        B, A = blocks(vals), blocks(act)
        keep = A.any(axis=(1, 2, 3))
        B, A = B[keep], A[keep]
        n = A.sum()
        per_axis = {ax: floor_sse(texels(B, ax), texels(A, ax), parts) for ax in "zyx"}
        best = np.minimum.reduce(list(per_axis.values()))
        rm = {ax: np.sqrt(s.sum() / n) for ax, s in per_axis.items()}
        ours, fp4 = measured(path, grid)
        print("%-28s %10d %10.3e %10.3e %10.3e %10.3e %9.3e %9.3e   floor z / fp4 %.2fx" % (
            os.path.basename(path)[:28], n, rm["z"], rm["y"], rm["x"], np.sqrt(best.sum() / n), ours, fp4, rm["z"] / fp4))
        if rm["z"] > ours * (1 + 1e-6):
            print("  ERROR: the floor is above what our encoder reaches: the floor is wrong")
            failed = True
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
