#!/usr/bin/python3
"""Compares what scripts/vpak_read.py decoded (an .npz) with what `vdbcook unpack`
wrote for the same frame (a .vdb, read by OpenVDB), voxel by voxel.

    /usr/bin/python3 cli/tests/spec_reader_check.py FRAME.npz UNPACKED.vdb

Prints one JSON object: per channel, the voxels the reader gave, how many of them
OpenVDB has active in the unpacked grid, the largest absolute difference, the
number of active voxels in the unpacked grid (so both sets can be compared), the
level the reader decoded the channel at, and the largest difference between the
reader's transform of the channel and the unpacked grid's (index to world).

    /usr/bin/python3 cli/tests/spec_reader_check.py --source SOURCE.vdb UNPACKED.vdb

The round trip of an f32 asset: per grid of SOURCE.vdb (vec3 grids whole), how many
voxels it has active, how many of them are not active in the unpacked grid, how many
voxels the unpacked grid has active that hold another value than the source's
(background included), the largest difference at the source's active voxels, and the
largest difference between the two grids' transforms.
"""

import json
import sys

import numpy as np
import pyopenvdb as vdb


def matrix(grid):
    """Index-to-world 4 x 4 (row-vector convention) of a linear transform."""
    t = grid.transform
    o = np.array(t.indexToWorld((0, 0, 0)), dtype=np.float64)
    rows = [np.array(t.indexToWorld(e), dtype=np.float64) - o for e in ((1, 0, 0), (0, 1, 0), (0, 0, 1))]
    out = np.zeros((4, 4))
    out[:3, :3], out[3, :3], out[3, 3] = rows, o, 1.0
    return out


def active_voxels(grid):
    """(ijk, value) of every active voxel, tiles expanded."""
    for item in grid.citerOnValues():
        lo, hi = item["min"], item["max"]
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    yield (i, j, k), item["value"]


def diff(a, b):
    a, b = np.atleast_1d(np.asarray(a, dtype=np.float64)), np.atleast_1d(np.asarray(b, dtype=np.float64))
    if np.array_equal(np.isnan(a), np.isnan(b)) and np.all(a[~np.isnan(a)] == b[~np.isnan(b)]):
        return 0.0
    return float(np.nanmax(np.abs(a - b))) if not np.isnan(a - b).all() else float("inf")


def compare_reader(npz, unpacked):
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
        if name + ".transform" in data.files:
            out[name]["level"] = int(data[name + ".level"])
            out[name]["transform_diff"] = float(np.abs(matrix(grid) - data[name + ".transform"]).max())
    return out


def compare_source(source, unpacked):
    grids = {g.name: g for g in vdb.readAll(unpacked)[0]}
    out = {}
    for src in vdb.readAll(source)[0]:
        got = grids.get(src.name)
        if got is None:
            out[src.name] = {"missing_grid": True}
            continue
        got_acc, src_acc = got.getConstAccessor(), src.getConstAccessor()
        n, missing, worst = 0, 0, 0.0
        for ijk, value in active_voxels(src):
            v, on = got_acc.probeValue(ijk)
            n += 1
            missing += not on
            worst = max(worst, diff(v, value))
        # The unpacked grid is active over every channel's voxels of its level: where
        # the source is not, it must hold what the source holds there (its background).
        other = sum(diff(v, src_acc.probeValue(ijk)[0]) != 0.0 for ijk, v in active_voxels(got))
        out[src.name] = {"source_active": n, "not_active": missing, "max_diff": worst, "other_values": other, "transform_diff": float(np.abs(matrix(got) - matrix(src)).max())}
    return out


def main():
    if sys.argv[1] == "--source":
        out = compare_source(sys.argv[2], sys.argv[3])
    else:
        out = compare_reader(sys.argv[1], sys.argv[2])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
