#!/usr/bin/python3
"""Write a long synthetic smoke sequence for cook benchmarks (not committed).

    /usr/bin/python3 scripts/make_bench_sequence.py OUTDIR [--frames 100] [--size 96]

Frame k holds a `density` fog grid (float, blosc, written by OpenVDB): a soft noisy
plume of about size³ voxels that rises by one voxel per frame and slowly changes
shape, plus a static cube-shaped block of smoke that is identical in every frame (the
part an animation-aware cooker should store once). Deterministic; files are named
smoke_0001.vdb, smoke_0002.vdb, ...
"""

import argparse
import os
import sys

import numpy as np

try:
    import pyopenvdb as vdb
except ImportError:
    sys.exit("make_bench_sequence.py needs pyopenvdb: run it with /usr/bin/python3")


def upsample(noise, n):
    """Trilinear upsampling of a cube of coarse noise (edge m + 2) to an n³ field
    spanning its first m + 1 samples."""
    idx = np.linspace(0, noise.shape[0] - 2, n).astype(np.float32)
    i0 = np.floor(idx).astype(int)
    t = idx - i0

    def up(a, axis):
        a0 = np.take(a, i0, axis=axis)
        a1 = np.take(a, i0 + 1, axis=axis)
        sh = [1, 1, 1]
        sh[axis] = n
        tt = t.reshape(sh)
        return a0 * (1 - tt) + a1 * tt

    return up(up(up(noise, 0), 1), 2)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("outdir")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--size", type=int, default=96)
    args = ap.parse_args()
    os.makedirs(args.outdir, exist_ok=True)
    n = args.size
    rng = np.random.default_rng(7)
    field = upsample(rng.random((n // 4 + 2,) * 3).astype(np.float32), n)
    c = (np.arange(n, dtype=np.float32) - n / 2) / (n / 2)
    r2 = c[:, None, None] ** 2 + c[None, :, None] ** 2 + c[None, None, :] ** 2
    static = np.zeros((16, 16, 16), dtype=np.float32) + 0.35
    for k in range(1, args.frames + 1):
        phase = k * 0.05
        dens = np.clip((1.0 - r2) * (0.6 + 0.4 * np.sin(field * 6.0 + phase)), 0.0, None).astype(np.float32)
        dens[dens < 0.02] = 0.0
        g = vdb.FloatGrid(0.0)
        g.copyFromArray(dens, ijk=(0, k, 0), tolerance=0.0)
        g.copyFromArray(static, ijk=(n + 32, 0, 0), tolerance=0.0)
        g.name = "density"
        g.gridClass = vdb.GridClass.FOG_VOLUME
        g.transform = vdb.createLinearTransform(voxelSize=0.02)
        vdb.write(os.path.join(args.outdir, "smoke_%04d.vdb" % k), grids=[g])
    print("%s: %d frames of about %d^3 voxels" % (args.outdir, args.frames, n))


if __name__ == "__main__":
    main()
