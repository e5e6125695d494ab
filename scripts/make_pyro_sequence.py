#!/usr/bin/python3
"""Write a pyro-style sequence whose velocity has its own voxel size (not committed).

    /usr/bin/python3 scripts/make_pyro_sequence.py OUTDIR [--frames 3] [--size 64]
        [--vel-scale 2] [--offset 0] [--split]

Frame k holds `density` and `temperature` (float fog grids at voxel size 0.1, about
size³ voxels: a rising noisy plume, temperature hottest at its core) and `vel` (a
vec3s grid of class staggered, at voxel size 0.1·vel-scale, covering the plume), as a
Houdini pyro export with a velocity voxel scale writes them. `--offset H` moves vel's
index origin by H half voxels of density along each axis (0: the grids share an
origin). With `--split`, density and temperature go to OUTDIR/noise/pyro_noise_####.vdb
and vel to OUTDIR/data/pyro_data_####.vdb (several files per frame, as Blender writes
its noise and data caches); else all to OUTDIR/pyro_####.vdb. Deterministic.
"""

import argparse
import os
import sys

import numpy as np

try:
    import pyopenvdb as vdb
except ImportError:
    sys.exit("make_pyro_sequence.py needs pyopenvdb: run it with /usr/bin/python3")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from make_bench_sequence import upsample  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("outdir")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--vel-scale", type=int, default=2)
    ap.add_argument("--offset", type=int, default=0, help="vel's origin in half density voxels")
    ap.add_argument("--split", action="store_true")
    args = ap.parse_args()
    n, s = args.size, args.vel_scale
    rng = np.random.default_rng(11)
    field = upsample(rng.random((n // 4 + 2,) * 3).astype(np.float32), n)
    c = (np.arange(n, dtype=np.float32) - n / 2) / (n / 2)
    r2 = c[:, None, None] ** 2 + c[None, :, None] ** 2 + c[None, None, :] ** 2
    m = n // s
    vfield = upsample(rng.random((m // 4 + 2,) * 3).astype(np.float32), m + 2)
    cm = (np.arange(m + 2, dtype=np.float32) - m / 2) / (m / 2)
    if args.split:
        os.makedirs(os.path.join(args.outdir, "noise"), exist_ok=True)
        os.makedirs(os.path.join(args.outdir, "data"), exist_ok=True)
    else:
        os.makedirs(args.outdir, exist_ok=True)
    voxel = 0.1
    for k in range(1, args.frames + 1):
        phase = k * 0.15
        dens = np.clip((1.0 - r2) * (0.6 + 0.4 * np.sin(field * 6.0 + phase)), 0.0, None).astype(np.float32)
        dens[dens < 0.02] = 0.0
        temp = (dens * (1.5 - r2) * 2.0).astype(np.float32)
        temp[dens == 0.0] = 0.0
        grids = []
        for name, a in (("density", dens), ("temperature", temp)):
            g = vdb.FloatGrid(0.0)
            g.copyFromArray(a, ijk=(0, k, 0), tolerance=0.0)
            g.name = name
            g.gridClass = vdb.GridClass.FOG_VOLUME
            g.transform = vdb.createLinearTransform(voxelSize=voxel)
            grids.append(g)
        # vel is active where the plume is: each of its voxels over the density
        # voxels it covers (vel voxel j covers density voxels s·j to s·j + s − 1).
        rows = (k + n) // s + 1
        occ = np.zeros((m * s, rows * s, m * s), dtype=bool)
        occ[:, k : k + n, :] = dens[: m * s, :, : m * s] > 0.0
        cover = occ.reshape(m, s, rows, s, m, s).any(axis=(1, 3, 5))
        f = vfield[:m, :rows, :m] if rows <= m + 2 else np.resize(vfield, (m, rows, m))
        swirl = np.sin(f * 5.0 + phase)
        vel = np.stack([swirl * cm[None, None, :m], np.cos(f * 3.0 + phase) + 1.5, -swirl * cm[:m, None, None]], axis=-1).astype(np.float32)
        vel[~cover] = 0.0
        v = vdb.Vec3SGrid((0.0, 0.0, 0.0))
        v.copyFromArray(vel, ijk=(0, 0, 0), tolerance=(0.0, 0.0, 0.0))
        v.name = "vel"
        v.gridClass = vdb.GridClass.STAGGERED
        t = vdb.createLinearTransform(voxelSize=voxel * s)
        if args.offset:
            t.translate((args.offset * voxel / 2.0,) * 3)
        v.transform = t
        if args.split:
            vdb.write(os.path.join(args.outdir, "noise", "pyro_noise_%04d.vdb" % k), grids=grids)
            vdb.write(os.path.join(args.outdir, "data", "pyro_data_%04d.vdb" % k), grids=[v])
        else:
            vdb.write(os.path.join(args.outdir, "pyro_%04d.vdb" % k), grids=grids + [v])


if __name__ == "__main__":
    main()
