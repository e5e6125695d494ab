"""The metadata of a `.vpak` body (format.md, "Metadata", "Time" and "Channel
resolutions"), for scripts/vpak_read.py.

Written from docs/format.md alone, like the reader: the `Metadata` record in bincode 2's
standard configuration, the `Time` record after it (version 9 on) and the channel
resolutions record after that (version 10), each rule the page states checked; where each
channel's voxels are (its level, stored levels and transform). A failure raises
`VpakError` with a one-line message.
"""

import math
import struct

import numpy as np

BODY_VERSION, SEGMENTED_VERSION, CODED_VERSION, TIMED_VERSION, RESOLVED_VERSION, CONTEXT_VERSION, L3_VERSION, WRAPPED_VERSION, MASKED_VERSION, SHOWN_VERSION = 6, 7, 8, 9, 10, 11, 12, 13, 14, 15
DEFAULT_FPS = 24.0  # the frame rate of an asset that records none
MAX_LEVELS = 5
# Channel resolutions (version 10): a channel's level at most 3 (voxels 8 times the
# asset's), its offset at most 8192 level-0 voxels (16384 half voxels).
MAX_CHANNEL_LEVEL, MAX_HALF_OFFSET = 3, 2 * 8192


class VpakError(Exception):
    """A problem with the input asset: reported as one line, never a traceback."""


# ---------------------------------------------------------------------------
# Metadata: bincode 2 standard configuration (varint integers, little-endian)
# ---------------------------------------------------------------------------

class Bincode:
    def __init__(self, data):
        self.data, self.pos = bytes(data), 0

    def take(self, n):
        if self.pos + n > len(self.data):
            raise VpakError("metadata truncated")
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def uint(self):
        # One byte below 251; else marker 251/252/253 then 2/4/8 little-endian bytes.
        b = self.take(1)[0]
        if b < 251:
            return b
        width = {251: 2, 252: 4, 253: 8}.get(b)
        if width is None:
            raise VpakError(f"metadata: bad varint marker {b}")
        return int.from_bytes(self.take(width), "little")

    def int(self):
        z = self.uint()  # zigzag: 0, 1, 2, 3 -> 0, -1, 1, -2
        return (z >> 1) ^ -(z & 1)

    def f32(self):
        return struct.unpack("<f", self.take(4))[0]

    def f64(self):
        return struct.unpack("<d", self.take(8))[0]

    def string(self):
        try:
            return self.take(self.uint()).decode("utf-8")
        except UnicodeDecodeError:
            raise VpakError("metadata: string is not UTF-8") from None

    def option(self, item):
        tag = self.take(1)[0]
        if tag > 1:
            raise VpakError(f"metadata: bad Option tag {tag}")
        return item() if tag else None

    def vec(self, item):
        return [item() for _ in range(self.uint())]

    def array(self, item, n):
        return [item() for _ in range(n)]


def decode_metadata(data, version=RESOLVED_VERSION):
    """The Metadata record, the Time record after it (version 9 on) and the channel
    resolutions record after that (version 10)."""
    r = Bincode(data)
    m = {}
    m["tool"] = r.string()
    m["frame_count"] = r.uint()
    m["map_type"] = r.string()
    m["transform"] = r.array(lambda: r.array(r.f64, 4), 4)
    m["index_offset"] = r.array(r.int, 3)
    m["index_bbox"] = r.option(lambda: (r.array(r.int, 3), r.array(r.int, 3)))

    def channel():
        return {
            "name": r.string(), "grid": r.string(), "component": r.option(r.uint),
            "value_type": r.string(), "class": r.string(), "background": r.f32(),
            "value_range": r.array(r.f32, 2), "group": r.uint(), "plane": r.uint(),
            "lane": r.uint(), "alternates": r.vec(r.uint),
        }

    m["channels"] = r.vec(channel)
    def plane():
        # PlaneInfo { plane: Plane { format, lanes, z_per_texel }, bricks, atlases }, flattened.
        pl = {"format": r.uint(), "lanes": r.uint(), "z_per_texel": r.uint()}
        pl["bricks"] = r.uint()
        pl["atlases"] = r.vec(lambda: {"bricks": r.array(r.uint, 3), "first_brick": r.uint(), "count": r.uint()})
        return pl

    m["planes"] = r.vec(plane)
    m["brick_count"] = r.uint()
    m["settings"] = r.vec(lambda: (r.string(), r.string()))
    m["sources"] = r.vec(lambda: {"path": r.string(), "bytes": r.uint(), "xxh3_128": r.string()})
    def level():
        return {"active_voxels": r.uint(), "leaves": r.uint(), "tiles": r.uint()}

    m["frames"] = r.vec(lambda: {"source": r.option(r.uint), "active_voxels": r.uint(),
                                 "leaves": r.uint(), "tiles": r.uint(), "coarse": r.vec(level)})
    m["levels"] = r.uint()
    m["level_filters"] = r.vec(r.uint)
    m["first_level"] = r.uint()
    m["time"] = None
    m["resolutions"] = None
    if r.pos != len(r.data):
        # Version 9: the Time record follows (format.md, "Time").
        t = {"fps": r.f64(), "numbers": r.vec(r.int)}
        if r.pos != len(r.data) and (version == BODY_VERSION or version >= RESOLVED_VERSION):
            # Version 10 (and a body of one on its own, a version-6 file): the channel
            # resolutions record follows ("Channel resolutions").
            m["resolutions"] = r.vec(lambda: {"level": r.uint(), "half_offset": r.array(r.int, 3)})
            if r.pos != len(r.data):
                raise VpakError(f"metadata has {len(r.data) - r.pos} bytes after the channel resolutions")
            check_resolutions(m)
        if r.pos != len(r.data):
            raise VpakError(f"metadata has {len(r.data) - r.pos} bytes after the time record")
        if not (math.isfinite(t["fps"]) and t["fps"] > 0):
            raise VpakError(f"metadata: frame rate {t['fps']} is not a finite number above 0")
        if len(t["numbers"]) != m["frame_count"]:
            raise VpakError(f"metadata: {len(t['numbers'])} frame numbers for {m['frame_count']} frames")
        if any(a >= b for a, b in zip(t["numbers"], t["numbers"][1:])):
            raise VpakError("metadata: frame numbers do not increase")
        m["time"] = t
    return m


