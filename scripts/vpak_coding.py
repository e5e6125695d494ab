"""Supercompressed sections of a `.vpak` body (format version 8), for scripts/vpak_read.py.

Written from docs/format.md ("Supercompression") alone, like the reader: the coding
section (kind 13) holds one 40-byte record per compressed section; a section is restored
by decompressing one zstd frame and undoing a shuffle, delta or tiles filter, and checked
against the record's XXH3-64 of the restored bytes. Every rule the page states is
checked; a failure raises `CodingError` with a one-line message.

Dependencies (Debian): python3-numpy, python3-zstandard.
"""

import struct

import numpy as np

K_CODING = 13
RECORD_SIZE = 40
SCHEME_ZSTD = 1
FILTER_NONE, FILTER_SHUFFLE, FILTER_DELTA, FILTER_TILES, FILTER_TILES_UNPREDICTED = 0, 1, 2, 3, 4
FILTER_NAMES = {FILTER_NONE: "none", FILTER_SHUFFLE: "shuffle", FILTER_DELTA: "delta", FILTER_TILES: "tiles",
                FILTER_TILES_UNPREDICTED: "tiles unpredicted"}
TILED = (FILTER_TILES, FILTER_TILES_UNPREDICTED)
# A zstd frame expands at most 2^15 times: a restored size beyond that is a lie.
MAX_EXPANSION = 1 << 15
MAX_STRIDE = 4096
# Input fed to the decompressor at a time, so a frame that decodes to more than its
# record says is stopped after at most MAX_EXPANSION times this many bytes.
FEED = 1 << 14


class CodingError(Exception):
    """A coding section or a compressed section that breaks the page's rules."""


def tiles_of(s):
    """A tiles record's stride as tiles along x and y."""
    return s % 65536, s // 65536


