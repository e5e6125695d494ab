#!/usr/bin/python3
"""Levels of detail (issue 14): what levels 1-3 cost in bytes and time, and how their
values differ from OpenVDB's `vdb_lod`, all measured in one run.

    /usr/bin/python3 scripts/bench_lod.py [--quick]

1. Bytes. For each input (real samples from ../shared/vdb-samples and a generated
   256^3 fog, scripts/make_bench_volume.py --size 256) and format (f16, bc7):
   `cook --lods 4` against `cook --lods 1` in the same format; the ratio is
   (bytes with levels 1-3 - bytes without) / bytes without, the target <= 0.2; 'L1 part':
   how much of that fraction is L1 nodes (each of 4^3 to 32^3 slots, as many as its tree
   needs: 20 bytes to 6152 bytes, one per frame and level); 'bricks': the distinct bricks
   levels 1-3 add over level 0's (after deduplication), a floor for any layout that stores
   one 8^3 brick per leaf. Also the bytes each level needs on its own
   (`inspect --json`, levels[k].bytes) over level 0's.
2. Time, on the 256^3 fog, best of 3, interleaved: `vdb_lod in.vdb out.vdb -range 1-3`
   (wall: read, filter, write) against vdbcook's `levels` stage (filtering levels 1-3
   and building their trees, from `cook --json`'s timings) and against the whole extra
   cost of a cook with levels (wall of `cook --lods 4` - wall of `cook --lods 1`, same
   format: levels, their encoding, nodes and writing). Target: levels <= 1/2 vdb_lod.
3. Values, on the 256^3 fog and a real smoke: our levels (`cook --format f32 --lods 4`,
   `unpack --lod k`, read by OpenVDB) against vdb_lod's. vdb_lod uses full weighting
   (vertex-centred [1,2,1]/4 per axis, level-k voxel i at source index 2^k i, activity
   dilated by one voxel), we use the box mean of docs/format.md "Levels" (voxel i at
   2^k i + (2^k-1)/2). So the script measures: (a) ours against vdb_lod voxel by voxel
   at the same index, and after resampling ours (trilinear) at vdb_lod's voxel centres,
   relative RMS over the voxels where either is non-zero (both fogs have background 0); (b) a numpy port of full weighting against
   vdb_lod (the filter explains the difference when this is ~0); (c) ours against the
   numpy box mean (0: ours is the box mean); (d) the integral (sum x 8^k) of the source,
   ours and vdb_lod's.
4. A byte budget (`cook --lods 4 --max-bytes B`), f16, B = half the full asset's bytes:
   the levels kept, the asset's bytes, and the wall time against the same cook without
   a budget (each try cooks the asset again without one more of the finest levels).
--quick: fewer inputs, one timing round.
"""

import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import system_python  # noqa: F401,E402  (re-runs under /usr/bin/python3 when needed)
import numpy as np  # noqa: E402
import pyopenvdb as vdb  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench-out", "lod")
EXE = os.path.join(ROOT, "target", "release", "vdbcook")
SAMPLES = os.path.join(ROOT, "..", "shared", "vdb-samples")
FOG = os.path.join(OUT, "fog_256.vdb")


def sample(p):
    return os.path.join(SAMPLES, p)


# (label, inputs, cook flags)
INPUTS = [
    ("fog_256 (generated)", [FOG], []),
    ("arnold-usd/smoke", [sample("arnold-usd/smoke.vdb")], []),
    ("elyg/pyro", [sample("elyg-visualizer/pyro.vdb")], []),
    ("elyg/test (affine, tiles)", [sample("elyg-visualizer/test.vdb")], []),
    ("vscode/smoke (double, dense)", [sample("vscode-cmaketemplate/smoke.vdb")], []),
    ("embergen fire 50 (2 grids)", [sample("vfx-toolkit-embergen/embergen_fire_a_50.vdb")], ["--grids", "all"]),
    ("waveletturbulence x4 (4 grids)", [sample("waveletturbulence/fluid_data_015%d.vdb" % k) for k in range(4)], ["--grids", "density,temperature,flame,shadow"]),
    ("mjurczyk/sphere (level set)", [sample("mjurczyk-openvdb/sphere.vdb")], ["--grid", "ls_sphere"]),
    ("hsim/writer (tiles)", [sample("hsim/writer.vdb")], []),
]


def run(cmd):
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def cook(inputs, flags, fmt, lods, out):
    """(file bytes, the cook's JSON report, wall seconds)."""
    t0 = time.perf_counter()
    rep = json.loads(run([EXE, "cook", "--json", "--force", "-o", out, "--format", fmt, "--lods", str(lods), *flags, *inputs]))
    return os.path.getsize(out), rep, time.perf_counter() - t0


