#!/usr/bin/python3
"""Writes a two-file-per-frame sequence with OpenVDB itself, for cli/tests/with.rs.

    /usr/bin/python3 cli/tests/with_sources.py OUTDIR

writes, as Blender's smoke with noise does, frames 1 to 3 of
* OUTDIR/noise/fluid_noise_####.vdb: float grids `density` and `flame`;
* OUTDIR/data/fluid_data_####.vdb: a vec3s grid `vel` and a float grid `density`
  (another density: a name found in both files),
every grid at voxel size 0.1 (one transform). Values are random (seeded), at
random voxels of a region that moves with the frame, so that no two frames or
grids share their bricks. Needs Debian's python3-openvdb and numpy.
"""

import os
import sys

import numpy as np
import pyopenvdb as vdb


def fill(grid, rng, frame, count, value):
    acc = grid.getAccessor()
    for _ in range(count):
        ijk = tuple(int(v) for v in rng.integers(-20, 20, size=3) + (4 * frame, 0, -2 * frame))
        acc.setValueOn(ijk, value(rng))
    grid.transform = vdb.createLinearTransform(voxelSize=0.1)
    return grid


def main():
    out = sys.argv[1]
    for sub in ("noise", "data"):
        os.makedirs(os.path.join(out, sub), exist_ok=True)
    for frame in (1, 2, 3):
        rng = np.random.default_rng(20261126 + frame)
        density = fill(vdb.FloatGrid(), rng, frame, 3000, lambda r: float(r.random()) + 0.01)
        density.name = "density"
        flame = fill(vdb.FloatGrid(), rng, frame, 1500, lambda r: float(r.random()) * 4.0)
        flame.name = "flame"
        vdb.write(os.path.join(out, "noise", f"fluid_noise_{frame:04d}.vdb"), grids=[density, flame])
        vel = fill(vdb.Vec3SGrid(), rng, frame, 2000, lambda r: tuple(float(x) for x in r.standard_normal(3)))
        vel.name = "vel"
        coarse = fill(vdb.FloatGrid(), rng, frame, 800, lambda r: float(r.random()) * 0.5 + 2.0)
        coarse.name = "density"
        vdb.write(os.path.join(out, "data", f"fluid_data_{frame:04d}.vdb"), grids=[vel, coarse])


if __name__ == "__main__":
    main()
