"""A .vdb grid's values as NumPy arrays, read by OpenVDB itself (pyopenvdb, or vdb_tool
through scripts/openvdb_oracle.py for the double grids pyopenvdb 10 cannot load).

Shared by the scripts that measure errors independently of vdbcook's own reader
(bc7_floor.py, bench_max_error.py). Needs /usr/bin/python3 (Debian's pyopenvdb).
"""

import system_python  # noqa: F401  (re-runs under /usr/bin/python3 when needed)
import numpy as np  # noqa: E402
import pyopenvdb as vdb  # noqa: E402

from openvdb_oracle import describe  # noqa: E402


def read_grid(path, name):
    """The first grid named `name` ("" for an unnamed grid, which pyopenvdb.read cannot name)."""
    if name:
        return vdb.read(path, name)
    return next(g for g in vdb.readAll(path)[0] if g.name == "")


def dense(path, grid):
    """Values (float64) and active mask over the leaf-aligned bounding box of the active voxels."""
    g = read_grid(path, grid)
    lo, hi = g.evalActiveVoxelBoundingBox()
    lo = np.array(lo) // 8 * 8
    hi = (np.array(hi) // 8 + 1) * 8
    shape = tuple(int(n) for n in hi - lo)
    vals = np.zeros(shape, np.float32)
    g.copyToArray(vals, ijk=tuple(int(c) for c in lo))
    act = np.zeros(shape, bool)
    for it in g.iterOnValues():  # voxels and tiles
        a = np.array(it["min"]) - lo
        b = np.array(it["max"]) - lo + 1
        act[a[0]:b[0], a[1]:b[1], a[2]:b[2]] = True
    return vals.astype(np.float64), act


def _expand(coords, values, tiles):
    """Leaf voxels plus every voxel of every active tile."""
    ijk, v = [np.asarray(coords, np.int64).reshape(-1, 3)], [np.asarray(values, np.float64)]
    for tmin, tmax, val, _count in tiles:
        g = np.mgrid[tmin[0]:tmax[0] + 1, tmin[1]:tmax[1] + 1, tmin[2]:tmax[2] + 1].reshape(3, -1).T
        ijk.append(g)
        v.append(np.full(len(g), float(np.asarray(val).ravel()[0])))
    return np.concatenate(ijk), np.concatenate(v)


def active_values(path, grid):
    """(ijk (n, 3) int64, values (n,) float64, value type) of the active voxels of the
    first scalar grid named `grid`, tiles expanded to voxels, as OpenVDB reads them
    (openvdb_oracle.describe: pyopenvdb for float grids, vdb_tool for double ones)."""
    result, dumps = describe(path, want_voxels=True)
    for index, coords, values, tiles in dumps:
        g = result["grids"][index]
        if g["name"] == grid and g["value_type"] in ("float", "double"):
            ijk, v = _expand(coords, values, tiles)
            return ijk, v, g["value_type"]
    raise ValueError("%s: no float or double grid named %r" % (path, grid))


def values_at(path, grid, ijk):
    """The values (float64) of grid `grid` of `path` at the voxels ijk: what a reader
    samples there (the background where the grid is inactive; NaN there for a double
    grid, read through the oracle's dump of active values)."""
    lo = ijk.min(axis=0)
    shape = tuple(int(n) for n in ijk.max(axis=0) - lo + 1)
    idx = tuple((ijk - lo).T)
    try:
        g = read_grid(path, grid)
    except TypeError:  # a double grid: pyopenvdb 10 has no DoubleGrid
        out = np.full(shape, np.nan)
        oi, ov, _ = active_values(path, grid)
        keep = np.all((oi >= lo) & (oi < lo + shape), axis=1)
        out[tuple((oi[keep] - lo).T)] = ov[keep]
        return out[idx]
    arr = np.empty(shape, np.float32)
    g.copyToArray(arr, ijk=tuple(int(c) for c in lo))
    return arr[idx].astype(np.float64)


def max_abs_error(src_ijk, src_values, path, grid):
    """The largest |decoded - source| over the source's active voxels (inf where the
    decoded value is missing)."""
    d = np.abs(values_at(path, grid, src_ijk) - src_values)
    return float(np.nan_to_num(d, nan=np.inf).max()) if len(d) else 0.0
