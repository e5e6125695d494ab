#!/usr/bin/python3
"""Reference ("oracle") description of an OpenVDB .vdb file, computed with OpenVDB itself.

Usage (always with the system interpreter, which has pyopenvdb; a pyenv `python3`
does not):

    /usr/bin/python3 scripts/openvdb_oracle.py FILE.vdb [--voxels OUT.bin]
        [--vec3-voxels OUT3.bin] [--crosscheck]

The Rust CLI's `vdbcook inspect --json` is tested against this output.

JSON printed on stdout
======================
    {"path": "<FILE as given>", "file_version": 224, "library_version": "10.0",
     "grids": [ <one object per grid, in file order>, ... ]}

Each grid object has exactly these keys:
    name          str   grid name (descriptor name with any "\\x1eN" uniquifying suffix
                        stripped, so duplicate names appear verbatim; "" for unnamed grids)
    value_type    str   OpenVDB value type name: "float", "double", "int32", "int64",
                        "bool", "mask", "vec3s", "vec3d", "vec3i", "ptdataidx32", ...
    class         str   "fog volume" | "level set" | "staggered" | "unknown"
                        ("unknown" when the grid has no / an unrecognised "class" metadata)
    half_float    bool  grid type name in the descriptor carries the "_HalfFloat" suffix
    voxel_size    [x,y,z] floats, Transform::voxelSize() (for a frustum map: at the centre
                        of the near plane, as OpenVDB defines it)
    map_type      str   Transform map type name as stored in the file ("UniformScaleMap",
                        "UniformScaleTranslateMap", "ScaleMap", "ScaleTranslateMap",
                        "TranslationMap", "AffineMap", "UnitaryMap", "NonlinearFrustumMap")
    background    number for scalar grids (float/double/int*), bool for bool grids,
                  [x,y,z] for vec3 grids, null otherwise (mask, point grids, ...)
    active_voxels int   active voxel count, every voxel covered by an active tile included
    bbox_min      [i,j,k] | null   inclusive index-space bbox of all active values
    bbox_max      [i,j,k] | null   (null when active_voxels == 0)
    leaf_count    int   number of allocated leaf nodes
    active_tiles  int   number of active tiles at every non-leaf level (root tiles and
                        internal-node tiles; a tile of a lower internal node covers 8^3)
    min, max      number | null   over active values only (tiles included);
                                  float and double grids only, null otherwise / when empty
    sum           number | null   float64 sum of all active values, a tile contributing
                                  value * (voxels it covers); computed with math.fsum, i.e.
                                  correctly rounded, so compare with a relative tolerance
                                  (~1e-9) rather than exactly. float/double grids only.

Float values are full-precision float32 widened to float64 (half-float grids: the
decoded half value, exactly representable). JSON floats are printed with Python's repr
(shortest round-trip form).

Binary voxel dump (--voxels OUT.bin), all little-endian, packed (no padding):
=============================================================================
    header (32 bytes):
        8 bytes   magic  b"VDBORC01"
        u32       grid_count        number of entries in the JSON "grids" list
        u32       reserved (0)
        u64       voxel_count       number of voxel records that follow
        u64       tile_count        number of tile records after the voxel records
    voxel records, voxel_count x 24 bytes, sorted by (grid_index, x, y, z):
        u32 grid_index, i32 x, i32 y, i32 z, f64 value
    tile records, tile_count x 36 bytes, sorted by (grid_index, min x, min y, min z):
        u32 grid_index, i32 min_x, i32 min_y, i32 min_z, i32 max_x, i32 max_y, i32 max_z,
        f64 value
Only active values of float and double grids are written (vec3 grids: see the next
dump); grid_index is the index in
the JSON "grids" list (file order, counting grids of every type). A voxel record is a
single active voxel stored in a leaf node; a tile record is one active tile (any level)
with its inclusive index-space bounds. Inactive values are never written. An instanced
grid is dumped like any other grid (its values are its parent's).

Binary vec3 dump (--vec3-voxels OUT3.bin), all little-endian, packed:
======================================================================
The same layout with three values, the (x, y, z) components, per record, for the active
values of vec3s and vec3d grids only (half-float vec3s grids: the decoded halves):
    header (32 bytes):
        8 bytes   magic  b"VDBORV01"
        u32       grid_count, u32 reserved (0), u64 voxel_count, u64 tile_count
    voxel records, voxel_count x 40 bytes, sorted by (grid_index, x, y, z):
        u32 grid_index, i32 x, i32 y, i32 z, f64 value_x, f64 value_y, f64 value_z
    tile records, tile_count x 52 bytes, sorted by (grid_index, min x, min y, min z):
        u32 grid_index, i32 min_x, i32 min_y, i32 min_z, i32 max_x, i32 max_y, i32 max_z,
        f64 value_x, f64 value_y, f64 value_z
vec3s values come from pyopenvdb (float32 widened), vec3d values from the uncompressed
rewrite described below (float64 as stored).

How the figures are obtained
============================
* file_version / library_version, grid order, names, half flag, class metadata,
  map type and background are read from the file's header, grid descriptors, grid
  metadata, transform record and root node (a small parser below; those records are
  uncompressed). The parsed transform is cross-checked against OpenVDB where OpenVDB's
  Python binding can load the grid.
* float, vec3s and bool grids (the types pyopenvdb 10 exposes) are loaded with
  pyopenvdb.read(); counts and bbox come from activeVoxelCount(),
  evalActiveVoxelBoundingBox(), leafCount(), activeLeafVoxelCount(); active tiles,
  min/max/sum and the dump come from iterating citerOnValues() (an item with count 1 is
  a leaf voxel, any other item an active tile; ~1 s per million voxels).
* every other type (double, int32, int64, vec3d, points, ...) cannot be loaded by
  pyopenvdb 10 (it raises TypeError, even for readAllGridMetadata). For those the file is
  decoded and rewritten by OpenVDB's own `vdb_tool -read FILE -write codec=none bits=32`
  (no compression, full precision) and the resulting plain node layout is walked here
  (masks + raw values) to count voxels/tiles/leaves and, for double grids, read the
  values. (vdb_tool writes grids in its own order, reverse-sorted by name, so the grids
  are first renamed to index-derived unique names in a temporary copy.)
  `--crosscheck` additionally compares every grid's counts, bbox, leaf/tile counts and
  printed min/max against `vdb_print -l`.
* A file that OpenVDB cannot read (e.g. a point grid with an unregistered attribute
  codec) makes the script exit with status 2 and a one-line message on stderr.
  With `--skip-unreadable`, a file that only vdb_tool cannot rewrite (Blender liquid
  caches: a readable vec3s `velocity` beside `particles` with the `trnc` codec) is still
  described: the grids that needed the rewrite get an extra key `"unreadable"` (the
  reason), null figures and no dump records; the float / vec3s / bool grids, which
  pyopenvdb loads one by one, are described and dumped as usual.

Surprises found on OpenVDB 10.0.1 (see also fixtures/README.md):
* Grid.evalMinMax() covers ACTIVE values only (tiles included; inactive values and the
  background are ignored) and returns (0, 0) for an empty grid. This script computes
  min/max from the value iterator anyway and checks it agrees.
* pyopenvdb.read(file, "name") silently returns the FIRST grid of that name (with a
  warning on stderr); "name[N]" selects the N-th duplicate (0-based).
* evalActiveVoxelBoundingBox() of an empty grid is the inverted max box
  ((INT_MAX,)*3, (INT_MIN,)*3); reported here as null.
* `vdb_print` exits 0 even when it fails to read a file (it prints "vdb_print ERROR").
* vdb_print -l lists grids sorted by name, not in file order; vdb_tool -write writes
  them in reverse name order.
* Half-float grids store leaf and internal-node values as halves, but the root
  background / root tiles and the explicit inactive values of the mask-compression
  codes 2/4/5 as 4-byte floats holding half-rounded values.
* io::Archive never applies ZIP to fog volume / level set grids (blosc it does).
"""

