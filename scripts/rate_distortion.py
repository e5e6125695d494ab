#!/usr/bin/python3
"""Rate against distortion: voxel RMSE and max error against bits per active voxel,
for every vdbcook format, its --max-error mode and NanoVDB's quantised grids, per real sample.

    /usr/bin/python3 scripts/rate_distortion.py [--no-build]

Writes docs/rate-distortion.md (the table) and docs/rate-distortion.png (per input, a
log-log panel of RMSE and one of max error, drawn with Pillow), with the release binary
(built first unless --no-build). Inputs: those of scripts/bench_size.py that exist. Points:
* vdbcook `cook --format f32 | f16 | unorm8 | bc4 | bc7` and bc4 at `--quality slow`:
  file bytes, and voxel RMSE and max error from the cook report;
* vdbcook `cook --max-error E` for E in MAX_ERRORS (a series: per-brick formats, their
  split in the table), figures as above;
* NanoVDB `nanovdb_convert --fp4 | --fp8 | --fp16`, and `--fpN -a E` at the same E
  (a series): .nvdb bytes; converted back to .vdb and compared with the source by
  `vdbcook diff`.
Exact points (RMSE 0) are listed in the table and drawn on the panel's floor.
"""

import argparse
import json
import math
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_size import EXE, INPUTS, OUT, brick_formats, grid_args, run  # noqa: E402

from PIL import Image, ImageDraw  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MAX_ERRORS = [0.03, 0.01, 0.003, 0.001, 0.0003]
# (label, series or None, flags); a series' points share its name and are joined by a line.
OURS = [(f, None, ["--format", f]) for f in ("f32", "f16", "unorm8", "bc4", "bc7")] + [("bc4 slow", None, ["--format", "bc4", "--quality", "slow"])] \
    + [("max-error %g" % e, "max-error", ["--max-error", repr(e)]) for e in MAX_ERRORS]
NANO = [("fp4", None, ["--fp4"]), ("fp8", None, ["--fp8"]), ("fp16", None, ["--fp16"])] + [("fpN %g" % e, "fpN", ["--fpN", "-a", repr(e)]) for e in MAX_ERRORS]
# Colours: vdbcook red (its --max-error series orange), NanoVDB blue (its fpN series teal).
COLOR = {("vdbcook", None): (200, 40, 40), ("vdbcook", "max-error"): (230, 120, 0), ("nanovdb", None): (40, 90, 200), ("nanovdb", "fpN"): (0, 150, 160)}


def measure(src):
    """(grid, active voxels, [(label, peer, series, bits per active voxel, rmse, max error, brick formats)])."""
    out = os.path.join(OUT, "rd.vpak")
    points, grid, active = [], None, None
    for label, series, flags in OURS:
        r = json.loads(run([EXE, "cook", "--json", "--force", *flags, *grid_args(src), "-o", out, src]))
        grid, active = r["grid"], r["active_voxels"]
        points.append((label, "vdbcook", series, r["file_bytes"] * 8 / active, float(r["voxel_rmse"]), float(r["voxel_max_error"]), brick_formats(r) if series else ""))
    nv, back = os.path.join(OUT, "rd.nvdb"), os.path.join(OUT, "rd_back.vdb")
    for label, series, flags in NANO:
        run(["nanovdb_convert", "-f", "-g", grid, *flags, src, nv])
        run(["nanovdb_convert", "-f", nv, back])
        d = json.loads(run([EXE, "diff", "--json", "--grid", grid, src, back]))
        points.append((label, "nanovdb", series, os.path.getsize(nv) * 8 / active, d["rmse"], d["max_error"], ""))
    return grid, active, points


