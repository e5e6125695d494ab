#!/usr/bin/python3
"""Tests scripts/vpak_read.py on version-8 files with supercompressed sections
(docs/format.md, "Supercompression").

    /usr/bin/python3 scripts/test_vpak_coding.py [--vdbcook PATH]

Cooks fixtures/smoke_seq with `--supercompress zstd` (several formats, levels and
segments) and rewrites each with `vdbcook recompress --supercompress none`: every
restored section must be the uncompressed asset's, byte for byte, and every frame decode
alike. Then files rewritten here with every filter the page allows (its own forward
filters, not the reader's) must decode alike too, and corrupt or rule-breaking coding
must be refused with the rule's message. Everything is written to a temporary
directory, removed at the end. Exit status 0 when every check passes.
"""

import argparse
import os
import struct
import subprocess
import sys
import tempfile

import numpy as np
import zstandard

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
import vpak_read as v  # noqa: E402
from vpak_coding import FILTER_NAMES  # noqa: E402
from test_vpak_segments import container, reseal, refused, same_frame, up, xxh  # noqa: E402

FIXTURE = os.path.join(ROOT, "fixtures", "smoke_seq")
K_CODING = 13


def sections_of(body):
    """The body's sections as stored, in table order: [kind, index, bytes]."""
    n = struct.unpack_from("<I", body, 16)[0]
    out = []
    for i in range(n):
        kind, index, off, size, _ = struct.unpack_from("<IIQQQ", body, 64 + 32 * i)
        out.append([kind, index, bytes(body[off:off + size])])
    return out


