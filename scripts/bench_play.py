#!/usr/bin/python3
"""Streaming playback benchmark: `vdbcook play --headless` of a segmented,
supercompressed asset against the same frames from a one-segment, uncompressed
asset held resident, in one run (runs alternate; medians).

    /usr/bin/python3 scripts/bench_play.py [--bin target/release/vdbcook] [--frames 96]
        [--size 128] [--segment 24] [--format f16] [--runs 3] [--px 256]

Prints, per asset: frames per second sustained (median), peak GPU-resident bytes (the
player's own sum of its buffers and textures), bytes read, frames that waited for
their segment after the first segment, and the worst wait; then the ratios the issue
asks for: streamed fps / resident fps, and peak resident / (the two largest
consecutive segments' GPU bytes, from `inspect`). The sequence is written with
scripts/make_bench_sequence.py under bench-out/ (not committed).
"""

import argparse
import json
import os
import statistics
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(cmd):
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{' '.join(cmd)}: {p.stderr.strip()}")
    return p.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target/release/vdbcook"))
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--segment", type=int, default=24)
    ap.add_argument("--format", default="f16")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--px", type=int, default=256)
    a = ap.parse_args()
    out = os.path.join(ROOT, "bench-out", f"play_{a.frames}x{a.size}")
    seq = os.path.join(out, "seq")
    if not os.path.isdir(seq) or len(os.listdir(seq)) != a.frames:
        run(["/usr/bin/python3", os.path.join(ROOT, "scripts/make_bench_sequence.py"), seq, "--frames", str(a.frames), "--size", str(a.size)])
    streamed = os.path.join(out, f"streamed_{a.format}.vpak")
    resident = os.path.join(out, f"resident_{a.format}.vpak")
    run([a.bin, "cook", "-q", "--force", seq, "-o", streamed, "--format", a.format, "--segment-frames", str(a.segment), "--supercompress", "zstd"])
    run([a.bin, "cook", "-q", "--force", seq, "-o", resident, "--format", a.format])
    info = json.loads(run([a.bin, "inspect", "--json", streamed]))["files"][0]
    seg_gpu = [s["gpu_bytes"] for s in info["segments"]]
    two = max(seg_gpu[i] + seg_gpu[i + 1] for i in range(len(seg_gpu) - 1)) if len(seg_gpu) > 1 else seg_gpu[0]
    whole = json.loads(run([a.bin, "inspect", "--json", resident]))["files"][0]
    plays = {"streamed": [], "resident": []}
    for _ in range(a.runs):
        for name, path in (("streamed", streamed), ("resident", resident)):
            plays[name].append(json.loads(run([a.bin, "play", "--headless", "--json", path, "--size", f"{a.px}x{a.px}"])))
    print(f"# play --headless, {a.frames} frames of make_bench_sequence --size {a.size}, {a.format}, {a.px}x{a.px}, {a.runs} alternating runs each")
    print(f"# adapter: {plays['streamed'][0]['adapter']}")
    print(f"streamed: {len(seg_gpu)} segments of {a.segment} frames, supercompressed, {info['file_bytes']} bytes on disk, segments' GPU bytes {seg_gpu}")
    print(f"resident: 1 segment, {whole['file_bytes']} bytes on disk, {whole['gpu_bytes']} GPU bytes")
    fps = {}
    for name, runs in plays.items():
        fps[name] = statistics.median(r["summary"]["fps"] for r in runs)
        peak = max(r["summary"]["peak_resident_bytes"] for r in runs)
        waited = [sum(1 for f in r["frames"] if f["segment"] > 0 and f["wait_ms"] > 0.5) for r in runs]
        worst_wait = max(f["wait_ms"] for r in runs for f in r["frames"] if f["segment"] > 0) if len(seg_gpu) > 1 and name == "streamed" else 0.0
        read = runs[0]["summary"]["bytes_read"]
        each = ", ".join("%.1f" % r["summary"]["fps"] for r in runs)
        print(f"{name:9} fps {fps[name]:.1f} (runs {each}), peak resident {peak} bytes, read {read} bytes, "
              f"frames waiting after segment 0 per run {waited}, worst such wait {worst_wait:.1f} ms")
        if name == "streamed":
            print(f"          peak resident / two largest consecutive segments' GPU bytes = {peak / two:.3f}")
    print(f"streamed fps / resident fps = {fps['streamed'] / fps['resident']:.3f} (target >= 0.9)")


if __name__ == "__main__":
    main()
