#!/usr/bin/env python3
"""Generate the c-blosc 1.x test vectors used by crates/blosc/tests/vectors.rs.

Uses ctypes on the system c-blosc 1.x shared library (Debian: libblosc1,
/usr/lib/x86_64-linux-gnu/libblosc.so.1; override with LIBBLOSC=/path), so
the vectors are what the real C library writes. Only the Python standard
library is needed.

Output, in crates/blosc/tests/data/:
  datasets/<name>.bin   the uncompressed inputs (= expected decoder output)
  vectors.bin           every compressed buffer, concatenated
  manifest.tsv          one line per vector: how it was made, where it is in
                        vectors.bin, and whether c-blosc itself decodes it
                        (expect=ok, output == dataset) or refuses it
                        (expect=err; the Rust decoder must refuse it too)

Every vector is checked here with blosc_decompress before it is written.

Run from anywhere:  /usr/bin/python3 scripts/make_blosc_vectors.py
The output is deterministic for a given libblosc build.
"""

import ctypes
import hashlib
import math
import os
import random
import struct
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "crates", "blosc", "tests", "data")

# blosc.h
NOSHUFFLE, SHUFFLE, BITSHUFFLE = 0, 1, 2
SHUFFLE_NAMES = {NOSHUFFLE: "none", SHUFFLE: "byte", BITSHUFFLE: "bit"}
SPLIT_MODES = {"always": 1, "never": 2, "auto": 3, "forward_compat": 4}
MAX_OVERHEAD = 16

lib = ctypes.CDLL(os.environ.get("LIBBLOSC", "libblosc.so.1"))
lib.blosc_list_compressors.restype = ctypes.c_char_p
lib.blosc_get_version_string.restype = ctypes.c_char_p
lib.blosc_compress_ctx.argtypes = [
    ctypes.c_int, ctypes.c_int, ctypes.c_size_t, ctypes.c_size_t,
    ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p,
    ctypes.c_size_t, ctypes.c_int,
]
lib.blosc_decompress_ctx.argtypes = [
    ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int,
]
HAVE_SPLITMODE = hasattr(lib, "blosc_set_splitmode")
lib.blosc_init()

VERSION = lib.blosc_get_version_string().decode()
CODECS = lib.blosc_list_compressors().decode().split(",")


def set_splitmode(mode):
    if HAVE_SPLITMODE:
        lib.blosc_set_splitmode(SPLIT_MODES[mode])
    elif mode != "forward_compat":
        raise SystemExit("this libblosc has no blosc_set_splitmode")


def compress(data, codec, clevel, shuffle, typesize, blocksize, split, destsize=None):
    """blosc_compress_ctx with a global split mode; returns the buffer."""
    set_splitmode(split)
    if destsize is None:
        # Roomy, so that incompressible streams are stored raw inside a
        # normal frame instead of the whole buffer becoming memcpyed.
        destsize = 2 * len(data) + 4096
    src = ctypes.create_string_buffer(data, len(data)) if data else ctypes.create_string_buffer(1)
    dst = ctypes.create_string_buffer(destsize)
    n = lib.blosc_compress_ctx(clevel, shuffle, typesize, len(data), src, dst,
                               destsize, codec.encode(), blocksize, 1)
    if n <= 0:
        raise RuntimeError(f"blosc_compress_ctx failed ({n}) for {codec} {len(data)} bytes")
    return dst.raw[:n]


def c_decompress(buf, nbytes):
    """Returns the decoded bytes, or None when c-blosc refuses the buffer."""
    src = ctypes.create_string_buffer(buf, len(buf))
    dst = ctypes.create_string_buffer(max(nbytes, 1))
    r = lib.blosc_decompress_ctx(src, dst, nbytes, 1)
    if r < 0 or r != nbytes:
        return None
    return dst.raw[:nbytes]


# ----------------------------------------------------------------------------
# Datasets (deterministic).

def ds_tiny():
    return bytes((i * 37 + 11) & 0xFF for i in range(100))


def ds_small():
    # 500 int16 samples: a sine with a little noise, under one block.
    rng = random.Random(2)
    vals = [int(3000 * math.sin(i / 17.0)) + rng.randint(-3, 3) for i in range(500)]
    return struct.pack("<500h", *vals)


