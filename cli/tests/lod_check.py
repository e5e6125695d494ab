#!/usr/bin/python3
"""Checks one level of detail that `vdbcook unpack --lod K` wrote against the level
computed here, independently, from the source grid as OpenVDB reads it.

    /usr/bin/python3 cli/tests/lod_check.py SOURCE.vdb GRID K mean|active UNPACKED.vdb

The level is the definition of docs/format.md ("Levels"), written again in numpy:
level-k voxel i covers level-(k-1) voxels 2i and 2i+1 per axis; it is active when any
child is; `mean` is the mean of the eight children with the background for inactive
ones, `active` the mean of the active ones; each level rounded to float32. Prints one
JSON object: voxel counts (reference, unpacked, missing, extra, and extra voxels whose
value is not the background: with several channels a voxel active in another channel's
level is active in every channel's, holding the background), the largest value
difference, the voxel sizes, and how far (in world units) the unpacked grid puts a
level voxel's centre from the centre of its source voxels.
"""

import json
import sys

import numpy as np
import pyopenvdb as vdb


def active_voxels(grid):
    ijk, vals = [], []
    for item in grid.citerOnValues():
        lo, hi = item["min"], item["max"]
        if lo == hi:
            ijk.append(lo)
            vals.append(item["value"])
            continue
        r = [np.arange(lo[a], hi[a] + 1) for a in range(3)]
        g = np.stack(np.meshgrid(*r, indexing="ij"), axis=-1).reshape(-1, 3)
        ijk.extend(map(tuple, g))
        vals.extend([item["value"]] * len(g))
    return np.array(ijk, dtype=np.int64).reshape(-1, 3), np.array(vals, dtype=np.float64)


def coarsen(ijk, vals, background, mode):
    parents, inv = np.unique(ijk >> 1, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    sums = np.zeros(len(parents))
    counts = np.zeros(len(parents))
    np.add.at(sums, inv, vals)
    np.add.at(counts, inv, 1)
    if mode == "mean":
        mean = (sums + background * (8 - counts)) / 8.0
    else:
        mean = sums / counts
    return parents, mean.astype(np.float32).astype(np.float64)


def main():
    source, name, level, mode, unpacked = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5]
    src = next(g for g in vdb.readAll(source)[0] if g.name == name)
    background = float(np.float32(src.background))
    ijk, vals = active_voxels(src)
    vals = vals.astype(np.float32).astype(np.float64)
    for _ in range(level):
        ijk, vals = coarsen(ijk, vals, background, mode)
    got = next(g for g in vdb.readAll(unpacked)[0] if g.name == name)
    gijk, gvals = active_voxels(got)
    want = {tuple(c): v for c, v in zip(ijk.tolist(), vals.tolist())}
    have = {tuple(c): v for c, v in zip(gijk.tolist(), gvals.tolist())}
    common = want.keys() & have.keys()
    diff = max((abs(want[c] - have[c]) for c in common), default=0.0)
    # A level voxel's centre is the centre of its 2^k x 2^k x 2^k source voxels.
    s = 2 ** level
    world_err = 0.0
    for c in list(want)[:: max(1, len(want) // 200)] + [(0, 0, 0), (-7, 3, 11)]:
        centre = np.mean([src.transform.indexToWorld((float(s * c[0] + dx), float(s * c[1] + dy), float(s * c[2] + dz)))
                          for dx in range(s) for dy in range(s) for dz in range(s)], axis=0)
        w = got.transform.indexToWorld((float(c[0]), float(c[1]), float(c[2])))
        world_err = max(world_err, float(np.max(np.abs(np.array(w) - centre))))
    print(json.dumps({
        "reference_voxels": len(want), "unpacked_voxels": len(have), "missing": len(want.keys() - have.keys()),
        "extra": len(have.keys() - want.keys()), "extra_not_background": sum(1 for c in have.keys() - want.keys() if have[c] != background), "max_diff": diff, "max_value": max((abs(v) for v in want.values()), default=0.0),
        "voxel_size": list(got.transform.voxelSize()), "source_voxel_size": list(src.transform.voxelSize()),
        "world_error": world_err, "class": got.gridClass, "background": got.background,
    }))


if __name__ == "__main__":
    main()
