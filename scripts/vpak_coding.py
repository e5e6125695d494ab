"""Supercompressed sections of a `.vpak` body (format version 8 and later), for scripts/vpak_read.py.

Written from docs/format.md ("Supercompression", "Context coding", "Mask coding") alone, like
the reader: the coding section (kind 13) holds one 40-byte record per compressed section; a
section is restored by decompressing one zstd frame (or, version 11, decoding a context-coded
stream; version 14, a mask-coded one; version 15, a context-coded one over the shown voxels)
and undoing a shuffle, delta, tiles or (version 12) l3 nodes filter, and checked against the record's XXH3-64 of
the restored bytes. Every rule the page states is
checked; a failure raises `CodingError` with a one-line message.

Dependencies (Debian): python3-numpy, python3-zstandard.
"""

import struct

import numpy as np

K_CODING = 13
K_L3 = 7
RECORD_SIZE = 40
SCHEME_ZSTD, SCHEME_CONTEXT, SCHEME_MASKS, SCHEME_SHOWN = 1, 2, 3, 4
K_ATLAS = 10
FILTER_NONE, FILTER_SHUFFLE, FILTER_DELTA, FILTER_TILES, FILTER_TILES_UNPREDICTED, FILTER_L3 = 0, 1, 2, 3, 4, 5
FILTER_NAMES = {FILTER_NONE: "none", FILTER_SHUFFLE: "shuffle", FILTER_DELTA: "delta", FILTER_TILES: "tiles",
                FILTER_TILES_UNPREDICTED: "tiles unpredicted", FILTER_L3: "l3 nodes"}
# The first file versions with context coding (scheme 2), the l3 nodes filter, mask coding (scheme 3)
# and context coding over the shown voxels (scheme 4).
CONTEXT_FROM, L3_FROM, MASKS_FROM, SHOWN_FROM = 11, 12, 14, 15
TILED = (FILTER_TILES, FILTER_TILES_UNPREDICTED)
# A zstd frame expands at most 2^15 times: a restored size beyond that is a lie.
MAX_EXPANSION = 1 << 15
MAX_STRIDE = 4096
# Input fed to the decompressor at a time, so a frame that decodes to more than its
# record says (or a wrapped body's limit) is stopped after at most MAX_EXPANSION times
# this many bytes more.
FEED = 1 << 8


class CodingError(Exception):
    """A coding section or a compressed section that breaks the page's rules."""


def tiles_of(s):
    """A tiles record's stride as tiles along x and y."""
    return s % 65536, s // 65536


