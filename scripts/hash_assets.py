#!/usr/bin/python3
"""Cooks a matrix of inputs with a given vdbcook binary and prints one SHA-256 per
asset (and one of its --json report, less timings and the output path), so that two binaries (say, main's and a refactoring branch's) can be shown
to write byte-identical assets and the same reports:

    /usr/bin/python3 scripts/hash_assets.py OLD/vdbcook > old.txt
    /usr/bin/python3 scripts/hash_assets.py NEW/vdbcook > new.txt
    diff old.txt new.txt

The matrix: the bundled fixtures (the 4-frame smoke sequence, tiles, a half level
set, a file of several grids) and a few real samples from ../shared/vdb-samples
(a pyro fog, a small Bifrost fog, EmberGen's two-grid fire sequence, four frames of
Mantaflow's five grids with a vec3 velocity, OpenVDB's smoke1, a dense vec3 velocity,
and three grids of c42 with a dense shadow), each with its default grid and, where
it has several, --grids all (the vec3 velocity: --grids all only); each in --format f32, f16, unorm8, bc4, bc7 and with
--max-error 0.01; each of those alone, with --clusters 16 and with --lods 3; plus a
few extras (channel groups, a byte budget, a small texture limit).  A cook that
fails prints its exit status and last line of error instead of a hash (so a change
in which cooks fail shows as well).  --quick: the fixtures only.  --sections: hash
every section but the metadata instead (of the one body of a version-6 file or of a
one-segment version-7 file), and no report: an old and a new format version compared.  The assets go to
a temporary directory, removed at the end.
"""

import hashlib
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SAMPLES = os.path.normpath(os.path.join(ROOT, "..", "shared", "vdb-samples"))
if not os.path.isdir(SAMPLES):
    SAMPLES = "/work/shared/vdb-samples"


def fixture(*p):
    return os.path.join(ROOT, "fixtures", *p)


def sample(*p):
    return os.path.join(SAMPLES, *p)


# (label, inputs, grid selections: the default and/or --grids all)
ONE, BOTH, ALL = [[]], [[], ["--grids", "all"]], [["--grids", "all"]]
FIXTURES = [
    ("smoke_seq", [fixture("smoke_seq")], ONE),
    ("tiles", [fixture("tiles.vdb")], ONE),
    ("levelset_half", [fixture("levelset_half.vdb")], ONE),
    ("multi_grid", [fixture("multi_grid.vdb")], BOTH),
]
REAL = [
    ("pyro", [sample("elyg-visualizer", "pyro.vdb")], ONE),
    ("torus", [sample("arnold-usd", "torus01.vdb")], ONE),
    ("embergen", [sample("vfx-toolkit-embergen", f"embergen_fire_a_{i}.vdb") for i in range(4)], BOTH),
    ("mantaflow", [sample("waveletturbulence", f"fluid_data_{i:04}.vdb") for i in range(150, 154)], BOTH),
    ("smoke1", [sample("arnold-usd", "smoke.vdb")], ONE),
    ("vel", [sample("zeno", "vel_VDB_bound_v02.vdb")], ALL),
]
FORMATS = [["--format", f] for f in ("f32", "f16", "unorm8", "bc4", "bc7")] + [["--max-error", "0.01"]]
EXTRAS = [[], ["--clusters", "16"], ["--lods", "3"]]


def cases(quick):
    for label, inputs, selections in FIXTURES + ([] if quick else REAL):
        for grids in selections:
            for fmt in FORMATS:
                for extra in EXTRAS:
                    yield label, inputs, grids + fmt + extra
    yield "smoke_seq", [fixture("smoke_seq")], ["--format", "bc7", "--max-texture-dim", "64"]
    yield "smoke_seq", [fixture("smoke_seq")], ["--format", "f16", "--lods", "4", "--max-bytes", "60kB"]
    if not quick:
        yield "embergen", REAL[2][1], ["--grids", "all", "--group", "temperature,flames=bc7"]
        yield "mantaflow", REAL[3][1], ["--grids", "all", "--group", "velocity=unorm8", "--format", "bc4", "--clusters", "16"]
        yield "mantaflow", REAL[3][1], ["--grids", "all", "--max-error", "0.001", "--lods", "2"]
        c42 = [sample("c42", "fluid_data_0001.vdb")]
        for fmt in FORMATS:
            yield "c42", c42, ["--grids", "density,shadow,temperature", *fmt, "--lods", "2"]


def report_digest(stdout):
    """SHA-256 of the --json report in its own key order, less what differs
    from run to run: the timings and the output path (a temporary directory)."""
    report = json.loads(stdout, object_pairs_hook=dict)
    report.pop("timings", None)
    report.pop("output", None)
    return hashlib.sha256(json.dumps(report).encode()).hexdigest()[:16]


def sections_digest(b):
    """SHA-256 of every section but the metadata, in table order, of a file's one body."""
    import struct
    version, n = struct.unpack_from("<I", b, 8)[0], struct.unpack_from("<I", b, 16)[0]
    if version == 7:
        if n != 1:
            return f"{n} segments"
        _, _, off, size, _ = struct.unpack_from("<IIQQQ", b, 64)
        b = b[off : off + size]
        n = struct.unpack_from("<I", b, 16)[0]
    h = hashlib.sha256()
    for i in range(n):
        kind, index, off, size, _ = struct.unpack_from("<IIQQQ", b, 64 + 32 * i)
        if kind != 1:
            h.update(struct.pack("<IIQ", kind, index, size) + b[off : off + size])
    return h.hexdigest()


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    quick = "--quick" in sys.argv[1:]
    by_section = "--sections" in sys.argv[1:]
    if len(args) != 1:
        sys.exit(__doc__)
    binary = os.path.abspath(args[0])
    with tempfile.TemporaryDirectory(prefix="hash_assets.") as tmp:
        out = os.path.join(tmp, "out.vpak")
        for label, inputs, flags in cases(quick):
            name = f"{label} {' '.join(flags) or '(defaults)'}"
            if os.path.exists(out):
                os.remove(out)
            run = subprocess.run([binary, "cook", *inputs, "-o", out, "--json", *flags], cwd=tmp, capture_output=True, text=True)
            if run.returncode == 0:
                with open(out, "rb") as f:
                    b = f.read()
                digest = sections_digest(b) if by_section else hashlib.sha256(b).hexdigest() + " " + report_digest(run.stdout)
            else:
                last = (run.stderr.strip().splitlines() or [""])[-1]
                digest = f"exit {run.returncode}: {last}"
            print(f"{digest}  {name}", flush=True)


if __name__ == "__main__":
    main()