def ds_multi():
    # 3 full 1024-byte blocks and a 324-byte leftover block (324 = 40 8-byte
    # elements plus 4 tail bytes), slowly varying u32 with noise in the low bits.
    rng = random.Random(3)
    n = (3 * 1024 + 324) // 4
    vals = [(1000 + i // 7) * 256 + rng.randint(0, 15) for i in range(n)]
    return struct.pack(f"<{n}I", *vals)


def ds_mixed():
    # Block 0 random, block 1 compressible, leftover of 3 bytes (smaller than
    # typesize 4 and 8, so it is never shuffled).
    rng = random.Random(4)
    a = bytes(rng.getrandbits(8) for _ in range(1024))
    b = bytes((i // 64) & 0xFF for i in range(1024))
    return a + b + bytes([1, 2, 3])


def ds_random():
    rng = random.Random(5)
    return bytes(rng.getrandbits(8) for _ in range(1500))


def ds_runs():
    # 64 KiB, highly compressible: long zero runs and a repeating pattern.
    out = bytearray(65536)
    pat = struct.pack("<4f", 1.0, 0.5, 0.25, 0.125)
    for start in range(0, 65536, 4096):
        for j in range(start + 1024, start + 1024 + 512, 16):
            out[j:j + 16] = pat
    return bytes(out)


def ds_smoke():
    # 8 x 16 x 16 float32 "smoke density": a soft blob with swirling detail,
    # exactly 0 outside it (like a sparse VDB leaf set).
    vals = []
    for z in range(8):
        for y in range(16):
            for x in range(16):
                dx, dy, dz = x - 7.5, y - 7.5, (z - 3.5) * 2
                r = math.sqrt(dx * dx + dy * dy + dz * dz)
                d = max(0.0, 1.0 - r / 7.0)
                if d > 0:
                    d *= 0.6 + 0.4 * math.sin(x * 0.9 + y * 0.4) * math.cos(z * 1.3 - y * 0.2)
                vals.append(d)
    return struct.pack(f"<{len(vals)}f", *vals)


def ds_far():
    # 12 KiB of random bytes repeated: blosclz must use "far" matches
    # (distance > 8191).
    rng = random.Random(6)
    a = bytes(rng.getrandbits(8) for _ in range(12288))
    return a + a


def ds_leaf():
    # What OpenVDB writes: one LeafNode<float, 3> buffer (512 floats), mostly
    # background with a narrow band of values.
    vals = []
    for i in range(512):
        x, y, z = i >> 6, (i >> 3) & 7, i & 7
        sd = (x + y + z - 10) * 0.1
        vals.append(max(-0.3, min(0.3, sd)))
    return struct.pack("<512f", *vals)


DATASETS = {
    "empty": b"",
    "tiny": ds_tiny(),
    "small": ds_small(),
    "multi": ds_multi(),
    "mixed": ds_mixed(),
    "random": ds_random(),
    "runs": ds_runs(),
    "smoke": ds_smoke(),
    "far": ds_far(),
    "leaf": ds_leaf(),
}


# ----------------------------------------------------------------------------
# Vector plan.

def plan():
    """Yields dicts describing each vector to make."""
    shuffles = [NOSHUFFLE, SHUFFLE, BITSHUFFLE]
    typesizes = [1, 2, 4, 8]
    clevels = [1, 5, 9]
    i = 0
    for codec in CODECS:
        # Empty and tiny (< 128 bytes: always memcpyed) buffers.
        yield dict(dataset="empty", codec=codec, clevel=5, shuffle=SHUFFLE, typesize=4,
                   blocksize=0, split="forward_compat")
        yield dict(dataset="tiny", codec=codec, clevel=5, shuffle=BITSHUFFLE, typesize=2,
                   blocksize=0, split="forward_compat")
        # clevel 0: memcpyed regardless of content.
        yield dict(dataset="small", codec=codec, clevel=0, shuffle=SHUFFLE, typesize=2,
                   blocksize=0, split="forward_compat")
        for shuffle in shuffles:
            for typesize in typesizes:
                i += 1
                clevel = clevels[i % 3]
                common = dict(codec=codec, shuffle=shuffle, typesize=typesize)
                # One block, automatic block size.
                yield dict(common, dataset="small", clevel=clevel, blocksize=0,
                           split="forward_compat")
                # Several blocks plus a leftover block, split both ways.
                for split in ("always", "never"):
                    yield dict(common, dataset="multi", clevel=clevels[(i + 1) % 3],
                               blocksize=1024, split=split)
                # Raw (incompressible) streams next to compressed ones.
                yield dict(common, dataset="mixed", clevel=clevel, blocksize=1024,
                           split="auto")
                # Highly compressible, automatic (large) block size.
                yield dict(common, dataset="runs", clevel=clevels[(i + 2) % 3], blocksize=0,
                           split="forward_compat")
                # Float32 smoke-like data in 4 blocks.
                yield dict(common, dataset="smoke", clevel=clevel, blocksize=2048,
                           split="auto" if i % 2 else "forward_compat")
        # Incompressible with the usual destination size: c-blosc falls back
        # to a memcpyed buffer.
        yield dict(dataset="random", codec=codec, clevel=9, shuffle=SHUFFLE, typesize=4,
                   blocksize=0, split="forward_compat", destsize=1500 + MAX_OVERHEAD)
        # Odd typesizes: 3 splits into 3 streams; 16 is the largest split;
        # c-blosc's reader never splits 32 (MAX_SPLITS = 16), so a buffer
        # forced to ALWAYS_SPLIT with it is unreadable (expect=err).
        for typesize in (3, 16, 32):
            for shuffle in (SHUFFLE, BITSHUFFLE):
                yield dict(dataset="multi", codec=codec, clevel=5, shuffle=shuffle,
                           typesize=typesize, blocksize=3072 if typesize == 3 else 4096,
                           split="always")
        # ... and typesize 32 as c-blosc writes it by default (not split).
        for shuffle in (SHUFFLE, BITSHUFFLE):
            yield dict(dataset="multi", codec=codec, clevel=5, shuffle=shuffle, typesize=32,
                       blocksize=4096, split="forward_compat")
        # Exactly what OpenVDB's bloscCompress does for a float leaf buffer
        # (lz4 in OpenVDB; here with every codec).
        yield dict(dataset="leaf", codec=codec, clevel=9, shuffle=SHUFFLE, typesize=4,
                   blocksize=2048, split="forward_compat", destsize=2048 + MAX_OVERHEAD)
        # c-blosc 1.14+ forced to ALWAYS_SPLIT where its own reader will not
        # split (800 / 8 < 128): c-blosc cannot read these back, and neither
        # must we (expect=err).
        yield dict(dataset="small", codec=codec, clevel=5, shuffle=NOSHUFFLE, typesize=8,
                   blocksize=800, split="always", dataset_len=800)
    # blosclz far matches (distance > 8191).
    for shuffle, typesize, clevel in ((NOSHUFFLE, 1, 5), (NOSHUFFLE, 1, 9), (SHUFFLE, 4, 9),
                                      (BITSHUFFLE, 2, 5)):
        yield dict(dataset="far", codec="blosclz", clevel=clevel, shuffle=shuffle,
                   typesize=typesize, blocksize=0, split="forward_compat")


def main():
    print(f"c-blosc {VERSION}, codecs: {', '.join(CODECS)}, "
          f"blosc_set_splitmode: {'yes' if HAVE_SPLITMODE else 'no'}")
    os.makedirs(os.path.join(OUT, "datasets"), exist_ok=True)
    for name, data in DATASETS.items():
        with open(os.path.join(OUT, "datasets", f"{name}.bin"), "wb") as f:
            f.write(data)

    blob = bytearray()
    lines = []
    seen = set()
    counts = {"ok": 0, "err": 0}
    for v in plan():
        data = DATASETS[v["dataset"]]
        if "dataset_len" in v:
            data = data[:v["dataset_len"]]
        buf = compress(data, v["codec"], v["clevel"], v["shuffle"], v["typesize"],
                       v["blocksize"], v["split"], v.get("destsize"))
        if buf in seen:
            continue
        seen.add(buf)
        decoded = c_decompress(buf, len(data))
        if decoded is None:
            expect = "err"
        elif decoded == data:
            expect = "ok"
        else:
            raise SystemExit(f"c-blosc round trip changed the data: {v}")
        if expect == "err" and v["split"] != "always":
            raise SystemExit(f"c-blosc cannot read its own buffer: {v}")
        counts[expect] += 1
        flags = buf[2]
        name = (f"{v['dataset']}-{v['codec']}-c{v['clevel']}-{SHUFFLE_NAMES[v['shuffle']]}"
                f"-t{v['typesize']}-b{v['blocksize']}-{v['split']}")
        lines.append("\t".join(str(x) for x in (
            name, v["dataset"], len(data), v["codec"], v["clevel"],
            SHUFFLE_NAMES[v["shuffle"]], v["typesize"], v["blocksize"], v["split"],
            f"0x{flags:02x}", len(blob), len(buf), expect,
            hashlib.sha256(data).hexdigest(),
        )))
        blob += buf

    with open(os.path.join(OUT, "vectors.bin"), "wb") as f:
        f.write(blob)
    header = ("# c-blosc test vectors made by scripts/make_blosc_vectors.py with c-blosc "
              f"{VERSION}\n"
              "# name\tdataset\tnbytes\tcodec\tclevel\tshuffle\ttypesize\tblocksize_arg"
              "\tsplitmode\tflags\toffset\tlength\texpect\tsha256_of_output\n")
    with open(os.path.join(OUT, "manifest.tsv"), "w") as f:
        f.write(header)
        f.write("\n".join(lines) + "\n")
    total = len(blob) + sum(len(d) for d in DATASETS.values())
    print(f"{len(lines)} vectors ({counts['ok']} ok, {counts['err']} refused by c-blosc), "
          f"{len(blob)} bytes of vectors, {total} bytes in all")


if __name__ == "__main__":
    sys.exit(main())