def filtered_size(filt, w, n):
    """Bytes of the filtered form F of n restored bytes: n, or n + w·T for tiles (T = n / (512·w) tiles)."""
    return n + w * (n // (512 * w)) if filt in TILED else n


def parse_records(data, table):
    """The coding section's records as {(kind, index): (scheme, filter, w, s, n, checksum)},
    each checked against the page's rules; `table` is the body's section table as stored
    {(kind, index): (offset, size, checksum)}."""
    if len(data) % RECORD_SIZE:
        raise CodingError(f"coding section of {len(data)} bytes is not whole {RECORD_SIZE}-byte records")
    if not data:
        raise CodingError("coding section without records (it is present exactly when some section is compressed)")
    records = {}
    for r in range(len(data) // RECORD_SIZE):
        kind, index, scheme, filt, w, s, n, checksum = struct.unpack_from("<IIIIIIQQ", data, RECORD_SIZE * r)
        name = f"coding record {r} (section kind {kind} index {index})"
        if (kind, index) in records:
            raise CodingError(f"{name} names a section named before")
        if (kind, index) not in table:
            raise CodingError(f"{name} names a section the body does not hold")
        if kind in (1, K_CODING):
            raise CodingError(f"{name}: the metadata and the coding section are never compressed")
        if scheme != SCHEME_ZSTD:
            raise CodingError(f"{name} has scheme {scheme} (1, zstd, is the only one)")
        allowed = {
            FILTER_NONE: w == 1 and s == 0,
            FILTER_SHUFFLE: w in (1, 2, 4, 8, 16) and s == 0,
            FILTER_DELTA: w in (1, 2, 4) and 1 <= s <= MAX_STRIDE,
            FILTER_TILES: w in (1, 2) and tiles_of(s)[0] >= 1 and tiles_of(s)[1] >= 1,
        }
        allowed[FILTER_TILES_UNPREDICTED] = allowed[FILTER_TILES]
        if not allowed.get(filt, False):
            raise CodingError(f"{name} has filter {filt} with width {w} and stride {s}, which the page does not allow")
        if n % w:
            raise CodingError(f"{name}: restored size {n} is not a multiple of the width {w}")
        if filt in TILED and n % (512 * tiles_of(s)[0] * tiles_of(s)[1] * w):
            raise CodingError(f"{name}: restored size {n} is not whole slabs of {tiles_of(s)[0]}x{tiles_of(s)[1]} tiles")
        stored = table[(kind, index)][1]
        if filtered_size(filt, w, n) > MAX_EXPANSION * stored:
            raise CodingError(f"{name}: restored size {n} is more than a {stored}-byte zstd frame can hold")
        records[(kind, index)] = (scheme, filt, w, s, n, checksum)
    return records


def decompress(stored, n):
    """The one zstd frame `stored` decoded, exactly n bytes, nothing after the frame."""
    try:
        import zstandard  # Debian python3-zstandard
    except ImportError:
        raise CodingError("cannot restore supercompressed sections: install python3-zstandard") from None
    stored = bytes(stored)
    try:
        size = zstandard.get_frame_parameters(stored).content_size
    except zstandard.ZstdError as e:
        raise CodingError(f"not a zstd frame ({e})") from None
    if size != zstandard.CONTENTSIZE_UNKNOWN and size != n:
        raise CodingError(f"its zstd frame holds {size} bytes, the record says {n}")
    d = zstandard.ZstdDecompressor().decompressobj()
    out, got, fed = [], 0, 0
    try:
        while fed < len(stored) and not d.eof:
            chunk = d.decompress(stored[fed:fed + FEED])
            fed += FEED
            got += len(chunk)
            if got > n:
                raise CodingError(f"its zstd frame decodes to more than the record's {n} bytes")
            out.append(chunk)
    except zstandard.ZstdError as e:
        raise CodingError(f"its zstd frame does not decode ({e})") from None
    if not d.eof:
        raise CodingError("its zstd frame is truncated")
    if d.unused_data or fed < len(stored):
        raise CodingError("bytes follow its zstd frame")
    if got != n:
        raise CodingError(f"its zstd frame decodes to {got} bytes, the record says {n}")
    return b"".join(out)


def unshuffle(f, w):
    """Elements of w bytes from F, which holds byte j of every element together."""
    return np.frombuffer(f, dtype=np.uint8).reshape(w, len(f) // w).T


def untile(elems, w, s, n, predicted):
    """Tiles: divisors, then each tile's residuals; quotients are the residuals, or
    (predicted) their running sums along i, j and k (modulo 2^(8w), as unsigned numpy
    integers wrap), times the tile's divisor, placed at the tile's elements of the
    8X x 8Y x 8Z texture."""
    dtype = {1: "<u1", 2: "<u2"}[w]
    e = elems.view(dtype).ravel()
    x, y = tiles_of(s)
    t = n // (512 * w)
    z = t // (x * y)
    g = e[:t]
    r = e[t:].reshape(z, y, x, 8, 8, 8)  # tile (c, b, a), then k, j, i
    u = np.cumsum(np.cumsum(np.cumsum(r, axis=5, dtype=r.dtype), axis=4, dtype=r.dtype), axis=3, dtype=r.dtype) if predicted else r
    v = (u * g.reshape(z, y, x, 1, 1, 1)).astype(dtype)
    # Texture element (8a + i, 8b + j, 8c + k): axes c, k, b, j, a, i, z slowest.
    return np.ascontiguousarray(v.transpose(0, 3, 1, 4, 2, 5)).tobytes()


def unfilter(f, filt, w, s, n=None):
    """The section (n bytes) from its filtered bytes F (format.md, "Restoring")."""
    if filt == FILTER_NONE or w == 1 and filt == FILTER_SHUFFLE:
        return f
    elems = np.ascontiguousarray(unshuffle(f, w))  # [m, w] bytes, element i byte j
    if filt == FILTER_SHUFFLE:
        return elems.tobytes()
    if filt in TILED:
        return untile(elems, w, s, n, filt == FILTER_TILES)
    # Delta: x[i] = d[i] + x[i - s] mod 2^(8w): per residue class of i mod s a running
    # sum, which unsigned numpy integers take modulo 2^(8w).
    dtype = {1: "<u1", 2: "<u2", 4: "<u4"}[w]
    d = elems.view(dtype).ravel()
    m = len(d)
    rows = -(-m // s)
    padded = np.zeros(rows * s, dtype=d.dtype)
    padded[:m] = d
    x = np.cumsum(padded.reshape(rows, s), axis=0, dtype=d.dtype).ravel()[:m]
    return x.astype(dtype).tobytes()


def restore(stored, record, xxh3_64):
    """A section's bytes from its stored bytes and its coding record."""
    _scheme, filt, w, s, n, checksum = record
    section = unfilter(decompress(stored, filtered_size(filt, w, n)), filt, w, s, n)
    if xxh3_64(section) != checksum:
        raise CodingError("restored bytes do not match the coding record's checksum")
    return section
