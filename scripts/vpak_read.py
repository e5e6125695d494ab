#!/usr/bin/python3
"""Independent reader for vdbcook's `.vpak` volume asset format (versions 15, 14, 13, 12, 11, 10, 9, 8, 7 and 6).

Written from docs/format.md alone (no Rust code, shaders or tests were read), to show
that the document is a complete specification: it decodes every channel of a frame.

    /usr/bin/python3 scripts/vpak_read.py ASSET.vpak --frame N [--lod K] --out OUT.npz [--json]

For every channel C (named as in the metadata) OUT.npz holds `C.ijk` (n x 3 int32,
source index space = asset index + index_offset) and `C.values` (n float32) over the
frame's active voxels (every active voxel of every L3 node and every voxel of every
tile), sorted by i, then j, then k, at the asset's first stored level (0, the frame
itself, unless the cook left finer levels out). With `--lod K`, the frame's level K, in
that level's index space (level index = level asset index + index_offset >> K). `--json` prints a summary of the metadata.
A version-10 asset may store a channel at its own, coarser voxels (format.md, "Channel
resolutions"): each channel is then decoded at its own first stored level (with `--lod
K`, its stored level nearest K), and OUT.npz also holds per channel `C.level` (the
level it was decoded at) and `C.transform` (4 x 4 float64, index to world of its
voxels there, its half-voxel offset included; every asset gets these two).
Frame N of a version-7 to 10 file is read from its segment's body alone; a version-8 to 10
body's supercompressed sections are restored (scripts/vpak_coding.py) before use.
`--source-frame S` reads the frame whose source frame number is S (version 9 records
each frame's number; older assets number their frames from 0). `--json` gives `fps` and
`frame_numbers` too (24 and 0, 1, ... when the asset records none).

As a module: `open_segments(path)` opens a version-6 to 15 file (every body validated,
every checksum verified; `.locate(N)`, `.read_frame(N)`, `.meta` of the whole sequence);
`open_asset(path)` gives `(metadata, sections)` of a file of one body.

Modules beside it: vpak_metadata.py (the metadata records), vpak_decode.py (node masks,
BC blocks, texture sizes), vpak_coding.py (supercompression).
Dependencies (Debian): python3-numpy, python3-pil (BC7 blocks), python3-xxhash,
python3-zstandard (version-8 to 10 assets with supercompressed sections).
Bad input exits with status 1 and one line `vpak_read.py: FILE: problem` on stderr.
"""

import argparse
import bisect
import json
import struct
import sys

import numpy as np

from vpak_coding import K_CODING, SCHEME_SHOWN, CodingError, inflate, parse_records, restore
from vpak_decode import (  # noqa: F401 (names the test scripts use as vpak_read.NAME)
    BC4, BC7, CONSTANT, F16, F32, FORMAT_NAMES, FORMAT_RULES, L2_MASK_WORDS, L2_WORDS, L3_WORDS, RANGED, UNORM8, UNORM16,
    decode_bc4, decode_bc7, l1_node_len, l1_starts, l3_active, slot_entries, slot_origin, texture_shape,
)
from vpak_metadata import (  # noqa: F401
    BODY_VERSION, CODED_VERSION, CONTEXT_VERSION, DEFAULT_FPS, L3_VERSION, RESOLVED_VERSION, SEGMENTED_VERSION, TIMED_VERSION, WRAPPED_VERSION,
    MASKED_VERSION, SHOWN_VERSION, VpakError, channel_level, channel_transform, decode_metadata, fps, frame_numbers,
)

MAGIC = b"VPAK\r\n\x1a\n"
MAX_LEVELS = 5
HEADER_SIZE = 64
SECTION_ALIGN = 256
CODED_ALIGN = 8  # the coding section and the sections it names (version 8)
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"  # a wrapped body (version 13)
MAX_WRAPPED = 1 << 20  # the most bytes a wrapped body restores to

# Section kinds (format.md, "Sections").
K_METADATA, K_FRAMES, K_L1, K_L1_ENTRIES, K_L2, K_L2_ENTRIES, K_L3, K_TILES, K_RANGES, K_ATLAS, K_TABLE, K_CHANNEL_TABLE = range(1, 13)
# Channel table entries: the plane's choice in bits 28..31, the plane brick below.
CHOICE_SHIFT, PLANE_BRICK_MASK, MAX_ALTERNATES = 28, (1 << 28) - 1, 15

# ---------------------------------------------------------------------------
# Header and section table
# ---------------------------------------------------------------------------

def xxh3_64(data):
    try:
        import xxhash  # Debian python3-xxhash
    except ImportError:
        raise VpakError("cannot verify checksums: install python3-xxhash") from None
    return xxhash.xxh3_64_intdigest(bytes(data))


def read_table(buf, versions, what):
    """Check magic, version, size and header checksum; return (version, table entries).

    A file and a body have one header; their tables (sections or segments) both have
    32-byte entries of u32, u32, u64, u64, u64.
    """
    if len(buf) < HEADER_SIZE:
        raise VpakError(f"{what} too short for a header")
    if buf[0:8] != MAGIC:
        raise VpakError("bad magic")
    version, _flags, n, _reserved, file_size, header_sum = struct.unpack_from("<IIIIQQ", buf, 8)
    if version not in versions:
        raise VpakError(f"unsupported format version {version} (a {what} here is version {' or '.join(map(str, versions))})")
    if file_size != len(buf):
        raise VpakError(f"{what} size {len(buf)} differs from header's {file_size}")
    table_end = HEADER_SIZE + 32 * n
    if table_end > len(buf):
        raise VpakError(f"table runs past the end of the {what}")
    # Header checksum covers bytes [0, 32) then the table (not bytes [32, 64)).
    if xxh3_64(bytes(buf[0:32]) + bytes(buf[HEADER_SIZE:table_end])) != header_sum:
        raise VpakError("header checksum mismatch")
    return version, [struct.unpack_from("<IIQQQ", buf, HEADER_SIZE + 32 * i) for i in range(n)]


