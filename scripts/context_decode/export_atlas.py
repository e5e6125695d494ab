#!/usr/bin/python3
"""An asset's tiled atlases as bricks for `context_decode` (issue 24: what the coder would
make of the texels an asset actually stores, against the zstd sections it stores today).

    /usr/bin/python3 export_atlas.py ASSET.vpak OUT

Every atlas section that the tiles filters coded (1-lane unorm8 or unorm16: 8x8x8 tiles,
one per brick) becomes bricks of levels: a tile's texels divided by their greatest common
divisor (the divisor the tiles filters use), every voxel coded (masks all set, minima 0).
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
import vpak_read as vr  # noqa: E402

TILED = (3, 4)  # the tiles filters


def main():
    path, out = sys.argv[1], sys.argv[2]
    _, secs = vr.open_asset(path)
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
                    bricks.append(t // g if g else t)
    if not by_width:
        raise SystemExit(f"{path}: no tiled atlas")
    print(f"{path}: {os.path.getsize(path)} B")
    for w, (bricks, divisors, stored) in sorted(by_width.items()):
        name = f"{out}_w{w}.bin"
        texel = "<u1" if w == 1 else "<u2"
        with open(name, "wb") as f:
            f.write(b"BRK1" + struct.pack("<IdI", len(bricks), 0.0, w))
            for t in bricks:
                f.write(b"\xff" * 64 + struct.pack("<i", 0))
                f.write(t.ravel().astype(texel).tobytes())
        gz = len(zstandard.ZstdCompressor(level=19).compress(np.array(divisors, dtype=texel).tobytes()))
        print(f"  {name}: {len(bricks)} tiles of {w} B texels, stored in {stored[0]} B; divisors {gz} B through zstd -19; largest level {max(int(t.max()) for t in bricks)}")


if __name__ == "__main__":
    main()
