#!/usr/bin/python3
"""Asset size against error: NanoVDB's quantised grids against vdbcook's BC formats.

    /usr/bin/python3 scripts/bench_size.py [FILE ...]

For each input (default: a fixture, a generated noisy volume and real samples from
../shared/vdb-samples), in one run:
* NanoVDB: `nanovdb_convert --fp4 | --fp8 | --fpN -a 0.005`, file bytes; the .nvdb is
  converted back to .vdb by nanovdb_convert and compared with the source by
  `vdbcook diff` (voxel RMSE over the source's active voxels);
* vdbcook: `cook --format bc7 | bc4`, with and without `--clusters 256`, bc4 at
  `--quality slow`, and `--format unorm8`; file bytes and the voxel RMSE from the cook
  report (the same figure `vdbcook diff` gives).
Prints bytes per active voxel and RMSE side by side, and the ratios bc7 / fp4, bc4 / fp4
(default and slow) and unorm8 / fp8.
"""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench-out")
EXE = os.path.join(ROOT, "target", "release", "vdbcook")
SAMPLES = os.path.join(ROOT, "..", "shared", "vdb-samples")


def run(cmd):
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def grid_args(path):
    # EmberGen files have no density grid; pick its flames.
    return ["--grid", "flames"] if "embergen" in path else []


def brick_formats(report):
    """A --max-error cook's bricks per format, e.g. 'const 40, bc7 30, u8 148' ("" for several channels)."""
    short = {"constant": "const", "unorm8": "u8", "unorm16": "u16"}
    fs = report["channels"][0]["formats"] if len(report["channels"]) == 1 else []
    return ", ".join("%s %d" % (short.get(f["format"], f["format"]), f["bricks"]) for f in fs)


# The inputs of the size table (bc7_floor.py uses the same ones, but fog_300).
INPUTS = [
    os.path.join(ROOT, "fixtures/fog_blosc.vdb"),
    os.path.join(ROOT, "fixtures/smoke_seq/smoke_0004.vdb"),
    os.path.join(SAMPLES, "arnold-usd/smoke.vdb"),
    os.path.join(SAMPLES, "elyg-visualizer/pyro.vdb"),
    os.path.join(SAMPLES, "vfx-toolkit-embergen/embergen_fire_a_50.vdb"),
    os.path.join(SAMPLES, "waveletturbulence/fluid_data_0153.vdb"),
    os.path.join(OUT, "fog_300.vdb"),
]


def nanovdb(src, grid, flags, stem="size"):
    """(bytes, voxel RMSE) of `nanovdb_convert FLAGS`: the .nvdb converted back to .vdb
    by nanovdb_convert and compared with the source by `vdbcook diff`."""
    nv, back = (os.path.join(OUT, stem + e) for e in (".nvdb", "_back.vdb"))
    run(["nanovdb_convert", "-f", "-g", grid, *flags, src, nv])
    run(["nanovdb_convert", "-f", nv, back])
    d = json.loads(run([EXE, "diff", "--json", "--grid", grid, src, back]))
    return os.path.getsize(nv), d["rmse"]


def main():
    os.makedirs(OUT, exist_ok=True)
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "vdbcook"], cwd=ROOT, check=True)
    inputs = sys.argv[1:] or INPUTS
    vp = os.path.join(OUT, "size.vpak")
    for src in inputs:
        if not os.path.exists(src):
            print("skipping %s (missing)" % src)
            continue
        g = grid_args(src)
        info = json.loads(run([EXE, "inspect", "--json", src]))
        grids = info["files"][0]["grids"]
        name = g[1] if g else next((x["name"] for x in grids if x["name"] == "density"), grids[0]["name"])
        active = next(x["active_voxels"] for x in grids if x["name"] == name)
        print("\n%s: grid %s, %d active voxels" % (os.path.relpath(src, ROOT), name, active))
        print("  %-24s %12s %10s %12s" % ("encoding", "bytes", "B/voxel", "voxel RMSE"))
        rows = {}
        for label, flags in [("nanovdb fp4", ["--fp4"]), ("nanovdb fp8", ["--fp8"]), ("nanovdb fpN -a 0.005", ["--fpN", "-a", "0.005"])]:
            rows[label] = nanovdb(src, name, flags)
        for fmt in ["bc7", "bc4"]:
            for clusters in [None, 256]:
                label = "vdbcook %s%s" % (fmt, " +256 clusters" if clusters else "")
                extra = ["--clusters", str(clusters)] if clusters else []
                r = json.loads(run([EXE, "cook", "--json", "--force", "--format", fmt, *g, *extra, "-o", vp, src]))
                rows[label] = (r["file_bytes"], r["voxel_rmse"])
        r = json.loads(run([EXE, "cook", "--json", "--force", "--format", "bc4", "--quality", "slow", *g, "-o", vp, src]))
        rows["vdbcook bc4 slow"] = (r["file_bytes"], r["voxel_rmse"])
        r = json.loads(run([EXE, "cook", "--json", "--force", "--format", "unorm8", *g, "-o", vp, src]))
        rows["vdbcook unorm8"] = (r["file_bytes"], r["voxel_rmse"])
        for label, (b, rmse) in rows.items():
            print("  %-24s %12d %10.4f %12.4e" % (label, b, b / active, rmse))
        for ours, theirs in [("vdbcook bc7", "nanovdb fp4"), ("vdbcook bc4", "nanovdb fp4"), ("vdbcook bc4 slow", "nanovdb fp4"), ("vdbcook unorm8", "nanovdb fp8")]:
            (ob, oe), (tb, te) = rows[ours], rows[theirs]
            print("  %s / %s: bytes %.3f, RMSE %.2f" % (ours[8:], theirs[8:], ob / tb, oe / te if te else float("inf")))


if __name__ == "__main__":
    main()
