#!/usr/bin/python3
"""One frame (issue 23): `cook --format F` of one file with this binary and earlier ones,
and `nanovdb_convert --fp16` on the same file, in alternating runs; medians of wall and
CPU (user + system), each as a ratio to the first binary given.

    /usr/bin/python3 scripts/make_bench_volume.py bench-out/cloud_320.vdb --size 320
    /usr/bin/python3 scripts/bench_oneframe.py bench-out/cloud_320.vdb \\
        --old 0ebd86e=bench-out/target-0ebd86e/release/vdbcook --old ddb55cc=bench-out/vdbcook-ddb55cc --runs 9 [--formats f16,unorm8,bc7]

Every output goes to a scratch directory that is removed at the end.
"""

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import tempfile
import time


def run(cmd):
    """(wall s, user + system s) of one command."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.perf_counter() - t, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input")
    ap.add_argument("--exe", default="target/release/vdbcook", help="this binary")
    ap.add_argument("--old", action="append", default=[], metavar="NAME=PATH", help="an earlier binary (repeatable; the first is the ratios' base)")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--formats", default="f16,unorm8,bc7")
    args = ap.parse_args()
    exes = dict(o.split("=", 1) for o in args.old)
    exes["now"] = args.exe
    tmp = tempfile.mkdtemp(prefix="bench-oneframe-")
    try:
        print(f"{args.input}; {args.runs} alternating runs; load {os.getloadavg()[0]:.2f}")
        print("| format | binary | wall | CPU | wall / first |")
        print("|---|---|---:|---:|---:|")
        targets = []
        for fmt in args.formats.split(","):
            names = list(exes) + (["nanovdb_convert --fp16"] if fmt == "f16" else [])
            res = {k: [] for k in names}
            for r in range(args.runs):
                for k in names if r % 2 == 0 else names[::-1]:
                    if k.startswith("nanovdb"):
                        res[k].append(run(["nanovdb_convert", "--fp16", "-f", args.input, os.path.join(tmp, "one.nvdb")]))
                    else:
                        res[k].append(run([exes[k], "cook", args.input, "--format", fmt, "-o", os.path.join(tmp, "one.vpak"), "--force", "-q"]))
            wall = {k: statistics.median(x for x, _ in v) for k, v in res.items()}
            for k, v in res.items():
                c = statistics.median(y for _, y in v)
                print(f"| {fmt} | {k} | {wall[k]:.3f} s | {c:.3f} s | {wall[k] / wall[names[0]]:.3f} |", flush=True)
            if "nanovdb_convert --fp16" in wall:
                targets.append(f"{fmt}: this binary / nanovdb_convert --fp16 = {wall['now'] / wall['nanovdb_convert --fp16']:.3f} (target <= 0.7)")
        for t in targets:
            print(t)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
