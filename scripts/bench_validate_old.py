#!/usr/bin/python3
"""validate's speed against the last binary before format v3 (issue 21), in one run.

    /usr/bin/python3 scripts/bench_validate_old.py [--runs R] [--size N]
        [--old-worktree DIR] [--old-target DIR] [--new-exe PATH] [--also NAME=EXE ...]

* old: commit 0ebd86e (the last before multi-channel assets), checked out in a git
  worktree (default bench-out/old-0ebd86e) and built with `cargo build --release` into
  its own target directory (default bench-out/target-0ebd86e); both are reused when
  there (the build takes about 10 minutes on 2 cores);
* new: this tree's release build (`cargo build --release`, CARGO_TARGET_DIR honoured),
  or --new-exe;
* input: bench-out/cloud_N.vdb (default N = 192), a generated N^3 smoke-like cloud
  (scripts/make_bench_volume.py --size N), made when missing;
* each binary cooks it in bc7 (each its own asset format), then runs
  `validate ASSET --source CLOUD --views 8 --size 512x512` once untimed (Mesa keeps the
  compiled shaders in its disk cache: the timed runs do not compile), then R times
  (default 3), the two binaries alternating;
* --also NAME=EXE (repeatable): another binary of this tree's format (e.g. an earlier
  build of main), timed in the same alternation on the new binary's asset, so a change
  and its base are measured against 0ebd86e in one run;
* prints every time (wall clock, and CPU time of every thread: the GPU here is Mesa's
  lavapipe, on the CPU) with the machine's load average after it, the medians and their ratios to old (target for new: at most
  1.05).
The machine's other work disturbs single runs: compare the medians, and run again when
the ratio looks off.
"""

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench-out")
OLD_COMMIT = "0ebd86e"


def run(cmd, **kw):
    return subprocess.run(cmd, check=True, **kw)


def old_binary(worktree, target):
    exe = os.path.join(target, "release", "vdbcook")
    if not os.path.isdir(worktree):
        run(["git", "-C", ROOT, "worktree", "add", "--detach", worktree, OLD_COMMIT])
    head = run(["git", "-C", worktree, "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    want = run(["git", "-C", ROOT, "rev-parse", OLD_COMMIT + "^{commit}"], capture_output=True, text=True).stdout.strip()
    if head != want:
        sys.exit("%s is at %s, not %s: remove it or pass another --old-worktree" % (worktree, head[:12], OLD_COMMIT))
    if not os.path.exists(exe):
        print("building %s in %s (about 10 minutes on 2 cores)" % (OLD_COMMIT, worktree), file=sys.stderr)
        run(["cargo", "build", "--release", "-q"], cwd=worktree, env=dict(os.environ, CARGO_TARGET_DIR=target))
    return exe


def new_binary():
    target = os.environ.get("CARGO_TARGET_DIR") or os.path.join(ROOT, "target")
    run(["cargo", "build", "--release", "-q"], cwd=ROOT)
    return os.path.join(target, "release", "vdbcook")


def validate(exe, asset, cloud):
    """Wall and CPU seconds (user + system, every thread) of one validate, and its text."""
    cmd = [exe, "validate", asset, "--source", cloud, "--views", "8", "--size", "512x512"]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = run(cmd, capture_output=True, text=True).stdout
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (wall, r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime), out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--size", type=int, default=192, help="edge of the generated cloud (default 192)")
    ap.add_argument("--old-worktree", default=os.path.join(OUT, "old-" + OLD_COMMIT))
    ap.add_argument("--old-target", default=os.path.join(OUT, "target-" + OLD_COMMIT))
    ap.add_argument("--new-exe", help="the new vdbcook binary (default: build this tree)")
    ap.add_argument("--also", action="append", default=[], metavar="NAME=EXE", help="another binary of this tree's format, timed in the same alternation")
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    old = old_binary(os.path.abspath(args.old_worktree), os.path.abspath(args.old_target))
    new = args.new_exe or new_binary()
    cloud = os.path.join(OUT, "cloud_%d.vdb" % args.size)
    if not os.path.exists(cloud):
        run(["/usr/bin/python3", os.path.join(ROOT, "scripts", "make_bench_volume.py"), cloud, "--size", str(args.size)])
    assets = {}
    for name, exe in (("old", old), ("new", new)):
        assets[name] = os.path.join(OUT, "cloud_%d_%s_bc7.vpak" % (args.size, name))
        run([exe, "cook", "-q", "--force", "--format", "bc7", "-o", assets[name], cloud])
    exes = {"old": old, "new": new}
    for spec in args.also:
        name, sep, exe = spec.partition("=")
        if not sep or not name or name in exes:
            sys.exit("--also %s: expected NAME=EXE with a NAME other than old, new and the others" % spec)
        exes[name] = os.path.abspath(exe)
        assets[name] = assets["new"]
    names = list(exes)
    # Untimed: fills Mesa's shader cache, so no timed run compiles shaders.
    for name in names:
        _, out = validate(exes[name], assets[name], cloud)
        print("%s (%s):\n%s" % (name, exes[name], out.rstrip()))
    times = {n: [] for n in names}
    for i in range(args.runs):
        for name in names:
            (wall, cpu), _ = validate(exes[name], assets[name], cloud)
            times[name].append((wall, cpu))
            print("run %d %s: %.2f s (CPU %.2f s) load %.2f" % (i + 1, name, wall, cpu, os.getloadavg()[0]), flush=True)
    print("validate --views 8 --size 512x512 of a bc7 cook of %s (median of %d, alternating):" % (os.path.relpath(cloud, ROOT), args.runs))
    for k, what in ((0, "wall"), (1, "CPU")):
        med = {n: statistics.median(t[k] for t in times[n]) for n in names}
        print("  %-4s old (%s): %.2f s   new: %.2f s   ratio new/old: %.3f" % (what, OLD_COMMIT, med["old"], med["new"], med["new"] / med["old"]))
        for n in names[2:]:
            print("  %-4s %s: %.2f s   ratio %s/old: %.3f" % (what, n, med[n], n, med[n] / med["old"]))


if __name__ == "__main__":
    main()
