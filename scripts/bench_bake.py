#!/usr/bin/python3
"""`vdbcook bake` against the same work done by hand, in one run.

    /usr/bin/python3 scripts/bench_bake.py [--exe PATH] [--jobs N] [--views V] [--size WxH]

A manifest of 12 assets (10 from ../shared/vdb-samples, two generated fogs from
scripts/make_bench_volume.py, cached in bench-out/), every one validated with a gate.

1. Peer: each asset cooked by `vdbcook cook` and then validated by `vdbcook validate`,
   one after another (what a script without `bake` does). Wall time.
2. `vdbcook bake --jobs N` of the same manifest into an empty directory. Wall time, and
   the ratio bake / peer (target: <= 0.6 with --jobs 2). Steps 1 and 2 run --runs times
   in turns (alternating which goes first); the median ratio and the range are printed.
3. The same bake again with nothing changed: every asset must be `cached`; the ratio to
   the first bake (target: < 2 %).
4. One input changed (one byte appended to a copy of a sample): exactly one asset must
   be re-baked.
Figures go to docs/benchmarks.md by hand, with the date and this command.
"""

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench-out")
SAMPLES = os.path.normpath(os.path.join(ROOT, "..", "shared", "vdb-samples"))

# name, inputs (relative to the samples or bench-out), frames, format, extra settings
ASSETS = [
    ("arnold_smoke", ["arnold-usd/smoke.vdb"], None, "bc7", {}),
    ("c42_fluid", ["c42/fluid_data_0001.vdb"], None, "f16", {}),
    ("embergen_50", ["vfx-toolkit-embergen/embergen_fire_a_50.vdb"], None, "bc4", {}),
    ("pyro", ["bake/pyro.vdb"], None, "unorm8", {}),
    ("wavelet_seq", ["waveletturbulence/fluid_data_0###.vdb"], "150-153", "bc7", {}),
    ("embergen_seq", ["vfx-toolkit-embergen/embergen_fire_a_#.vdb"], "1-3", "f16", {}),
    ("elyg_test", ["elyg-visualizer/test.vdb"], None, "bc4", {}),
    ("vscode_smoke", ["vscode-cmaketemplate/smoke.vdb"], None, "f16", {}),
    ("tommy", ["elyg-visualizer/fogTommy.vdb"], None, "unorm8", {}),
    ("plasma", ["plasmadxr/fluid_data_0001.vdb"], None, "bc7", {}),
    ("fog_a", ["bake/fog_a.vdb"], None, "bc7", {}),
    ("fog_b", ["bake/fog_b.vdb"], None, "f16", {"clusters": 64}),
]


def path_of(rel):
    return os.path.join(OUT, rel[len("bake/"):]) if rel.startswith("bake/") else os.path.join(SAMPLES, rel)


def prepare():
    os.makedirs(OUT, exist_ok=True)
    for name, args in [("fog_a.vdb", ["--size", "120", "--seed", "1"]), ("fog_b.vdb", ["--size", "100", "--seed", "2"])]:
        p = os.path.join(OUT, name)
        if not os.path.exists(p):
            subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "scripts", "make_bench_volume.py"), p, *args], check=True, capture_output=True)
    # A copy of a sample that step 4 changes.
    shutil.copyfile(os.path.join(SAMPLES, "elyg-visualizer", "pyro.vdb"), os.path.join(OUT, "pyro.vdb"))


def manifest(views, size):
    lines = ["[defaults]", "validate = true", "max_rmse = 0.25", f"views = {views}", f'size = "{size}"', ""]
    for name, inputs, frames, fmt, extra in ASSETS:
        lines += ["[[asset]]", f'name = "{name}"', f'output = "{name}.vpak"', "inputs = [" + ", ".join(json.dumps(path_of(i)) for i in inputs) + "]", f'format = "{fmt}"']
        if frames:
            lines.append(f'frames = "{frames}"')
        lines += [f"{k} = {v}" for k, v in extra.items()]
        lines.append("")
    return "\n".join(lines)


CPU = [0.0]


