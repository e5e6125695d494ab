#!/usr/bin/env python3
"""Level sets in the validation: cook each level set with --max-error E over a series
of bounds (and in bc7 and unorm8), validate it, and print the image RMSE (the surface's
movement as the images see it) and the voxel max error. The image error must be
non-zero for lossy assets and grow with E (exit 1 unless it does on two level sets).

    /usr/bin/python3 scripts/levelset_series.py [--bin target/release/vdbcook]
"""
import argparse, json, os, subprocess, sys, tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "..", "shared", "vdb-samples")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "vdbcook"))
    ap.add_argument("--views", default="4")
    ap.add_argument("--size", default="256x256")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        import pyopenvdb as vdb
        gen = os.path.join(tmp, "ls_sphere.vdb")
        ls = vdb.createLevelSetSphere(radius=24.0, center=(0, 0, 0), voxelSize=1.0, halfWidth=3.0)
        ls.name = "surface"
        vdb.write(gen, grids=[ls])
        inputs = [
            ("mjurczyk-openvdb/sphere.vdb", os.path.join(SAMPLES, "mjurczyk-openvdb", "sphere.vdb"), 0.05),
            ("zeno/sphere.vdb", os.path.join(SAMPLES, "zeno", "sphere.vdb"), None),
            ("openvdb-testsuite/isosurface_mesh.vdb", os.path.join(SAMPLES, "openvdb-testsuite", "isosurface_mesh.vdb"), None),
            ("generated sphere r=24", gen, 1.0),
        ]
        print("| level set | voxel size | setting | voxel max error | image RMSE | FLIP |")
        print("|---|---:|---|---:|---:|---:|")
        increasing = 0
        for label, path, voxel in inputs:
            if voxel is None:
                info = json.loads(subprocess.run([a.bin, "inspect", "--json", path], capture_output=True, text=True, check=True).stdout)
                g = info["files"][0]["grids"][0]
                voxel = g.get("voxel_size", [1.0])[0] if isinstance(g.get("voxel_size"), list) else g.get("voxel_size", 1.0)
            settings = [["--format", "bc7"], ["--format", "unorm8"]] + [["--max-error", f"{f * voxel:g}"] for f in (0.01, 0.03, 0.1, 0.3)]
            series = []
            for s in settings:
                out = os.path.join(tmp, "a.vpak")
                subprocess.run([a.bin, "cook", "-q", "--force", "-o", out, *s, path], check=True)
                v = subprocess.run([a.bin, "validate", out, "--views", a.views, "--size", a.size, "--json"], capture_output=True, text=True)
                if v.returncode != 0:
                    print(f"| {label} | {voxel:g} | {' '.join(s)} | - | - | exit {v.returncode}: {v.stderr.strip()} |")
                    continue
                d = json.loads(v.stdout)
                rmse = d["worst"]["rmse"]
                if s[0] == "--max-error":
                    series.append(rmse)
                print(f"| {label} | {voxel:g} | `{' '.join(s)}` | {d['voxel']['max_error']:.3e} | {rmse:.3e} | {d['worst_flip']['flip']:.4f} |")
            ok = all(x < y for x, y in zip(series, series[1:])) and all(x > 0 for x in series)
            increasing += ok
            print(f"| {label} | | --max-error series | | {'increasing' if ok else 'NOT increasing'} | |")
        # The bar: a monotone series on at least two level sets.
        print(f"\n{increasing} of {len(inputs)} level sets: image error increasing with --max-error")
        return 0 if increasing >= 2 else 1


if __name__ == "__main__":
    sys.exit(main())
