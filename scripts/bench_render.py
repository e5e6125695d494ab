#!/usr/bin/python3
"""Validation render speed against OpenVDB's vdb_render, on the same file, in one run.

    /usr/bin/python3 scripts/bench_render.py [FILE] [--runs R]

Default FILE: the OpenVDB "smoke1" sample (../shared/vdb-samples/arnold-usd/smoke.vdb,
111x222x112 voxels, the 256³-class smoke volume), else bench-out/fog_256.vdb.
* ours: `vdbcook validate` of an f16 cook of FILE against FILE, 8 views at 512x512:
  cooking the lossless reference in memory, uploading both, and 16 images (8 of the
  asset, 8 of the reference), on whatever adapter wgpu picks (lavapipe here);
* OpenVDB: `vdb_render FILE out.ppm -res 512x512 -cpus 2` (one view, its default
  volume shading with shadows).
Best of R runs each; prints the ratio of one vdb_render view to all of ours.
"""

import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench-out")
EXE = os.path.join(ROOT, "target", "release", "vdbcook")


def best(cmd, runs):
    t = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        t = min(t, time.perf_counter() - t0)
    return t


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    runs = int(sys.argv[sys.argv.index("--runs") + 1]) if "--runs" in sys.argv else 3
    if "--runs" in sys.argv:
        args = [a for a in args if a != str(runs)]
    os.makedirs(OUT, exist_ok=True)
    src = args[0] if args else os.path.join(ROOT, "..", "shared", "vdb-samples", "arnold-usd", "smoke.vdb")
    if not os.path.exists(src):
        src = os.path.join(OUT, "fog_256.vdb")
        if not os.path.exists(src):
            subprocess.run([sys.executable, os.path.join(ROOT, "scripts/make_bench_volume.py"), src, "--size", "256"], check=True)
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "vdbcook"], cwd=ROOT, check=True)
    asset = os.path.join(OUT, "render.vpak")
    subprocess.run([EXE, "cook", "-q", "--force", "--format", "f16", "-o", asset, src], check=True)
    ours = best([EXE, "validate", "-q", asset, "--source", src, "--views", "8", "--size", "512x512"], runs)
    # The same run with one 8x8 view: reading, cooking the reference, GPU set-up.
    fixed = best([EXE, "validate", "-q", asset, "--source", src, "--views", "1", "--size", "8x8"], runs)
    per_image = (ours - fixed) / 16
    theirs = best(["vdb_render", src, os.path.join(OUT, "render.ppm"), "-res", "512x512", "-cpus", "2"], runs)
    adapter = subprocess.run([EXE, "validate", asset, "--source", src, "--views", "1", "--size", "8x8"], capture_output=True, text=True).stdout.split(" on ")[-1].split("\n")[0]
    print("file              %s" % os.path.relpath(src, ROOT))
    print("vdbcook validate  %.2f s  for 8 views x 2 images at 512x512 (%s)" % (ours, adapter))
    print("  of which        %.2f s  fixed (read, reference cook, GPU set-up), %.3f s per 512x512 image" % (fixed, per_image))
    print("  8 asset views   %.2f s  (8 images)" % (8 * per_image))
    print("vdb_render        %.2f s  for 1 view at 512x512 (-cpus 2)" % theirs)
    print("ratio             %.2fx (one vdb_render view / all of validate), %.2fx (one vdb_render view / 8 asset views), best of %d" % (theirs / ours, theirs / (8 * per_image), runs))


if __name__ == "__main__":
    main()
