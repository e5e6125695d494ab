#!/usr/bin/python3
"""Time `zstd -d -T1 -c FILE > /dev/null` (the CLI): median of RUNS after a warm-up, on FILE
and on K copies of its frame concatenated (zstd decodes them one after another, the same
data), so that process start-up weighs little. Prints output MB/s."""
import os, subprocess, sys, time, statistics
zf, runs = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 7
out_size = int(subprocess.run(["zstd", "-d", "-T1", "-c", zf], capture_output=True, check=True).stdout.__len__())
frame = open(zf, "rb").read()
k = max(1, -(-200_000_000 // out_size))
big = zf + f".x{k}"
if not os.path.exists(big):
    open(big, "wb").write(frame * k)
for name, path, size in (("1 frame", zf, out_size), (f"{k} frames", big, out_size * k)):
    ts = []
    for r in range(runs + 1):
        with open(os.devnull, "wb") as dn:
            t0 = time.perf_counter()
            subprocess.run(["zstd", "-q", "-d", "-T1", "-c", path], stdout=dn, check=True)
            t = time.perf_counter() - t0
        if r:
            ts.append(t)
    m = statistics.median(ts)
    print(f"  zstd CLI -d -T1 ({name}, {size} B out): median {m*1e3:.2f} ms = {size/m/1e6:.1f} MB/s (runs: {' '.join(f'{t*1e3:.1f}' for t in ts)})")
