#!/usr/bin/python3
"""Writes vec3 .vdb files with OpenVDB itself, for cli/tests/vec3.rs.

    /usr/bin/python3 cli/tests/vec3_sources.py OUTDIR

prints the names of the files it wrote into OUTDIR, one per line. Needs Debian's
python3-openvdb (the system /usr/bin/python3), numpy and vdb_tool (openvdb-tools).

One vec3s grid `vel` (class staggered, background (0.5, -1, 2), voxel size 0.25) holds:
* seven leaves whose inactive values make OpenVDB's writer choose each per-node
  active-mask code 0 to 6 (background; -background; one other value; +-background with a
  selection mask; background and one other; two others; three values: all stored);
* a dense, fully active leaf, active leaves at negative coordinates;
* active and inactive (non-background) tiles at every level: 8^3 (in a 16^3 node),
  128^3 (in a 32^3 node) and 4096^3 (at the root).
pyopenvdb writes it blosc + active-mask; vdb_tool rewrites it with every other codec
(none, zip + mask, mask only) and as halves (three halves per value). A vec3d copy is
made by converting the uncompressed file's values to doubles here (pyopenvdb 10 has no
Vec3DGrid), then re-encoded by vdb_tool the same ways.
"""

import os
import struct
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts"))
import openvdb_oracle as oracle  # noqa: E402
import pyopenvdb as vdb  # noqa: E402

BG = (0.5, -1.0, 2.0)


def base_grid():
    rng = np.random.default_rng(20261123)
    g = vdb.Vec3SGrid(BG)
    g.name = "vel"
    g.gridClass = vdb.GridClass.STAGGERED
    g.transform = vdb.createLinearTransform(voxelSize=0.25)
    acc = g.getAccessor()
    neg = tuple(-x for x in BG)
    one = (7.0, 8.0, -9.0)
    two = (0.25, 0.125, -4.0)
    patterns = [
        lambda i: BG,
        lambda i: neg,
        lambda i: one,
        lambda i: neg if i % 2 else BG,
        lambda i: one if i % 2 else BG,
        lambda i: one if i % 2 else two,
        lambda i: (one, two, neg)[i % 3],
    ]
    for k, pattern in enumerate(patterns):
        ox, oy, oz = 8 * k - 24, -16, 8
        active = rng.random(512) < 0.3
        vals = rng.standard_normal((512, 3)).astype(np.float32)
        for i in range(512):
            ijk = (ox + (i >> 6), oy + ((i >> 3) & 7), oz + (i & 7))
            if active[i]:
                acc.setValueOn(ijk, tuple(float(v) for v in vals[i]))
        for i in range(512):
            ijk = (ox + (i >> 6), oy + ((i >> 3) & 7), oz + (i & 7))
            if not active[i]:
                acc.setValueOff(ijk, pattern(i))
    # a dense, fully active leaf with full-precision floats
    vals = (rng.random((512, 3)) * 1e3 - 500).astype(np.float32)
    for i in range(512):
        acc.setValueOn((40 + (i >> 6), 40 + ((i >> 3) & 7), 40 + (i & 7)), tuple(float(v) for v in vals[i]))
    # tiles at every level, active and inactive with non-background values
    g.fill((64, 64, 64), (71, 71, 71), (1.0, 2.0, 3.0), True)
    g.fill((72, 64, 64), (79, 71, 71), (-1.0, -2.0, -3.5), False)
    g.fill((256, 0, 0), (383, 127, 127), (4.0, 5.0, 6.0), True)
    g.fill((384, 0, 0), (511, 127, 127), (0.5, -1.0, 7.0), False)
    g.fill((4096, 0, 0), (8191, 4095, 4095), (0.1, 0.2, 0.3), True)
    g.fill((-8192, 0, 0), (-4097, 4095, 4095), (9.0, 9.0, 9.0), False)
    return g


def vdb_tool(src, dst, codec, bits=32):
    p = subprocess.run(["vdb_tool", "-read", src, "-write", "codec=%s" % codec, "bits=%d" % bits, dst],
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if p.returncode != 0 or not os.path.exists(dst):
        raise RuntimeError("vdb_tool failed on %s: %s" % (src, (p.stdout + p.stderr).decode()))


def to_vec3d(src, dst):
    """Rewrites an uncompressed vec3s file (every node: metadata 6 + all values) as vec3d."""
    info = oracle.parse_file_structure(src)
    grids = []
    for g in info["grids"]:
        assert g["compression"] == 0 and not g["half_float"] and g["value_type"] == "vec3s", g["type_name"]
        data = info["data"]
        pos = g["transform_end"]
        out = bytearray()

        def copy(n):
            nonlocal pos
            out.extend(data[pos:pos + n])
            pos += n

        def vals(n):
            nonlocal pos
            out.extend(np.frombuffer(data, "<f4", 3 * n, pos).astype("<f8").tobytes())
            pos += 12 * n

        def mask_bits(nbits):
            words = np.frombuffer(data, "<u8", nbits // 64, pos)
            return np.unpackbits(words.view(np.uint8), bitorder="little").astype(bool)

        leaves = 0

        def internal(log2, leaf_level):
            nonlocal pos, leaves
            n = 1 << (3 * log2)
            child = mask_bits(n)
            copy(2 * n // 8)
            assert data[pos] == 6
            copy(1)
            vals(n)
            for _ in np.nonzero(child)[0]:
                if leaf_level:
                    copy(64)
                    leaves += 1
                else:
                    internal(4, True)

        copy(4)
        vals(1)
        ntiles, nchildren = struct.unpack_from("<II", data, pos)
        copy(8)
        for _ in range(ntiles):
            copy(12)
            vals(1)
            copy(1)
        for _ in range(nchildren):
            copy(12)
            internal(5, False)
        block_rel = len(out)
        for _ in range(leaves):
            copy(64)
            assert data[pos] == 6
            copy(1)
            vals(512)
        assert pos == g["end_pos"], (pos, g["end_pos"])
        h = dict(g)
        h["type_name"] = "Tree_vec3d_5_4_3"
        h["body"] = bytes(out)
        h["body_block_rel"] = block_rel
        grids.append(h)
    with open(dst, "wb") as f:
        f.write(oracle.rebuild_file(info, grids))


def main():
    out = sys.argv[1]
    written = []

    def path(name):
        written.append(name)
        return os.path.join(out, name)

    blosc = path("vec3s_blosc.vdb")
    vdb.write(blosc, grids=[base_grid()])
    for codec in ("none", "zip", "active"):
        vdb_tool(blosc, path("vec3s_%s.vdb" % codec), codec)
    for codec in ("blosc", "zip", "active"):
        vdb_tool(blosc, path("vec3s_half_%s.vdb" % codec), codec, 16)
    plain_d = path("vec3d_none.vdb")
    to_vec3d(os.path.join(out, "vec3s_none.vdb"), plain_d)
    for codec in ("blosc", "zip", "active"):
        vdb_tool(plain_d, path("vec3d_%s.vdb" % codec), codec)
    vdb_tool(plain_d, path("vec3d_half_blosc.vdb"), "blosc", 16)
    for name in written:
        print(name)


if __name__ == "__main__":
    main()