import argparse
import itertools
import json
import math
import os
import struct
import subprocess
import sys
import tempfile
from array import array

import system_python  # noqa: F401,E402  (re-runs under /usr/bin/python3 when needed)
import numpy as np  # noqa: E402
import pyopenvdb as vdb  # noqa: E402,F401

VDB_MAGIC = 0x56444220
DUMP_MAGIC = b"VDBORC01"
VEC3_DUMP_MAGIC = b"VDBORV01"
VEC3_TYPES = ("vec3s", "vec3d")
SEP = "\x1e"

# File format version constants (openvdb/version.h)
FV_SELECTIVE_COMPRESSION = 220
FV_NODE_MASK_COMPRESSION = 222
FV_GRID_INSTANCING = 216

# Per-grid compression flags (io/Compression.h)
COMPRESS_ZIP = 0x1
COMPRESS_ACTIVE_MASK = 0x2
COMPRESS_BLOSC = 0x4

# Scalar/vector value layouts for raw (uncompressed) values and backgrounds
VALUE_FORMATS = {
    "float": ("<f4", 1), "double": ("<f8", 1), "int32": ("<i4", 1), "int64": ("<i8", 1),
    "uint32": ("<u4", 1), "ptdataidx32": ("<u4", 1), "ptdataidx64": ("<u8", 1),
    "bool": ("u1", 1), "mask": ("u1", 1), "int16": ("<i2", 1), "uint16": ("<u2", 1),
    "half": ("<f2", 1),
    "vec3s": ("<f4", 3), "vec3d": ("<f8", 3), "vec3i": ("<i4", 3), "vec3u32": ("<u4", 3),
    "vec2s": ("<f4", 2), "vec2d": ("<f8", 2), "vec2i": ("<i4", 2),
}

LINEAR_MAP_DOUBLES = {
    "UniformScaleMap": 15, "ScaleMap": 15,
    "UniformScaleTranslateMap": 18, "ScaleTranslateMap": 18,
    "TranslationMap": 3, "AffineMap": 16, "UnitaryMap": 16,
}

GRID_CLASSES = ("level set", "fog volume", "staggered")


class OracleError(Exception):
    """A file OpenVDB (or this script) cannot describe."""


# --------------------------------------------------------------------------------------
# Low-level parsing of the uncompressed records of a .vdb file
# --------------------------------------------------------------------------------------

class ByteReader:
    def __init__(self, data, pos=0):
        self.data = data
        self.pos = pos

    def take(self, n):
        if n < 0 or self.pos + n > len(self.data):
            raise OracleError("truncated file (need %d bytes at offset %d, size %d)"
                              % (n, self.pos, len(self.data)))
        b = self.data[self.pos:self.pos + n]
        self.pos += n
        return b

    def unpack(self, fmt):
        size = struct.calcsize(fmt)
        vals = struct.unpack_from(fmt, self.take(size))
        return vals if len(vals) > 1 else vals[0]

    def u8(self):
        return self.unpack("<B")

    def u32(self):
        return self.unpack("<I")

    def i32(self):
        return self.unpack("<i")

    def i64(self):
        return self.unpack("<q")

    def f64(self):
        return self.unpack("<d")

    def string(self):
        n = self.u32()
        return self.take(n).decode("utf-8", errors="surrogateescape")


def _decode_meta(type_name, raw):
    try:
        if type_name == "string":
            return raw.decode("utf-8", errors="surrogateescape")
        if type_name == "bool":
            return bool(raw[0]) if raw else False
        simple = {"int32": "<i", "int64": "<q", "float": "<f", "double": "<d",
                  "vec3i": "<3i", "vec3s": "<3f", "vec3d": "<3d", "vec2i": "<2i",
                  "vec2s": "<2f", "vec2d": "<2d", "mat4s": "<16f", "mat4d": "<16d"}
        if type_name in simple:
            vals = struct.unpack(simple[type_name], raw)
            return vals[0] if len(vals) == 1 else list(vals)
    except struct.error:
        pass
    return None


def parse_metamap(r):
    """MetaMap::readMeta: u32 count, then (string name, string type, u32 size, bytes)."""
    out = []
    count = r.u32()
    for _ in range(count):
        name = r.string()
        type_name = r.string()
        size = r.u32()
        raw = r.take(size)
        out.append({"name": name, "type": type_name, "raw": raw,
                    "value": _decode_meta(type_name, raw)})
    return out