def make_body(sections, align=256):
    """A version-6 body of `sections` [kind, index, bytes], each at the next multiple of
    `align` bytes (256, or 8 as a version-11 or 12 writer packs a supercompressed body)."""
    to = lambda n: -(-n // align) * align
    at, table = to(64 + 32 * len(sections)), []
    for kind, index, data in sections:
        table.append((kind, index, at, len(data), xxh(data)))
        at = to(at + len(data))
    out = bytearray(max([64 + 32 * len(sections)] + [e[2] + e[3] for e in table]))
    out[0:8] = v.MAGIC
    struct.pack_into("<IIIIQ", out, 8, 6, 0, len(sections), 0, len(out))
    for i, e in enumerate(table):
        struct.pack_into("<IIQQQ", out, 64 + 32 * i, *e)
        out[e[2]:e[2] + e[3]] = sections[i][2]
    return reseal(out)


def make_file(bodies, version=15):
    """A file of `bodies` (segments), of the given version."""
    out = bytearray(container(bodies))
    struct.pack_into("<I", out, 8, version)
    return reseal(out)


def stored_bodies(data):
    """The bodies of a segmented file as the segment table places them (not validated):
    a wrapped one (version 13) as its zstd frame."""
    _, table = v.read_table(memoryview(data), (7, 8, 9, 10, 11, 12, 13, 14, 15), "file")
    return [bytes(data[e[2]:e[2] + e[3]]) for e in table]


def bodies_of(data):
    """The bodies of a segmented file, a wrapped one decompressed (not validated)."""
    return [v.inflate(b, v.MAX_WRAPPED) if b[:4] == v.ZSTD_MAGIC else b for b in stored_bodies(data)]


def records_of(sections):
    coding = [d for k, _, d in sections if k == K_CODING]
    if not coding:
        return {}
    recs = [list(struct.unpack_from("<IIIIIIQQ", coding[0], 40 * r)) for r in range(len(coding[0]) // 40)]
    return {(r[0], r[1]): r for r in recs}


def coding_bytes(recs):
    return b"".join(struct.pack("<IIIIIIQQ", *r) for r in recs)


def shuffle(data, w):
    """Forward shuffle: byte j of every w-byte element together."""
    return np.frombuffer(data, np.uint8).reshape(len(data) // w, w).T.tobytes()


def delta(data, w, s):
    """Forward delta: d[i] = x[i] - x[i - s] (mod 2^(8w)) for i >= s, then shuffled."""
    x = np.frombuffer(data, {1: "<u1", 2: "<u2", 4: "<u4"}[w]).astype(np.int64)
    d = x.copy()
    d[s:] = (x[s:] - x[:-s]) % (1 << (8 * w)) if s < len(x) else d[s:]
    return shuffle(d.astype({1: "<u1", 2: "<u2", 4: "<u4"}[w]).tobytes(), w)


def tiles(data, w, x, y, predict=True):
    """Forward tiles: per 8x8x8 tile of the 8x x 8y x 8z texture, the gcd of its elements,
    then its elements over the gcd, and (predict) their 3D differences along i, j and k,
    mod 2^(8w)."""
    dt = {1: "<u1", 2: "<u2"}[w]
    e = np.frombuffer(data, dt).astype(np.int64)
    z = len(e) // (512 * x * y)
    t = e.reshape(z, 8, y, 8, x, 8).transpose(0, 2, 4, 1, 3, 5).reshape(-1, 512)  # tiles (c, b, a), then k, j, i
    g = np.gcd.reduce(t, axis=1)
    u = (t // np.maximum(g, 1)[:, None]).reshape(-1, 8, 8, 8)
    for axis in (1, 2, 3) if predict else ():
        u = np.diff(u, axis=axis, prepend=0)
    out = np.concatenate([g, (u % (1 << (8 * w))).ravel()]).astype(dt)
    return shuffle(out.tobytes(), w)


def l3_nodes(data):
    """Forward l3 nodes: the count; per node its brick less the one before (0 before the
    first), its states, its first word less where the node before's sub-masks end (1 + 3c
    before the first), as three runs of c words shuffled by byte; the sub-masks as they are."""
    words = np.frombuffer(data, "<u4").astype(np.int64)
    c = int(words[0])
    rec = words[1:1 + 3 * c].reshape(c, 3)
    states = rec[:, 1]
    ends = rec[:, 2] + 2 * np.array([bin((int(x) >> 1) & 0x5555).count("1") for x in states], np.int64)
    steps_b = rec[:, 0] - np.concatenate([[0], rec[:-1, 0]])
    steps_f = rec[:, 2] - np.concatenate([[1 + 3 * c], ends[:-1]])
    fields = (np.concatenate([steps_b, states, steps_f]) % 2**32).astype("<u4").tobytes()
    return data[:4] + shuffle(fields, 4) + data[4 + 12 * c:]


def cook(vdbcook, work, tag, flags):
    path = os.path.join(work, f"{tag}.vpak")
    subprocess.run([vdbcook, "cook", "-q", "--force", "-o", path, FIXTURE, *flags], check=True)
    with open(path, "rb") as f:
        return f.read()


def recompress(vdbcook, work, data, coding):
    src, dst = os.path.join(work, "in.vpak"), os.path.join(work, "out.vpak")
    with open(src, "wb") as f:
        f.write(data)
    subprocess.run([vdbcook, "recompress", "-q", "--force", src, "-o", dst, "--supercompress", coding], check=True)
    with open(dst, "rb") as f:
        return f.read()


def same_asset(a, b, frames=4):
    """Two files decode alike: same segments, every frame and level equal."""
    x, y = v.Asset(memoryview(a)), v.Asset(memoryview(b))
    assert [e[:2] for e in x.table] == [e[:2] for e in y.table]
    for lod in range(x.meta["first_level"], x.meta["levels"]):
        for f in range(frames):
            same_frame(x.read_frame(f, lod), y.read_frame(f, lod))
    return x, y


def check_restores(vdbcook, work, flags):
    """A vdbcook zstd asset restores exactly the sections of the same asset uncompressed."""
    packed = cook(vdbcook, work, "z", ["--supercompress", "zstd", *flags])
    plain = recompress(vdbcook, work, packed, "none")
    assert struct.unpack_from("<I", packed, 8)[0] == 15
    z, p = same_asset(packed, plain)
    filters = set()
    for (mz, sz), (_, sp), body in zip(z.bodies, p.bodies, bodies_of(packed)):
        assert (K_CODING, 0) not in sp.table, "recompress --supercompress none left a coding section"
        recs = records_of(sections_of(body))
        assert recs, f"{flags}: no section supercompressed"
        filters |= {(r[3], r[4]) for r in recs.values()}
        for key in sp.table:
            if key[0] != v.K_METADATA:  # the metadata records the supercompress setting
                assert bytes(sz.get(*key)) == bytes(sp.get(*key)), f"{flags}: section {key} restored differs"
        assert set(sz.table) - {(K_CODING, 0)} == set(sp.table)
        stored = sum(sz.table[k][1] for k in recs)
        assert stored < sum(r[6] for r in recs.values()), "compressed sections not smaller than restored"
    return packed, plain, filters


def check_every_filter(plain):
    """Sections compressed here with every allowed filter (forward filters written from the
    page) decode as the plain asset does."""
    # Tiles first: only atlases fit them, and there are few.
    variants = [(3, 2, 1 | 1 << 16), (3, 1, 1 | 2 << 16), (4, 2, 1 | 1 << 16), (5, 4, 0), (0, 1, 0)] \
        + [(1, w, 0) for w in (1, 2, 4, 8, 16)] + [(2, w, s) for w in (1, 2, 4) for s in (1, 3, 4096)]
    # A section fits a filter when it is whole elements (tiles: whole slabs of X x Y tiles).
    unit = lambda filt, w, s: w * 512 * (s % 65536) * (s // 65536) if filt in (3, 4) else w
    bodies, used, k = [], set(), 0
    for body in bodies_of(plain):
        secs, recs = sections_of(body), []
        for sec in secs:
            kind, index, data = sec
            if kind == v.K_METADATA or not data:
                continue
            # The first filter not yet used that fits the section (else any that fits).
            fits = [x for x in variants if len(data) % unit(*x) == 0 and (x[0] == 5) == (kind == v.K_L3)]
            filt, w, s = next((x for x in fits if x not in used), fits[k % len(fits)])
            k += 1
            used.add((filt, w, s))
            f = data if filt == 0 else shuffle(data, w) if filt == 1 else delta(data, w, s) if filt == 2 else \
                l3_nodes(data) if filt == 5 else tiles(data, w, s % 65536, s // 65536, filt == 3)
            # Frames with and without their content size in the header.
            sec[2] = zstandard.ZstdCompressor(level=3, write_content_size=k % 2 == 0).compress(f)
            recs.append((kind, index, 1, filt, w, s, len(data), xxh(data)))
        bodies.append(make_body(secs + [[K_CODING, 0, coding_bytes(recs)]]))
    assert len(used) == len(variants), f"only {len(used)} of {len(variants)} filters used: {sorted(set(variants) - used)} not"
    same_asset(make_file(bodies), plain)


def with_body(packed, edit, seg=0):
    """`packed` rebuilt with segment `seg`'s sections (a list of [kind, index, bytes]) edited."""
    bodies = bodies_of(packed)
    secs = sections_of(bodies[seg])
    edit(secs)
    bodies[seg] = make_body(secs)
    return make_file(bodies)


def edit_section(kind, fn):
    """An edit of the first compressed section of `kind` (its stored bytes)."""
    def edit(secs):
        recs = records_of(secs)
        sec = next(s for s in secs if (s[0], s[1]) in recs and s[0] == kind)
        sec[2] = fn(sec[2])
    return edit


def edit_record(fn):
    """An edit of the coding records (list of [kind, index, scheme, filter, w, s, n, checksum])."""
    def edit(secs):
        recs = list(records_of(secs).values())
        fn(recs)
        next(s for s in secs if s[0] == K_CODING)[2] = coding_bytes(recs)
    return edit


def l3_as(filtered, filt, w):
    """An edit that stores the L3 array as the zstd frame of `filtered`, recorded under
    filter `filt` of width `w` (its restored size and checksum kept)."""
    def edit(secs):
        next(x for x in secs if x[0] == v.K_L3)[2] = zstandard.ZstdCompressor().compress(filtered)
        recs = [r if r[0] != v.K_L3 else r[:3] + [filt, w, 0] + r[6:] for r in records_of(secs).values()]
        next(x for x in secs if x[0] == K_CODING)[2] = coding_bytes(recs)
    return edit


def check_refusals(packed, plain, work):
    # The file rebuilt by this script's writer, unedited, reads alike (the helpers are sound).
    same_asset(with_body(packed, lambda secs: None), plain)
    recs = records_of(sections_of(bodies_of(packed)[0]))
    atlas = min(k for k in recs if k[0] == v.K_ATLAS)  # an atlas vdbcook compressed
    at = lambda f: edit_section(v.K_ATLAS, f)
    refused(with_body(packed, at(lambda d: d[:-5])), "section kind 10 index")
    refused(with_body(packed, at(lambda d: d[:len(d) // 2])), "zstd frame")
    refused(with_body(packed, at(lambda d: d + b"\0\0\0\1")), "bytes follow its zstd frame")
    refused(with_body(packed, at(lambda d: d + zstandard.ZstdCompressor().compress(b"more"))), "bytes follow its zstd frame")
    flipped = 0
    for i in range(20, 4000, 131):
        def flip(d, i=i):
            d = bytearray(d)
            d[i % len(d)] ^= 0x04
            return bytes(d)
        refused(with_body(packed, at(flip)), "section kind 10 index")
        flipped += 1
    # The record's facts: restored size, checksum, scheme, filters, names.
    def rec(f):
        def edit(recs):
            r = next(r for r in recs if (r[0], r[1]) == atlas)
            f(r)
        return edit_record(edit)
    n = recs[atlas][6]
    filt, w, stride = recs[atlas][3:6]
    assert filt in (3, 4), f"the f16 atlas has filter {filt}, not tiles"
    slab = 512 * (stride % 65536) * (stride // 65536) * w
    for lie in (n + slab, n - slab):
        # The frame decodes to n + w·T bytes; T follows the lie.
        refused(with_body(packed, rec(lambda r, lie=lie: r.__setitem__(6, lie))), f"record says {lie + w * lie // (512 * w)}")
    refused(with_body(packed, rec(lambda r: r.__setitem__(6, n + w))), "not whole slabs")
    refused(with_body(packed, rec(lambda r: r.__setitem__(4, 4))), f"filter {filt} with width 4")
    refused(with_body(packed, rec(lambda r: r.__setitem__(5, stride & ~0xffff))), f"filter {filt} with width 2 and stride")
    refused(with_body(packed, rec(lambda r: r.__setitem__(5, stride % 65536))), f"filter {filt} with width 2 and stride")
    # The other tiles filter on the same bytes restores other bytes.
    refused(with_body(packed, rec(lambda r: r.__setitem__(3, 7 - filt))), "restored bytes do not match")
    refused(with_body(packed, rec(lambda r: r.__setitem__(6, (1 << 30) * slab))), "more than a")
    refused(with_body(packed, rec(lambda r: r.__setitem__(7, r[7] ^ 1))), "restored bytes do not match")
    refused(with_body(packed, rec(lambda r: r.__setitem__(2, 5))), "scheme 5")
    refused(with_body(packed, rec(lambda r: r.__setitem__(2, 4))), "over its shown voxels with filter 3")
    refused(with_body(packed, rec(lambda r: r.__setitem__(2, 3))), "mask-coded with filter")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(2, 4), [2, 3]))), "context-coded with filter 3")
    refused(with_body(packed, rec(lambda r: r.__setitem__(3, 5))), "filter 5")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(3, 6), [0, 2, 0]))), "filter 0 with width 2")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(3, 6), [1, 3, 0]))), "filter 1 with width 3")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(3, 6), [1, 4, 1]))), "filter 1 with width 4 and stride 1")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(3, 6), [2, 8, 1]))), "filter 2 with width 8")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(3, 6), [2, 4, 0]))), "stride 0")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(3, 6), [2, 4, 4097]))), "stride 4097")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(3, 7), [1, 16, 0, 16 * (n // 16) + 8]))), "not a multiple of the width 16")
    # Another geometry of the same texture (half as many tiles along x, twice along y)
    # decodes to other bytes: the checksum says so.
    if stride % 65536 % 2 == 0:
        other = stride % 65536 // 2 | (stride // 65536 * 2) << 16
        refused(with_body(packed, rec(lambda r: r.__setitem__(5, other))), "restored bytes do not match")
    refused(with_body(packed, rec(lambda r: r.__setitem__(1, 999))), "names a section the body does not hold")
    refused(with_body(packed, rec(lambda r: r.__setitem__(slice(0, 2), [1, 0]))), "never compressed")
    refused(with_body(packed, edit_record(lambda rs: rs.append(list(rs[0])))), "named before")
    refused(with_body(packed, edit_record(lambda rs: rs.clear())), "without records")
    def short(secs):
        c = next(s for s in secs if s[0] == K_CODING)
        c[2] = c[2][:-1]
    refused(with_body(packed, short), "not whole 40-byte records")
    # A body has one coding section, of index 0: kind 13 of another index is refused;
    # a section of an unknown kind is ignored.
    refused(with_body(packed, lambda secs: secs.append([K_CODING, 1, b"x"])), "index other than 0")
    same_asset(with_body(packed, lambda secs: secs.append([99, 0, b"y"])), plain)
    # A section no record names is stored as it is: drop a record and the stored zstd
    # frame is taken as the section, which then fails validation (or its use).
    def unnamed(secs):
        # (The coding section goes too when the atlas's was its only record, as in a wrapped body.)
        edit_record(lambda rs: rs.remove(next(r for r in rs if (r[0], r[1]) == atlas)))(secs)
        secs[:] = [x for x in secs if x[0] != K_CODING or x[2]]
    refused(with_body(packed, unnamed), "texture has the wrong size")
    # A frame without its content size that decodes to more, or fewer, bytes than the record says.
    def unsized(lie):
        def edit(secs):
            sec = next(s for s in secs if (s[0], s[1]) == atlas)
            rec = (*atlas, 1, 0, 1, 0, len(sec[2]) + lie, xxh(sec[2]))
            sec[2] = zstandard.ZstdCompressor(write_content_size=False).compress(sec[2])
            secs.append([K_CODING, 0, coding_bytes([rec])])
        return edit
    plain_secs = sections_of(bodies_of(plain)[0])
    n0 = len(next(d for k, i, d in plain_secs if (k, i) == atlas))
    refused(with_body(plain, unsized(-1)), f"decodes to more than the record's {n0 - 1} bytes")
    refused(with_body(plain, unsized(1)), f"decodes to {n0} bytes, the record says {n0 + 1}")
    # The l3 nodes filter is version 12 on, and its count must fit the section.
    refused(make_file(bodies_of(packed), version=11), "filter 5 (l3 nodes) in a file older than version 12")
    l3 = next(d for k, i, d in plain_secs if k == v.K_L3)
    assert records_of(sections_of(bodies_of(packed)[0]))[(v.K_L3, 0)][3] == 5, "vdbcook's L3 array not filtered as l3 nodes"

    lie = l3_nodes(l3)
    lie = struct.pack("<I", len(l3) // 12 + 1) + lie[4:]
    refused(with_body(packed, l3_as(lie, 5, 4)), "its l3 nodes filter counts")
    # A supercompressed body packs its sections at multiples of 8 from version 11 on (its L3
    # array, shuffled here, as a version-10 writer could have stored it).
    secs = sections_of(bodies_of(packed)[0])
    l3_as(shuffle(l3, 4), 1, 4)(secs)
    ten = make_file([make_body(secs, align=8)] + bodies_of(packed)[1:], version=10)
    refused(ten, "is not at a 256-byte boundary")
    # From version 12 a body with a coding section starts at a multiple of 8 (vdbcook puts the
    # first right after the segment table), one without at a multiple of 256.
    _, table = v.read_table(memoryview(packed), (15,), "file")
    assert table[0][2] == -(-(64 + 32 * len(table)) // 8) * 8 < 256, table[0]
    eleven = bytearray(packed)
    struct.pack_into("<I", eleven, 8, 11)
    refused(reseal(eleven), "segment 0 at")
    plain_bodies = bodies_of(plain)
    moved = container(plain_bodies, entries=lambda t: t.__setitem__(0, t[0][:2] + [64 + 32 * len(t)] + t[0][3:]))
    moved = bytearray(moved)
    struct.pack_into("<I", moved, 8, 12)
    refused(reseal(moved), "has no coding section")
    # Supercompression is version 8 on.
    refused(make_file(bodies_of(packed), version=7), "older than version 8")
    refused(bodies_of(packed)[0], "older than version 8")
    # Segment 1 too, and the command line: one line naming the file and the problem.
    segs = len(bodies_of(packed))
    bad = with_body(packed, rec(lambda r: r.__setitem__(6, n + slab)), seg=segs - 1) if segs == 1 else \
        with_body(packed, edit_record(lambda rs: rs[0].__setitem__(7, rs[0][7] ^ 1)), seg=segs - 1)
    path = os.path.join(work, "bad.vpak")
    with open(path, "wb") as f:
        f.write(bad)
    r = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "vpak_read.py"), path, "--frame", "0"], capture_output=True, text=True)
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and r.stderr.startswith(f"vpak_read.py: {path}: segment {segs - 1}: section kind"), r.stderr
    return flipped


def with_section(packed, seg, key, fn, version, also=None):
    """`packed` with section `key` (kind, index) of segment `seg` through fn, and the other
    sections through `also` when given, as a file of `version`."""
    bodies = bodies_of(packed)
    secs = sections_of(bodies[seg])
    sec = next(x for x in secs if (x[0], x[1]) == key)
    sec[2] = fn(sec[2])
    if also:
        also(secs)
    bodies[seg] = make_body(secs)
    return make_file(bodies, version)


def refused_damaged(edit, stored, where, header):
    """A coded stream `stored` cut short (inside its `header`-byte header, after it, halfway,
    one byte short) or with a bit flipped every 1/40 of it: `edit(fn)`, the file with the
    stream through fn, is refused naming `where`."""
    for cut in (0, header // 2, header, len(stored) // 2, len(stored) - 1):
        refused(edit(lambda d, cut=cut: d[:cut]), where)
    # A flip of a bit zstd's decoder never reads (in its side frame) restores the same
    # bytes, which the record's checksum then proves: taken, at most once or twice.
    taken = 0
    for i in range(0, len(stored), len(stored) // 40 + 1):
        def flip(d, i=i):
            d = bytearray(d)
            d[i] ^= 0x10
            return bytes(d)
        try:
            refused(edit(flip), where)
        except AssertionError:
            taken += 1
    assert taken <= 2, f"{taken} of 40 damaged streams taken"


def check_context(vdbcook, work):
    """Atlases context-coded by `--optimize disk` over the voxels their nodes show (scheme 4,
    version 15) restore the uncompressed asset's sections; damaged streams, such a stream in a
    file older than version 15, and one told other shown voxels (a damaged L3 array's), are
    refused. Returns how many context-coded sections were read."""
    packed, plain, _ = check_restores(vdbcook, work, ["--max-error", "0.004", "--optimize", "disk", "--segment-frames", "2"])
    coded = [(s, k) for s, body in enumerate(bodies_of(packed)) for k, r in records_of(sections_of(body)).items() if r[2] == 4]
    assert coded, "no section context-coded over its shown voxels"
    seg, atlas = coded[0]

    def edit(fn, version=15, also=None):
        return with_section(packed, seg, atlas, fn, version, also)

    same_asset(edit(lambda d: d), plain)
    refused(edit(lambda d: d, version=14), "older than version 15")
    bodies = bodies_of(packed)
    secs = sections_of(bodies[seg])
    recs = [r if (r[0], r[1]) != atlas else r[:3] + [3] + r[4:] for r in records_of(secs).values()]
    next(x for x in secs if x[0] == K_CODING)[2] = coding_bytes(recs)
    bodies[seg] = make_body(secs)
    refused(make_file(bodies, 15), "with filter 3")
    # The L3 array stored plainly with every node showing all its voxels: the atlas's left-out
    # elements are then decoded as coded ones, and the restored bytes are not the record's.
    l3 = next(d for k, i, d in sections_of(bodies_of(plain)[seg]) if k == v.K_L3)
    words = list(struct.unpack_from(f"<{len(l3) // 4}I", l3))
    for k in range(words[0]):
        words[2 + 3 * k] = 0x5555
    full = struct.pack(f"<{len(words)}I", *words)

    def plain_l3(secs):
        rs = [r for r in records_of(secs).values() if (r[0], r[1]) != (v.K_L3, 0)]
        next(x for x in secs if x[0] == K_CODING)[2] = coding_bytes(rs)
        next(x for x in secs if x[0] == v.K_L3)[2] = full
    refused(edit(lambda d: d, also=plain_l3), f"section kind 10 index {atlas[1]}")
    stored = next(x for x in sections_of(bodies_of(packed)[seg]) if (x[0], x[1]) == atlas)[2]
    refused_damaged(edit, stored, f"section kind 10 index {atlas[1]}", header=24)
    return len(coded)


def check_masks(vdbcook, work):
    """An L3 array mask-coded by `--optimize disk` (scheme 3, version 14) restores the
    uncompressed asset's; damaged streams, and such a stream in a version-13 file, are
    refused. Returns how many mask-coded sections were read."""
    packed, plain, _ = check_restores(vdbcook, work, ["--max-error", "0.004", "--optimize", "disk"])
    coded = [(s, k) for s, body in enumerate(bodies_of(packed)) for k, r in records_of(sections_of(body)).items() if r[2] == 3]
    assert coded, "no L3 array mask-coded"
    seg, l3 = coded[0]

    def edit(fn, version=15):
        return with_section(packed, seg, l3, fn, version)

    same_asset(edit(lambda d: d), plain)
    refused(edit(lambda d: d, version=13), "older than version 14")
    stored = next(x for x in sections_of(bodies_of(packed)[seg]) if (x[0], x[1]) == l3)[2]
    refused_damaged(edit, stored, f"section kind {v.K_L3} index 0", header=16)
    return len(coded)


def check_wrapped(vdbcook, work):
    """vdbcook wraps the small supercompressed body of a one-segment asset in one zstd frame
    (version 13): it reads as the uncompressed asset does, so do this writer's own frames,
    and damaged frames, or a wrapped body among several segments, are refused."""
    path = os.path.join(work, "wrapped.vpak")
    subprocess.run([vdbcook, "cook", "-q", "--force", "-o", path, os.path.join(FIXTURE, "smoke_0001.vdb"), "--format", "f16", "--supercompress", "zstd"], check=True)
    with open(path, "rb") as f:
        packed = f.read()
    plain = recompress(vdbcook, work, packed, "none")
    [frame] = stored_bodies(packed)
    assert frame[:4] == v.ZSTD_MAGIC, "vdbcook left the small supercompressed body unwrapped"
    assert v.Asset(memoryview(packed)).wrapped == [True]
    same_asset(packed, plain, frames=1)

    def wrapped(stored, version=15):
        """A file of the stored bodies `stored` (frames or bodies) of one frame each, a frame's checksum its own."""
        sums = lambda t: [e.__setitem__(4, xxh(b) if b[:4] == v.ZSTD_MAGIC else e[4]) for e, b in zip(t, stored)]
        out = bytearray(container(stored, counts=[1] * len(stored), entries=sums))
        struct.pack_into("<I", out, 8, version)
        return reseal(out)

    # A frame of this script's own making (the body inside as vdbcook restores it).
    same_asset(wrapped([zstandard.ZstdCompressor(level=3).compress(bodies_of(packed)[0])]), plain, frames=1)
    refused(wrapped([frame + b"\0" * 8]), "bytes follow its zstd frame")
    refused(wrapped([frame[:-3]]), "its wrapped body")
    huge = zstandard.ZstdCompressor(level=3).compress(bodies_of(packed)[0] + bytes(v.MAX_WRAPPED))
    refused(wrapped([huge]), f"bytes of content (at most {v.MAX_WRAPPED})")
    unsized = zstandard.ZstdCompressor(level=3, write_content_size=False).compress(bodies_of(packed)[0])
    refused(wrapped([unsized]), "does not state its content size")
    refused(wrapped([frame + os.urandom(v.MAX_WRAPPED)]), f"bytes (at most {v.MAX_WRAPPED})")
    flipped = bytearray(packed)
    flipped[v.read_table(memoryview(packed), (15,), "file")[1][0][2] + len(frame) // 2] ^= 0x10
    refused(bytes(flipped), "its wrapped body is not the one the segment table names")
    # Only a file of one segment wraps its body; version 12 wraps none (its frame is no body).
    refused(wrapped([frame, frame]), "in a file of 2 segments")
    refused(wrapped([frame], version=12), "segment 0")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vdbcook", default=os.environ.get("VDBCOOK", os.path.join(ROOT, "target", "release", "vdbcook")))
    args = ap.parse_args()
    filters = set()
    with tempfile.TemporaryDirectory(prefix="vpak-coding-") as work:
        for flags in (["--format", "f16", "--segment-frames", "1"], ["--max-error", "0.004", "--lods", "2"],
                      ["--format", "bc7", "--segment-frames", "3"], ["--format", "unorm8"]):
            packed, plain, used = check_restores(args.vdbcook, work, flags)
            filters |= used
            if flags[:2] == ["--format", "f16"]:
                kept = packed, plain
        check_every_filter(kept[1])
        check_wrapped(args.vdbcook, work)
        flips = check_refusals(*kept, work)
        contexts = check_context(args.vdbcook, work)
        masks = check_masks(args.vdbcook, work)
    names = sorted(f"{FILTER_NAMES[f]}/{w}" for f, w in filters)
    print(f"ok: 4 supercompressed cooks restore the uncompressed sections (filter/width used: {', '.join(names)}); "
          f"every allowed filter decodes; wrapped bodies read, damaged frames refused; corrupt coding refused ({flips} flipped compressed bytes); "
          f"{contexts} context-coded sections and {masks} mask-coded L3 arrays restore, damaged ones refused")


if __name__ == "__main__":
    main()
