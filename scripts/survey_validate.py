#!/usr/bin/env python3
"""Validation truth survey: every real sample in ../shared/vdb-samples (and a few
generated volumes) cooked in bc7 and validated; prints, per input, the channel the
scene shows, its model (scatter, glow, surface), the coverage of the reference
images (share of pixels that differ from the empty scene) and the worst image RMSE.
No reference image of a frame with non-zero active voxels may be blank: validate
itself refuses that (exit 1), and this script says which inputs did.

    /usr/bin/python3 scripts/survey_validate.py [--bin target/release/vdbcook]
"""
import argparse, json, os, subprocess, sys, tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "..", "shared", "vdb-samples")


def generated(dirname):
    """Generated inputs: a fog under other names, a level-set sphere, a fog with a NaN voxel."""
    import numpy as np
    import pyopenvdb as vdb
    out = []
    n = 48
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float32)
    r = np.sqrt((x - n / 2) ** 2 + (y - n / 2) ** 2 + (z - n / 2) ** 2)
    fog = np.clip(1.0 - r / (n * 0.4), 0.0, 1.0).astype(np.float32)
    for name in ["density", "smoke", "dens", ""]:
        g = vdb.FloatGrid()
        g.copyFromArray(fog)
        g.name = name
        g.gridClass = vdb.GridClass.FOG_VOLUME
        p = os.path.join(dirname, f"fog_{name or 'unnamed'}.vdb")
        vdb.write(p, grids=[g])
        out.append((f"generated fog named \"{name}\"", [p], []))
    nan = fog.copy()
    nan[n // 2, n // 2, n // 2] = np.nan
    g = vdb.FloatGrid()
    g.copyFromArray(nan)
    g.name = "density"
    p = os.path.join(dirname, "fog_nan.vdb")
    vdb.write(p, grids=[g])
    out.append(("generated fog with a NaN voxel", [p], []))
    ls = vdb.createLevelSetSphere(radius=20.0, center=(0, 0, 0), voxelSize=1.0, halfWidth=3.0)
    ls.name = "surface"
    p = os.path.join(dirname, "ls_sphere.vdb")
    vdb.write(p, grids=[ls])
    out.append(("generated level-set sphere", [p], []))
    return out


def real():
    s = lambda *p: os.path.join(SAMPLES, *p)
    return [
        ("arnold-usd/smoke.vdb", [s("arnold-usd", "smoke.vdb")], []),
        ("arnold-usd/torus01.vdb", [s("arnold-usd", "torus01.vdb")], []),
        ("mjurczyk-openvdb/sphere.vdb (level set)", [s("mjurczyk-openvdb", "sphere.vdb")], []),
        ("elyg-visualizer/fogTommy.vdb", [s("elyg-visualizer", "fogTommy.vdb")], []),
        ("elyg-visualizer/pyro.vdb", [s("elyg-visualizer", "pyro.vdb")], []),
        ("elyg-visualizer/test.vdb", [s("elyg-visualizer", "test.vdb")], []),
        ("zeno/sphere.vdb (unnamed level set)", [s("zeno", "sphere.vdb")], []),
        ("openvdb-testsuite/isosurface_mesh.vdb (unnamed level set)", [s("openvdb-testsuite", "isosurface_mesh.vdb")], []),
        ("vscode-cmaketemplate/smoke.vdb", [s("vscode-cmaketemplate", "smoke.vdb")], []),
        ("hsim/writer.vdb (temperature)", [s("hsim", "writer.vdb")], []),
        ("waveletturbulence (4 frames, 4 channels)", [s("waveletturbulence")], ["--grids", "density,temperature,flame"]),
        ("EmberGen fire (frames 0-3: flames, temperature)", [s("vfx-toolkit-embergen", f"embergen_fire_a_{i}.vdb") for i in range(4)], ["--grids", "temperature,flames"]),
        ("EmberGen fire frame 50", [s("vfx-toolkit-embergen", "embergen_fire_a_50.vdb")], ["--grids", "temperature,flames"]),
        ("c42 phi_obstacle (level set)", [s("c42", "fluid_data_0001.vdb")], ["--grid", "phi_obstacle"]),
    ]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "vdbcook"))
    ap.add_argument("--format", default="bc7")
    ap.add_argument("--views", default="4")
    ap.add_argument("--size", default="256x256")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = []
        for label, inputs, extra in real() + generated(tmp):
            out = os.path.join(tmp, "a.vpak")
            c = subprocess.run([a.bin, "cook", "-q", "--force", "--format", a.format, "-o", out, *extra, *inputs], capture_output=True, text=True)
            if c.returncode != 0:
                rows.append((label, "-", "-", "-", "-", "cook: " + c.stderr.strip()))
                continue
            v = subprocess.run([a.bin, "validate", out, "--views", a.views, "--size", a.size, "--json"], capture_output=True, text=True)
            if v.returncode != 0:
                rows.append((label, "-", "-", "-", "-", f"exit {v.returncode}: " + v.stderr.strip()))
                continue
            d = json.loads(v.stdout)
            cov = d.get("coverage") or {}
            rows.append((label, d.get("shown") or "", d.get("model", ""), f"{100 * cov.get('min', 0):.1f} %", f"{d['worst']['rmse']:.3e}", ""))
        print(f"| input | channel | model | coverage (emptiest view) | worst image RMSE ({a.format}) | note |")
        print("|---|---|---|---:|---:|---|")
        for r in rows:
            print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    sys.exit(main())
