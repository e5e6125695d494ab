#!/usr/bin/python3
"""Where a command's resident memory is over time: runs CMD, samples /proc/PID/status
every 2 ms and prints the peak (VmHWM, as /usr/bin/time -f %M reports it), the sample
with the most resident memory split into anonymous and file-backed pages (a cook's spill
files are file-backed), and forty samples spread over the run (seconds:anon+file MB).

    /usr/bin/python3 scripts/memtrace.py target/release/vdbcook cook IN --spill-above 64MiB -o OUT.vpak --force -q
"""

import subprocess
import sys
import time


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)
    t0, best, hwm, samples = time.time(), None, 0, []
    while p.poll() is None:
        try:
            d = {}
            with open(f"/proc/{p.pid}/status") as f:
                for line in f:
                    key, _, value = line.partition(":")
                    if key in ("RssAnon", "RssFile", "RssShmem", "VmHWM"):
                        d[key] = int(value.split()[0]) // 1024
            t, total = time.time() - t0, d["RssAnon"] + d["RssFile"] + d["RssShmem"]
            hwm = max(hwm, d["VmHWM"])
            samples.append((t, d["RssAnon"], d["RssFile"] + d["RssShmem"]))
            if best is None or total > best[0]:
                best = (total, t, d["RssAnon"], d["RssFile"] + d["RssShmem"])
        except (OSError, KeyError, ValueError):
            pass  # the process ended between the check and the read
        time.sleep(0.002)
    if best is None:
        sys.exit(f"exit status {p.returncode}; no sample")
    print(f"exit status {p.returncode}; peak {hwm} MB; most in one sample {best[0]} MB at {best[1]:.2f} s: {best[2]} MB anonymous, {best[3]} MB file-backed")
    step = max(1, len(samples) // 40)
    print(" ".join(f"{t:.2f}:{a}+{f}" for t, a, f in samples[::step]))
    sys.exit(p.returncode)


if __name__ == "__main__":
    main()