def sizes(quick):
    print("\n== 1. Bytes: levels 1-3 against level 0 alone, in the same format (target <= 0.200)")
    print("  %-32s %-5s %12s %12s %8s %8s %8s   %s" % ("input", "fmt", "lods 1 B", "lods 4 B", "added", "L1 part", "bricks", "each level alone / level 0 alone (inspect)"))
    worst = 0.0
    for label, inputs, flags in INPUTS[: 4 if quick else None]:
        if not all(os.path.exists(p) for p in inputs):
            print("  %-32s missing, skipped" % label)
            continue
        for fmt in ["f16", "bc7"]:
            a, b = os.path.join(OUT, "s1.vpak"), os.path.join(OUT, "s4.vpak")
            b1, r1, _ = cook(inputs, flags, fmt, 1, a)
            b4, r4, _ = cook(inputs, flags, fmt, 4, b)
            # The part of the added bytes that is L1 nodes (their section's growth).
            l1_bytes = lambda r: sum(x["bytes"] for x in r["sections"] if x["name"] == "l1 nodes")
            l1_part = (l1_bytes(r4) - l1_bytes(r1)) / b1
            lv = json.loads(run([EXE, "inspect", "--json", b]))["files"][0]["levels"]
            alone = " ".join("L%d %.3f" % (x["level"], x["bytes"] / lv[0]["bytes"]) for x in lv[1:])
            added = (b4 - b1) / b1
            worst = max(worst, added)
            # Distinct bricks levels 1-3 add over level 0's (after deduplication): what any
            # format of one 8^3 brick per leaf pays at least, whatever its nodes cost.
            bricks = (r4["stored_bricks"] - r1["stored_bricks"]) / max(1, r1["stored_bricks"])
            print("  %-32s %-5s %12d %12d %8.3f %8.3f %8.3f   %s" % (label, fmt, b1, b4, added, l1_part, bricks, alone))
    print("  largest added fraction: %.3f (target 0.200)" % worst)


def budget(quick):
    print("\n== 4. A byte budget: cook --lods 4 --max-bytes B, f16, B = half the full asset")
    print("  %-32s %12s %12s %12s %6s %9s %9s %6s" % ("input", "full B", "budget B", "asset B", "kept", "full s", "budget s", "ratio"))
    for label, inputs, flags in INPUTS[: 4 if quick else None]:
        if not all(os.path.exists(p) for p in inputs):
            continue
        out = os.path.join(OUT, "b.vpak")
        full, _, w_full = cook(inputs, flags, "f16", 4, out)
        cap = full // 2
        t0 = time.perf_counter()
        rep = json.loads(run([EXE, "cook", "--json", "--force", "-o", out, "--format", "f16", "--lods", "4", "--max-bytes", str(cap), *flags, *inputs]))
        w_cap = time.perf_counter() - t0
        kept = "%d-3" % rep["first_level"]
        print("  %-32s %12d %12d %12d %6s %9.3f %9.3f %6.2f" % (label, full, cap, rep["file_bytes"], kept, w_full, w_cap, w_cap / w_full))


def timing(quick):
    print("\n== 2. Time on fog_256: building levels 1-3, best of %d, interleaved" % (1 if quick else 3))
    rounds = 1 if quick else 3
    lod_out = os.path.join(OUT, "vdb_lod_out.vdb")
    best = {"vdb_lod": 1e9, "levels": 1e9, "cook1": 1e9, "cook4": 1e9}
    for _ in range(rounds):
        t0 = time.perf_counter()
        run(["vdb_lod", FOG, lod_out, "-range", "1-3"])
        best["vdb_lod"] = min(best["vdb_lod"], time.perf_counter() - t0)
        _, _, w1 = cook([FOG], [], "f16", 1, os.path.join(OUT, "t1.vpak"))
        _, rep, w4 = cook([FOG], [], "f16", 4, os.path.join(OUT, "t4.vpak"))
        best["cook1"] = min(best["cook1"], w1)
        best["cook4"] = min(best["cook4"], w4)
        best["levels"] = min(best["levels"], rep["timings"]["levels"])
    extra = best["cook4"] - best["cook1"]
    print("  vdb_lod -range 1-3 (wall: read, filter, write)   %7.3f s" % best["vdb_lod"])
    print("  vdbcook levels stage (filter + trees of 1-3)     %7.3f s   ratio to vdb_lod %.3f (target <= 0.5)" % (best["levels"], best["levels"] / best["vdb_lod"]))
    print("  vdbcook cook --lods 4 - cook --lods 1 (f16 wall) %7.3f s   ratio to vdb_lod %.3f  (cook --lods 1: %.3f s)" % (extra, extra / best["vdb_lod"], best["cook1"]))
    print("  threads: vdbcook uses every core (%d here); vdb_lod too (OpenVDB/TBB)" % os.cpu_count())


def dense(grid, shape, origin):
    """A grid's values over the box [origin, origin + shape) (OpenVDB's copyToArray)."""
    a = np.zeros(shape, np.float32)
    grid.copyToArray(a, ijk=tuple(int(v) for v in origin))
    return a.astype(np.float64)


def full_weighting(a):
    """vdb_lod's restriction: coarse i from fine 2i-1, 2i, 2i+1 with weights 1/4, 1/2, 1/4 per axis (zero outside)."""
    p = np.pad(a, ((1, 2),) * 3)
    for ax in range(3):
        p = np.moveaxis(p, ax, 0)
        m = (p.shape[0] - 1) // 2
        p = (p[0:2 * m:2] + 2 * p[1:2 * m + 1:2] + p[2:2 * m + 2:2]) / 4
        p = np.moveaxis(p, 0, ax)
    return p