def panel(draw, box, title, points, metric):
    """A log-log panel of RMSE (metric 4) or max error (metric 5) against bits per active voxel (x) in `box`."""
    x0, y0, x1, y1 = box
    draw.rectangle(box, outline=(160, 160, 160))
    draw.text((x0 + 6, y0 + 4), title, fill=(0, 0, 0))
    px0, py0, px1, py1 = x0 + 50, y0 + 22, x1 - 10, y1 - 30
    xs = [p[3] for p in points]
    ys = [p[metric] for p in points if p[metric] > 0]
    lx0, lx1 = math.floor(math.log10(min(xs))), math.ceil(math.log10(max(xs)))
    ly0, ly1 = math.floor(math.log10(min(ys))) - 1, math.ceil(math.log10(max(ys)))
    fx = lambda v: px0 + (math.log10(v) - lx0) / max(lx1 - lx0, 1) * (px1 - px0)  # noqa: E731
    fy = lambda v: py1 - (math.log10(v) - ly0) / max(ly1 - ly0, 1) * (py1 - py0) if v > 0 else py1  # noqa: E731
    for e in range(lx0, lx1 + 1):
        draw.line((fx(10**e), py0, fx(10**e), py1), fill=(230, 230, 230))
        draw.text((fx(10**e) - 10, py1 + 4), f"1e{e}", fill=(90, 90, 90))
    for e in range(ly0, ly1 + 1):
        draw.line((px0, fy(10**e), px1, fy(10**e)), fill=(230, 230, 230))
        draw.text((x0 + 6, fy(10**e) - 6), f"1e{e}", fill=(90, 90, 90))
    draw.text((px1 - 150, py1 + 16), "bits per active voxel", fill=(0, 0, 0))
    what = "voxel RMSE" if metric == 4 else "voxel max error"
    draw.text((px0 + 4, py0), what + " (exact: on the floor)", fill=(0, 0, 0))
    # The two series: a line through their points in the order of E.
    for key in (("vdbcook", "max-error"), ("nanovdb", "fpN")):
        line = [(fx(p[3]), fy(p[metric])) for p in points if (p[1], p[2]) == key]
        if len(line) > 1:
            draw.line(line, fill=COLOR[key], width=2)
    legend = {("vdbcook", "max-error"): "vdbcook --max-error E", ("nanovdb", "fpN"): "NanoVDB --fpN -a E"}
    for i, (key, text) in enumerate(legend.items()):
        draw.text((px1 - 150, py0 + 14 * i), text, fill=COLOR[key])
    for label, peer, series, x, *ys, _ in points:
        cx, cy = fx(x), fy(ys[metric - 4])
        color = COLOR[(peer, series)]
        if series:  # small marks labelled by E alone
            mark = draw.ellipse if peer == "vdbcook" else draw.rectangle
            mark((cx - 3, cy - 3, cx + 3, cy + 3), fill=color)
            draw.text((cx + 5, cy + (2 if peer == "vdbcook" else -12)), label.split()[-1], fill=color)
        elif peer == "vdbcook":
            draw.ellipse((cx - 4, cy - 4, cx + 4, cy + 4), fill=color)
            draw.text((cx + 6, cy - 6), label, fill=color)
        else:
            draw.rectangle((cx - 4, cy - 4, cx + 4, cy + 4), fill=color)
            draw.text((cx + 6, cy - 6), label, fill=color)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--no-build", action="store_true", help="use target/release/vdbcook as it is")
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    if not args.no_build:
        subprocess.run(["cargo", "build", "--release", "-q", "-p", "vdbcook"], cwd=ROOT, check=True)
    results = []
    for src in INPUTS:
        if not os.path.exists(src):
            print(f"skipping {src} (missing)")
            continue
        grid, active, points = measure(src)
        results.append((os.path.relpath(src, ROOT), grid, active, points))
        print(f"{results[-1][0]}: {len(points)} points")
    lines = ["# Rate against distortion", "", "`/usr/bin/python3 scripts/rate_distortion.py` (release build). Voxel RMSE and max error over",
             "the source's active voxels; bits = file bytes · 8 / active voxels. vdbcook figures from the",
             "cook report; NanoVDB's through `nanovdb_convert` back to .vdb and `vdbcook diff`. `max-error E` is",
             "`cook --max-error E` (each brick in the cheapest format whose active voxels decode within E;",
             "the last column gives its bricks per format), `fpN E` is `nanovdb_convert --fpN -a E`.",
             "The picture: [rate-distortion.png](rate-distortion.png), RMSE left, max error right (red dots",
             "vdbcook's formats, orange line its --max-error series, blue squares NanoVDB, teal line fpN;",
             "series points are labelled with E). scripts/bench_max_error.py checks the max errors with OpenVDB.", ""]
    for name, grid, active, points in results:
        lines += [f"## {name} (grid {grid}, {active} active voxels)", "", "| encoding | bits / voxel | RMSE | max error | brick formats |", "|---|---:|---:|---:|---|"]
        for label, peer, _, x, y, m, fs in sorted(points, key=lambda p: p[3]):
            lines.append(f"| {peer} {label} | {x:.3f} | {y:.3e} | {m:.3e} | {fs} |")
        lines.append("")
    with open(os.path.join(ROOT, "docs", "rate-distortion.md"), "w") as f:
        f.write("\n".join(lines))
    w, h = 620, 400
    img = Image.new("RGB", (2 * w, len(results) * h), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    for i, (name, grid, active, points) in enumerate(results):
        for j, metric in enumerate((4, 5)):
            x, y = j * w, i * h
            panel(draw, (x + 5, y + 5, x + w - 5, y + h - 5), f"{name} ({grid}, {active} active voxels)", points, metric)
    img.save(os.path.join(ROOT, "docs", "rate-distortion.png"))
    print("wrote docs/rate-distortion.md and docs/rate-distortion.png")


if __name__ == "__main__":
    main()
