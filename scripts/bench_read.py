#!/usr/bin/python3
"""Read throughput: vdbcook's reader against OpenVDB's, on the same file, in one run.

    /usr/bin/python3 scripts/bench_read.py [--size N] [--runs R] [--half]

Builds the release binary, generates a large procedural fog volume with OpenVDB
(scripts/make_bench_volume.py, blosc, cached in bench-out/), then times, best of R runs:

* ours:    `vdbcook inspect --json FILE` — a whole process: read the file, decode every
           leaf, and compute active count, bbox, min/max/sum;
* OpenVDB: `pyopenvdb.read(FILE, "density")` then `evalMinMax()` and `activeVoxelCount()`
           in this process (import excluded), with delayed loading disabled
           (OPENVDB_DISABLE_DELAYED_LOAD=1) so that it really decodes the leaves.

Prints active voxels per second for both and the ratio (ours / OpenVDB).  Timings are
never asserted anywhere: the machines here are noisy, the ratio is what we record in
docs/benchmarks.md.
"""

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=300, help="edge of the generated volume (default 300)")
    ap.add_argument("--runs", type=int, default=3, help="runs per reader; the best is kept (default 3)")
    ap.add_argument("--half", action="store_true", help="store the volume as 16-bit halves")
    args = ap.parse_args()

    os.environ["OPENVDB_DISABLE_DELAYED_LOAD"] = "1"
    import pyopenvdb as vdb

    out_dir = os.path.join(ROOT, "bench-out")
    os.makedirs(out_dir, exist_ok=True)
    vol = os.path.join(out_dir, "fog_%d%s.vdb" % (args.size, "_half" if args.half else ""))
    if not os.path.exists(vol):
        cmd = [sys.executable, os.path.join(ROOT, "scripts/make_bench_volume.py"), vol, "--size", str(args.size)]
        if args.half:
            cmd.append("--half")
        subprocess.run(cmd, check=True)
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "vdbcook"], cwd=ROOT, check=True)
    exe = os.path.join(ROOT, "target", "release", "vdbcook")

    ours_best, ours_report = float("inf"), None
    theirs_best, theirs_count = float("inf"), None
    for _ in range(args.runs):
        t0 = time.perf_counter()
        res = subprocess.run([exe, "inspect", "--json", vol], check=True, capture_output=True)
        ours_best = min(ours_best, time.perf_counter() - t0)
        ours_report = json.loads(res.stdout)

        t0 = time.perf_counter()
        grid = vdb.read(vol, "density")
        lo, hi = grid.evalMinMax()
        theirs_count = grid.activeVoxelCount()
        theirs_best = min(theirs_best, time.perf_counter() - t0)
        del grid

    g = ours_report["files"][0]["grids"][0]
    n = g["active_voxels"]
    if n != theirs_count:
        sys.exit("active voxel counts differ: ours %d, OpenVDB %d" % (n, theirs_count))
    size = os.path.getsize(vol)
    print("file            %s (%.1f MB, %d active voxels, %d leaves, %s)" % (
        os.path.relpath(vol, ROOT), size / 1e6, n, g["leaf_count"], "+".join(g["compression"])))
    print("vdbcook         %.3f s  %.1f M active voxels/s" % (ours_best, n / ours_best / 1e6))
    print("OpenVDB %-7s %.3f s  %.1f M active voxels/s" % (".".join(map(str, vdb.LIBRARY_VERSION)), theirs_best, n / theirs_best / 1e6))
    print("ratio           %.2fx (vdbcook / OpenVDB throughput, best of %d, %d cores)" % (theirs_best / ours_best, args.runs, os.cpu_count()))


if __name__ == "__main__":
    main()
