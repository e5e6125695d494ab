#!/usr/bin/python3
"""Production sequences (issue 23): memory, time and bytes of whole-sequence cooks, one
segment against segments, parts on two pinned cores against one (in every format), and
nanovdb_convert --fp16 on the same files in the same run. Prints a table with the ratios.

    /usr/bin/python3 scripts/make_bench_sequence.py bench-out/seq224 --frames 96 --size 224
    /usr/bin/python3 scripts/bench_segments.py bench-out/seq224 [--segment 24] [--formats f16,bc7,max-error:0.01,clusters:64] [--spill-above 512MiB] [--small-budget 64MiB]

The one-segment cook runs twice: with its buffers in memory (`--spill-above never`) and
spilled to a file past --spill-above (the same asset, checked byte for byte). Then the
memory a cook needs beyond its buffers: the first frames, one segment and segments, each
spilled past --small-budget, the median peak of --runs runs each (peaks on two busy cores
move by tens of MB with the spill trimmer's timing), against nanovdb_convert's one frame.

Peak RSS is /usr/bin/time's %M (KiB). Every cook writes into a scratch directory that is
removed at the end.
"""

import argparse
import glob
import os
import shutil
import subprocess
import tempfile
import time


def timed(cmd, **kw):
    """(wall s, user+sys s, peak KiB) of one command under /usr/bin/time."""
    out = subprocess.run(["/usr/bin/time", "-f", "%e %U %S %M"] + cmd, capture_output=True, text=True, **kw)
    if out.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{out.stderr}")
    wall, user, sys_, peak = out.stderr.strip().splitlines()[-1].split()
    return float(wall), float(user) + float(sys_), int(peak)