def box(a, bg=0.0):
    s = [n // 2 for n in a.shape]
    return a[: 2 * s[0], : 2 * s[1], : 2 * s[2]].reshape(s[0], 2, s[1], 2, s[2], 2).mean(axis=(1, 3, 5)).astype(np.float32).astype(np.float64)


def shift_to_vertex_centres(b, k):
    """Our level-k values (voxel j at fine 2^k j + (2^k-1)/2) trilinearly at fine 2^k i: j = i - s, s = (2^k-1)/2^(k+1)."""
    s = (2 ** k - 1) / 2 ** (k + 1)
    out = np.pad(b, ((1, 0),) * 3)
    for ax in range(3):
        out = np.moveaxis(out, ax, 0)
        out = (1 - s) * out[1:] + s * out[:-1]
        out = np.pad(out, ((1, 0), (0, 0), (0, 0)))
        out = np.moveaxis(out, 0, ax)
    return out[1:, 1:, 1:]


def values(label, src, grid):
    print("\n-- %s (%s)" % (label, os.path.relpath(src, ROOT)))
    asset = os.path.join(OUT, "v.vpak")
    lod_out = os.path.join(OUT, "v_lod.vdb")
    run([EXE, "cook", "-q", "--force", "-o", asset, "--format", "f32", "--lods", "4", "--grid", grid, src])
    run(["vdb_lod", src, lod_out, "-range", "1-3", "-name", grid])
    g0 = vdb.read(src, grid)
    (lo, hi) = g0.evalActiveVoxelBoundingBox()
    # Work in a box from a multiple of 16 (so every level's voxels are whole), one voxel of margin for vdb_lod's dilation.
    o = np.array([(v // 16) * 16 - 16 for v in lo])
    shape = tuple(int(n) for n in ((np.array(hi) - o + 32) // 16 * 16))
    d = dense(g0, shape, o)
    theirs = {g.name: g for g in vdb.readAll(lod_out)[0]}
    fw, bx = d, d
    print("  %-3s %10s %10s %10s %10s %10s   %s" % ("lvl", "same idx", "resampled", "FW port", "ours-box", "max value", "integral x 8^k: source / ours / vdb_lod"))
    for k in (1, 2, 3):
        fw, bx = full_weighting(fw), box(bx)
        ok = o >> k
        sh = tuple(int(n) >> k for n in shape)
        unpacked = os.path.join(OUT, "v_%d.vdb" % k)
        run([EXE, "unpack", "-q", "--force", asset, "--frame", "0", "--lod", str(k), "-o", unpacked])
        ours = dense(vdb.read(unpacked, grid), sh, ok)
        th = dense(theirs["%s_level_%d" % (grid, k)], sh, ok)
        # Fog with background 0: compare where either level holds something.
        tm = (th != 0) | (ours != 0)
        n = min(fw.shape[0], sh[0]), min(fw.shape[1], sh[1]), min(fw.shape[2], sh[2])
        fwc = np.zeros(sh)
        fwc[: n[0], : n[1], : n[2]] = fw[: n[0], : n[1], : n[2]]
        rms = np.sqrt(np.mean(th[tm] ** 2))
        same = np.sqrt(np.mean((ours - th)[tm] ** 2)) / rms
        res = np.sqrt(np.mean((shift_to_vertex_centres(ours, k) - th)[tm] ** 2)) / rms
        fw_err = np.max(np.abs(fwc - th)[tm])
        box_err = np.max(np.abs(ours - bx[: sh[0], : sh[1], : sh[2]]))
        print("  %-3d %9.1f%% %9.1f%% %10.2g %10.2g %10.4g   %.6g / %.6g / %.6g" % (k, 100 * same, 100 * res, fw_err, box_err, th.max(), d.sum(), ours.sum() * 8 ** k, th.sum() * 8 ** k))


def main():
    quick = "--quick" in sys.argv
    os.makedirs(OUT, exist_ok=True)
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "vdbcook"], cwd=ROOT, check=True)
    if not os.path.exists(FOG):
        run([sys.executable, os.path.join(ROOT, "scripts", "make_bench_volume.py"), FOG, "--size", "256"])
    print("vdbcook levels of detail; %s" % run([EXE, "--version"]).strip())
    print("fog_256: %s" % run(["vdb_print", FOG]).strip().splitlines()[-1])
    sizes(quick)
    budget(quick)
    timing(quick)
    print("\n== 3. Values against vdb_lod (relative RMS where either is non-zero; 'same idx': ours and vdb_lod's")
    print("   voxel i compared directly; 'resampled': ours trilinearly at vdb_lod's centres; 'FW port': max |numpy full")
    print("   weighting - vdb_lod|; 'ours-box': max |ours - numpy box mean|)")
    values("fog_256", FOG, "density")
    if not quick:
        values("arnold-usd/smoke", sample("arnold-usd/smoke.vdb"), "density")


if __name__ == "__main__":
    main()
