#!/usr/bin/python3
"""`vdbcook bake` against the same work done by hand, in one run.

    /usr/bin/python3 scripts/bench_bake.py [--exe PATH] [--jobs N] [--views V] [--size WxH]

A manifest of 12 assets (10 from ../shared/vdb-samples, two generated fogs from
scripts/make_bench_volume.py, cached in bench-out/), every one validated with a gate.

1. Peer: each asset cooked by `vdbcook cook` and then validated by `vdbcook validate`,
   one after another (what a script without `bake` does). Wall time.
2. `vdbcook bake --jobs N` of the same manifest into an empty directory. Wall time, and
   the ratio bake / peer (target: <= 0.6 with --jobs 2).
3. The same bake again with nothing changed: every asset must be `cached`; the ratio to
   the first bake (target: < 2 %).
4. One input changed (one byte appended to a copy of a sample): exactly one asset must
   be re-baked.
Figures go to docs/benchmarks.md by hand, with the date and this command.
"""

import argparse
import json
import os
import shutil
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
    ("blender_seq", ["csc415-blender/fluid_data_000#.vdb"], "1-2", "bc4", {}),
    ("vscode_smoke", ["vscode-cmaketemplate/smoke.vdb"], None, "f16", {}),
    ("tommy", ["elyg-visualizer/fogTommy.vdb"], None, "unorm8", {}),
    ("plasma", ["plasmadxr/fluid_data_0001.vdb"], None, "bc7", {}),
    ("fog_a", ["bake/fog_a.vdb"], None, "bc7", {}),
    ("fog_b", ["bake/fog_b.vdb"], None, "f16", {"clusters": 64}),
]


def path_of(rel):
    return os.path.join(OUT, rel[len("bake/"):]) if rel.startswith("bake/") else os.path.join(SAMPLES, rel)


def prepare():
    d = os.path.join(OUT, "bake")
    os.makedirs(d, exist_ok=True)
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


def run(cmd):
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    return time.perf_counter() - t0, res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--exe", default=os.path.join(ROOT, "target", "release", "vdbcook"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", default="256x256")
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

    # 1. The peer: cook, then validate, one asset after another.
    seq = os.path.join(work, "by-hand")
    os.makedirs(seq)
    t_peer = 0.0
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
        t_peer += t
        sf = ["--source-frames", frames] if frames else []
        t, r = run([a.exe, "-q", "validate", out, "--source", *src, *sf, "--views", str(a.views), "--size", a.size, "--max-rmse", "0.25"])
        if r.returncode != 0:
            sys.exit(f"validate {name} failed: {r.stderr}")
        t_peer += t

    # 2. The bake.
    bake = [a.exe, "bake", m, "--json", "--jobs", str(a.jobs), "--out-dir", os.path.join(work, "out")]
    t_bake, r = run(bake)
    if r.returncode != 0:
        sys.exit(f"bake failed ({r.returncode}): {r.stderr}")
    first = json.loads(r.stdout)
    assert first["summary"]["baked"] == len(ASSETS), first["summary"]

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
    print(f"peer: cook + validate one after another   {t_peer:8.2f} s")
    print(f"bake --jobs {a.jobs}, empty output directory     {t_bake:8.2f} s   ratio bake/peer {t_bake / t_peer:.3f}")
    print(f"bake again, nothing changed               {t_again:8.3f} s   ratio to first bake {t_again / t_bake * 100:.2f} %   cached {cached}/{len(ASSETS)}")
    print(f"bake after one input changed              {t_one:8.2f} s   re-baked {len(rebaked)}: {', '.join(rebaked)}")


if __name__ == "__main__":
    main()
