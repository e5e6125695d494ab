#!/usr/bin/python3
"""Write a large procedural smoke-like fog volume for read-throughput benchmarks.

    /usr/bin/python3 scripts/make_bench_volume.py OUT.vdb [--size N] [--seed S] [--half] [--scale K]

* one float grid "density" (class fog volume), values in (0, 1], written by OpenVDB
  itself (pyopenvdb.write: blosc + active-mask compression; --half stores 16-bit halves);
* a dense N^3 block (default N = 300) of which roughly three quarters is active
  (size 300 -> about 24 million active voxels in 50k leaves, ~84 MB), with
  noisy values so blosc has real work to do;
* deterministic: the same arguments give a byte-identical file (OpenVDB's random header
  UUID is replaced by one derived from the arguments);
* needs /usr/bin/python3 (Debian's pyopenvdb) and numpy; ~3 s and ~0.7 GB RAM at N=300.
"""

import argparse
import hashlib
import os
import sys
import time

import system_python  # noqa: F401,E402  (re-runs under /usr/bin/python3 when needed)
import numpy as np  # noqa: E402
import pyopenvdb as vdb  # noqa: E402,F401


def upsample_axis(a, n_out, axis):
    n_in = a.shape[axis]
    x = np.linspace(0.0, n_in - 1.0, n_out)
    i0 = np.minimum(np.floor(x).astype(np.int64), n_in - 2)
    t = (x - i0).astype(np.float32)
    sh = [1, 1, 1]
    sh[axis] = n_out
    t = t.reshape(sh)
    return np.take(a, i0, axis=axis) * (1 - t) + np.take(a, i0 + 1, axis=axis) * t


def value_noise(rng, n, octaves=((5, 1.0), (11, 0.55), (23, 0.3), (47, 0.18))):
    out = np.zeros((n, n, n), dtype=np.float32)
    total = 0.0
    for cells, amp in octaves:
        a = rng.uniform(-1.0, 1.0, size=(cells + 1,) * 3).astype(np.float32)
        for axis in range(3):
            a = upsample_axis(a, n, axis)
        out += np.float32(amp) * a
        total += amp
        del a
    out *= np.float32(1.8 / total)
    return out


def bench_density(n, seed):
    rng = np.random.default_rng(seed)
    c = (n - 1) / 2.0
    coord = ((np.arange(n, dtype=np.float32) - c) / (0.5 * n)).astype(np.float32)
    # super-ellipsoid envelope (|x|^4 + |y|^4 + |z|^4) filling most of the cube
    x4 = coord ** 4
    r4 = x4[:, None, None] + (x4 * 1.15)[None, :, None] + (x4 * 0.9)[None, None, :]
    env = np.exp(-(r4 / 0.55) ** 2).astype(np.float32)
    del r4
    noise = value_noise(rng, n)
    dens = env * np.clip(np.float32(0.55) + np.float32(0.7) * noise, 0.0, 1.6)
    del env, noise
    np.clip(dens, 0.0, 1.0, out=dens)
    dens[dens < 2e-3] = 0.0
    return dens


def fix_uuid(path, key):
    h = hashlib.sha256(key.encode()).hexdigest()
    uuid = "%s-%s-%s-%s-%s" % (h[0:8], h[8:12], h[12:16], h[16:20], h[20:32])
    with open(path, "r+b") as f:
        f.seek(8 + 4 + 4 + 4 + 1)  # magic, file version, library major/minor, offsets flag
        f.write(uuid.encode("ascii"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--size", type=int, default=300, help="edge of the dense block (default 300)")
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--voxel-size", type=float, default=0.02)
    ap.add_argument("--half", action="store_true", help="store values as 16-bit halves")
    ap.add_argument("--scale", type=float, default=1.0, help="multiply every density by this (thin smoke: 0.05)")
    args = ap.parse_args()
    if args.size < 8:
        ap.error("--size must be at least 8")
    t0 = time.time()
    dens = bench_density(args.size, args.seed)
    if args.scale != 1.0:
        dens *= np.float32(args.scale)
    t1 = time.time()
    g = vdb.FloatGrid(0.0)
    # centre the block on the origin so that the volume spans 8 root-node octants
    origin = (-(args.size // 2),) * 3
    g.copyFromArray(dens, origin, 0.0)
    g.pruneInactive()
    g.name = "density"
    g.gridClass = "fog volume"
    g.transform = vdb.createLinearTransform(args.voxel_size)
    g.saveFloatAsHalf = bool(args.half)
    active = g.activeVoxelCount()
    leaves = g.leafCount()
    del dens
    t2 = time.time()
    vdb.write(args.out, [g], metadata={"creator": "vdbcook scripts/make_bench_volume.py"})
    fix_uuid(args.out, "bench size=%d seed=%d vs=%r half=%d" % (args.size, args.seed, args.voxel_size, args.half)
             + ("" if args.scale == 1.0 else " scale=%r" % args.scale))
    t3 = time.time()
    print("%s: %d active voxels, %d leaves, bbox %s; noise %.1fs, build %.1fs, write %.1fs"
          % (args.out, active, leaves, g.evalActiveVoxelBoundingBox(), t1 - t0, t2 - t1, t3 - t2),
          file=sys.stderr)


if __name__ == "__main__":
    main()