def run(cmd):
    """Runs `cmd`; its wall seconds (its CPU seconds are added to CPU[0])."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    t = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    CPU[0] += (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return t, res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--exe", default=os.path.join(ROOT, "target", "release", "vdbcook"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--runs", type=int, default=3)
    a = ap.parse_args()
    prepare()
    work = os.path.join(OUT, "bake-run")
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    m = os.path.join(work, "bake.toml")
    with open(m, "w") as f:
        f.write(manifest(a.views, a.size))
    # Warm the page cache for both contenders (--plan reads every input to hash it).
    subprocess.run([a.exe, "bake", m, "--plan"], check=True, capture_output=True)

    def peer(seq):
        """Cook, then validate, one asset after another; seconds."""
        shutil.rmtree(seq, ignore_errors=True)
        os.makedirs(seq)
        total = 0.0
        for name, inputs, frames, fmt, extra in ASSETS:
            src = [path_of(i) for i in inputs]
            fr = ["--frames", frames] if frames else []
            out = os.path.join(seq, name + ".vpak")
            cook = [a.exe, "-q", "cook", *src, *fr, "--format", fmt, "-o", out]
            for k, v in extra.items():
                cook += ["--" + k.replace("_", "-"), str(v)]
            t, r = run(cook)
            if r.returncode != 0:
                sys.exit(f"cook {name} failed: {r.stderr}")
            total += t
            sf = ["--source-frames", frames] if frames else []
            t, r = run([a.exe, "-q", "validate", out, "--source", *src, *sf, "--views", str(a.views), "--size", a.size, "--max-rmse", "0.25"])
            if r.returncode != 0:
                sys.exit(f"validate {name} failed: {r.stderr}")
            total += t
        return total

    out_dir = os.path.join(work, "out")
    bake = [a.exe, "bake", m, "--json", "--jobs", str(a.jobs), "--out-dir", out_dir]

    def fresh_bake():
        shutil.rmtree(out_dir, ignore_errors=True)
        t, r = run(bake)
        if r.returncode != 0:
            sys.exit(f"bake failed ({r.returncode}): {r.stderr}")
        doc = json.loads(r.stdout)
        assert doc["summary"]["baked"] == len(ASSETS), doc["summary"]
        return t

    # 1, 2. Peer and bake in turns (the order alternates), on a machine whose load drifts.
    pairs = []
    cpus = []
    for k in range(a.runs):
        def timed(f):
            c0 = CPU[0]
            t = f()
            return t, CPU[0] - c0

        by_hand = os.path.join(work, "by-hand")
        if k % 2 == 0:
            tp, cpu_p = timed(lambda: peer(by_hand))
            tb, cpu_b = timed(fresh_bake)
        else:
            tb, cpu_b = timed(fresh_bake)
            tp, cpu_p = timed(lambda: peer(by_hand))
        pairs.append((tp, tb))
        cpus.append((cpu_p, cpu_b))
    ratios = sorted(tb / tp for tp, tb in pairs)
    t_peer = statistics.median(tp for tp, _ in pairs)
    t_bake = statistics.median(tb for _, tb in pairs)

    # 3. Nothing changed.
    t_again, r = run(bake)
    again = json.loads(r.stdout)
    cached = again["summary"]["cached"]

    # 4. One input changed.
    with open(os.path.join(OUT, "pyro.vdb"), "ab") as f:
        f.write(b"\0")
    t_one, r = run(bake)
    one = json.loads(r.stdout)
    rebaked = [x["name"] for x in one["assets"] if x["status"] != "cached"]

    print(f"assets: {len(ASSETS)} ({sum(len(x[1]) for x in ASSETS)} inputs), validate {a.views} views at {a.size}, exe {a.exe}")
    for k, ((tp, tb), (cp, cb)) in enumerate(zip(pairs, cpus)):
        print(f"run {k + 1}: peer {tp:.2f} s, bake {tb:.2f} s, ratio {tb / tp:.3f}; CPU time peer {cp:.2f} s, bake {cb:.2f} s, ratio {cb / cp:.3f}")
    cpu_ratios = sorted(cb / cp for cp, cb in cpus)
    print(f"CPU time (user + system) bake/peer: median {statistics.median(cpu_ratios):.3f}, range {cpu_ratios[0]:.3f}-{cpu_ratios[-1]:.3f}")
    print(f"peer: cook + validate one after another   {t_peer:8.2f} s (median of {a.runs})")
    print(f"bake --jobs {a.jobs}, empty output directory     {t_bake:8.2f} s (median)   ratio bake/peer: median {statistics.median(ratios):.3f}, range {ratios[0]:.3f}-{ratios[-1]:.3f}")
    print(f"bake again, nothing changed               {t_again:8.3f} s   ratio to first bake {t_again / t_bake * 100:.2f} %   cached {cached}/{len(ASSETS)}")
    print(f"bake after one input changed              {t_one:8.2f} s   re-baked {len(rebaked)}: {', '.join(rebaked)}")


if __name__ == "__main__":
    main()
