#!/usr/bin/python3
"""Tests scripts/vpak_read.py on version-7 (segmented) files, built here from the version-6
bodies of files that vdbcook cooks (docs/format.md, "File layout" and "Segments").

    /usr/bin/python3 scripts/test_vpak_segments.py [--vdbcook PATH]

Cooks fixtures/smoke_seq whole and in two halves (frames 1-2 and 3-4, the same settings),
wraps the halves' files as the bodies of a two-segment file, and checks that every frame
decodes as in its half (and as in the whole cook), that the merged metadata is the
union, and that damaged containers are refused with the expected message. Everything is
written to a temporary directory, removed at the end. Exit status 0 when every check passes.
"""

import argparse
import os
import shutil
import struct
import subprocess
import sys
import tempfile

import numpy as np
import xxhash

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
import vpak_read as v  # noqa: E402

FIXTURE = os.path.join(ROOT, "fixtures", "smoke_seq")


def xxh(b):
    return xxhash.xxh3_64_intdigest(bytes(b))


def up(n):
    return -(-n // 256) * 256


def head_len(body):
    return 64 + 32 * struct.unpack_from("<I", body, 16)[0]


def container(bodies, counts=None, entries=None, count=None, gap=0):
    """A version-7 file of `bodies` (version-6 files). `entries(list)` may edit the table
    [first, count, offset, size, head] before the header checksum is computed; bodies are
    placed at the table's offsets (`gap` bytes more between bodies)."""
    counts = counts or [v.decode_metadata(v.Sections(b, v.read_header(b)).get(v.K_METADATA))["frame_count"] for b in bodies]
    table, at, first = [], up(64 + 32 * len(bodies)), 0
    for b, n in zip(bodies, counts):
        table.append([first, n, at, len(b), xxh(b[:head_len(b)])])
        first, at = first + n, up(at + len(b) + gap)
    if entries:
        entries(table)
    size = max([e[2] + e[3] for e in table] + [64 + 32 * len(table)])
    out = bytearray(size)
    for b, e in zip(bodies, table):
        out[e[2]:e[2] + len(b)] = b
    out[0:64] = bytes(64)
    out[0:8] = v.MAGIC
    struct.pack_into("<IIIIQ", out, 8, 7, 0, len(table) if count is None else count, 0, size)
    for i, e in enumerate(table):
        struct.pack_into("<IIQQQ", out, 64 + 32 * i, *e)
    return reseal(out)


def reseal(out):
    """Recompute the header checksum of a file or body (after an edit of its table)."""
    n = struct.unpack_from("<I", out, 16)[0]
    struct.pack_into("<Q", out, 32, xxh(bytes(out[0:32]) + bytes(out[64:64 + 32 * n])))
    return bytes(out)


def patch_metadata(body, old, new):
    """The body with `old` replaced by `new` (same length) in its metadata, checksums renewed."""
    assert len(old) == len(new)
    out = bytearray(body)
    for i in range(struct.unpack_from("<I", body, 16)[0]):
        kind, _, off, size, _ = struct.unpack_from("<IIQQQ", body, 64 + 32 * i)
        if kind == v.K_METADATA:
            data = bytes(out[off:off + size])
            assert old in data, old
            out[off:off + size] = data.replace(old, new)
            struct.pack_into("<Q", out, 64 + 32 * i + 24, xxh(out[off:off + size]))
    return reseal(out)


def refused(data, expect):
    try:
        v.Asset(memoryview(data))
    except v.VpakError as e:
        assert expect in str(e), f"expected {expect!r}, got {e!r}"
        return str(e)
    raise AssertionError(f"accepted a file that should fail with {expect!r}")


def same_frame(x, y):
    assert x.keys() == y.keys()
    for name in x:
        assert np.array_equal(x[name][0], y[name][0]), name
        assert np.array_equal(x[name][1].view(np.uint32), y[name][1].view(np.uint32)), name


def cook(vdbcook, work, name, frames, flags):
    """Cook `frames` of the fixture as `seq` from a directory of their own (so the settings,
    the input path included, are the same for every part)."""
    d = os.path.join(work, name)
    os.makedirs(os.path.join(d, "seq"))
    for f in frames:
        shutil.copy(os.path.join(FIXTURE, f"smoke_{f:04d}.vdb"), os.path.join(d, "seq"))
    subprocess.run([vdbcook, "cook", "-q", "-o", "out.vpak", "seq", *flags], cwd=d, check=True)
    with open(os.path.join(d, "out.vpak"), "rb") as f:
        data = f.read()
    # vdbcook writes a segmented file (version 7 or later) even of one segment: its body,
    # uncompressed, is the version-6 file this test wraps.
    version, table = v.read_table(memoryview(data), (6, 7, 8, 9, 10, 11, 12, 13, 14, 15), "file")
    if version == 6:
        return data
    assert len(table) == 1, table
    body = data[table[0][2]:table[0][2] + table[0][3]]
    # A small supercompressed body is stored wrapped in one zstd frame (version 13).
    return v.inflate(body, v.MAX_WRAPPED) if body[:4] == v.ZSTD_MAGIC else body


def check_flags(vdbcook, work, flags, exact_vs_whole):
    tag = "-".join(flags) or "default"
    whole = cook(vdbcook, work, f"{tag}-whole", [1, 2, 3, 4], flags)
    a, b = cook(vdbcook, work, f"{tag}-a", [1, 2], flags), cook(vdbcook, work, f"{tag}-b", [3, 4], flags)
    two = container([a, b])
    path = os.path.join(work, f"{tag}-two.vpak")
    with open(path, "wb") as f:
        f.write(two)
    asset, wa, halves = v.open_segments(path), v.Asset(memoryview(whole)), [v.Asset(memoryview(a)), v.Asset(memoryview(b))]
    assert asset.version == 7 and [e[:2] for e in asset.table] == [(0, 2), (2, 2)]
    assert [asset.locate(f) for f in range(4)] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    refused_frame = False
    try:
        asset.locate(4)
    except v.VpakError:
        refused_frame = True
    assert refused_frame
    for lod in range(wa.meta["first_level"], wa.meta["levels"]):
        for f in range(4):
            got = asset.read_frame(f, lod)
            same_frame(got, halves[f // 2].read_frame(f % 2, lod))
            if exact_vs_whole:
                same_frame(got, wa.read_frame(f, lod))
    # A body cut out of the file is a version-6 file of its own.
    e = asset.table[1]
    same_frame(v.Asset(memoryview(two[e[2]:e[2] + e[3]])).read_frame(1), halves[1].read_frame(1))
    # The whole sequence's facts: the union of the segments'.
    m, w = asset.meta, wa.meta
    assert m["frame_count"] == 4 and len(m["frames"]) == 4
    assert [c["value_range"] for c in m["channels"]] == [c["value_range"] for c in w["channels"]]
    assert m["index_bbox"] == w["index_bbox"] and m["index_offset"] == w["index_offset"]
    assert [m["sources"][f["source"]]["path"] for f in m["frames"]] == [f"seq/smoke_{i:04d}.vdb" for i in range(1, 5)]
    assert [f["active_voxels"] for f in m["frames"]] == [f["active_voxels"] for f in w["frames"]]
    # open_asset: one body (version 6, or version 7 of one segment), not several.
    one = container([whole])
    with open(os.path.join(work, "one.vpak"), "wb") as f:
        f.write(one)
    m1, s1 = v.open_asset(os.path.join(work, "one.vpak"))
    assert m1["frame_count"] == 4 and np.array_equal(s1.u32(v.K_FRAMES), wa.bodies[0][1].u32(v.K_FRAMES))
    try:
        v.open_asset(path)
        raise AssertionError("open_asset read a file of two segments")
    except v.VpakError as e:
        assert "2 segments" in str(e)
    # The command line decodes frame 3 from segment 1.
    npz = os.path.join(work, f"{tag}.npz")
    r = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "vpak_read.py"), path, "--frame", "3", "--out", npz, "--json"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    got, want = np.load(npz), halves[1].read_frame(1)
    assert all(np.array_equal(got[f"{n}.values"], want[n][1]) for n in want)
    return a, b, two


def check_refusals(a, b, two, work):
    """Damaged containers: each refused with its rule's message (checksums renewed where the
    damage must reach the rule)."""
    refused(container([a, b], entries=lambda t: t[1].__setitem__(0, 3)), "segment 1 starts at frame 3, the segments before it end at frame 2")
    refused(container([a, b], entries=lambda t: t[1].__setitem__(2, t[1][2] + 8)), "segment 1 at")
    refused(container([a, b], entries=lambda t: t[1].__setitem__(2, t[0][2] + 256)), "overlaps the one before")
    refused(container([a, b], entries=lambda t: t[0].__setitem__(2, 0)), "segment 0 at 0+")
    refused(container([a, b], entries=lambda t: t[1].__setitem__(4, t[1][4] ^ 1)), "segment 1: its header and section table are not the ones")
    refused(container([a, b], counts=[3, 2]), "segment 0: its metadata has 2 frames, the segment table 3")
    refused(container([a], count=0), "0 segments")
    refused(container([a, two], counts=[2, 4]), "segment 1: unsupported format version 7 (a body here is version 6)")
    refused(container([a, patch_metadata(b, b"density", b"densitx")]), "segment 1's channels differ from segment 0's")
    refused(container([a, patch_metadata(b, b"vdbcook 0.", b"vdbcook 9.")]), "segment 1 and segment 0 differ in tool")
    refused(container([a, patch_metadata(b, b"f16", b"f32")]), "segment 1 and segment 0 differ in settings")
    # Padding between bodies, and after the last, must be zero.
    gap = bytearray(container([a, b], gap=256))
    ok = bytes(gap)
    v.Asset(memoryview(ok))
    gap[up(64 + 64) + len(a) + 3] = 1
    refused(bytes(gap), "non-zero padding between segments")
    # A flipped byte anywhere but the reserved header bytes [40, 64): in the table
    # (header checksum), in a body's header or sections.
    heads = list(range(0, 40)) + list(range(64, 128))
    e1 = struct.unpack_from("<Q", two, 64 + 32 + 8)[0]
    bodies = [e1 + i for i in range(0, head_len(b))] + list(range(up(128), len(two), 997))
    for i in heads + bodies:
        bad = bytearray(two)
        bad[i] ^= 0x10
        refused(bytes(bad), "")
    for i in range(40, 64):
        bad = bytearray(two)
        bad[i] ^= 0x10
        v.Asset(memoryview(bytes(bad)))
    refused(two[:-1], "file size")
    refused(bytes(bytearray(two[:64]) + bytes(32)), "")
    # The command line: one line naming the file and the problem, status 1.
    bad_path = os.path.join(work, "bad.vpak")
    with open(bad_path, "wb") as f:
        f.write(container([a, b], entries=lambda t: t[1].__setitem__(0, 1)))
    r = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "vpak_read.py"), bad_path, "--frame", "0"], capture_output=True, text=True)
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and r.stderr.startswith(f"vpak_read.py: {bad_path}: segment 1 starts at frame 1"), r.stderr
    return len(heads) + len(bodies)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vdbcook", default=os.environ.get("VDBCOOK", os.path.join(ROOT, "target", "release", "vdbcook")))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="vpak-seg-") as work:
        # f16 decodes each voxel alike in any cook; per-brick formats may place a
        # channel in other planes per segment; levels of detail.
        a, b, two = check_flags(args.vdbcook, work, [], True)
        check_flags(args.vdbcook, work, ["--max-error", "0.004"], False)
        check_flags(args.vdbcook, work, ["--lods", "3", "--format", "bc4"], False)
        flips = check_refusals(a, b, two, work)
    print(f"ok: 3 cooks of two segments decoded frame by frame; damaged containers refused ({flips} flipped bytes)")


if __name__ == "__main__":
    main()