def parse_map(r, map_type):
    """Read the doubles of a math::MapBase::write() record (see math/Maps.h)."""
    if map_type in LINEAR_MAP_DOUBLES:
        n = LINEAR_MAP_DOUBLES[map_type]
        return {"doubles": list(r.unpack("<%dd" % n))}
    if map_type == "NonlinearFrustumMap":
        bbox = list(r.unpack("<6d"))
        taper = r.f64()
        depth = r.f64()
        second_type = r.string()
        second = parse_map(r, second_type)
        return {"bbox": bbox, "taper": taper, "depth": depth,
                "second_type": second_type, "second": second}
    raise OracleError("unknown transform map type %r" % map_type)


def map_to_affine(map_type, m):
    """4x4 row-vector matrix (world = [x y z 1] * M) of a linear map."""
    d = m["doubles"]
    mat = np.eye(4)
    if map_type in ("UniformScaleMap", "ScaleMap"):
        mat[0, 0], mat[1, 1], mat[2, 2] = d[0:3]
    elif map_type in ("UniformScaleTranslateMap", "ScaleTranslateMap"):
        mat[3, 0:3] = d[0:3]
        mat[0, 0], mat[1, 1], mat[2, 2] = d[3:6]
    elif map_type == "TranslationMap":
        mat[3, 0:3] = d[0:3]
    elif map_type in ("AffineMap", "UnitaryMap"):
        mat = np.array(d, dtype=np.float64).reshape(4, 4)
    else:
        raise OracleError("not a linear map: %s" % map_type)
    return mat


def map_voxel_size(map_type, m):
    """Transform::voxelSize() computed from the parsed map record."""
    if map_type in ("UniformScaleMap", "ScaleMap"):
        return list(m["doubles"][3:6])          # stored mVoxelSize
    if map_type in ("UniformScaleTranslateMap", "ScaleTranslateMap"):
        return list(m["doubles"][6:9])          # stored mVoxelSize
    if map_type == "TranslationMap":
        return [1.0, 1.0, 1.0]
    if map_type in LINEAR_MAP_DOUBLES:
        mat = map_to_affine(map_type, m)
        return [float(np.linalg.norm(mat[i, 0:3])) for i in range(3)]
    if map_type == "NonlinearFrustumMap":
        (x0, y0, z0, x1, y1, z1) = m["bbox"]
        lx, ly, lz = x1 - x0, y1 - y0, z1 - z0
        gamma = (1.0 / m["taper"] - 1.0) / m["depth"]
        depth_on_lz = m["depth"] / lz
        second = map_to_affine(m["second_type"], m["second"])

        def apply(p):
            x = p[0] - x0 - 0.5 * lx
            y = p[1] - y0 - 0.5 * ly
            z = (p[2] - z0) * depth_on_lz
            s = (gamma * z + 1.0) / lx
            return np.array([x * s, y * s, z, 1.0]) @ second

        loc = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), z0])
        pos = apply(loc)
        return [float(np.linalg.norm((apply(loc + e) - pos)[0:3])) for e in np.eye(3)]
    raise OracleError("unknown transform map type %r" % map_type)


def value_type_of(type_name):
    """'Tree_float_5_4_3' -> 'float'; 'Tree_vec3s_5_4_3' -> 'vec3s'."""
    parts = type_name.split("_")
    if len(parts) >= 3 and parts[0] == "Tree":
        i = len(parts)
        while i > 1 and parts[i - 1].isdigit():
            i -= 1
        return "_".join(parts[1:i])
    return type_name


def tree_config(type_name):
    """'Tree_float_5_4_3' -> [5, 4, 3] (log2 dims of internal..leaf nodes)."""
    parts = type_name.split("_")
    dims = []
    for p in reversed(parts):
        if p.isdigit():
            dims.append(int(p))
        else:
            break
    return list(reversed(dims))


def parse_file_structure(path_or_bytes):
    """Header, file metadata and, per grid, the descriptor and uncompressed grid records."""
    if isinstance(path_or_bytes, (bytes, bytearray)):
        data = bytes(path_or_bytes)
    else:
        with open(path_or_bytes, "rb") as f:
            data = f.read()
    r = ByteReader(data)
    if len(data) < 8 or struct.unpack_from("<q", data, 0)[0] != VDB_MAGIC:
        raise OracleError("not a VDB file (bad magic)")
    r.pos = 8
    info = {"data": data}
    info["file_version"] = r.u32()
    info["library_major"] = r.u32()
    info["library_minor"] = r.u32()
    info["has_grid_offsets"] = bool(r.u8())
    if FV_SELECTIVE_COMPRESSION <= info["file_version"] < FV_NODE_MASK_COMPRESSION:
        info["file_compressed"] = bool(r.u8())
    info["uuid"] = r.take(36).decode("ascii", errors="replace")
    info["file_metadata"] = parse_metamap(r)
    if not info["has_grid_offsets"]:
        raise OracleError("stream without grid offsets is not supported by this parser")
    info["grid_count_pos"] = r.pos
    count = r.i32()
    grids = []
    for index in range(count):
        g = {"index": index, "desc_pos": r.pos}
        g["unique_name"] = r.string()
        g["name"] = g["unique_name"].split(SEP)[0]
        type_name = r.string()
        g["half_float"] = type_name.endswith("_HalfFloat")
        if g["half_float"]:
            type_name = type_name[:-len("_HalfFloat")]
        g["type_name"] = type_name
        g["value_type"] = value_type_of(type_name)
        g["instance_parent"] = r.string() if info["file_version"] >= FV_GRID_INSTANCING else ""
        g["offsets_pos"] = r.pos
        g["grid_pos"], g["block_pos"], g["end_pos"] = r.i64(), r.i64(), r.i64()
        # grid records
        gr = ByteReader(data, g["grid_pos"])
        if info["file_version"] >= FV_NODE_MASK_COMPRESSION:
            g["compression"] = gr.u32()
        else:
            g["compression"] = (COMPRESS_ZIP if info.get("file_compressed") else 0)
        g["meta_pos"] = gr.pos
        g["metadata"] = parse_metamap(gr)
        g["transform_pos"] = gr.pos
        g["map_type"] = gr.string()
        g["map"] = parse_map(gr, g["map_type"])
        g["transform_end"] = gr.pos
        g["topology_pos"] = gr.pos if not g["instance_parent"] else None
        g["meta"] = {m["name"]: m["value"] for m in g["metadata"]}
        grids.append(g)
        r.pos = g["end_pos"]
    info["grids"] = grids
    return info