def zero_outside(buf, at, spans, what):
    """Every byte from `at` on that no (offset, size) span holds is zero padding."""
    for offset, size in sorted(spans) + [(len(buf), 0)]:
        if any(bytes(buf[at:max(at, offset)])):
            raise VpakError(f"non-zero padding between {what} (after byte {at})")
        at = max(at, offset + size)


def read_header(buf):
    """A body (a version-6 file): its section table {(kind, index): (offset, size, checksum)}."""
    _, table = read_table(buf, (BODY_VERSION,), "body")
    sections = {}
    for s, (kind, index, offset, size, checksum) in enumerate(table):
        if offset % CODED_ALIGN or offset + size > len(buf):
            raise VpakError(f"section {s} (kind {kind}) not inside the body at an 8-byte boundary")
        if (kind, index) in sections:
            raise VpakError(f"section kind {kind} index {index} appears twice")
        sections[(kind, index)] = (offset, size, checksum)
    zero_outside(buf, HEADER_SIZE + 32 * len(table), [(o, n) for o, n, _ in sections.values()], "sections")
    return sections


class Sections:
    """Section bytes by (kind, index), checksum verified on first use; a supercompressed
    section (named in `coding`) restored, and its restored checksum verified, on first use."""

    def __init__(self, buf, table, version=BODY_VERSION):
        self.buf, self.table, self.checked, self.coding, self.restored = buf, table, set(), {}, {}
        self.version = version

    def get(self, kind, index=0):
        if (kind, index) not in self.table:
            raise VpakError(f"missing section kind {kind} index {index}")
        offset, size, checksum = self.table[(kind, index)]
        data = self.buf[offset:offset + size]
        if (kind, index) not in self.checked:
            if xxh3_64(data) != checksum:
                raise VpakError(f"checksum mismatch in section kind {kind} index {index}")
            self.checked.add((kind, index))
        if (kind, index) in self.coding:
            if (kind, index) not in self.restored:
                record = self.coding[(kind, index)]
                shown = None
                if record[0] == SCHEME_SHOWN:
                    # The atlas's shown voxels, from the body's metadata, L3 array and tables.
                    shown = shown_tiles(decode_metadata(self.get(K_METADATA), self.version), self, index, record[4] // (512 * record[2]))
                try:
                    self.restored[(kind, index)] = restore(data, record, xxh3_64, shown)
                except CodingError as e:
                    raise VpakError(f"section kind {kind} index {index}: {e}") from None
            return self.restored[(kind, index)]
        return data

    def u32(self, kind, index=0):
        data = self.get(kind, index)
        if len(data) % 4:
            raise VpakError(f"section kind {kind} is not whole u32 words")
        return np.frombuffer(data, dtype="<u4")

    def f32(self, kind, index=0):
        data = self.get(kind, index)
        if len(data) % 4:
            raise VpakError(f"section kind {kind} is not whole f32 words")
        return np.frombuffer(data, dtype="<f4")


def node_voxels(l3):
    """Each node's active voxels [n, 512] in tile order (x + 8y + 64z) from the L3 array's
    words; a node whose record or sub-masks lie outside the array shows nothing."""
    n = int(l3[0]) if len(l3) else 0
    n = min(n, (len(l3) - 1) // 3)
    recs = l3[1:1 + 3 * n].reshape(n, 3).astype(np.int64)
    states, first = recs[:, 1], recs[:, 2]
    out = np.zeros((n, 512), dtype=bool)
    ok = np.ones(n, dtype=bool)
    x, y, z = np.meshgrid(np.arange(8), np.arange(8), np.arange(8), indexing="ij")
    x, y, z = x.ravel(), y.ravel(), z.ravel()
    sub, bit = (x // 4) * 4 + (y // 4) * 2 + z // 4, (x % 4) * 16 + (y % 4) * 4 + z % 4
    tile = x + 8 * y + 64 * z
    rank = np.zeros(n, dtype=np.int64)
    for b in range(8):
        st = (states >> (2 * b)) & 3
        sel = sub == b
        if (st == 1).any():
            out[np.ix_(st == 1, tile[sel])] = True
        part = st == 2
        at = first + 2 * rank
        fits = part & (at >= 0) & (at + 1 < len(l3))
        ok &= ~part | fits
        idx = np.nonzero(fits)[0]
        if len(idx):
            words = l3[at[idx]].astype(np.uint64) | (l3[at[idx] + 1].astype(np.uint64) << np.uint64(32))
            on = ((words[:, None] >> bit[sel].astype(np.uint64)[None, :]) & np.uint64(1)) == 1
            out[np.ix_(idx, tile[sel])] = on
        rank += part
    out[~ok] = False
    return recs[:, 0], out


def shown_tiles(m, secs, index, tiles):
    """Atlas section `index` (of a 1-lane plane): per tile, its 512 elements (x fastest) that
    some L3 node shows (format.md, "Shown voxels"): the union over the nodes whose brick's
    plane brick, for a channel stored in the atlas's plane, is the tile's."""
    out = np.zeros((tiles, 512), dtype=bool)
    place = next(((p, a) for p in range(len(m["planes"])) for a in range(len(m["planes"][p]["atlases"]))
                  if atlas_section(m, p, a) == index), None)
    if place is None or (K_L3, 0) not in secs.table:
        return out
    p, a = place
    first, count = m["planes"][p]["atlases"][a]["first_brick"], m["planes"][p]["atlases"][a]["count"]
    bricks, voxels = node_voxels(secs.u32(K_L3))
    bricks = bricks.astype(np.int64)
    for c, ch in enumerate(m["channels"]):
        planes = channel_planes(ch)
        if p not in planes:
            continue
        if ch["alternates"]:
            if (K_CHANNEL_TABLE, c) not in secs.table:
                continue
            t = secs.u32(K_CHANNEL_TABLE, c).astype(np.int64)
            inside = bricks < len(t)
            e = np.where(inside, t[np.minimum(bricks, len(t) - 1)] if len(t) else 0, 0)
            pb = np.where(inside & ((e >> CHOICE_SHIFT) == planes.index(p)), e & PLANE_BRICK_MASK, -1)
        elif m["planes"][p]["bricks"] != m["brick_count"] and not mixed_plane(m, p):
            if (K_TABLE, p) not in secs.table:
                continue
            t = secs.u32(K_TABLE, p).astype(np.int64)
            pb = np.where(bricks < len(t), t[np.minimum(bricks, len(t) - 1)] if len(t) else 0, -1)
        else:
            pb = bricks
        local = pb - first
        sel = np.nonzero((pb >= 0) & (local >= 0) & (local < count) & (local < tiles))[0]
        np.logical_or.at(out, local[sel], voxels[sel])
    return out


# ---------------------------------------------------------------------------
# Validation (format.md, "Validation")
# ---------------------------------------------------------------------------

def validate(m, secs):
    C, P = len(m["channels"]), len(m["planes"])
    if not (1 <= C <= 256 and 1 <= P <= 256):
        raise VpakError("channel or plane count out of 1..256")
    for p, pl in enumerate(m["planes"]):
        rule = FORMAT_RULES.get(pl["format"])
        if rule is None or pl["lanes"] not in rule[0] or pl["z_per_texel"] not in rule[1]:
            raise VpakError(f"plane {p} has a format/lanes/zpt the table does not allow")
    used = [set() for _ in range(P)]
    for c, ch in enumerate(m["channels"]):
        if ch["alternates"]:
            # A channel in several planes has each of them to itself, from lane 0.
            if len(ch["alternates"]) > MAX_ALTERNATES or ch["lane"] != 0:
                raise VpakError(f"channel {c} has too many alternates or does not start at lane 0")
            for p in channel_planes(ch):
                if p >= P or used[p]:
                    raise VpakError(f"channel {c} names a missing or shared plane {p}")
                used[p] = set(range(4))
            continue
        p = ch["plane"]
        if p >= P:
            raise VpakError(f"channel {c} in a missing plane")
        zpt, lanes = m["planes"][p]["z_per_texel"], m["planes"][p]["lanes"]
        span = set(range(ch["lane"], ch["lane"] + zpt))
        if ch["lane"] % zpt or ch["lane"] + zpt > lanes or span & used[p]:
            raise VpakError(f"channel {c} has bad or shared lanes")
        used[p] |= span
    if any(not u for u in used):
        raise VpakError("a plane holds no channel")
    for p, pl in enumerate(m["planes"]):
        validate_plane(m, secs, p, pl)
    for c, ch in enumerate(m["channels"]):
        present = (K_CHANNEL_TABLE, c) in secs.table
        if present != bool(ch["alternates"]):
            raise VpakError(f"channel {c}: a channel table must exist exactly when it has alternates")
        if present:
            t = secs.u32(K_CHANNEL_TABLE, c).astype(np.int64)
            planes = channel_planes(ch)
            choice, k = t >> CHOICE_SHIFT, t & PLANE_BRICK_MASK
            if len(t) != m["brick_count"] or (len(t) and choice.max() >= len(planes)):
                raise VpakError(f"channel {c}: channel table of the wrong length or naming a missing plane")
            limit = np.array([m["planes"][p]["bricks"] for p in planes])[choice]
            if (k >= limit).any():
                raise VpakError(f"channel {c}: channel table entry past its plane's bricks")
    if m["index_offset"][0] % 128 or m["index_offset"][1] % 128 or m["index_offset"][2] % 128:
        raise VpakError("index_offset not a multiple of 128")
    if len(m["frames"]) != m["frame_count"]:
        raise VpakError("frame info list is not frame_count long")
    L = m["levels"]
    if not 1 <= L <= MAX_LEVELS:
        raise VpakError(f"{L} levels (need 1 to {MAX_LEVELS})")
    if len(m["level_filters"]) != (C if L > 1 else 0) or any(f > 1 for f in m["level_filters"]):
        raise VpakError("level filters are not one per channel (with levels > 1) or unknown")
    if any(len(f["coarse"]) != L - 1 for f in m["frames"]):
        raise VpakError("a frame's level figures do not match the levels")
    if not m["first_level"] < L:
        raise VpakError(f"first stored level {m['first_level']} of {L} levels")


def channel_planes(ch):
    """A channel's planes: its plane, then its alternates (choices 0, 1, ...)."""
    return [ch["plane"]] + list(ch["alternates"])


def mixed_plane(m, p):
    """True when plane p belongs to a channel with alternates (its channel table addresses it)."""
    return any(ch["alternates"] and p in channel_planes(ch) for ch in m["channels"])


def slots_of(pl):
    """Channel slots S of a plane (range pairs per plane brick)."""
    return pl["lanes"] // pl["z_per_texel"]


def atlas_section(m, p, a):
    """Section index of atlas a of plane p: the atlases of the planes before it, plus a."""
    return sum(len(q["atlases"]) for q in m["planes"][:p]) + a


def validate_plane(m, secs, p, pl):
    """Plane bricks, brick table, ranges and atlases of plane p (format.md, "Validation")."""
    n, bricks = m["brick_count"], pl["bricks"]
    if bricks > n or (bricks == 0) != (n == 0):
        raise VpakError(f"plane {p} stores {bricks} plane bricks for {n} bricks")
    has_table = bricks != n and not mixed_plane(m, p)
    table = secs.u32(K_TABLE, p) if (K_TABLE, p) in secs.table else None
    if has_table != (table is not None):
        raise VpakError(f"plane {p}: a brick table must exist exactly when the plane stores fewer bricks")
    if table is not None and (len(table) != n or (n and table.max() >= bricks)):
        raise VpakError(f"plane {p}: brick table of the wrong length or past the plane's bricks")
    ranges = secs.f32(K_RANGES, p)
    if len(ranges) != bricks * slots_of(pl) * 2:
        raise VpakError(f"plane {p}: brick ranges section has the wrong length")
    if len(ranges) and not (ranges[0::2] <= ranges[1::2]).all():
        raise VpakError(f"plane {p}: a brick range has min > max (or NaN)")
    if pl["format"] == CONSTANT:
        if pl["atlases"] or (len(ranges) and not (ranges[0::2] == ranges[1::2]).all()):
            raise VpakError(f"plane {p}: a constant plane with atlases or a range with min != max")
        return
    # Atlases: consecutive from plane brick 0, all but the last full and of one shape,
    # and the last one's bricks placeable with the first one's shape.
    atlases, first = pl["atlases"], 0
    for a, at in enumerate(atlases):
        bx, by, bz = at["bricks"]
        if at["first_brick"] != first or at["count"] > bx * by * bz or first + at["count"] > bricks:
            raise VpakError(f"plane {p} atlas {a} not consecutive, over-full or past the plane's bricks")
        if a < len(atlases) - 1 and (at["bricks"] != atlases[0]["bricks"] or at["count"] != bx * by * bz):
            raise VpakError(f"plane {p} atlas {a} is not full with the first atlas's shape")
        first += at["count"]
    if atlases:
        last, (fx, fy, fz) = atlases[-1], atlases[0]["bricks"]
        lx, ly, lz = last["bricks"]
        # The shader finds a brick's atlas by the first atlas's capacity.
        if last["count"] > fx * fy * fz:
            raise VpakError(f"plane {p}: the last atlas holds more bricks than the first")
        # Every brick of the last atlas must sit where the first atlas's shape puts it
        # (the shader addresses all atlases with the first one's shape).
        i = np.arange(last["count"])
        first_pos = np.stack([i % fx, (i // fx) % fy, i // (fx * fy)])
        own_pos = np.stack([i % lx, (i // lx) % ly, i // (lx * ly)])
        if not np.array_equal(first_pos, own_pos) or (len(i) and (first_pos.max(axis=1) >= [lx, ly, lz]).any()):
            raise VpakError(f"plane {p}: last atlas's bricks cannot be placed with the first atlas's shape")
    if first != bricks:
        raise VpakError(f"plane {p}: atlases do not cover the plane's bricks")
    for a in range(len(atlases)):
        if len(secs.get(K_ATLAS, atlas_section(m, p, a))) != texture_shape(pl, a)[3]:
            raise VpakError(f"plane {p} atlas {a} texture has the wrong size")


# ---------------------------------------------------------------------------
# Node walk
# ---------------------------------------------------------------------------

def walk_frame(m, secs, frame, lod=None):
    """Walk a frame's L1 node and its L2 children.

    Returns tile_parts [(asset-space origin, edge 128 or 8, tile index)] and leaf_parts
    [(asset-space origin, L3 node index)]. The frame's L1 node covers asset space
    [0, 128 * 2^L)^3; an empty frame is simply an L1 node with no slot set. `lod`:
    a stored level (default: the first, `first_level`).
    """
    lod = m["first_level"] if lod is None else lod
    if not m["first_level"] <= lod < m["levels"]:
        raise VpakError(f"level {lod} is not stored (asset has levels {m['first_level']} to {m['levels'] - 1})")
    frames = secs.u32(K_FRAMES)
    l1 = secs.u32(K_L1)
    l1e = secs.u32(K_L1_ENTRIES)
    l2 = secs.u32(K_L2)
    l2e = secs.u32(K_L2_ENTRIES)
    l3 = secs.u32(K_L3)
    if len(frames) != m["frame_count"] * (m["levels"] - m["first_level"]):
        raise VpakError("frame table is not frame_count x stored levels long")
    if len(l2) % L2_WORDS:
        raise VpakError("node arrays are not whole records")
    if len(l3) < 1 or len(l3) < 1 + L3_WORDS * int(l3[0]):
        raise VpakError("L3 array shorter than its node count")
    n2, n3 = len(l2) // L2_WORDS, int(l3[0])
    TILE = 1 << 31

    root = int(frames[(lod - m["first_level"]) * m["frame_count"] + frame])
    if root not in set(l1_starts(l1)):
        raise VpakError(f"frame {frame} points at word {root} of the L1 nodes, where no node starts")
    L = int(l1[root])
    node1 = l1[root + 1:root + l1_node_len(L)]
    slots1, ent1 = slot_entries(node1, (1 << (3 * L)) // 32, l1e, "L1")
    org1 = slot_origin(slots1, L, 7)

    tile_parts, leaf_parts = [], []  # (origin, size, tile id) / (origin, l3 node)
    for o1, e in zip(org1, ent1):
        e = int(e)
        if e & TILE:
            tile_parts.append((o1, 128, e & ~TILE))
            continue
        if e >= n2:
            raise VpakError("L1 entry points at a missing L2 node")
        node2 = l2[e * L2_WORDS:(e + 1) * L2_WORDS]
        slots2, ent2 = slot_entries(node2, L2_MASK_WORDS, l2e, "L2")
        org2 = o1 + slot_origin(slots2, 4, 3)
        for o2, e2 in zip(org2, ent2):
            e2 = int(e2)
            if e2 & TILE:
                tile_parts.append((o2, 8, e2 & ~TILE))
            elif e2 >= n3:
                raise VpakError("L2 entry points at a missing L3 node")
            else:
                leaf_parts.append((o2, e2))
    limit = m["frames"][frame]["leaves"] if lod == 0 else m["frames"][frame]["coarse"][lod - 1]["leaves"]
    if len(leaf_parts) > limit:
        raise VpakError(f"frame {frame} expands to more leaves than its FrameInfo says ({limit})")
    return tile_parts, leaf_parts


# ---------------------------------------------------------------------------
# Bricks: planes, atlases, texel addressing, block decoding and ranges
# ---------------------------------------------------------------------------

def load_plane_texture(secs, m, p, a):
    """Plane p of atlas a as a float32 array [z, y, x, lane] of levels or values."""
    pl = m["planes"][p]
    fmt, lanes = pl["format"], pl["lanes"]
    W, H, D, size = texture_shape(pl, a)
    data = secs.get(K_ATLAS, atlas_section(m, p, a))
    if len(data) != size:
        raise VpakError(f"plane {p} atlas {a} texture has the wrong size")
    if fmt in (F32, F16, UNORM8, UNORM16):
        dtype = {F32: "<f4", F16: "<f2", UNORM8: "u1", UNORM16: "<u2"}[fmt]
        tex = np.frombuffer(data, dtype=dtype).reshape(D, H, W, lanes).astype(np.float32)
        scale = {UNORM8: 255, UNORM16: 65535}.get(fmt)
        return tex / np.float32(scale) if scale else tex
    return decode_bc4(data, W, H, D) if fmt == BC4 else decode_bc7(data, W, H, D)


def plane_values(m, secs, p, lane, k, textures):
    """Values [len(k), 512] (leaf order) of the channel at `lane` of plane p, for plane bricks k."""
    pl = m["planes"][p]
    zpt, slices = pl["z_per_texel"], 8 // pl["z_per_texel"]
    out = np.zeros((len(k), 512), dtype=np.float32)
    ranges = secs.f32(K_RANGES, p)
    r = 2 * (k * slots_of(pl) + lane // zpt)
    if pl["format"] == CONSTANT:
        # No texels: every voxel is the range's min.
        out[:] = ranges[r][:, None]
        return out
    x, y, z = np.meshgrid(np.arange(8), np.arange(8), np.arange(8), indexing="ij")
    x, y, z = x.ravel(), y.ravel(), z.ravel()
    for a, at in enumerate(pl["atlases"]):
        sel = np.nonzero((k >= at["first_brick"]) & (k < at["first_brick"] + at["count"]))[0]
        if not len(sel):
            continue
        bx, by, _ = at["bricks"]
        i = k[sel] - at["first_brick"]
        px, py, pz = i % bx, (i // bx) % by, i // (bx * by)
        if (p, a) not in textures:
            textures[(p, a)] = load_plane_texture(secs, m, p, a)
        tex = textures[(p, a)]
        # texel (8px + x, 8py + y, slices*pz + z/zpt), lane = channel lane + z % zpt
        X = 8 * px[:, None] + x[None, :]
        Y = 8 * py[:, None] + y[None, :]
        Z = slices * pz[:, None] + (z // zpt)[None, :]
        L = lane + (z % zpt)[None, :]
        out[sel, :] = tex[Z, Y, X, np.broadcast_to(L, X.shape)]
    # Ranged formats: level t over the plane brick's [min, max] for the channel's
    # slot. In f32, min + t * (max - min): found by experiment to match `vdbcook
    # unpack` exactly.
    if pl["format"] in RANGED:
        lo, hi = ranges[r][:, None], ranges[r + 1][:, None]
        out = np.where(hi > lo, lo + out * (hi - lo), lo)
    return out


def brick_values(m, secs, bricks):
    """Values [len(bricks), C, 512] (leaf order) of the given bricks, every channel."""
    C = len(m["channels"])
    bricks = np.asarray(bricks, dtype=np.int64)
    if len(bricks) and bricks.max() >= m["brick_count"]:
        raise VpakError("L3 node points at a missing brick")
    out = np.zeros((len(bricks), C, 512), dtype=np.float32)
    textures = {}
    for c, ch in enumerate(m["channels"]):
        if ch["alternates"]:
            # Per-brick formats: the channel table names the plane and the plane brick.
            e = secs.u32(K_CHANNEL_TABLE, c).astype(np.int64)[bricks]
            choice, k = e >> CHOICE_SHIFT, e & PLANE_BRICK_MASK
            for j, p in enumerate(channel_planes(ch)):
                sel = np.nonzero(choice == j)[0]
                if len(sel):
                    out[sel, c, :] = plane_values(m, secs, p, 0, k[sel], textures)
            continue
        p = ch["plane"]
        # Brick b's plane brick k: entry b of the plane's brick table, or b without one.
        table = secs.u32(K_TABLE, p).astype(np.int64) if m["planes"][p]["bricks"] != m["brick_count"] else None
        k = table[bricks] if table is not None else bricks
        out[:, c, :] = plane_values(m, secs, p, ch["lane"], k, textures)
    return out


# ---------------------------------------------------------------------------
# Frame decoding
# ---------------------------------------------------------------------------

def read_frame(m, secs, frame, lod=None):
    """Per-channel (ijk int32 n x 3, values float32 n), sorted by i, j, k (source space of
    the level), each channel at `channel_level(m, c, lod)`: without channel resolutions,
    every channel at `lod` (default: the first stored level)."""
    if lod is not None and not m["first_level"] <= lod < m["levels"]:
        raise VpakError(f"level {lod} is not stored (asset has levels {m['first_level']} to {m['levels'] - 1})")
    want = [channel_level(m, c, lod) for c in range(len(m["channels"]))]
    # One walk per level some channel is taken from; a channel is never read at a level
    # where it is absent (its bricks there hold only its background).
    trees = {k: read_level(m, secs, frame, k) for k in sorted(set(want))}
    return {ch["name"]: (trees[want[c]][0], trees[want[c]][1][:, c]) for c, ch in enumerate(m["channels"])}


def placement(m, lod=None):
    """Per channel (level it is decoded at, its 4 x 4 index-to-world transform there)."""
    return [(k, channel_transform(m, c, k)) for c, k in ((c, channel_level(m, c, lod)) for c in range(len(m["channels"])))]


def read_level(m, secs, frame, lod):
    """The frame's tree at stored level `lod`: (ijk int32 n x 3 sorted by i, j, k, in the
    level's source index space; values float32 n x C, every channel)."""
    C = len(m["channels"])
    tile_parts, leaf_parts = walk_frame(m, secs, frame, lod)
    ijk_parts, val_parts = [], []

    if tile_parts:
        tiles = secs.f32(K_TILES)
        if len(tiles) % C:
            raise VpakError("tiles section is not a multiple of C floats")
        for origin, size, t in tile_parts:
            if (t + 1) * C > len(tiles):
                raise VpakError("tile index out of range")
            g = np.arange(size)
            gi, gj, gk = np.meshgrid(g, g, g, indexing="ij")
            ijk = np.stack([gi.ravel(), gj.ravel(), gk.ravel()], axis=1) + origin
            ijk_parts.append(ijk)
            val_parts.append(np.broadcast_to(tiles[t * C:(t + 1) * C], (len(ijk), C)))

    if leaf_parts:
        l3 = secs.u32(K_L3)
        origins = np.array([o for o, _ in leaf_parts], dtype=np.int64)
        nodes = [k for _, k in leaf_parts]
        masks, cache = [], {}
        for k in nodes:  # identical nodes are shared: decode each mask once
            if k not in cache:
                cache[k] = l3_active(l3, k)
            masks.append(cache[k])
        masks = np.array(masks)
        brick_ids = np.array([int(l3[1 + L3_WORDS * k]) for k in nodes], dtype=np.int64)
        uniq, inv = np.unique(brick_ids, return_inverse=True)
        vals = brick_values(m, secs, uniq)[inv]  # [leaves, C, 512]
        x, y, z = np.meshgrid(np.arange(8), np.arange(8), np.arange(8), indexing="ij")
        local = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
        leaf, vox = np.nonzero(masks)
        ijk_parts.append(origins[leaf] + local[vox])
        val_parts.append(vals[leaf, :, vox])

    if ijk_parts:
        ijk = np.concatenate(ijk_parts) + (np.array(m["index_offset"], dtype=np.int64) >> lod)
        vals = np.concatenate(val_parts)
    else:
        ijk, vals = np.zeros((0, 3), dtype=np.int64), np.zeros((0, C))
    order = np.lexsort((ijk[:, 2], ijk[:, 1], ijk[:, 0]))
    ijk, vals = ijk[order].astype(np.int32), vals[order].astype(np.float32)
    if len(ijk) > 1 and not np.any(np.diff(ijk, axis=0) != 0, axis=1).all():
        raise VpakError(f"frame {frame} covers a voxel twice")
    return ijk, vals


def summary(m):
    s = dict(m)
    for ch in s["channels"]:
        ch["format"] = "+".join(FORMAT_NAMES[m["planes"][p]["format"]] for p in channel_planes(ch))
    s["planes"] = [dict(p, format=FORMAT_NAMES[p["format"]]) for p in m["planes"]]
    return s


# ---------------------------------------------------------------------------
# Segments (version 7): a table of version-6 bodies, each a run of frames
# ---------------------------------------------------------------------------

# Equal in every segment (format.md, "Segments"; `background` bit for bit); the rest is per segment.
SHARED = ("tool", "settings", "map_type", "transform", "levels", "first_level", "level_filters", "resolutions")
SHARED_CHANNEL = ("name", "grid", "component", "value_type", "class", "group")


def open_body(buf, head_sum=None, coded=False, version=BODY_VERSION, at=0):
    """(metadata, sections) of a body validated as a version-6 file, every checksum verified;
    `head_sum`: the segment table's checksum of its header and section table; `coded`: a
    version-8 body, whose supercompressed sections are restored and checked here;
    `version`: the file's (a version-10 file's metadata may record channel resolutions);
    `at`: where the body starts in its file (off a multiple of 256 only with a coding section)."""
    secs = Sections(buf, read_header(buf), version)
    if at % SECTION_ALIGN and (K_CODING, 0) not in secs.table:
        raise VpakError(f"its body at byte {at} has no coding section (such a body starts at a multiple of 256)")
    if head_sum is not None and xxh3_64(buf[:HEADER_SIZE + 32 * len(secs.table)]) != head_sum:
        raise VpakError("its header and section table are not the ones the segment table names")
    # Verify every section up front (in table order) so that a corrupt asset is refused
    # whichever frame is asked for, not only when the damaged bytes are used.
    for kind, index in secs.table:
        secs.get(kind, index)
    if any(kind == K_CODING for kind, _ in secs.table) and not coded:
        raise VpakError("a coding section (kind 13) in a file older than version 8")
    if any(kind == K_CODING and index != 0 for kind, index in secs.table):
        raise VpakError("a coding section (kind 13) of an index other than 0")
    if (K_CODING, 0) in secs.table:
        try:
            secs.coding = parse_records(secs.get(K_CODING), secs.table, version)
        except CodingError as e:
            raise VpakError(str(e)) from None
        for kind, index in secs.table:  # restore every compressed section, checking each
            secs.get(kind, index)
    # Every other section starts at a multiple of 256 bytes (in a version-11 body with a
    # coding section, every section at a multiple of 8, which read_header checked).
    packed = version >= CONTEXT_VERSION and (K_CODING, 0) in secs.table
    for (kind, index), (offset, _, _) in secs.table.items():
        if not packed and kind != K_CODING and (kind, index) not in secs.coding and offset % SECTION_ALIGN:
            raise VpakError(f"section kind {kind} index {index} is not at a 256-byte boundary")
    m = decode_metadata(secs.get(K_METADATA), version)
    validate(m, secs)
    return m, secs


def check_segment_table(buf, table, version):
    """Bodies inside the file at 256-byte boundaries (version 12: at 8-byte ones, a body off a
    256-byte one having a coding section, which open_body checks), in order, frames counted on
    without a gap."""
    if not table:
        raise VpakError("a segmented file of 0 segments")
    align = CODED_ALIGN if version >= L3_VERSION else SECTION_ALIGN
    at, frame = HEADER_SIZE + 32 * len(table), 0
    for s, (first, count, offset, size, _) in enumerate(table):
        if offset % align or offset < at or offset + size > len(buf) or size < HEADER_SIZE:
            raise VpakError(f"segment {s} at {offset}+{size} is outside the file, misaligned or overlaps the one before")
        if first != frame:
            raise VpakError(f"segment {s} starts at frame {first}, the segments before it end at frame {frame}")
        at, frame = offset + size, frame + count
    if frame > 0xFFFFFFFF:
        raise VpakError("more than 2^32 - 1 frames")
    zero_outside(buf, HEADER_SIZE + 32 * len(table), [(e[2], e[3]) for e in table], "segments")


def check_shared(a, b, s):
    """Segment s's metadata `b` agrees with segment 0's (`a`) on every shared field."""
    for key in SHARED:
        if a[key] != b[key]:
            raise VpakError(f"segment {s} and segment 0 differ in {key}")
    bits = lambda c: struct.pack("<d", c["background"])  # exact for a decoded f32
    same = lambda x, y: all(x[k] == y[k] for k in SHARED_CHANNEL) and bits(x) == bits(y)
    if len(a["channels"]) != len(b["channels"]) or not all(map(same, a["channels"], b["channels"])):
        raise VpakError(f"segment {s}'s channels differ from segment 0's")
    rate = lambda m: m["time"] and struct.pack("<d", m["time"]["fps"])
    if rate(a) != rate(b):
        raise VpakError(f"segment {s}'s frame rate differs from segment 0's")


def merged(metas):
    """The whole sequence's metadata: segment 0's shared fields; frames (each source listed
    once) of all; value ranges and bounding boxes united; vdbcook's whole index offset."""
    m = {k: metas[0][k] for k in SHARED}
    m["frame_count"] = sum(x["frame_count"] for x in metas)
    m["channels"] = [{k: ch[k] for k in SHARED_CHANNEL + ("background",)} for ch in metas[0]["channels"]]
    for c, ch in enumerate(m["channels"]):
        ranges = [x["channels"][c]["value_range"] for x in metas]
        ch["value_range"] = [min(r[0] for r in ranges), max(r[1] for r in ranges)]
    placed = [x for x in metas if x["index_bbox"] is not None]
    m["index_offset"] = [min(x["index_offset"][i] for x in placed) for i in range(3)] if placed else metas[0]["index_offset"]
    m["index_bbox"] = ([min(x["index_bbox"][0][i] for x in placed) for i in range(3)],
                       [max(x["index_bbox"][1][i] for x in placed) for i in range(3)]) if placed else None
    m["sources"], m["frames"], seen = [], [], {}
    for x in metas:
        for f in x["frames"]:
            f, i = dict(f), f["source"]
            if i is not None and i < len(x["sources"]):
                src = x["sources"][i]
                f["source"] = seen.setdefault(tuple(src.values()), len(seen))
                if f["source"] == len(m["sources"]):
                    m["sources"].append(src)
            else:
                f["source"] = None
            m["frames"].append(f)
    m["time"] = None
    if metas[0]["time"]:
        numbers = [n for x in metas for n in x["time"]["numbers"]]
        if any(a >= b for a, b in zip(numbers, numbers[1:])):
            raise VpakError("the segments' frame numbers do not increase")
        m["time"] = {"fps": metas[0]["time"]["fps"], "numbers": numbers}
    return m


class Asset:
    """A version-6 to 15 file: `table` [(first_frame, frame_count, offset, size, head checksum)]
    and `bodies` [(metadata, sections)] per segment (frames numbered from 0 in each), `meta`
    the whole sequence's metadata (a version-6 file: its own, one segment of all its frames)."""

    def __init__(self, buf):
        self.version, table = read_table(buf, (BODY_VERSION, SEGMENTED_VERSION, CODED_VERSION, TIMED_VERSION, RESOLVED_VERSION, CONTEXT_VERSION, L3_VERSION, WRAPPED_VERSION, MASKED_VERSION, SHOWN_VERSION), "file")
        if self.version == BODY_VERSION:
            self.bodies = [open_body(buf)]
            self.meta = self.bodies[0][0]
            self.table = [(0, self.meta["frame_count"], 0, len(buf), xxh3_64(buf[:HEADER_SIZE + 32 * len(table)]))]
            self.wrapped = [False]
            return
        check_segment_table(buf, table, self.version)
        self.table, self.bodies, self.wrapped = table, [], []
        for s, (_, count, offset, size, head_sum) in enumerate(table):
            try:
                body = buf[offset:offset + size]
                self.wrapped.append(self.version >= WRAPPED_VERSION and bytes(body[:4]) == ZSTD_MAGIC)
                if self.wrapped[-1]:
                    # A wrapped body (of a file of one segment): the frame checked whole, then the body inside as any body.
                    if len(table) > 1:
                        raise VpakError(f"its body is wrapped in a zstd frame in a file of {len(table)} segments")
                    if size > MAX_WRAPPED:
                        raise VpakError(f"its body is wrapped in a zstd frame of {size} bytes (at most {MAX_WRAPPED})")
                    if xxh3_64(body) != head_sum:
                        raise VpakError("its wrapped body is not the one the segment table names")
                    try:
                        body = memoryview(inflate(body, MAX_WRAPPED))
                    except CodingError as e:
                        raise VpakError(f"its wrapped body: {e}") from None
                    head_sum, offset = None, 0
                m, secs = open_body(body, head_sum, self.version >= CODED_VERSION, self.version, offset)
                if m["frame_count"] != count:
                    raise VpakError(f"its metadata has {m['frame_count']} frames, the segment table {count}")
            except VpakError as e:
                raise VpakError(f"segment {s}: {e}") from None
            check_shared(self.bodies[0][0] if s else m, m, s)
            self.bodies.append((m, secs))
        self.meta = merged([m for m, _ in self.bodies])

    def locate(self, frame):
        """(segment, frame within it) of frame `frame` of the whole sequence."""
        s = bisect.bisect_right([first + count for first, count, *_ in self.table], frame)
        if frame < 0 or s == len(self.table):
            raise VpakError(f"frame {frame} out of range (asset has {self.meta['frame_count']})")
        return s, frame - self.table[s][0]

    def read_frame(self, frame, lod=None):
        """Frame `frame` of the whole sequence, decoded from its segment's body alone."""
        s, f = self.locate(frame)
        return read_frame(*self.bodies[s], f, lod)

    def frame_of_number(self, number):
        """The frame whose source frame number is `number`."""
        numbers = frame_numbers(self.meta)
        i = bisect.bisect_left(numbers, number)
        if i == len(numbers) or numbers[i] != number:
            raise VpakError(f"no frame has source number {number} (frames {numbers[0] if numbers else '-'} to {numbers[-1] if numbers else '-'})")
        return i

    def summary(self):
        time = {"fps": fps(self.meta), "frame_numbers": frame_numbers(self.meta)}
        if self.version == BODY_VERSION:
            return dict(summary(self.meta), **time)
        keys = ("first_frame", "frame_count", "offset", "size")
        return dict(self.meta, **time, segments=[dict(zip(keys, e), **summary(m)) for e, (m, _) in zip(self.table, self.bodies)])


def open_segments(path):
    """A version-6 to 15 file as an `Asset`, every body validated (and restored)."""
    try:
        with open(path, "rb") as f:
            buf = memoryview(f.read())
    except OSError as e:
        raise VpakError(e.strerror or str(e)) from None
    return Asset(buf)


def open_asset(path):
    """(metadata, sections) of a file of one body: version 6, or version 7 to 10 of one segment."""
    a = open_segments(path)
    if len(a.bodies) != 1:
        raise VpakError(f"the asset has {len(a.bodies)} segments: read it with open_segments")
    return a.bodies[0]


def main(argv=None):
    ap = argparse.ArgumentParser(description="Decode a .vpak frame (written from docs/format.md).")
    ap.add_argument("asset")
    ap.add_argument("--frame", type=int, default=None)
    ap.add_argument("--source-frame", type=int, default=None, help="the frame of this source frame number")
    ap.add_argument("--lod", type=int, default=None, help="level of detail (0: the frame itself; default: the asset's first stored level)")
    ap.add_argument("--out", help="write C.ijk / C.values per channel to this .npz")
    ap.add_argument("--json", action="store_true", help="print a metadata summary")
    args = ap.parse_args(argv)
    try:
        asset = open_segments(args.asset)
        if args.json:
            print(json.dumps(asset.summary(), indent=2))
        frame = args.frame
        if args.source_frame is not None:
            frame = asset.frame_of_number(args.source_frame)
        if frame is not None or args.out:
            chans = asset.read_frame(0 if frame is None else frame, args.lod)
            if args.out:
                arrays = {}
                for (name, (ijk, vals)), (level, transform) in zip(chans.items(), placement(asset.meta, args.lod)):
                    arrays[f"{name}.ijk"], arrays[f"{name}.values"] = ijk, vals
                    arrays[f"{name}.level"], arrays[f"{name}.transform"] = np.int32(level), transform
                np.savez(args.out, **arrays)
    except VpakError as e:
        print(f"vpak_read.py: {args.asset}: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"vpak_read.py: {args.asset}: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
