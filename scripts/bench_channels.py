#!/usr/bin/python3
"""Several grids in one asset: packed against separate assets, against NanoVDB, and
what the extra channels cost the renderer.

    /usr/bin/python3 scripts/bench_channels.py [--runs N] [--parts ABC]

All in one run, with the release binary (built first):

A. For each input set (EmberGen fire: temperature + flames; waveletturbulence:
   density, temperature, flame, velocity; c42: density, temperature, colour and
   velocity) and each format: the channels cooked into one asset (`cook --grids`)
   against each grid cooked into its own asset (`cook --grid`, a vec3 grid is one
   asset of three channels): file bytes, the ratio packed / separate, the worst
   per-channel ratio of voxel RMSE (packed / separate, from the cook reports: over each
   channel's own active voxels), and cook time packed / sum of the separate cooks.
B. For one frame of each set: NanoVDB holding the same grids (`nanovdb_convert -g GRID
   --fp4 | --fp8 | --fpN -a 0.01` per grid, bytes summed; vec3 grids stay float32 in
   NanoVDB): bytes and per-channel RMSE (each .nvdb converted back by nanovdb_convert,
   then `vdbcook diff --grid`; vec3 is exact in NanoVDB), against every
   vdbcook format (and, with a vec3 grid, the scalars in a format and the vec3 in f32):
   for each NanoVDB point, the smallest of our assets with no more bytes and no
   higher RMSE on any channel, if there is one.
C. `validate` (8 views, 256x256, lavapipe or whatever adapter is there) of the
   waveletturbulence frames with four channels (density, temperature, flame, shadow)
   against density alone: median of N runs each, and the ratio.
"""

import json
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench-out", "channels")
EXE = os.path.join(ROOT, "target", "release", "vdbcook")
S = os.path.join(ROOT, "..", "shared", "vdb-samples")
FORMATS = ["f32", "f16", "unorm8", "bc4", "bc7"]


def run(cmd):
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def cook(files, grid_flags, fmt, out, extra=()):
    t0 = time.perf_counter()
    r = json.loads(run([EXE, "cook", "--json", "--force", "--format", fmt, *grid_flags, *extra, "-o", out, *files]))
    return r, time.perf_counter() - t0


SETS = [
    ("embergen fire (frames 1-3)", [os.path.join(S, "vfx-toolkit-embergen", "embergen_fire_a_%d.vdb" % k) for k in (1, 2, 3)], ["temperature", "flames"]),
    ("waveletturbulence (150-153)", [os.path.join(S, "waveletturbulence", "fluid_data_%04d.vdb" % k) for k in range(150, 154)], ["density", "temperature", "flame", "velocity"]),
    ("c42 (frame 1)", [os.path.join(S, "c42", "fluid_data_0001.vdb")], ["density", "temperature", "color_r", "color_g", "color_b", "velocity"]),
]
VEC3 = {"velocity"}


def part_a():
    print("A. packed (--grids) against one asset per grid, same format")
    print("  %-28s %-7s %11s %11s %7s %14s %9s" % ("input", "format", "packed B", "separate B", "ratio", "worst RMSE x", "time x"))
    for label, files, grids in SETS:
        for fmt in FORMATS:
            packed, tp = cook(files, ["--grids", ",".join(grids)], fmt, os.path.join(OUT, "packed.vpak"))
            sep_bytes, sep_time, worst = 0, 0.0, 0.0
            for g in grids:
                r, t = cook(files, ["--grid", g], fmt, os.path.join(OUT, "one.vpak"))
                sep_bytes += r["file_bytes"]
                sep_time += t
                for ch in r["channels"]:
                    p = next(c for c in packed["channels"] if c["name"] == ch["name"])
                    if ch["voxel_rmse"] > 0:
                        worst = max(worst, p["voxel_rmse"] / ch["voxel_rmse"])
                    elif p["voxel_rmse"] > 0:
                        worst = float("inf")
            print("  %-28s %-7s %11d %11d %7.3f %14.3f %9.2f" % (label, fmt, packed["file_bytes"], sep_bytes, packed["file_bytes"] / sep_bytes, worst, tp / sep_time))


def nanovdb_point(src, grids, scalars, flags):
    """(bytes, RMSE per scalar grid) of each grid converted on its own, or None when
    nanovdb_convert fails on the file."""
    nv, back = os.path.join(OUT, "n.nvdb"), os.path.join(OUT, "n_back.vdb")
    total, rmse = 0, {}
    for g in grids:
        done = subprocess.run(["nanovdb_convert", "-f", "-g", g, *flags, src, nv], capture_output=True, text=True)
        if done.returncode != 0:
            return None
        total += os.path.getsize(nv)
        if g in scalars:
            run(["nanovdb_convert", "-f", nv, back])
            rmse[g] = json.loads(run([EXE, "diff", "--json", "--grid", g, src, back]))["rmse"]
    return total, rmse


