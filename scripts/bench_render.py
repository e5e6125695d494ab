#!/usr/bin/python3
"""Validation render speed against OpenVDB's vdb_render, on the same files, in one run.

    /usr/bin/python3 scripts/bench_render.py [FILE...] [--runs R]

Default FILEs: the OpenVDB "smoke1" sample (../shared/vdb-samples/arnold-usd/smoke.vdb,
111x222x112 voxels), bench-out/fog_256.vdb (a generated 256^3 smoke-like fog, 15 M
active voxels, densities up to 1) and bench-out/thin_256.vdb (the same at 1/20 of the
density: thin smoke); the last two are made by scripts/make_bench_volume.py when missing.
* ours: `vdbcook validate` of an f16 cook of FILE against FILE, 8 views at 512x512:
  cooking the lossless reference in memory, uploading both, and 16 images (8 of the
  asset, 8 of the reference), on whatever adapter wgpu picks (lavapipe here);
* OpenVDB: `vdb_render FILE out.ppm -res 512x512 -cpus 2` (one view), twice:
  - with its defaults (extinction 1.6 per voxel at density 1: a dense volume turns
    opaque within a few voxels, so its rays stop early and the picture is nearly black);
  - with the extinction of our scene (an optical depth of 4 across the bounding box at
    the largest value, split absorb:scatter 1:15 like its defaults), so that both
    renderers march the same semi-transparent volume (cameras and light still differ).
Best of R runs each (the matched vdb_render run once: it takes minutes); prints the
ratios of one vdb_render view to our 8 asset views. Also times 8 views of a bc7 cook,
its bricks read through the texture unit and decoded in the shader (--bc-decode).
"""

import json
import math
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


def ppm_mean(path):
    """Mean and max of a binary PPM's 8-bit samples: how much of the volume the picture shows."""
    data = open(path, "rb").read()
    header = data.split(b"\n", 3)
    pixels = header[3]
    return sum(pixels) / max(1, len(pixels)), max(pixels, default=0)


def scene_extinction(exe, asset):
    """Extinction per voxel at density 1 in vdbcook's validation scene (Scene::for_asset)."""
    info = json.loads(subprocess.run([exe, "inspect", "--json", asset], check=True, capture_output=True, text=True).stdout)["files"][0]
    lo, hi = info["index_bbox"]["min"], info["index_bbox"]["max"]
    diag = max(1.0, math.sqrt(sum((hi[a] - lo[a] + 1) ** 2 for a in range(3))))
    peak = max(max(abs(v) for v in info["value_range"]), 1e-6)
    return 4.0 / (peak * diag)


def bench(src, runs):
    asset = os.path.join(OUT, "render.vpak")
    ppm = os.path.join(OUT, "render.ppm")
    subprocess.run([EXE, "cook", "-q", "--force", "--format", "f16", "-o", asset, src], check=True)
    ours = best([EXE, "validate", "-q", asset, "--source", src, "--views", "8", "--size", "512x512"], runs)
    # The same run with one 8x8 view: reading, cooking the reference, GPU set-up.
    fixed = best([EXE, "validate", "-q", asset, "--source", src, "--views", "1", "--size", "8x8"], runs)
    per_image = (ours - fixed) / 16
    # A bc7 cook of the same file: BC7 read through the texture unit, and decoded in the shader.
    bc7 = os.path.join(OUT, "render_bc7.vpak")
    subprocess.run([EXE, "cook", "-q", "--force", "--format", "bc7", "-o", bc7, src], check=True)
    bc7_views = {}
    for where in ("texture", "shader"):
        t = best([EXE, "validate", "-q", bc7, "--source", src, "--views", "8", "--size", "512x512", "--bc-decode", where], runs)
        # An estimate: the f16 run's fixed part and reference images are taken off.
        bc7_views[where] = t - fixed - 8 * per_image
    render = ["vdb_render", src, ppm, "-res", "512x512", "-cpus", "2"]
    default = best(render, runs)
    default_pixels = ppm_mean(ppm)
    sigma = scene_extinction(EXE, asset)
    matched = best(render + ["-absorb", ",".join(["%g" % (sigma / 16)] * 3), "-scatter", ",".join(["%g" % (sigma * 15 / 16)] * 3)], 1)
    matched_pixels = ppm_mean(ppm)
    adapter = subprocess.run([EXE, "validate", asset, "--source", src, "--views", "1", "--size", "8x8"], capture_output=True, text=True).stdout.split(" on ")[-1].split("\n")[0]
    print("file              %s" % os.path.relpath(src, ROOT))
    print("vdbcook validate  %.2f s  for 8 views x 2 images at 512x512 (%s)" % (ours, adapter))
    print("  of which        %.2f s  fixed (read, reference cook, GPU set-up), %.3f s per 512x512 image" % (fixed, per_image))
    print("  8 asset views   %.2f s  (8 images)" % (8 * per_image))
    print("  bc7, 8 views    %.2f s  read through the texture unit, %.2f s  decoded in the shader (--bc-decode)" % (bc7_views["texture"], bc7_views["shader"]))
    print("vdb_render        %.2f s  for 1 view at 512x512 (-cpus 2), its default extinction (pixels: mean %.1f, max %d of 255)" % ((default,) + default_pixels))
    print("vdb_render        %.2f s  for 1 view at 512x512 (-cpus 2), our extinction %.3g per voxel (pixels: mean %.1f, max %d of 255)" % ((matched, sigma) + matched_pixels))
    print("ratio, defaults   %.2fx (one vdb_render view / 8 asset views), %.2fx (/ all of validate)" % (default / (8 * per_image), default / ours))
    print("ratio, matched    %.2fx (one vdb_render view / 8 asset views), %.2fx (/ all of validate)" % (matched / (8 * per_image), matched / ours))
    print()


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    runs = int(sys.argv[sys.argv.index("--runs") + 1]) if "--runs" in sys.argv else 3
    if "--runs" in sys.argv:
        args.remove(str(runs))
    os.makedirs(OUT, exist_ok=True)
    generated = {os.path.join(OUT, "fog_256.vdb"): [], os.path.join(OUT, "thin_256.vdb"): ["--scale", "0.05"]}
    files = args or [os.path.join(ROOT, "..", "shared", "vdb-samples", "arnold-usd", "smoke.vdb")] + list(generated)
    for path, extra in generated.items():
        if path in files and not os.path.exists(path):
            subprocess.run([sys.executable, os.path.join(ROOT, "scripts/make_bench_volume.py"), path, "--size", "256", *extra], check=True)
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "vdbcook"], cwd=ROOT, check=True)
    print("best of %d runs (the matched vdb_render: one run)\n" % runs)
    for src in files:
        if not os.path.exists(src):
            sys.exit("%s: no such file" % src)
        bench(src, runs)


if __name__ == "__main__":
    main()
