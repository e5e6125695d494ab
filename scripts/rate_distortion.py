#!/usr/bin/python3
"""Rate against distortion: voxel RMSE and max error against bits per active voxel,
for every vdbcook format and NanoVDB's quantised grids, per real sample.

    /usr/bin/python3 scripts/rate_distortion.py

Writes docs/rate-distortion.md (the table) and docs/rate-distortion.png (one log-log
panel per input, drawn with Pillow), with the release binary (built first). Inputs:
those of scripts/bench_size.py that exist. Points:
* vdbcook `cook --format f32 | f16 | unorm8 | bc4 | bc7` and bc4 at `--quality slow`:
  file bytes, and voxel RMSE and max error from the cook report;
* NanoVDB `nanovdb_convert --fp4 | --fp8 | --fp16 | --fpN -a 0.01 | --fpN -a 0.001`:
  .nvdb bytes; converted back to .vdb and compared with the source by `vdbcook diff`.
Exact points (RMSE 0) are listed in the table and drawn on the panel's floor.
`cook --max-error E` (issue 13, not built yet) is the missing series.
"""

import json
import math
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_size import EXE, INPUTS, OUT, grid_args, run  # noqa: E402

from PIL import Image, ImageDraw  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OURS = [("f32", []), ("f16", []), ("unorm8", []), ("bc4", []), ("bc4 slow", ["--quality", "slow"]), ("bc7", [])]
NANO = [("fp4", ["--fp4"]), ("fp8", ["--fp8"]), ("fp16", ["--fp16"]), ("fpN 0.01", ["--fpN", "-a", "0.01"]), ("fpN 0.001", ["--fpN", "-a", "0.001"])]


def measure(src):
    """(grid, active voxels, [(label, peer, bits per active voxel, rmse, max error)])."""
    out = os.path.join(OUT, "rd.vpak")
    points, grid, active = [], None, None
    for label, extra in OURS:
        fmt = label.split()[0]
        r = json.loads(run([EXE, "cook", "--json", "--force", "--format", fmt, *extra, *grid_args(src), "-o", out, src]))
        grid, active = r["grid"], r["active_voxels"]
        points.append((label, "vdbcook", r["file_bytes"] * 8 / active, float(r["voxel_rmse"]), float(r["voxel_max_error"])))
    nv, back = os.path.join(OUT, "rd.nvdb"), os.path.join(OUT, "rd_back.vdb")
    for label, flags in NANO:
        run(["nanovdb_convert", "-f", "-g", grid, *flags, src, nv])
        run(["nanovdb_convert", "-f", nv, back])
        d = json.loads(run([EXE, "diff", "--json", "--grid", grid, src, back]))
        points.append((label, "nanovdb", os.path.getsize(nv) * 8 / active, d["rmse"], d["max_error"]))
    return grid, active, points


def panel(draw, box, title, points):
    """A log-log panel of RMSE (y) against bits per active voxel (x) in `box`."""
    x0, y0, x1, y1 = box
    draw.rectangle(box, outline=(160, 160, 160))
    draw.text((x0 + 6, y0 + 4), title, fill=(0, 0, 0))
    px0, py0, px1, py1 = x0 + 50, y0 + 22, x1 - 10, y1 - 30
    xs = [p[2] for p in points]
    ys = [p[3] for p in points if p[3] > 0]
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
    draw.text((px0 + 4, py0), "voxel RMSE (exact: on the floor)", fill=(0, 0, 0))
    for label, peer, x, y, _ in points:
        cx, cy = fx(x), fy(y)
        color = (200, 40, 40) if peer == "vdbcook" else (40, 90, 200)
        if peer == "vdbcook":
            draw.ellipse((cx - 4, cy - 4, cx + 4, cy + 4), fill=color)
        else:
            draw.rectangle((cx - 4, cy - 4, cx + 4, cy + 4), fill=color)
        draw.text((cx + 6, cy - 6), label, fill=color)


def main():
    os.makedirs(OUT, exist_ok=True)
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
             "cook report; NanoVDB's through `nanovdb_convert` back to .vdb and `vdbcook diff`. The picture:",
             "[rate-distortion.png](rate-distortion.png) (red dots vdbcook, blue squares NanoVDB).", ""]
    for name, grid, active, points in results:
        lines += [f"## {name} (grid {grid}, {active} active voxels)", "", "| encoding | bits / voxel | RMSE | max error |", "|---|---:|---:|---:|"]
        for label, peer, x, y, m in sorted(points, key=lambda p: p[2]):
            lines.append(f"| {peer} {label} | {x:.3f} | {y:.3e} | {m:.3e} |")
        lines.append("")
    with open(os.path.join(ROOT, "docs", "rate-distortion.md"), "w") as f:
        f.write("\n".join(lines))
    cols, w, h = 2, 620, 380
    rows = (len(results) + cols - 1) // cols
    img = Image.new("RGB", (cols * w, rows * h), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    for i, (name, grid, active, points) in enumerate(results):
        x, y = (i % cols) * w, (i // cols) * h
        panel(draw, (x + 5, y + 5, x + w - 5, y + h - 5), f"{name} ({grid}, {active} active voxels)", points)
    img.save(os.path.join(ROOT, "docs", "rate-distortion.png"))
    print("wrote docs/rate-distortion.md and docs/rate-distortion.png")


if __name__ == "__main__":
    main()
