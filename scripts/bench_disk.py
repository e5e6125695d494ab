#!/usr/bin/python3
"""Bytes on disk within an error bound: supercompressed assets against NanoVDB's zipped FpN.

    /usr/bin/python3 scripts/bench_disk.py [--no-build] [--quick] [--sizes | --timings] [--fog PATH]

One run, release binary (built first unless --no-build), inputs: the real samples of
../shared/vdb-samples with at least 10 k active voxels in the grid cooked, and a generated
256^3 fog (bench-out/fog_256.vdb, make_bench_volume.py --size 256). Per input and E in
(0.01, 0.001):
* NanoVDB: `nanovdb_convert -g GRID --fpN -a E -z`, file bytes;
* vdbcook: `cook --grid GRID --max-error E`, its file and the file through `zstd -19`,
  `cook ... --supercompress zstd` (default level), and with `--optimize disk` at the
  default level and at `zstd:19`; every voxel of the last is checked within E (`unpack`,
  then `vdbcook diff`); ratios to NanoVDB's bytes and to the source .vdb's.
Then `--format bc7` with and without `--supercompress zstd` against the asset's own
`zstd -19`; the cook time with and without `--supercompress` (and `--optimize disk`;
median of 3, alternating); and the restore throughput on one core
(crates/vpak/examples/restore.rs: decompress or context-decode and unfilter every
supercompressed section, a wrapped body's frame first, each segment into the memory of the
one before as the runtime's reader does, and into fresh memory) against `zstd -d -T1` on
the same sections as zstd frames (a wrapped body's frame and the frames inside it; a
context-coded one as the zstd frame of its filtered bytes at level 19), repeated
to about 100 MB for zstd; five alternating rounds, the median of their ratios: for four
fog assets, and for every `--optimize disk` asset the size tables made in the same run.
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench-out", "disk")
TARGET = os.environ.get("CARGO_TARGET_DIR") or os.path.join(ROOT, "target")
EXE = os.path.join(TARGET, "release", "vdbcook")
RESTORE = os.path.join(TARGET, "release", "examples", "restore")
SAMPLES = os.path.join(ROOT, "..", "shared", "vdb-samples")
FOG = os.path.join(ROOT, "bench-out", "fog_256.vdb")

# (name, path, grid): fog grids of the shared samples with >= 10 k active voxels, and the generated fog.
INPUTS = [
    ("arnold smoke", os.path.join(SAMPLES, "arnold-usd/smoke.vdb"), "density"),
    ("houdini pyro", os.path.join(SAMPLES, "elyg-visualizer/pyro.vdb"), "density"),
    ("blender smoke", os.path.join(SAMPLES, "waveletturbulence/fluid_data_0153.vdb"), "density"),
    ("embergen flames", os.path.join(SAMPLES, "vfx-toolkit-embergen/embergen_fire_a_50.vdb"), "flames"),
    ("embergen temperature", os.path.join(SAMPLES, "vfx-toolkit-embergen/embergen_fire_a_50.vdb"), "temperature"),
    ("double smoke", os.path.join(SAMPLES, "vscode-cmaketemplate/smoke.vdb"), "density"),
    ("level set sphere", os.path.join(SAMPLES, "mjurczyk-openvdb/sphere.vdb"), "ls_sphere"),
    ("generated fog 256", FOG, "density"),
]
ERRORS = [0.01, 0.001]


def run(cmd, env=None):
    return subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout


def size(p):
    return os.path.getsize(p)


def cook(src, grid, out, flags):
    t = time.perf_counter()
    run([EXE, "cook", "-q", "--force", "--grid", grid, "-o", out, src] + flags)
    return time.perf_counter() - t


def zstd19(path):
    out = path + ".zst"
    run(["zstd", "-19", "-q", "-f", "-T1", path, "-o", out])
    return size(out)


def max_error(asset, src, grid):
    back = asset + ".vdb"
    run([EXE, "unpack", "-q", "--force", asset, "--frame", "0", "-o", back])
    d = json.loads(run([EXE, "diff", "--json", "--grid", grid, src, back]))
    return d["max_error"], d["inactive_in_b"]


def geomean(xs):
    return math.exp(sum(math.log(x) for x in xs) / len(xs)) if xs else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--no-build", action="store_true")
    ap.add_argument("--quick", action="store_true", help="the first three inputs only")
    ap.add_argument("--sizes", action="store_true", help="the size tables only (no timings)")
    ap.add_argument("--timings", action="store_true", help="the timing tables only (no sizes)")
    ap.add_argument("--fog", default=FOG, help="the generated 256^3 fog (default bench-out/fog_256.vdb, made if missing)")
    a = ap.parse_args()
    fog = a.fog
    if not a.no_build:
        subprocess.run(["cargo", "build", "--release", "-q"], cwd=ROOT, check=True)
        subprocess.run(["cargo", "build", "--release", "-q", "-p", "vdbcook-vpak", "--example", "restore"], cwd=ROOT, check=True)
    os.makedirs(OUT, exist_ok=True)
    if not os.path.exists(fog):
        run(["/usr/bin/python3", os.path.join(ROOT, "scripts/make_bench_volume.py"), fog, "--size", "256"])
    inputs = [(n, fog if p == FOG else p, g) for n, p, g in INPUTS]
    inputs = [i for i in inputs if os.path.exists(i[1])][: 3 if a.quick else None]
    disk = sizes(inputs) if not a.timings else []
    if not a.sizes:
        timings(inputs, fog, disk)


def sizes(inputs):
    """Prints the size tables; returns (name, E, path) of each `--optimize disk` asset made."""
    disk = []
    print("## Bytes within E: supercompressed asset / NanoVDB `--fpN -a E -z`\n")
    print("| input | E | source | nanovdb -z | asset | asset·zstd-19 | zstd | zstd disk | zstd:19 disk | zstd / nano | zstd disk / nano | zstd:19 disk / nano | source / zstd:19 disk | max error |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    ratios = {e: [] for e in ERRORS}
    ratios19 = {e: [] for e in ERRORS}
    for k, (name, src, grid) in enumerate(inputs):
        for e in ERRORS:
            stem = os.path.join(OUT, "%d_%g" % (k, e))
            nv = stem + ".nvdb"
            run(["nanovdb_convert", "-f", "-g", grid, "--fpN", "-a", repr(e), "-z", src, nv])
            plain, z, zd, z19 = (stem + x for x in (".vpak", "_z.vpak", "_zd.vpak", "_z19.vpak"))
            cook(src, grid, plain, ["--max-error", repr(e)])
            cook(src, grid, z, ["--max-error", repr(e), "--supercompress", "zstd"])
            cook(src, grid, zd, ["--max-error", repr(e), "--supercompress", "zstd", "--optimize", "disk"])
            cook(src, grid, z19, ["--max-error", repr(e), "--supercompress", "zstd:19", "--optimize", "disk"])
            disk.append((name, e, zd))
            err, missing = max_error(z19, src, grid)
            assert err <= e and missing == 0, (name, e, err, missing)
            r, r19 = size(zd) / size(nv), size(z19) / size(nv)
            ratios[e].append(r)
            ratios19[e].append(r19)
            print("| %s | %g | %d | %d | %d | %d | %d | %d | %d | %.3f | %.3f | %.3f | %.1f | %.2e |" % (
                name, e, size(src), size(nv), size(plain), zstd19(plain), size(z), size(zd), size(z19), size(z) / size(nv), r, r19, size(src) / size(z19), err))
            sys.stdout.flush()
    for e in ERRORS:
        print("\nE = %g: zstd disk / nano geometric mean %.3f, largest %.3f; zstd:19 disk / nano geometric mean %.3f, largest %.3f"
              % (e, geomean(ratios[e]), max(ratios[e]), geomean(ratios19[e]), max(ratios19[e])))

    print("\n## bc7: supercompressed against the asset's own `zstd -19`\n")
    print("| input | bc7 | bc7·zstd-19 | bc7 zstd | bc7 zstd:19 | zstd:19 / bc7·zstd-19 | source / bc7 zstd:19 |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for k, (name, src, grid) in enumerate(inputs):
        stem = os.path.join(OUT, "%d_bc7" % k)
        cook(src, grid, stem + ".vpak", ["--format", "bc7"])
        cook(src, grid, stem + "_z.vpak", ["--format", "bc7", "--supercompress", "zstd"])
        cook(src, grid, stem + "_z19.vpak", ["--format", "bc7", "--supercompress", "zstd:19"])
        zz = zstd19(stem + ".vpak")
        print("| %s | %d | %d | %d | %d | %.3f | %.1f |" % (name, size(stem + ".vpak"), zz, size(stem + "_z.vpak"), size(stem + "_z19.vpak"),
                                                     size(stem + "_z19.vpak") / zz, size(src) / size(stem + "_z19.vpak")))
        sys.stdout.flush()
    return disk


def timings(inputs, fog, disk):
    print("\n## Cook time with and without --supercompress (median of 3, alternating)\n")
    print("| input | flags | plain | zstd | ratio |")
    print("|---|---|---:|---:|---:|")
    for name, src, grid in [i for i in inputs if i[1] == fog] or inputs[-1:]:
        # (flags, what --supercompress adds): --optimize disk context-codes atlases too.
        for flags, extra in ((["--max-error", "0.01"], []), (["--max-error", "0.01"], ["--optimize", "disk"]), (["--format", "f16"], []), (["--format", "bc7"], [])):
            plain, coded = [], []
            for _ in range(3):
                plain.append(cook(src, grid, os.path.join(OUT, "t.vpak"), flags))
                coded.append(cook(src, grid, os.path.join(OUT, "tz.vpak"), flags + ["--supercompress", "zstd"] + extra))
            p, c = statistics.median(plain), statistics.median(coded)
            print("| %s | %s | %.2f s | %.2f s | %.2f |" % (name, " ".join(flags + extra), p, c, c / p))
            sys.stdout.flush()

    print("\n## Restoring on one core against `zstd -d -T1` on the same frames\n")
    print("| asset | restored MB | restore MB/s | zstd -d MB/s | ratio | restore MB/s, fresh memory | ratio, fresh memory |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for flags in (["--max-error", "0.01"], ["--max-error", "0.01", "--optimize", "disk"], ["--format", "f16"], ["--format", "bc7"]):
        asset = os.path.join(OUT, "r.vpak")
        cook(fog, "density", asset, flags + ["--supercompress", "zstd"])
        restore_row("fog 256 " + " ".join(flags), asset)

    # Every `--optimize disk` asset the size tables made in this run.
    if disk:
        print("\n## Restoring every `zstd disk` asset of the size table\n")
        print("| asset | restored MB | restore MB/s | zstd -d MB/s | ratio | restore MB/s, fresh memory | ratio, fresh memory |")
        print("|---|---:|---:|---:|---:|---:|---:|")
        for name, e, asset in disk:
            restore_row("%s, %g, zstd disk" % (name, e), asset)


def restore_row(label, asset, rounds=5):
    """One row of a restore table: `asset` restored on one core against `zstd -d -T1`
    on its supercompressed sections as zstd frames, repeated to about 100 MB so that
    zstd's start-up does not count. Rounds alternate (the restore's best of its three
    passes, each restoring the asset again until about 100 MB are restored, then the best
    of three runs of zstd), so that a busy spell weighs on both; the median of the
    rounds' ratios."""
    env = dict(os.environ, RAYON_NUM_THREADS="1")
    frames = os.path.join(OUT, "r.frames.zst")
    rows = []
    for _ in range(rounds):
        got = json.loads(run([RESTORE, asset, frames], env=env))
        if got["restored_bytes"] == 0:
            print("| %s | no supercompressed section | | | | | |" % label)
            os.remove(frames)
            return
        mb = got["restored_bytes"] / 1e6
        reps = max(1, int(100e6 / max(1, got["restored_bytes"])))
        with open(frames, "rb") as f:
            data = f.read()
        with open(frames + ".rep", "wb") as f:
            f.write(data * reps)
        best = float("inf")
        for _ in range(3):
            t = time.perf_counter()
            subprocess.run(["zstd", "-d", "-T1", "-q", "-c", frames + ".rep"], check=True, stdout=subprocess.DEVNULL)
            best = min(best, (time.perf_counter() - t) / reps)
        rows.append((mb / got["seconds"], mb / best, mb / got["seconds_fresh"]))
    for f in (frames, frames + ".rep"):
        os.remove(f)
    ours, theirs, fresh = (statistics.median(r[i] for r in rows) for i in range(3))
    ratio, ratio_fresh = statistics.median(r[0] / r[1] for r in rows), statistics.median(r[2] / r[1] for r in rows)
    print("| %s | %.1f | %.0f | %.0f | %.2f | %.0f | %.2f |" % (label, mb, ours, theirs, ratio, fresh, ratio_fresh))
    sys.stdout.flush()

if __name__ == "__main__":
    main()