def filtered_size(filt, w, n):
    """Bytes of the filtered form F of n restored bytes: n, or n + w·T for tiles (T = n / (512·w) tiles)."""
    return n + w * (n // (512 * w)) if filt in TILED else n


def parse_records(data, table, version):
    """The coding section's records as {(kind, index): (scheme, filter, w, s, n, checksum)},
    each checked against the page's rules; `table` is the body's section table as stored
    {(kind, index): (offset, size, checksum)}; `version`: the file's, which says whether
    scheme 2 (11 and later), filter 5 (12 and later), scheme 3 (14 and later) and scheme 4
    (15 and later) may appear."""
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
        if scheme not in (SCHEME_ZSTD, SCHEME_CONTEXT, SCHEME_MASKS, SCHEME_SHOWN):
            raise CodingError(f"{name} has scheme {scheme} (1, zstd, 2, context coding, 3, mask coding, or 4, context coding over the shown voxels)")
        if scheme == SCHEME_SHOWN and version < SHOWN_FROM:
            raise CodingError(f"{name} is context-coded over its shown voxels (scheme 4) in a file older than version {SHOWN_FROM}")
        if scheme == SCHEME_SHOWN and (filt != FILTER_TILES_UNPREDICTED or kind != K_ATLAS):
            raise CodingError(f"{name} is context-coded over its shown voxels with filter {filt} (an atlas, kind {K_ATLAS}, under tiles unpredicted only)")
        if scheme == SCHEME_MASKS and version < MASKS_FROM:
            raise CodingError(f"{name} is mask-coded (scheme 3) in a file older than version {MASKS_FROM}")
        if scheme == SCHEME_MASKS and (filt != FILTER_L3 or kind != K_L3):
            raise CodingError(f"{name} is mask-coded with filter {filt} (an L3 array, kind {K_L3}, under l3 nodes only)")
        if scheme == SCHEME_CONTEXT and version < CONTEXT_FROM:
            raise CodingError(f"{name} is context-coded (scheme 2) in a file older than version 11")
        if scheme == SCHEME_CONTEXT and filt != FILTER_TILES_UNPREDICTED:
            raise CodingError(f"{name} is context-coded with filter {filt} (tiles unpredicted only)")
        allowed = {
            FILTER_NONE: w == 1 and s == 0,
            FILTER_SHUFFLE: w in (1, 2, 4, 8, 16) and s == 0,
            FILTER_DELTA: w in (1, 2, 4) and 1 <= s <= MAX_STRIDE,
            FILTER_TILES: w in (1, 2) and tiles_of(s)[0] >= 1 and tiles_of(s)[1] >= 1,
        }
        allowed[FILTER_TILES_UNPREDICTED] = allowed[FILTER_TILES]
        allowed[FILTER_L3] = w == 4 and s == 0 and n >= 4
        if filt == FILTER_L3 and version < L3_FROM:
            raise CodingError(f"{name} has filter 5 (l3 nodes) in a file older than version {L3_FROM}")
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


def inflate(stored, limit, record=False):
    """The one zstd frame `stored` decoded, nothing after the frame: with `record`, exactly
    the `limit` bytes a coding record says; else (a wrapped body) the content size the frame
    must state, at most `limit`, checked before anything is decoded."""
    try:
        import zstandard  # Debian python3-zstandard
    except ImportError:
        raise CodingError("cannot restore supercompressed sections: install python3-zstandard") from None
    stored = bytes(stored)
    most = f"the record's {limit}" if record else f"{limit}"
    try:
        size = zstandard.get_frame_parameters(stored).content_size
    except zstandard.ZstdError as e:
        raise CodingError(f"not a zstd frame ({e})") from None
    if record and size != zstandard.CONTENTSIZE_UNKNOWN and size != limit:
        raise CodingError(f"its zstd frame holds {size} bytes, the record says {limit}")
    if not record and size == zstandard.CONTENTSIZE_UNKNOWN:
        raise CodingError("its zstd frame does not state its content size")
    if not record and size > limit:
        raise CodingError(f"its zstd frame states {size} bytes of content (at most {limit})")
    d = zstandard.ZstdDecompressor().decompressobj()
    out, got, fed = [], 0, 0
    # Fed in small pieces (an RLE block's 4 bytes can stand for 128 KiB, and a decoder checks
    # a stated size only at the frame's end), so that the output is checked against the limit
    # before it grows more than 8 MiB past it.
    try:
        while fed < len(stored) and not d.eof:
            chunk = d.decompress(stored[fed:fed + FEED])
            fed += FEED
            got += len(chunk)
            if got > limit:
                raise CodingError(f"its zstd frame decodes to more than {most} bytes")
            out.append(chunk)
    except zstandard.ZstdError as e:
        raise CodingError(f"its zstd frame does not decode ({e})") from None
    if not d.eof:
        raise CodingError("its zstd frame is truncated")
    if d.unused_data or fed < len(stored):
        raise CodingError("bytes follow its zstd frame")
    if got != (limit if record else size):
        raise CodingError(f"its zstd frame decodes to {got} bytes, {'the record says' if record else 'it states'} {limit if record else size}")
    return b"".join(out)


def decompress(stored, n):
    """The one zstd frame `stored` decoded, exactly n bytes, nothing after the frame."""
    return inflate(stored, n, record=True)


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
    if filt == FILTER_L3:
        return unfilter_l3(f)
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


def unfilter_l3(f):
    """The l3 nodes filter undone: the count, the records from their steps (fields shuffled
    by byte weight), the sub-masks as they are; all arithmetic modulo 2^32 (unsigned numpy
    integers wrap). Node k's first word is the running sum of the first-word steps, each
    after the first plus twice the sub-masks of the node before, from 1 + 3c."""
    c = struct.unpack_from("<I", f, 0)[0]
    if 4 + 12 * c > len(f):
        raise CodingError(f"its l3 nodes filter counts {c} nodes in {len(f)} bytes")
    fields = np.frombuffer(f, dtype=np.uint8, count=12 * c, offset=4).reshape(4, 3 * c).T.copy().view("<u4").ravel()
    step_b, states, step_f = fields[:c], fields[c:2 * c], fields[2 * c:]
    bricks = np.cumsum(step_b, dtype=np.uint32)
    partial = (states >> np.uint32(1)) & np.uint32(0x5555)
    masks = np.unpackbits(partial.astype("<u4").view(np.uint8).reshape(-1, 4), axis=1).sum(axis=1).astype(np.uint32)
    inc = step_f.copy()
    inc[1:] += np.uint32(2) * masks[:-1]
    if c:
        inc[0] += np.uint32(1 + 3 * c)
    firsts = np.cumsum(inc, dtype=np.uint32)
    words = np.frombuffer(f, dtype="<u4").copy()
    words[1:1 + 3 * c] = np.stack([bricks, states, firsts], axis=1).ravel()
    return words.astype("<u4").tobytes()


def rans_tables(table, contexts, nsym, prec, what):
    """Per used context of a frequency table (`contexts` rows of `nsym` frequencies): the
    symbol of each slot, each symbol's cum and its frequency; a row summing to neither 0 nor
    2^prec is refused."""
    total = 1 << prec
    tables = {}
    for c in range(contexts):
        f = table[c * nsym:(c + 1) * nsym]
        if sum(f) == 0:
            continue
        if sum(f) != total:
            raise CodingError(f"its {what} context {c}'s frequencies sum to {sum(f)}, not 0 or {total}")
        tables[c] = ([s for s in range(nsym) for _ in range(f[s])], [sum(f[:s]) for s in range(nsym)], f)
    return tables


def rans_symbol(x, ctx, tables, prec, what):
    """One symbol of state x in context ctx: (symbol, the state before renormalising)."""
    if ctx not in tables:
        raise CodingError(f"its {what} stream codes in unused context {ctx}")
    slots, cums, freqs = tables[ctx]
    slot = x % (1 << prec)
    sym = slots[slot]
    return sym, freqs[sym] * (x >> prec) + slot - cums[sym]


def context_decode(stored, w, size, shown=None):
    """A context-coded stream (format.md, "Context coding") decoded into the filtered bytes
    F of `size` bytes: T divisors and 512·T quotients of w bytes, shuffled by byte. `shown`
    (scheme 4): per tile, a boolean array of its 512 elements (x fastest) that some node shows."""
    stored = bytes(stored)
    m = size // w
    t_count = m // 513
    if len(stored) < 24:
        raise CodingError(f"its context stream is {len(stored)} bytes, shorter than its header")
    lanes, prec, nsym, a_len, b_len, words_len = struct.unpack_from("<6I", stored, 0)
    if not (1 <= lanes <= 256 and 9 <= prec <= 12 and 1 <= nsym <= 48):
        raise CodingError(f"its context stream has N={lanes}, P={prec}, S={nsym}")
    if 24 + a_len + b_len + 2 * words_len != len(stored) or words_len < 2 * lanes:
        raise CodingError("its context stream's parts do not add up to its size")
    n_flags = 0 if shown is None else -(-t_count // 8)
    side = decompress(stored[24:24 + a_len], w * t_count + n_flags + 256 * nsym)
    bits = stored[24 + a_len:24 + a_len + b_len]
    words = struct.unpack_from(f"<{words_len}H", stored, 24 + a_len + b_len)
    divisors = [int.from_bytes(side[w * t:w * t + w], "little") for t in range(t_count)]
    flags = side[w * t_count:w * t_count + n_flags]
    if t_count % 8 and n_flags and flags[-1] >> (t_count % 8):
        raise CodingError("its context stream has a flag set past its last tile")
    limit = 1 << (8 * w)
    if shown is not None and len(shown) != t_count:
        raise CodingError(f"its context stream is given {len(shown)} tiles' shown voxels for {t_count} tiles")
    # Scheme 4: a flagged tile leaves out its elements no node shows; every prediction within the tile's levels.
    left_out = [shown is not None and (flags[t // 8] >> (t % 8)) & 1 == 1 for t in range(t_count)]
    for t in range(t_count):
        if left_out[t] and all(shown[t]):
            raise CodingError(f"its context stream has tile {t}'s flag set, but its every voxel is shown")
    top = [((limit - 1) // g if g else 0) for g in divisors]
    table = struct.unpack_from(f"<{128 * nsym}H", side, w * t_count + n_flags)
    tables = rans_tables(table, 128, nsym, prec, "context")
    elems = divisors + [0] * (512 * t_count)
    states = [words[2 * l] * 65536 + words[2 * l + 1] for l in range(lanes)]
    if shown is not None and min(states) < 65536:
        raise CodingError("its context stream has a lane's first state below 2^16")
    wp, bp = 2 * lanes, 0

    def bit(b):
        return (bits[b >> 3] >> (b & 7)) & 1 if b >> 3 < len(bits) else None

    u = {}  # (tile, i, j, k): (value, |r|)
    for g in range(-(-t_count // lanes)):
        for v in range(512):
            i, j, k = v % 8, (v // 8) % 8, v // 64
            cls = 4 * (k > 0) + 2 * (j > 0) + (i > 0)
            for lane in range(lanes):
                t = g * lanes + lane
                if t >= t_count:
                    break
                def val(di, dj, dk):
                    return u.get((t, i - di, j - dj, k - dk), (0, 0))
                a, b, c = val(0, 0, 1)[0], val(0, 1, 0)[0], val(1, 0, 0)[0]
                pred = {0: 0, 1: c, 2: b, 4: a, 3: b + c - val(1, 1, 0)[0], 5: a + c - val(1, 0, 1)[0],
                        6: a + b - val(0, 1, 1)[0]}.get(cls)
                if pred is None:
                    pred = (2 * (a + b + c) - val(0, 1, 1)[0] - val(1, 0, 1)[0] - val(1, 1, 0)[0] + 1) // 3
                if shown is not None:
                    pred = min(max(pred, 0), top[t])
                    if left_out[t] and not shown[t][v]:
                        u[(t, i, j, k)] = (pred, 0)
                        elems[t_count + 512 * t + v] = pred
                        continue
                e = min(255, val(1, 0, 0)[1] + val(0, 1, 0)[1] + val(0, 0, 1)[1])
                bucket = e if e < 4 else min(15, (e * e).bit_length() - 1)
                ctx = 8 * bucket + cls
                sym, x = rans_symbol(states[lane], ctx, tables, prec, "context")
                if x < 65536:
                    if wp >= words_len:
                        raise CodingError("its context stream runs past its words")
                    x = x * 65536 + words[wp]
                    wp += 1
                states[lane] = x
                if sym < 16:
                    z = sym
                else:
                    kk = sym - 16
                    raw = 0
                    for n_ in range(kk):
                        got = bit(bp + n_)
                        if got is None:
                            raise CodingError("its context stream runs past its escape bits")
                        raw |= got << n_
                    bp += kk
                    z = 15 + (1 << kk) + raw
                r = z // 2 if z % 2 == 0 else -(z + 1) // 2
                q = pred + r
                if not 0 <= q < limit:
                    raise CodingError(f"its context stream decodes to {q}, outside the {w}-byte element")
                u[(t, i, j, k)] = (q, abs(r))
                elems[t_count + 512 * t + v] = q
        u.clear()
    if wp != words_len or any(x != 65536 for x in states) or bp > 8 * b_len:
        raise CodingError("its context stream does not end where its coder does")
    e = np.array(elems, dtype="<u2")
    planes = [(e & 0xFF).astype(np.uint8)] + ([(e >> 8).astype(np.uint8)] if w == 2 else [])
    return b"".join(p.tobytes() for p in planes)


MASK_CONTEXTS = 114


def mask_context(a, b):
    """The context of a row whose neighbour rows along x and y are a and b (None: outside the node)."""
    if a is not None and b is not None:
        return sum((((a >> z) & 1) + ((b >> z) & 1)) * 3 ** z for z in range(4))
    if a is not None:
        return 81 + a
    if b is not None:
        return 97 + b
    return 113


def masks_decode(stored, n):
    """A mask-coded stream (format.md, "Mask coding") decoded into the l3 nodes filter's
    output F of n bytes: its head from the side frame, its sub-masks row by row."""
    stored = bytes(stored)
    if len(stored) < 16:
        raise CodingError(f"its mask stream is {len(stored)} bytes, shorter than its header")
    lanes, prec, a_len, words_len = struct.unpack_from("<4I", stored, 0)
    if not (1 <= lanes <= 64 and 9 <= prec <= 12):
        raise CodingError(f"its mask stream has N={lanes}, P={prec}")
    if 16 + a_len + 2 * words_len != len(stored):
        raise CodingError("its mask stream's parts do not add up to its size")
    table_len = MASK_CONTEXTS * 16 * 2
    side = inflate(stored[16:16 + a_len], n + table_len + 4 * lanes)
    c = struct.unpack_from("<I", side, 0)[0] if len(side) >= 4 else None
    if c is None or 4 + 12 * c > n or len(side) != 4 + 12 * c + table_len + 4 * lanes:
        raise CodingError(f"its mask stream's side frame of {len(side)} bytes is not an L3 array's head for {n} bytes, a table and {lanes} runs")
    head = 4 + 12 * c
    # Node k's states: field c + k, byte j at 4 + j·3c + c + k.
    states = [sum(side[4 + j * 3 * c + c + k] << (8 * j) for j in range(4)) for k in range(c)]
    owners = [(k, b) for k in range(c) for b in range(8) if (states[k] >> (2 * b)) & 3 == 2]
    most = [2 + 16 * sum(1 for k, _ in owners if k % lanes == l) for l in range(lanes)]
    if n - head != 8 * len(owners):
        raise CodingError(f"its L3 array holds {(n - head) / 8} sub-masks where its states name {len(owners)}")
    table = struct.unpack_from(f"<{MASK_CONTEXTS * 16}H", side, head)
    runs = struct.unpack_from(f"<{lanes}I", side, head + table_len)
    tables = rans_tables(table, MASK_CONTEXTS, 16, prec, "mask")
    if any(r < 2 or r > m for r, m in zip(runs, most)) or sum(runs) != words_len:
        raise CodingError(f"its mask stream's runs {list(runs)} are not its {words_len} words, each 2 to 2 + 16 per sub-mask of its lane")
    words = struct.unpack_from(f"<{words_len}H", stored, 16 + a_len)
    starts = [sum(runs[:l]) for l in range(lanes)]
    state = [words[starts[l]] * 65536 + words[starts[l] + 1] for l in range(lanes)]
    at = [starts[l] + 2 for l in range(lanes)]
    ends = [starts[l] + runs[l] for l in range(lanes)]
    known = {}  # (node, sub-block): mask

    def sub_mask(k, b):
        st = (states[k] >> (2 * b)) & 3
        return 0xFFFFFFFFFFFFFFFF if st == 1 else known.get((k, b), 0) if st == 2 else 0

    out = bytearray(side[:head])
    for k, b in owners:
        lane = k % lanes
        m = 0
        for t in range(16):
            row = lambda mask, r: (mask >> (4 * r)) & 15
            a = row(m, t - 4) if t >= 4 else row(sub_mask(k, b - 4), 12 + t) if b & 4 else None
            bb = row(m, t - 1) if t % 4 else row(sub_mask(k, b - 2), 4 * (t // 4) + 3) if b & 2 else None
            ctx = mask_context(a, bb)
            sym, x = rans_symbol(state[lane], ctx, tables, prec, "mask")
            if x < 65536:
                if at[lane] >= ends[lane]:
                    raise CodingError("its mask stream runs past a lane's words")
                x = x * 65536 + words[at[lane]]
                at[lane] += 1
            state[lane] = x
            m |= sym << (4 * t)
        known[(k, b)] = m
        out += struct.pack("<Q", m)
    if at != ends or any(x != 65536 for x in state):
        raise CodingError("its mask stream does not end where its coder does")
    return bytes(out)


def restore(stored, record, xxh3_64, shown=None):
    """A section's bytes from its stored bytes and its coding record; `shown` (scheme 4):
    its tiles' shown voxels (vpak_read.shown_tiles)."""
    scheme, filt, w, s, n, checksum = record
    size = filtered_size(filt, w, n)
    if scheme == SCHEME_SHOWN:
        if shown is None:
            raise CodingError("is context-coded over its shown voxels, which were not given")
        f = context_decode(stored, w, size, shown)
    elif scheme == SCHEME_CONTEXT:
        f = context_decode(stored, w, size)
    elif scheme == SCHEME_MASKS:
        f = masks_decode(stored, size)
    else:
        f = decompress(stored, size)
    section = unfilter(f, filt, w, s, n)
    if xxh3_64(section) != checksum:
        raise CodingError("restored bytes do not match the coding record's checksum")
    return section