def part_b():
    print("\nB. NanoVDB holding every grid of the file against vdbcook (one frame)")
    for label, files, grids in SETS:
        src = files[-1]
        info = json.loads(run([EXE, "inspect", "--json", src]))["files"][0]["grids"]
        present = [g for g in grids if any(x["name"] == g for x in info)]
        scalars = [g for g in present if g not in VEC3]
        print("  %s, %s: %s" % (label, os.path.basename(src), ", ".join(present)))
        ours = []
        configs = [(f, []) for f in FORMATS]
        if any(g in VEC3 for g in present):
            configs += [(f, ["--group", "velocity=f32"]) for f in FORMATS if f != "f32"]
        for fmt, extra in configs:
            r, _ = cook([src], ["--grids", ",".join(present)], fmt, os.path.join(OUT, "b.vpak"), extra)
            per = {}
            for c in r["channels"]:
                base = c["name"].split(".")[0] if c["name"].split(".")[0] in VEC3 else c["name"]
                per[base] = max(per.get(base, 0.0), c["voxel_rmse"])
            ours.append((fmt + (" +velocity f32" if extra else ""), r["file_bytes"], per))
        for nlabel, flags in [("fp4", ["--fp4"]), ("fp8", ["--fp8"]), ("fpN -a 0.01", ["--fpN", "-a", "0.01"])]:
            point = nanovdb_point(src, present, scalars, flags)
            if point is None:
                print("    nanovdb %-12s nanovdb_convert failed on this file (a crash of the peer, not compared)" % nlabel)
                continue
            nb, nr = point
            for g in present:
                nr.setdefault(g, 0.0)  # vec3 grids stay float32 in NanoVDB: exact
            fits = [o for o in ours if o[1] <= nb and all(o[2].get(g, 0.0) <= nr[g] for g in present)]
            best = min(fits, key=lambda o: o[1]) if fits else None
            rm = ", ".join("%s %.2e" % (g, nr[g]) for g in scalars)
            if best:
                print("    nanovdb %-12s %9d B (%s) -> vdbcook %s: %d B (%.2fx), RMSE %s" % (nlabel, nb, rm, best[0], best[1], best[1] / nb, ", ".join("%s %.2e" % (g, best[2].get(g, 0.0)) for g in scalars)))
            else:
                close = min(ours, key=lambda o: max((o[2].get(g, 0.0) / nr[g] if nr[g] > 0 else (1.0 if o[2].get(g, 0.0) == 0 else float("inf"))) for g in present))
                print("    nanovdb %-12s %9d B (%s) -> no vdbcook asset no larger with no higher RMSE on every channel; closest %s: %d B, RMSE %s" % (nlabel, nb, rm, close[0], close[1], ", ".join("%s %.2e" % (g, close[2].get(g, 0.0)) for g in scalars)))


def part_c(runs):
    print("\nC. validate (8 views, 256x256): four channels against density alone")
    files = SETS[1][1]
    times = {}
    for label, grids in [("density", "density"), ("4 channels", "density,temperature,flame,shadow")]:
        out = os.path.join(OUT, "v.vpak")
        run([EXE, "cook", "-q", "--force", "--grids", grids, "--format", "f16", "-o", out, *files])
        t = []
        for _ in range(runs):
            t0 = time.perf_counter()
            run([EXE, "validate", out, "--views", "8", "--size", "256x256", "--source", *files])
            t.append(time.perf_counter() - t0)
        times[label] = statistics.median(t)
        print("  %-12s median %.2f s (runs: %s)" % (label, times[label], ", ".join("%.2f" % x for x in t)))
    print("  ratio 4 channels / density: %.2fx" % (times["4 channels"] / times["density"]))


def main():
    runs = int(sys.argv[sys.argv.index("--runs") + 1]) if "--runs" in sys.argv else 3
    parts = sys.argv[sys.argv.index("--parts") + 1] if "--parts" in sys.argv else "ABC"
    os.makedirs(OUT, exist_ok=True)
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "vdbcook"], cwd=ROOT, check=True)
    for part, fn in [("A", part_a), ("B", part_b), ("C", lambda: part_c(runs))]:
        if part in parts:
            fn()


if __name__ == "__main__":
    main()