def check_resolutions(m):
    """The rules of format.md's "Channel resolutions" for the record's items."""
    res, C = m["resolutions"], len(m["channels"])
    if not res or len(res) != C:
        raise VpakError(f"metadata: {len(res)} channel resolutions for {C} channels")
    for c, x in enumerate(res):
        if x["level"] > MAX_CHANNEL_LEVEL or x["level"] >= m["levels"]:
            raise VpakError(f"metadata: channel {c} at level {x['level']} (at most {MAX_CHANNEL_LEVEL}, below the asset's {m['levels']} levels)")
        if any(abs(h) > MAX_HALF_OFFSET for h in x["half_offset"]):
            raise VpakError(f"metadata: channel {c}'s offset is more than {MAX_HALF_OFFSET // 2} voxels")
    if min(x["level"] for x in res) != 0:
        raise VpakError("metadata: no channel at level 0")
    if m["first_level"] >= detail_levels(m):
        raise VpakError(f"metadata: first stored level {m['first_level']} leaves the level-0 channels no level")


def resolution(m, c):
    """Channel c's (level, half_offset): level 0 and no offset without the record."""
    res = m.get("resolutions")
    return (res[c]["level"], res[c]["half_offset"]) if res else (0, [0, 0, 0])


def detail_levels(m):
    """D: the levels each channel has, counted from its own (`levels` less the coarsest channel's level)."""
    res = m.get("resolutions")
    return m["levels"] - (max(x["level"] for x in res) if res else 0)


def channel_levels(m, c):
    """The levels channel c is stored at: max(level_c, first_level) to level_c + D - 1."""
    own = resolution(m, c)[0]
    return range(max(own, m["first_level"]), own + detail_levels(m))


def channel_level(m, c, lod=None):
    """The level channel c is decoded at: its first stored one, or its stored one nearest `lod`."""
    levels = channel_levels(m, c)
    return levels[0] if lod is None else min(max(lod, levels[0]), levels[-1])


def channel_transform(m, c, k):
    """Index to world of channel c's voxels at level k (format.md, "Levels" and
    "Channel resolutions"): rows 0-2 of `transform` times 2^k; row 3 plus
    ((2^k - 1)/2 + half_offset/2) times rows 0-2."""
    t = np.array(m["transform"], dtype=np.float64)
    h = resolution(m, c)[1]
    out = t.copy()
    out[:3] = t[:3] * float(1 << k)
    out[3] = t[3] + (float((1 << k) - 1) / 2.0) * (t[0] + t[1] + t[2])
    out[3] = out[3] + (h[0] * t[0] + h[1] * t[1] + h[2] * t[2]) / 2.0
    return out


def frame_numbers(m):
    """Each frame's source number: recorded (version 9), else 0, 1, ..."""
    return m["time"]["numbers"] if m["time"] else list(range(m["frame_count"]))


def fps(m):
    return m["time"]["fps"] if m["time"] else DEFAULT_FPS
