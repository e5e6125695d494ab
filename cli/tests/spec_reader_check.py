#!/usr/bin/python3
"""Compares what scripts/vpak_read.py decoded (an .npz) with what `vdbcook unpack`
wrote for the same frame (a .vdb, read by OpenVDB), voxel by voxel.

    /usr/bin/python3 cli/tests/spec_reader_check.py FRAME.npz UNPACKED.vdb

Prints one JSON object: per channel, the voxels the reader gave, how many of them
OpenVDB has active in the unpacked grid, the largest absolute difference, and the
number of active voxels in the unpacked grid (so both sets can be compared).
"""

import json
import sys

import numpy as np
import pyopenvdb as vdb


def main():
    npz, unpacked = sys.argv[1], sys.argv[2]
    data = np.load(npz)
    grids = {g.name: g for g in vdb.readAll(unpacked)[0]}
    out = {}
    names = sorted({k.rsplit(".", 1)[0] for k in data.files if k.endswith(".values")})
    for name in names:
        ijk, values = data[name + ".ijk"], data[name + ".values"]
        if name in grids:
            grid, comp = grids[name], None
        else:
            grid, comp = grids[name[:-2]], "xyz".index(name[-1])
        acc = grid.getConstAccessor()
        active, worst = 0, 0.0
        for (i, j, k), v in zip(ijk.tolist(), values.tolist()):
            value, on = acc.probeValue((i, j, k))
            if comp is not None:
                value = value[comp]
            active += bool(on)
            worst = max(worst, abs(float(value) - v))
        out[name] = {"voxels": int(len(values)), "active_in_unpacked": active, "max_diff": worst, "unpacked_active_voxels": int(grid.activeVoxelCount())}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
