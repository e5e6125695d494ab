#!/usr/bin/python3
"""Channels at their own voxel size (issue 26): bytes, wall time and peak memory of
cooking a pyro-style sequence with `vel` on voxels twice (or more) the density's,
against the density + temperature cook of the same files, against `vel` resampled
to the density's voxels (what an asset without per-channel voxel sizes must store), and
`vel` cooked alone (the two cooks apart: a floor on the time of cooking them as one).
Runs alternate (with vel, without), medians of --runs; ratios from the same run.

    /usr/bin/python3 scripts/make_pyro_sequence.py bench-out/pyro192 --frames 4 --size 192
    /usr/bin/python3 scripts/bench_resolution.py bench-out/pyro192 [--runs 5] [--formats f16,bc7]

Peak RSS is /usr/bin/time's %M (KiB). Outputs go to a scratch directory removed at the end.
"""

import argparse
import os
import shutil
import statistics
import subprocess
import tempfile


def timed(cmd):
    """(wall s, peak KiB) of one command under /usr/bin/time."""
    out = subprocess.run(["/usr/bin/time", "-f", "%e %M"] + cmd, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{out.stderr}")
    wall, peak = out.stderr.strip().splitlines()[-1].split()
    return float(wall), int(peak)


def resampled(seq, tmp):
    """The sequence with vel resampled (nearest) to the density's voxels, via pyopenvdb."""
    out = os.path.join(tmp, "fullres")
    os.makedirs(out)
    code = r"""
import sys, os, glob, pyopenvdb as vdb
src, dst = sys.argv[1], sys.argv[2]
for f in sorted(glob.glob(os.path.join(src, '*.vdb'))):
    grids = vdb.readAll(f)[0]
    dens = [g for g in grids if g.name == 'density'][0]
    vel = [g for g in grids if g.name == 'vel'][0]
    fine = vdb.Vec3SGrid((0.0, 0.0, 0.0))
    fine.transform = dens.transform
    fine.name = 'vel'
    fine.gridClass = vel.gridClass
    import numpy as np
    lo, hi = dens.evalActiveVoxelBoundingBox()
    shape = tuple(h - l + 1 for l, h in zip(lo, hi))
    coarse_lo, coarse_hi = vel.evalActiveVoxelBoundingBox()
    cshape = tuple(h - l + 1 for l, h in zip(coarse_lo, coarse_hi))
    c = np.zeros(cshape + (3,), dtype=np.float32)
    vel.copyToArray(c, ijk=coarse_lo)
    s = round(vel.transform.voxelSize()[0] / dens.transform.voxelSize()[0])
    idx = [np.clip((np.arange(l, h + 1) + s // 2) // s - cl, 0, cs - 1) for l, h, cl, cs in zip(lo, hi, coarse_lo, cshape)]
    a = c[idx[0][:, None, None], idx[1][None, :, None], idx[2][None, None, :]]
    m = np.zeros(shape, dtype=np.float32)
    dens.copyToArray(m, ijk=lo)
    a[m == 0] = 0.0
    fine.copyFromArray(np.ascontiguousarray(a), ijk=lo, tolerance=(0.0, 0.0, 0.0))
    vdb.write(os.path.join(dst, os.path.basename(f)), grids=[g for g in grids if g.name != 'vel'] + [fine])
"""
    r = subprocess.run(["/usr/bin/python3", "-c", code, seq, out], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(r.stderr)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("seq")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--formats", default="f16,bc7")
    ap.add_argument("--exe", default="target/release/vdbcook")
    args = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="bench-resolution-")
    try:
        full = resampled(args.seq, tmp)
        print(f"{args.seq}; {args.runs} alternating runs per format; load {os.getloadavg()[0]:.2f}", flush=True)
        print("| format | density+temperature: bytes, wall, peak | + vel at its own voxels: bytes, wall, peak | bytes ratio | wall ratio | peak ratio | + vel resampled to density's voxels: bytes (ratio) | vel alone: wall (density+temperature's + vel alone's, as a ratio) |")
        print("|---|---|---|---:|---:|---:|---|---|")
        for fmt in args.formats.split(","):
            flags = ["--max-error", fmt.split(":", 1)[1]] if fmt.startswith("max-error:") else ["--format", fmt]
            runs = {"fine": [], "vel": [], "alone": []}
            for _ in range(args.runs):
                for name, grids in (("fine", "density,temperature"), ("vel", "density,temperature,vel"), ("alone", "vel")):
                    out = os.path.join(tmp, name + ".vpak")
                    runs[name].append(timed([args.exe, "cook", "-q", "--force", "-o", out, "--grids", grids] + flags + [args.seq]))
            size = {k: os.path.getsize(os.path.join(tmp, k + ".vpak")) for k in runs}
            wall = {k: statistics.median(w for w, _ in v) for k, v in runs.items()}
            peak = {k: max(p for _, p in v) for k, v in runs.items()}
            out = os.path.join(tmp, "full.vpak")
            timed([args.exe, "cook", "-q", "--force", "-o", out, "--grids", "density,temperature,vel"] + flags + [full])
            fb = os.path.getsize(out)
            mb = lambda b: f"{b / 1e6:.2f} MB"
            floor = (wall["fine"] + wall["alone"]) / wall["fine"]
            print(f"| {fmt} | {mb(size['fine'])}, {wall['fine']:.2f} s, {peak['fine'] / 1024:.0f} MiB | {mb(size['vel'])}, {wall['vel']:.2f} s, {peak['vel'] / 1024:.0f} MiB | {size['vel'] / size['fine']:.3f} | {wall['vel'] / wall['fine']:.2f} | {peak['vel'] / peak['fine']:.2f} | {mb(fb)} ({fb / size['fine']:.2f}) | {wall['alone']:.2f} s ({floor:.2f}) |", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