# --------------------------------------------------------------------------------------
# Re-serialising the uncompressed records (used to rename grids before handing a file
# to vdb_tool, and by fixtures/make_fixtures.py to patch transforms / metadata)
# --------------------------------------------------------------------------------------

def ser_string(s):
    b = s.encode("utf-8", errors="surrogateescape")
    return struct.pack("<I", len(b)) + b


def ser_metamap(entries):
    out = [struct.pack("<I", len(entries))]
    for m in entries:
        out += [ser_string(m["name"]), ser_string(m["type"]),
                struct.pack("<I", len(m["raw"])), m["raw"]]
    return b"".join(out)


def ser_map(map_type, m):
    if map_type in LINEAR_MAP_DOUBLES:
        d = m["doubles"]
        if len(d) != LINEAR_MAP_DOUBLES[map_type]:
            raise OracleError("%s needs %d doubles" % (map_type, LINEAR_MAP_DOUBLES[map_type]))
        return struct.pack("<%dd" % len(d), *d)
    if map_type == "NonlinearFrustumMap":
        return (struct.pack("<6d", *m["bbox"]) + struct.pack("<dd", m["taper"], m["depth"])
                + ser_string(m["second_type"]) + ser_map(m["second_type"], m["second"]))
    raise OracleError("unknown transform map type %r" % map_type)


def rebuild_file(info, grids):
    """Write a file from parsed records: header/file metadata verbatim, then for every
    grid its (possibly edited) descriptor, compression flags, metadata and transform,
    followed by the grid's original topology + buffer bytes, with the descriptor's
    64-bit grid/block/end offsets recomputed. `grids` are dicts as produced by
    parse_file_structure (edit unique_name, instance_parent, type_name, half_float,
    compression, metadata, map_type, map as needed; or set "body" and "body_block_rel"
    to replace the topology + buffer bytes)."""
    data = info["data"]
    out = bytearray(data[:info["grid_count_pos"]])
    out += struct.pack("<i", len(grids))
    for g in grids:
        out += ser_string(g["unique_name"])
        out += ser_string(g["type_name"] + ("_HalfFloat" if g["half_float"] else ""))
        if info["file_version"] >= FV_GRID_INSTANCING:
            out += ser_string(g["instance_parent"])
        offsets_pos = len(out)
        out += b"\0" * 24
        grid_pos = len(out)
        if info["file_version"] >= FV_NODE_MASK_COMPRESSION:
            out += struct.pack("<I", g["compression"])
        out += ser_metamap(g["metadata"])
        out += ser_string(g["map_type"]) + ser_map(g["map_type"], g["map"])
        body_start = len(out)
        if "body" in g:  # replacement topology + buffers, block offset relative to body
            out += g["body"]
            block_pos = body_start + g["body_block_rel"] if g["body_block_rel"] is not None else 0
        else:
            out += data[g["transform_end"]:g["end_pos"]]
            block_pos = (g["block_pos"] - g["transform_end"] + body_start) if g["block_pos"] else 0
        struct.pack_into("<qqq", out, offsets_pos, grid_pos, block_pos, len(out))
    return bytes(out)


def set_meta(g, name, type_name, raw):
    """Replace (or append) one grid metadata entry."""
    entry = {"name": name, "type": type_name, "raw": raw, "value": _decode_meta(type_name, raw)}
    for i, m in enumerate(g["metadata"]):
        if m["name"] == name:
            g["metadata"][i] = entry
            break
    else:
        g["metadata"].append(entry)
    g["meta"] = {m["name"]: m["value"] for m in g["metadata"]}


def read_background(info, g):
    """Root node background value (always stored at full precision)."""
    vt = g["value_type"]
    src = g
    if g["instance_parent"]:
        parents = [p for p in info["grids"] if p["unique_name"] == g["instance_parent"]]
        if not parents:
            raise OracleError("missing instance parent %r" % g["instance_parent"])
        src = parents[0]
    if vt not in VALUE_FORMATS:
        return None
    dtype, ncomp = VALUE_FORMATS[vt]
    pos = src["topology_pos"] + 4  # skip Tree buffer count (int32)
    vals = np.frombuffer(info["data"], dtype=np.dtype(dtype), count=ncomp, offset=pos)
    if vt in ("bool",):
        return bool(vals[0])
    if vt in ("mask", "ptdataidx32", "ptdataidx64"):
        return None
    if ncomp == 1:
        v = vals[0].item()
        return float(v) if np.issubdtype(vals.dtype, np.floating) else int(v)
    return [float(x) if np.issubdtype(vals.dtype, np.floating) else int(x) for x in vals]


# --------------------------------------------------------------------------------------
# Walking the node layout of an UNCOMPRESSED file written by OpenVDB (compression 0)
# --------------------------------------------------------------------------------------

