#!/usr/bin/python3
"""An asset's tiled atlases as bricks for `context_decode` (issue 24: what the coder would
make of the texels an asset actually stores, against the zstd sections it stores today).

    /usr/bin/python3 export_atlas.py ASSET.vpak OUT [--all-texels]

Every atlas section that the tiles filters coded (1-lane unorm8 or unorm16: 8x8x8 tiles,
one per brick) becomes bricks of levels: a tile's texels divided by their greatest common
divisor (the divisor the tiles filters use), minima 0, and as masks the voxels the
asset's frames show of the tile's brick (from the L3 nodes, which the asset holds
anyway); `--all-texels`: masks all set (every texel coded as the asset stores it).
Bricks of 1-byte texels go to OUT_w1.bin, of 2-byte ones to OUT_w2.bin. Prints, for the
asset: its bytes, and per width the stored bytes of those atlas sections and the bytes of
the tiles' divisors through zstd -19 (side information a coded atlas would also need).
"""

import os
import struct
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import system_python  # noqa: F401,E402  (re-runs under /usr/bin/python3 when needed)
import numpy as np  # noqa: E402
import zstandard  # noqa: E402
import vpak_decode as vdec  # noqa: E402
import vpak_read as vr  # noqa: E402

TILED = (3, 4)  # the tiles filters


def shown_masks(m, secs):
    """{(atlas section index, tile index): the voxels shown of the tile's brick, in leaf
    order}: the union of the masks of every L3 node of every frame that names the brick,
    for the channels whose plane the atlas belongs to."""
    l3 = secs.u32(vr.K_L3)
    by_brick = {}
    for frame in range(m["frame_count"]):
        for _, node in vr.walk_frame(m, secs, frame)[1]:
            b = int(l3[1 + vr.L3_WORDS * node])
            by_brick[b] = by_brick.get(b, np.zeros(512, bool)) | vdec.l3_active(l3, node)
    out = {}
    for c, ch in enumerate(m["channels"]):
        planes = vr.channel_planes(ch)
        # Brick b's plane and plane brick: through the channel table, or the plane's brick table, or b.
        if ch["alternates"]:
            entries = secs.u32(vr.K_CHANNEL_TABLE, c).astype(np.int64)
            where = lambda b: (planes[int(entries[b]) >> vr.CHOICE_SHIFT], int(entries[b]) & vr.PLANE_BRICK_MASK)  # noqa: E731
        elif m["planes"][ch["plane"]]["bricks"] != m["brick_count"]:
            table = secs.u32(vr.K_TABLE, ch["plane"])
            where = lambda b: (ch["plane"], int(table[b]))  # noqa: E731
        else:
            where = lambda b: (ch["plane"], b)  # noqa: E731
        for b, mask in by_brick.items():
            p, k = where(b)
            for a, at in enumerate(m["planes"][p]["atlases"]):
                if at["first_brick"] <= k < at["first_brick"] + at["count"]:
                    key = (vr.atlas_section(m, p, a), k - at["first_brick"])
                    out[key] = out.get(key, np.zeros(512, bool)) | mask
    return out


def main():
    path, out = sys.argv[1], sys.argv[2]
    try:
        m, secs = vr.open_asset(path)
    except vr.VpakError as e:
        raise SystemExit(f"error: {path}: {e}") from None
    all_texels = "--all-texels" in sys.argv
    shown = {} if all_texels else shown_masks(m, secs)
    by_width = {}  # w: (bricks, divisors, stored bytes)
    for (kind, index), (_, filt, w, s, n, _) in sorted(secs.coding.items()):
        if kind != vr.K_ATLAS or filt not in TILED:
            continue
        bricks, divisors, stored = by_width.setdefault(w, ([], [], [0]))
        stored[0] += secs.table[(kind, index)][1]
        tx, ty = s % 65536, s // 65536
        tz = n // (512 * tx * ty * w)
        tex = np.frombuffer(secs.get(kind, index), dtype="<u1" if w == 1 else "<u2").reshape(8 * tz, 8 * ty, 8 * tx)
        for c in range(tz):
            for b in range(ty):
                for a in range(tx):
                    t = tex[8 * c:8 * c + 8, 8 * b:8 * b + 8, 8 * a:8 * a + 8].astype(np.int64)
                    g = int(np.gcd.reduce(t.ravel()))
                    divisors.append(g)
                    # The tile is [z][y][x]; a mask is in leaf order, x slowest.
                    mask = np.ones(512, bool) if all_texels else shown.get((index, a + tx * (b + ty * c)), np.zeros(512, bool))
                    bricks.append((t // g if g else t, np.packbits(mask.reshape(8, 8, 8).transpose(2, 1, 0).ravel(), bitorder="little")))
    if not by_width:
        raise SystemExit(f"{path}: no tiled atlas")
    print(f"{path}: {os.path.getsize(path)} B")
    for w, (bricks, divisors, stored) in sorted(by_width.items()):
        name = f"{out}_w{w}.bin"
        texel = "<u1" if w == 1 else "<u2"
        with open(name, "wb") as f:
            f.write(b"BRK1" + struct.pack("<IdI", len(bricks), 0.0, w))
            for t, mask in bricks:
                f.write(mask.tobytes() + struct.pack("<i", 0))
                f.write(t.ravel().astype(texel).tobytes())
        gz = len(zstandard.ZstdCompressor(level=19).compress(np.array(divisors, dtype=texel).tobytes()))
        print(f"  {name}: {len(bricks)} tiles of {w} B texels, stored in {stored[0]} B; divisors {gz} B through zstd -19; largest level {max(int(t.max()) for t, _ in bricks)}; {sum(int(np.unpackbits(k).sum()) for _, k in bricks)} voxels shown")


if __name__ == "__main__":
    main()
