#!/usr/bin/python3
"""Cook benchmarks, each against a peer or a reference on the same input, in one run.

    /usr/bin/python3 scripts/bench_cook.py [--runs R]

1. Tree size: `vdbcook cook --json` on the fixtures and on a 100-frame synthetic
   sequence (scripts/make_bench_sequence.py, cached in bench-out/); our node arrays
   against what the seed thesis's layout takes for the same frames (4100 B per L1,
   516 B per L2 with all 32768 allocated per frame, 68 B per L3 for every leaf).
2. Cook throughput: `vdbcook cook --format f16` against `nanovdb_convert --fp16` on the
   24M-voxel fog volume (scripts/make_bench_volume.py), R alternating runs each: best
   and median times, active voxels per second, and both ratios.
3. Peak memory (max RSS, /usr/bin/time): cooking the 100-frame sequence against cooking
   its largest single frame and against merely reading that frame (`inspect`).
Figures go to docs/benchmarks.md by hand, with the date and this command.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench-out")
EXE = os.path.join(ROOT, "target", "release", "vdbcook")


def cook(inputs, out, fmt="f16", extra=()):
    res = subprocess.run([EXE, "cook", "--json", "--force", "--format", fmt, "-o", out, *extra, *inputs], check=True, capture_output=True)
    return json.loads(res.stdout)


def max_rss_kb(cmd):
    res = subprocess.run(["/usr/bin/time", "-f", "%M", *cmd], check=True, capture_output=True, text=True)
    return int(res.stderr.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "vdbcook"], cwd=ROOT, check=True)
    seq = os.path.join(OUT, "seq100")
    if not os.path.exists(os.path.join(seq, "smoke_0100.vdb")):
        subprocess.run([sys.executable, os.path.join(ROOT, "scripts/make_bench_sequence.py"), seq], check=True)
    vol = os.path.join(OUT, "fog_300.vdb")
    if not os.path.exists(vol):
        subprocess.run([sys.executable, os.path.join(ROOT, "scripts/make_bench_volume.py"), vol], check=True)
    tmp = os.path.join(OUT, "bench.vpak")

    print("1. tree size (node arrays) against the thesis layout")
    print("   %-28s %6s %9s %12s %16s %9s" % ("input", "frames", "leaves", "ours (B)", "thesis (B)", "ratio"))
    for name, inputs in [
        ("fixtures/fog_blosc.vdb", [os.path.join(ROOT, "fixtures/fog_blosc.vdb")]),
        ("fixtures/tiles.vdb", [os.path.join(ROOT, "fixtures/tiles.vdb")]),
        ("fixtures/smoke_seq (4)", [os.path.join(ROOT, "fixtures/smoke_seq")]),
        ("bench-out/seq100 (100)", [seq]),
    ]:
        r = cook(inputs, tmp)
        print("   %-28s %6d %9d %12d %16d %8.0fx" % (name, r["frames"], r["bricks"], r["tree_bytes"], r["thesis_tree_bytes"], r["thesis_tree_bytes"] / r["tree_bytes"]))
    r = cook([seq], tmp)
    print("   seq100: %d leaves -> %d unique bricks -> %d stored; L1 %d, L2 %d, L3 %d; file %.1f MB, %.2f bits/active voxel"
          % (r["bricks"], r["unique_bricks"], r["stored_bricks"], r["l1_nodes"], r["l2_nodes"], r["l3_nodes"], r["file_bytes"] / 1e6, r["bits_per_active_voxel"]))

    print("2. cook throughput, f16, %s" % os.path.relpath(vol, ROOT))
    ours, theirs, n = [], [], 0
    nvdb = os.path.join(OUT, "bench.nvdb")
    for _ in range(args.runs):
        t0 = time.perf_counter()
        r = cook([vol], tmp, "f16")
        ours.append(time.perf_counter() - t0)
        n = r["active_voxels"]
        t0 = time.perf_counter()
        subprocess.run(["nanovdb_convert", "-f", "--fp16", vol, nvdb], check=True, capture_output=True)
        theirs.append(time.perf_counter() - t0)
    for name, t, out in [("vdbcook cook --format f16", ours, tmp), ("nanovdb_convert --fp16", theirs, nvdb)]:
        print("   %-27s best %.3f s, median %.3f s  %.1f M active voxels/s at best  (%.1f MB)" % (name, min(t), statistics.median(t), n / min(t) / 1e6, os.path.getsize(out) / 1e6))
    print("   ratio %.2fx best, %.2fx median (vdbcook / nanovdb_convert throughput, %d alternating runs)"
          % (min(theirs) / min(ours), statistics.median(theirs) / statistics.median(ours), args.runs))

    print("3. peak memory (max RSS)")
    frames = sorted(os.listdir(seq))
    biggest = max(frames, key=lambda f: os.path.getsize(os.path.join(seq, f)))
    one = os.path.join(seq, biggest)
    seq_out = os.path.join(OUT, "bench_seq.vpak")
    m_seq = max_rss_kb([EXE, "cook", "-q", "--force", "-o", seq_out, seq])
    m_one = max_rss_kb([EXE, "cook", "-q", "--force", "-o", tmp, one])
    m_read = max_rss_kb([EXE, "inspect", "-q", one])
    print("   read one frame (%s)      %7.1f MB" % (biggest, m_read / 1024))
    print("   cook that one frame              %7.1f MB" % (m_one / 1024))
    print("   cook all %d frames              %7.1f MB  (output %.1f MB)" % (len(frames), m_seq / 1024, os.path.getsize(seq_out) / 1e6))


if __name__ == "__main__":
    main()