def cook_flags(fmt):
    """A --formats entry as cook flags: a format, `max-error:E`, or `clusters:K` (unorm8)."""
    kind, _, arg = fmt.partition(":")
    if kind == "max-error":
        return ["--max-error", arg]
    if kind == "clusters":
        return ["--format", "unorm8", "--clusters", arg]
    return ["--format", fmt]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("seq")
    ap.add_argument("--segment", type=int, default=24)
    ap.add_argument("--formats", default="f16,bc7")
    ap.add_argument("--exe", default="target/release/vdbcook")
    ap.add_argument("--no-parts", action="store_true")
    ap.add_argument("--spill-above", default="512MiB", help="the spilled one-segment cook's --spill-above")
    ap.add_argument("--small-budget", default="64MiB", help="--spill-above of the memory-floor cooks ('none': skip them)")
    ap.add_argument("--runs", type=int, default=3, help="runs of each memory-floor cook (median peak)")
    args = ap.parse_args()
    files = sorted(glob.glob(os.path.join(args.seq, "*.vdb")))
    n, seg = len(files), str(args.segment)
    tmp = tempfile.mkdtemp(prefix="bench-segments-")
    rows = []
    try:
        print(f"{n} frames of {args.seq}; segments of {seg}; load {os.getloadavg()[0]:.2f}", flush=True)
        results, small = {}, {}
        for fmt in args.formats.split(","):
            flags = cook_flags(fmt)
            def cook(name, inputs, extra):
                out = os.path.join(tmp, name + ".vpak")
                r = timed([args.exe, "cook", "-q", "--force", "-o", out] + flags + extra + inputs)
                return r + (os.path.getsize(out),)
            first = cook(f"{fmt}-first", files[: args.segment], ["--segment-frames", seg])
            whole = cook(f"{fmt}-one", files, ["--spill-above", "never"])
            spilled = cook(f"{fmt}-spilled", files, ["--spill-above", args.spill_above])
            if open(os.path.join(tmp, f"{fmt}-one.vpak"), "rb").read() != open(os.path.join(tmp, f"{fmt}-spilled.vpak"), "rb").read():
                raise SystemExit(f"{fmt}: the spilled cook wrote another asset")
            os.remove(os.path.join(tmp, f"{fmt}-spilled.vpak"))
            segd = cook(f"{fmt}-seg", files, ["--segment-frames", seg])
            results[fmt] = (first, whole, segd, spilled)
            if args.small_budget != "none":
                def floor(name, inputs, extra):
                    runs = sorted((cook(name, inputs, extra + ["--spill-above", args.small_budget]) for _ in range(args.runs)), key=lambda r: r[2])
                    return runs[len(runs) // 2]
                small[fmt] = (floor(f"{fmt}-small-first", files[: args.segment], ["--segment-frames", seg]), floor(f"{fmt}-small-one", files, []), floor(f"{fmt}-small-seg", files, ["--segment-frames", seg]))
                for label, r in zip([f"first {seg} frames", "one segment", f"segments of {seg}"], small[fmt]):
                    print(f"  {fmt}: {label}, spilled past {args.small_budget}: {r[2] / 1024:.1f} MB peak (median of {args.runs}), {r[0]:.2f} s wall", flush=True)
            for label, r in [(f"{fmt}: first {seg} frames", first), (f"{fmt}: {n} frames, one segment", whole), (f"{fmt}: {n} frames, one segment, spilled", spilled), (f"{fmt}: {n} frames, segments of {seg}", segd)]:
                rows.append((label, r))
                print(f"  {label:<40} {r[0]:7.2f} s wall {r[1]:7.2f} s cpu {r[2] / 1024:8.1f} MB peak {r[3] / 1e6:9.2f} MB file", flush=True)
        nano = os.path.join(tmp, "nano")
        os.makedirs(nano)
        one = timed(["nanovdb_convert", "--fp16", files[0], os.path.join(nano, "one.nvdb")])
        t0 = time.time()
        xargs = subprocess.run(f"printf '%s\\n' {' '.join(files)} | xargs -P2 -I{{}} sh -c 'nanovdb_convert -f --fp16 \"$1\" {nano}/$(basename \"$1\" .vdb).nvdb' _ {{}}", shell=True, capture_output=True, text=True)
        xargs_wall = time.time() - t0
        if xargs.returncode != 0:
            raise SystemExit(f"nanovdb_convert failed: {xargs.stderr}")
        print(f"  nanovdb_convert --fp16 one frame: {one[2] / 1024:.1f} MB peak; xargs -P2 over {n} files: {xargs_wall:.2f} s", flush=True)
        # Parts as if on two machines, in every format (the issue asks for each).
        for fmt in [] if args.no_parts else args.formats.split(","):
            flags = cook_flags(fmt) + ["--segment-frames", seg]
            single = timed(["taskset", "-c", "0", args.exe, "cook", "-q", "--force", "-o", os.path.join(tmp, "single.vpak")] + flags + files)
            procs = []
            t0 = time.time()
            for i in (1, 2):
                cmd = ["/usr/bin/time", "-f", "%e %U %S %M", "taskset", "-c", str(i - 1), args.exe, "cook", "-q", "--force", "-o", os.path.join(tmp, f"p{i}.part"), "--part", f"{i}/2"] + flags + files
                procs.append(subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True))
            cpu = 0.0
            for p in procs:
                err = p.communicate()[1]
                if p.returncode != 0:
                    raise SystemExit(err)
                _, u, s_, _ = err.strip().splitlines()[-1].split()
                cpu += float(u) + float(s_)
            parts_wall = time.time() - t0
            part_files = [os.path.join(tmp, f"p{i}.part") for i in (1, 2)]
            join_cmd = [args.exe, "join", "-q", "--force"] + part_files + ["-o", os.path.join(tmp, "joined.vpak")]
            # The parts as the cooks left them (written past the page cache:
            # read from disk), then again once read (as a downloaded artifact is).
            join = timed(join_cmd)
            for f in part_files:
                with open(f, "rb") as fh:
                    while fh.read(1 << 24):
                        pass
            join_cached = timed(join_cmd)
            same = open(os.path.join(tmp, "joined.vpak"), "rb").read() == open(os.path.join(tmp, "single.vpak"), "rb").read()
            print(f"  {fmt} parts: one process on one core {single[0]:.2f} s ({single[1]:.2f} s cpu); two parts on a core each {parts_wall:.2f} s wall, {cpu:.2f} s cpu; join {join[0]:.2f} s, parts in the page cache {join_cached[0]:.2f} s; joined == one process: {same}", flush=True)
            print(f"    parts wall / one process {parts_wall / single[0]:.3f} (target <= 0.6); parts cpu / one process cpu {cpu / single[1]:.3f} (<= 1.1); join / one process {join[0] / single[0]:.3f}, parts cached {join_cached[0] / single[0]:.3f} (< 0.05)")
            # What the disk takes: the joined bytes written past the cache, as join writes them.
            size = os.path.getsize(os.path.join(tmp, "joined.vpak"))
            dd = timed(["dd", "if=/dev/zero", f"of={os.path.join(tmp, 'dd.bin')}", "bs=8M", f"count={max(1, size >> 23)}", "oflag=direct"])
            print(f"    the disk: {size / 1e6:.0f} MB written with dd oflag=direct in {dd[0]:.2f} s ({dd[0] / single[0]:.3f} of one process)", flush=True)
            for f in part_files + [os.path.join(tmp, name) for name in ("single.vpak", "joined.vpak", "dd.bin")]:
                os.remove(f)
        print("ratios:")
        for fmt, (first, whole, segd, spilled) in results.items():
            print(f"  {fmt}: peak RSS {n} frames in segments / first {seg} frames {segd[2] / first[2]:.3f} (<= 1.25); one segment / first {whole[2] / first[2]:.3f}, spilled past {args.spill_above} {spilled[2] / first[2]:.3f}; segments / nanovdb one frame {segd[2] / one[2]:.2f} (<= 3)")
            print(f"  {fmt}: one segment spilled / in memory: wall {spilled[0] / whole[0]:.3f}, cpu {spilled[1] / whole[1]:.3f}, peak {spilled[2] / whole[2]:.3f}")
            print(f"  {fmt}: bytes segments / one segment {segd[3] / whole[3]:.3f} (<= 1.1); wall segments / xargs -P2 nanovdb {segd[0] / xargs_wall:.3f}, one segment / xargs -P2 {whole[0] / xargs_wall:.3f} (<= 0.8)")
            if fmt in small:
                f, o, g = (r[2] for r in small[fmt])
                print(f"  {fmt}: spilled past {args.small_budget}: peak one segment / first {seg} frames {o / f:.3f} (<= 1.25), segments / first {g / f:.3f}; segments / nanovdb one frame {g / one[2]:.2f} (<= 3), first {seg} frames / nanovdb {f / one[2]:.2f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