def _mask_bits(data, pos, nbits):
    words = np.frombuffer(data, dtype="<u8", count=nbits // 64, offset=pos)
    bits = np.unpackbits(words.view(np.uint8), bitorder="little").astype(bool)
    return bits, pos + nbits // 8


def _offset_to_xyz(n, log2dim):
    m = (1 << log2dim) - 1
    return ((n >> (2 * log2dim)) & m, (n >> log2dim) & m, n & m)


class RawTree:
    """Topology (+ optionally leaf values) of one grid in an uncompressed file."""

    def __init__(self):
        self.background = None
        self.root_tiles = []     # (origin, value, active)
        self.nodes = []          # internal nodes: dict(level, origin, child, active, values)
        self.leaves = []         # dict(origin, mask, values)


def walk_raw_tree(info, g, read_values):
    """Walk a grid written with compression 0 (every value stored, no mask tricks)."""
    if g["compression"] != 0:
        raise OracleError("walk_raw_tree needs an uncompressed grid")
    src = g
    if g["instance_parent"]:
        src = [p for p in info["grids"] if p["unique_name"] == g["instance_parent"]][0]
    vt = src["value_type"]
    if vt not in VALUE_FORMATS:
        raise OracleError("value type %s has no raw layout here" % vt)
    dtype, ncomp = VALUE_FORMATS[vt]
    dtype = np.dtype(dtype)
    vsize = dtype.itemsize * ncomp
    # vdb_tool keeps the half flag of double and vec3d grids: their node values are
    # then halves (the half flag only changes the layout of floating-point values;
    # the root's background and tiles stay at full precision).
    node_dtype = np.dtype("<f2") if src["half_float"] and dtype.kind == "f" else dtype
    node_vsize = node_dtype.itemsize * ncomp
    dims = tree_config(src["type_name"])       # e.g. [5, 4, 3]
    total = [sum(dims[i:]) for i in range(len(dims))]  # log2 extent of each node level
    data = info["data"]
    t = RawTree()
    pos = src["topology_pos"]
    buffer_count = struct.unpack_from("<i", data, pos)[0]
    pos += 4
    if buffer_count != 1:
        raise OracleError("unexpected tree buffer count %d" % buffer_count)
    t.background = np.frombuffer(data, dtype=dtype, count=ncomp, offset=pos).copy()
    pos += vsize
    num_tiles, num_children = struct.unpack_from("<II", data, pos)
    pos += 8
    for _ in range(num_tiles):
        origin = struct.unpack_from("<3i", data, pos)
        pos += 12
        value = np.frombuffer(data, dtype=dtype, count=ncomp, offset=pos).copy()
        pos += vsize
        active = data[pos] != 0
        pos += 1
        t.root_tiles.append((origin, value, active))

    def read_internal(level, origin, pos):
        log2 = dims[level]
        nvals = 1 << (3 * log2)
        child, pos = _mask_bits(data, pos, nvals)
        active, pos = _mask_bits(data, pos, nvals)
        meta = data[pos]
        pos += 1
        if meta != 6:  # NO_MASK_AND_ALL_VALS
            raise OracleError("unexpected value metadata %d in uncompressed node" % meta)
        values = np.frombuffer(data, dtype=node_dtype, count=nvals * ncomp, offset=pos).astype(dtype)
        pos += nvals * node_vsize
        node = {"level": level, "origin": origin, "child": child, "active": active,
                "values": values.reshape(nvals, ncomp) if ncomp > 1 else values,
                "log2": log2, "child_log2": total[level + 1]}
        t.nodes.append(node)
        for n in np.nonzero(child)[0]:
            x, y, z = _offset_to_xyz(int(n), log2)
            s = total[level + 1]
            corigin = (origin[0] + (x << s), origin[1] + (y << s), origin[2] + (z << s))
            if level + 1 == len(dims) - 1:
                mask, pos = _mask_bits(data, pos, 1 << (3 * dims[-1]))
                t.leaves.append({"origin": corigin, "mask": mask})
            else:
                pos = read_internal(level + 1, corigin, pos)
        return pos

    for _ in range(num_children):
        origin = struct.unpack_from("<3i", data, pos)
        pos += 12
        pos = read_internal(0, origin, pos)
    if pos != src["block_pos"]:
        raise OracleError("topology size mismatch (%d vs block pos %d)" % (pos, src["block_pos"]))
    if read_values:
        leaf_vals = 1 << (3 * dims[-1])
        for leaf in t.leaves:
            mask, pos = _mask_bits(data, pos, leaf_vals)
            meta = data[pos]
            pos += 1
            if meta != 6:
                raise OracleError("unexpected value metadata %d in uncompressed leaf" % meta)
            vals = np.frombuffer(data, dtype=node_dtype, count=leaf_vals * ncomp, offset=pos).astype(dtype)
            pos += leaf_vals * node_vsize
            leaf["values"] = vals.reshape(leaf_vals, ncomp) if ncomp > 1 else vals
        if pos != src["end_pos"]:
            raise OracleError("buffer size mismatch (%d vs end pos %d)" % (pos, src["end_pos"]))
    return t


def raw_tree_stats(t, dims, want_values):
    """Counts, bbox and (optionally) values of a RawTree."""
    leaf_log2 = dims[-1]
    leaf_dim = 1 << leaf_log2
    root_log2 = sum(dims)
    voxels = 0
    tiles = []   # (min xyz, max xyz, value, count)
    lo = np.array([np.iinfo(np.int64).max] * 3)
    hi = np.array([np.iinfo(np.int64).min] * 3)
    for origin, value, active in t.root_tiles:
        if active:
            ext = 1 << root_log2
            tiles.append((origin, tuple(o + ext - 1 for o in origin), value, ext ** 3))
    for node in t.nodes:
        tile_on = node["active"] & ~node["child"]
        s = node["child_log2"]
        ext = 1 << s
        for n in np.nonzero(tile_on)[0]:
            x, y, z = _offset_to_xyz(int(n), node["log2"])
            o = (node["origin"][0] + (x << s), node["origin"][1] + (y << s),
                 node["origin"][2] + (z << s))
            tiles.append((o, tuple(c + ext - 1 for c in o), node["values"][n], ext ** 3))
    for (tmin, tmax, _v, cnt) in tiles:
        voxels += cnt
        lo = np.minimum(lo, tmin)
        hi = np.maximum(hi, tmax)
    coords = []
    values = []
    idx = np.arange(leaf_dim ** 3)
    lx, ly, lz = idx >> (2 * leaf_log2), (idx >> leaf_log2) & (leaf_dim - 1), idx & (leaf_dim - 1)
    for leaf in t.leaves:
        on = leaf["mask"]
        c = int(on.sum())
        if not c:
            continue
        voxels += c
        o = leaf["origin"]
        xyz = np.stack([lx[on] + o[0], ly[on] + o[1], lz[on] + o[2]], axis=1)
        lo = np.minimum(lo, xyz.min(axis=0))
        hi = np.maximum(hi, xyz.max(axis=0))
        if want_values:
            coords.append(xyz)
            values.append(np.asarray(leaf["values"])[on])
    return {"active_voxels": int(voxels), "bbox": (lo, hi) if voxels else None,
            "leaf_count": len(t.leaves), "active_tiles": len(tiles), "tiles": tiles,
            "coords": (np.concatenate(coords).astype(np.int64) if coords
                       else np.zeros((0, 3), dtype=np.int64)),
            "values": (np.concatenate(values).astype(np.float64).ravel() if values
                       else np.zeros(0))}


# --------------------------------------------------------------------------------------
# OpenVDB-backed evaluation
# --------------------------------------------------------------------------------------

def _import_pyopenvdb():
    try:
        import pyopenvdb  # noqa: F401
        return pyopenvdb
    except ImportError:
        raise OracleError("pyopenvdb is not importable by %s; run this script with "
                          "/usr/bin/python3 (Debian's python3-openvdb)" % sys.executable)


def _name_as_string(unique_name):
    """GridDescriptor::nameAsString: 'density\\x1e1' -> 'density[1]'."""
    if SEP in unique_name:
        base, n = unique_name.split(SEP, 1)
        return "%s[%s]" % (base, n)
    return unique_name


def stats_from_pyopenvdb(vdb, path, g, want_values):
    """Stats of a float/vec3s/bool grid as reported by pyopenvdb (plus a value dump)."""
    try:
        grid = vdb.read(path, _name_as_string(g["unique_name"]))
    except Exception as e:  # OpenVDB errors surface as various Python exceptions
        raise OracleError("OpenVDB cannot read grid %r: %s: %s"
                          % (g["unique_name"], type(e).__name__, e))
    out = {}
    out["pyopenvdb_class"] = grid.gridClass
    out["pyopenvdb_map_type"] = grid.transform.typeName
    out["voxel_size"] = [float(v) for v in grid.transform.voxelSize()]
    bg = grid.background
    out["background"] = list(bg) if isinstance(bg, tuple) else bg
    out["active_voxels"] = int(grid.activeVoxelCount())
    out["leaf_count"] = int(grid.leafCount())
    bmin, bmax = grid.evalActiveVoxelBoundingBox()
    out["bbox"] = (bmin, bmax) if out["active_voxels"] else None
    scalar = g["value_type"] == "float"
    if g["value_type"] == "vec3s" and want_values:
        return _vec3_from_pyopenvdb(grid, g, out)
    # An item with count 1 is a single voxel of a leaf node; every tile (root or
    # internal node level) covers at least one whole leaf (count >= 512).
    values, xyz, tiles = array("d"), array("i"), []
    n_tile_voxels = 0
    it = grid.citerOnValues()
    if scalar and want_values:
        put_v, put_c = values.append, xyz.extend
        for item in it:
            cnt = item.count
            if cnt == 1:
                put_v(item.value)
                put_c(item.min)
            else:
                tiles.append((item.min, item.max, item.value, cnt))
                n_tile_voxels += cnt
    elif scalar:
        put_v = values.append
        for item in it:
            cnt = item.count
            if cnt == 1:
                put_v(item.value)
            else:
                tiles.append((item.min, item.max, item.value, cnt))
                n_tile_voxels += cnt
    else:
        for item in it:
            cnt = item.count
            if cnt != 1:
                tiles.append((item.min, item.max, item.value, cnt))
                n_tile_voxels += cnt
    n_leaf_voxels = int(grid.activeLeafVoxelCount())
    if n_leaf_voxels + n_tile_voxels != out["active_voxels"]:
        raise OracleError("iterator/activeVoxelCount mismatch in %r" % g["unique_name"])
    if scalar and len(values) != n_leaf_voxels:
        raise OracleError("iterator/activeLeafVoxelCount mismatch in %r" % g["unique_name"])
    out["active_tiles"] = len(tiles)
    out["tiles"] = tiles
    if scalar:
        out["values"] = np.frombuffer(values, dtype=np.float64) if len(values) else np.zeros(0)
        out["coords"] = (np.frombuffer(xyz, dtype=np.intc).astype(np.int64).reshape(-1, 3)
                         if len(xyz) else np.zeros((0, 3), dtype=np.int64))
        if out["active_voxels"]:
            emin, emax = grid.evalMinMax()
            out["evalMinMax"] = (float(emin), float(emax))
    return out


def _vec3_from_pyopenvdb(grid, g, out):
    """Counts, active tiles and every active (x, y, z) value of a vec3s grid."""
    values, xyz, tiles = array("d"), array("i"), []
    n_tile_voxels = 0
    for item in grid.citerOnValues():
        cnt = item.count
        if cnt == 1:
            values.extend(item.value)
            xyz.extend(item.min)
        else:
            tiles.append((item.min, item.max, item.value, cnt))
            n_tile_voxels += cnt
    n_leaf_voxels = int(grid.activeLeafVoxelCount())
    if n_leaf_voxels + n_tile_voxels != out["active_voxels"] or len(values) != 3 * n_leaf_voxels:
        raise OracleError("iterator/activeVoxelCount mismatch in %r" % g["unique_name"])
    out["active_tiles"] = len(tiles)
    out["tiles"] = tiles
    out["values"] = (np.frombuffer(values, dtype=np.float64).reshape(-1, 3) if len(values)
                     else np.zeros((0, 3)))
    out["coords"] = (np.frombuffer(xyz, dtype=np.intc).astype(np.int64).reshape(-1, 3)
                     if len(xyz) else np.zeros((0, 3), dtype=np.int64))
    return out


def stats_from_raw(info_raw, g_raw, want_values):
    t = walk_raw_tree(info_raw, g_raw, read_values=want_values)
    src = g_raw
    if g_raw["instance_parent"]:
        src = [p for p in info_raw["grids"] if p["unique_name"] == g_raw["instance_parent"]][0]
    return raw_tree_stats(t, tree_config(src["type_name"]), want_values)


def oracle_name(i):
    return "__oracle_grid_%06d" % i


def run_vdb_tool_none(info, path, tmpdir):
    """Let OpenVDB decode the file and rewrite it uncompressed at full precision.
    vdb_tool writes grids in its own order (reverse-sorted by name), so every grid is
    first renamed to a unique index-derived name in a temporary copy."""
    renamed = []
    new_names = {g["unique_name"]: oracle_name(g["index"]) for g in info["grids"]}
    for g in info["grids"]:
        h = dict(g)
        h["metadata"] = list(g["metadata"])
        h["unique_name"] = new_names[g["unique_name"]]
        if g["instance_parent"]:
            h["instance_parent"] = new_names.get(g["instance_parent"], g["instance_parent"])
        if "name" in g["meta"]:
            set_meta(h, "name", "string", h["unique_name"].encode())
        renamed.append(h)
    src = os.path.join(tmpdir, "renamed.vdb")
    with open(src, "wb") as f:
        f.write(rebuild_file(info, renamed))
    out = os.path.join(tmpdir, "plain.vdb")
    p = subprocess.run(["vdb_tool", "-read", src, "-write", "codec=none", "bits=32", out],
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    msg = (p.stdout + p.stderr).decode("utf-8", "replace")
    if p.returncode != 0 or not os.path.exists(out):
        why = msg.strip()
        if "Fatal error in Tool::run:" in why:
            why = why.split("Fatal error in Tool::run:", 1)[1]
        raise OracleError("OpenVDB cannot read this file: %s" % why.strip().splitlines()[-1])
    return out


def parse_vdb_print(path):
    """Parse `vdb_print -l` (grids come sorted by name)."""
    p = subprocess.run(["vdb_print", "-l", path], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    text = (p.stdout + p.stderr).decode("utf-8", "replace")
    if "vdb_print ERROR" in text or p.returncode != 0:
        raise OracleError("vdb_print cannot read %s: %s" % (path, text.strip().splitlines()[-1]))
    blocks = []
    cur = None
    for line in text.splitlines():
        s = line.strip()
        if line.startswith("Name:"):
            cur = {"name": line[len("Name:"):].strip()}
            blocks.append(cur)
        elif cur is None:
            continue
        elif s.startswith("Type:"):
            cur["type"] = s.split(":", 1)[1].strip()
        elif s.startswith("Root("):
            leaf = s.split("Leaf(")[1].split(" x ")[0].replace(",", "")
            cur["leaf_count"] = int(leaf)
        elif s.startswith("Number of active voxels:"):
            cur["active_voxels"] = int(s.split(":")[1].replace(",", ""))
        elif s.startswith("Number of active tiles:"):
            cur["active_tiles"] = int(s.split(":")[1].replace(",", ""))
        elif s.startswith("Bounding box of active voxels:"):
            b = s.split(":", 1)[1].replace("[", "").replace("]", "").split("->")
            cur["bbox"] = ([int(v) for v in b[0].split(",")], [int(v) for v in b[1].split(",")])
        elif s.startswith("Min value:"):
            cur["min"] = s.split(":", 1)[1].strip()
        elif s.startswith("Max value:"):
            cur["max"] = s.split(":", 1)[1].strip()
        elif s.startswith("Background value:"):
            cur["background"] = s.split(":", 1)[1].strip()
    return blocks


def describe(path, want_voxels=False, crosscheck=False, skip_unreadable=False):
    info = parse_file_structure(path)
    vdb = None
    needs_raw = False
    for g in info["grids"]:
        if g["value_type"] in ("float", "vec3s", "bool"):
            vdb = vdb or _import_pyopenvdb()
        else:
            needs_raw = True
    grids_json = []
    dumps = []  # (grid_index, coords list, values list, tiles)
    with tempfile.TemporaryDirectory(prefix="vdb_oracle_") as tmpdir:
        info_raw = None
        raw_error = None
        if needs_raw:
            try:
                plain = run_vdb_tool_none(info, path, tmpdir)
            except OracleError as e:
                if not skip_unreadable:
                    raise
                raw_error = str(e)
        if needs_raw and raw_error is None:
            info_raw = parse_file_structure(plain)
            if len(info_raw["grids"]) != len(info["grids"]):
                raise OracleError("vdb_tool rewrote %d grids, file has %d"
                                  % (len(info_raw["grids"]), len(info["grids"])))
            raw_by_name = {g["unique_name"]: g for g in info_raw["grids"]}
        for g in info["grids"]:
            vt = g["value_type"]
            scalar = vt in ("float", "double")
            entry = {"name": g["name"], "value_type": vt}
            cls = g["meta"].get("class")
            entry["class"] = cls if cls in GRID_CLASSES else "unknown"
            entry["half_float"] = g["half_float"]
            entry["voxel_size"] = map_voxel_size(g["map_type"], g["map"])
            entry["map_type"] = g["map_type"]
            entry["background"] = read_background(info, g)
            if vt in ("float", "vec3s", "bool"):
                st = stats_from_pyopenvdb(vdb, path, g, want_voxels)
                # cross-check the parsed records against OpenVDB
                if st["pyopenvdb_map_type"] != g["map_type"]:
                    raise OracleError("map type mismatch %s vs %s"
                                      % (st["pyopenvdb_map_type"], g["map_type"]))
                if st["pyopenvdb_class"] != entry["class"]:
                    raise OracleError("class mismatch %s vs %s"
                                      % (st["pyopenvdb_class"], entry["class"]))
                if not np.allclose(st["voxel_size"], entry["voxel_size"], rtol=1e-9, atol=0):
                    raise OracleError("voxel size mismatch %s vs %s"
                                      % (st["voxel_size"], entry["voxel_size"]))
                if st["background"] != entry["background"]:
                    raise OracleError("background mismatch %r vs %r"
                                      % (st["background"], entry["background"]))
                entry["voxel_size"] = st["voxel_size"]
            elif raw_error is not None:
                # --skip-unreadable: OpenVDB cannot decode this grid (and vdb_tool
                # not the file); only its header fields are reported.
                entry.update({"unreadable": raw_error, "active_voxels": None, "bbox_min": None,
                              "bbox_max": None, "leaf_count": None, "active_tiles": None,
                              "min": None, "max": None, "sum": None})
                grids_json.append(entry)
                continue
            else:
                g_raw = raw_by_name.get(oracle_name(g["index"]))
                if g_raw is None or g_raw["value_type"] != vt:
                    raise OracleError("grid %d (%r) missing from vdb_tool's rewrite"
                                      % (g["index"], g["name"]))
                vec_values = want_voxels and vt == "vec3d"
                st = stats_from_raw(info_raw, g_raw, want_values=(vt == "double" or vec_values))
                if vec_values:
                    st["values"] = st["values"].reshape(-1, 3)
            entry["active_voxels"] = st["active_voxels"]
            if st["bbox"] is not None:
                entry["bbox_min"] = [int(v) for v in st["bbox"][0]]
                entry["bbox_max"] = [int(v) for v in st["bbox"][1]]
            else:
                entry["bbox_min"] = entry["bbox_max"] = None
            entry["leaf_count"] = st["leaf_count"]
            entry["active_tiles"] = st["active_tiles"]
            entry["min"] = entry["max"] = entry["sum"] = None
            if scalar and st["active_voxels"]:
                vals = st["values"]
                tvals = [float(np.asarray(t[2]).ravel()[0]) for t in st["tiles"]]
                mins = ([float(vals.min())] if len(vals) else []) + tvals
                maxs = ([float(vals.max())] if len(vals) else []) + tvals
                entry["min"] = min(mins)
                entry["max"] = max(maxs)
                entry["sum"] = math.fsum(itertools.chain(
                    array("d", vals.tobytes()) if len(vals) else (),
                    (tv * t[3] for tv, t in zip(tvals, st["tiles"]))))
                if "evalMinMax" in st and st["evalMinMax"] != (entry["min"], entry["max"]):
                    raise OracleError("evalMinMax %r disagrees with iterated %r"
                                      % (st["evalMinMax"], (entry["min"], entry["max"])))
            if want_voxels and (scalar or vt in VEC3_TYPES):
                dumps.append((g["index"], st["coords"], st["values"], st["tiles"]))
            grids_json.append(entry)
        if crosscheck:
            crosscheck_vdb_print(path, grids_json)
    result = {"path": path, "file_version": info["file_version"],
              "library_version": "%d.%d" % (info["library_major"], info["library_minor"]),
              "grids": grids_json}
    return result, dumps


def crosscheck_vdb_print(path, grids_json):
    blocks = parse_vdb_print(path)
    if len(blocks) != len(grids_json):
        raise OracleError("vdb_print lists %d grids, oracle %d" % (len(blocks), len(grids_json)))
    by_name = {}
    for b in blocks:
        by_name.setdefault(b["name"], []).append(b)
    for e in grids_json:
        cands = by_name.get(e["name"], [])
        ok = False
        for b in cands:
            if (b.get("active_voxels") == e["active_voxels"]
                    and b.get("active_tiles") == e["active_tiles"]
                    and b.get("leaf_count") == e["leaf_count"]
                    and (b.get("bbox") is None) == (e["bbox_min"] is None)
                    and (b.get("bbox") is None or (b["bbox"][0] == e["bbox_min"]
                                                   and b["bbox"][1] == e["bbox_max"]))):
                if e["min"] is not None and "min" in b:
                    if not (math.isclose(float(b["min"]), e["min"], rel_tol=1e-5, abs_tol=1e-30)
                            and math.isclose(float(b["max"]), e["max"], rel_tol=1e-5,
                                             abs_tol=1e-30)):
                        continue
                cands.remove(b)
                ok = True
                break
        if not ok:
            raise OracleError("crosscheck: no vdb_print block matches grid %r: %r vs %r"
                              % (e["name"], {k: e[k] for k in ("active_voxels", "active_tiles",
                                                               "leaf_count", "bbox_min",
                                                               "bbox_max", "min", "max")},
                                 by_name.get(e["name"])))


def write_dump(out_path, grid_count, dumps, components=1):
    """The --voxels dump (components 1) or the --vec3-voxels dump (components 3)."""
    vt = ("<f8", (3,)) if components == 3 else "<f8"
    vox_dt = np.dtype([("g", "<u4"), ("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("v", vt)])
    tile_dt = np.dtype([("g", "<u4"), ("x0", "<i4"), ("y0", "<i4"), ("z0", "<i4"),
                        ("x1", "<i4"), ("y1", "<i4"), ("z1", "<i4"), ("v", vt)])
    assert vox_dt.itemsize == 16 + 8 * components and tile_dt.itemsize == 28 + 8 * components
    vox_parts, tile_parts = [], []
    for gi, c, v, tiles in dumps:
        if (np.ndim(v) == 2) != (components == 3):
            continue
        if len(v):
            a = np.empty(len(v), dtype=vox_dt)
            a["g"] = gi
            a["x"], a["y"], a["z"] = c[:, 0], c[:, 1], c[:, 2]
            a["v"] = v
            vox_parts.append(a)
        if tiles:
            a = np.empty(len(tiles), dtype=tile_dt)
            a["g"] = gi
            for i, (tmin, tmax, val, _cnt) in enumerate(tiles):
                tv = np.asarray(val, dtype=np.float64).ravel()
                a[i] = (gi, tmin[0], tmin[1], tmin[2], tmax[0], tmax[1], tmax[2],
                        tv if components == 3 else float(tv[0]))
            tile_parts.append(a)
    vox = np.concatenate(vox_parts) if vox_parts else np.zeros(0, dtype=vox_dt)
    til = np.concatenate(tile_parts) if tile_parts else np.zeros(0, dtype=tile_dt)
    vox = vox[np.lexsort((vox["z"], vox["y"], vox["x"], vox["g"]))]
    til = til[np.lexsort((til["z0"], til["y0"], til["x0"], til["g"]))]
    with open(out_path, "wb") as f:
        f.write(VEC3_DUMP_MAGIC if components == 3 else DUMP_MAGIC)
        f.write(struct.pack("<IIQQ", grid_count, 0, len(vox), len(til)))
        f.write(vox.tobytes())
        f.write(til.tobytes())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("file")
    ap.add_argument("--voxels", metavar="OUT.bin", help="write the binary active-value dump")
    ap.add_argument("--vec3-voxels", metavar="OUT3.bin",
                    help="write the binary active-value dump of the vec3 grids")
    ap.add_argument("--skip-unreadable", action="store_true",
                    help="describe the grids OpenVDB can load even when vdb_tool cannot "
                         "rewrite the file (the others are marked \"unreadable\")")
    ap.add_argument("--crosscheck", action="store_true",
                    help="also compare every grid against `vdb_print -l`")
    args = ap.parse_args(argv)
    try:
        result, dumps = describe(args.file, want_voxels=bool(args.voxels or args.vec3_voxels),
                                 crosscheck=args.crosscheck,
                                 skip_unreadable=args.skip_unreadable)
        if args.voxels:
            write_dump(args.voxels, len(result["grids"]), dumps)
        if args.vec3_voxels:
            write_dump(args.vec3_voxels, len(result["grids"]), dumps, components=3)
    except OracleError as e:
        print("openvdb_oracle: %s: %s" % (args.file, e), file=sys.stderr)
        return 2
    except OSError as e:
        print("openvdb_oracle: %s: %s" % (args.file, e), file=sys.stderr)
        return 2
    json.dump(result, sys.stdout)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
