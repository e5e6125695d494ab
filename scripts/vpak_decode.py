"""Pure decoders of docs/format.md's encodings, for scripts/vpak_read.py: L1 node
sizes, occupancy masks with their prefix counts, slot positions, L3 sub-masks ("Nodes"),
BC4 and BC7 blocks and the size of an atlas texture ("Bricks, planes and atlases").

Written from docs/format.md alone, like the reader. Dependencies (Debian): python3-numpy,
python3-pil (BC7 blocks).
"""

import numpy as np

from vpak_metadata import VpakError

L2_WORDS, L3_WORDS = 193, 3
L2_MASK_WORDS = 128


def l1_node_len(L):
    """Words of an L1 node of 2^L slots per axis: L, mask, prefix counts, first entry."""
    mask_words = (1 << (3 * L)) // 32
    return 1 + mask_words + mask_words // 2 + 1


def l1_starts(l1):
    """The word each L1 node starts at (they differ in size); raises unless the array is whole nodes."""
    starts, at = [], 0
    while at < len(l1):
        L = int(l1[at])
        if not 2 <= L <= 5:
            raise VpakError(f"L1 node at word {at} has L = {L} (need 2 to 5)")
        starts.append(at)
        at += l1_node_len(L)
    if at != len(l1):
        raise VpakError("L1 nodes are not whole")
    return starts

F32, F16, UNORM8, BC4, BC7, UNORM16, CONSTANT = range(7)
FORMAT_NAMES = ["f32", "f16", "unorm8", "bc4", "bc7", "unorm16", "constant"]
RANGED = (UNORM8, BC4, BC7, UNORM16)
# Allowed (lanes, zpt) per format (format.md, planes table).
FORMAT_RULES = {
    F32: ({1, 2, 4}, {1}),
    F16: ({1, 2, 4}, {1}),
    UNORM8: ({1, 2, 4}, {1}),
    BC4: ({1}, {1}),
    BC7: ({4}, {1, 2, 4}),
    UNORM16: ({1, 2, 4}, {1}),
    CONSTANT: ({1}, {1}),
}


def occupied_slots(node, mask_words):
    """Set bits s of the occupancy mask, with their ranks (entry offsets from `first`).

    The stored prefix counts are what a GPU reader uses for constant-time lookup; here
    every one is checked against the mask so a reader that trusts them reads the same.
    """
    mask = np.asarray(node[:mask_words], dtype=np.uint32)
    bits = np.unpackbits(mask.view(np.uint8), bitorder="little")
    slots = np.nonzero(bits)[0]
    k = np.arange(mask_words)
    words = np.asarray(node[mask_words + k // 2], dtype=np.uint32)
    stored = (words >> (16 * (k % 2)).astype(np.uint32)) & 0xFFFF
    counted = np.concatenate([[0], np.cumsum(bits.reshape(mask_words, 32).sum(axis=1))[:-1]])
    if not np.array_equal(stored, counted):
        raise VpakError("node prefix counts disagree with its occupancy mask")
    # With the prefixes verified, the document's entry offset
    # prefix(s / 32) + popcount(mask[s / 32] & ((1 << s % 32) - 1)) is the bit's rank.
    return slots, np.arange(len(slots))


def slot_entries(node, mask_words, entries, what):
    slots, ranks = occupied_slots(node, mask_words)
    first = int(node[-1])
    idx = first + ranks
    if len(idx) and idx[-1] >= len(entries):
        raise VpakError(f"{what} entry index out of range")
    return slots, entries[idx]


def slot_origin(slots, L, shift):
    """Slot s = (x << 2L) | (y << L) | z; its origin is (x, y, z) << shift voxels."""
    m = (1 << L) - 1
    return np.stack([(slots >> (2 * L)) & m, (slots >> L) & m, slots & m], axis=1).astype(np.int64) << shift


def l3_active(l3, node_index):
    """Active-voxel mask (512 bools, leaf order) of L3 node k, from states and sub-masks."""
    base = 1 + L3_WORDS * node_index
    states, first = int(l3[base + 1]), int(l3[base + 2])
    active = np.zeros(512, dtype=bool)
    x, y, z = np.meshgrid(np.arange(8), np.arange(8), np.arange(8), indexing="ij")
    x, y, z = x.ravel(), y.ravel(), z.ravel()  # leaf order x*64 + y*8 + z
    sub = (x // 4) * 4 + (y // 4) * 2 + z // 4
    j = (x % 4) * 16 + (y % 4) * 4 + z % 4
    r = 0
    for b in range(8):
        st = (states >> (2 * b)) & 3
        sel = sub == b
        if st == 1:
            active[sel] = True
        elif st == 2:
            w0 = first + 2 * r
            if w0 + 2 > len(l3):
                raise VpakError("L3 sub-mask out of range")
            bits = np.unpackbits(np.asarray(l3[w0:w0 + 2], dtype="<u4").view(np.uint8), bitorder="little")
            active[sel] = bits[j[sel]].astype(bool)  # bit j%32 of word first+2r+j/32
            r += 1
        elif st == 3:
            raise VpakError("L3 node has an invalid sub-block state")
    return active


def decode_bc4(data, W, H, D):
    """BC4 UNORM blocks to float32 levels in [0, 1], with the palette in float.

    format.md: palette entries are the endpoints and their exact weighted means. The
    document does not fix the float arithmetic; this order (endpoints e/255 in f32, then
    ((7-k)*f0 + k*f1) / 7 in f32) was found by experiment to match `vdbcook unpack`
    bit for bit; other orders differ by 1 ulp.
    """
    blocks = np.frombuffer(data, dtype=np.uint8).reshape(-1, 8)
    f0 = (blocks[:, 0] / 255.0).astype(np.float32)
    f1 = (blocks[:, 1] / 255.0).astype(np.float32)
    eight = blocks[:, 0] > blocks[:, 1]  # e0 > e1: 8-level mode, else 6 levels + 0 and 1
    pal = np.zeros((len(blocks), 8), dtype=np.float32)
    pal[:, 0], pal[:, 1] = f0, f1
    for k in range(1, 7):
        mean = (np.float32(7 - k) * f0 + np.float32(k) * f1) / np.float32(7)
        pal[:, 1 + k] = np.where(eight, mean, pal[:, 1 + k])
    for k in range(1, 5):
        mean = (np.float32(5 - k) * f0 + np.float32(k) * f1) / np.float32(5)
        pal[:, 1 + k] = np.where(eight, pal[:, 1 + k], mean)
    pal[:, 6] = np.where(eight, pal[:, 6], 0.0)
    pal[:, 7] = np.where(eight, pal[:, 7], 1.0)
    # 48 index bits after the endpoints, 3 bits per texel k = (Y%4)*4 + X%4 from bit 0.
    bits = np.zeros(len(blocks), dtype=np.uint64)
    for i in range(6):
        bits |= blocks[:, 2 + i].astype(np.uint64) << np.uint64(8 * i)
    shifts = np.arange(16, dtype=np.uint64) * np.uint64(3)
    idx = ((bits[:, None] >> shifts[None, :]) & np.uint64(7)).astype(np.int64)
    texels = np.take_along_axis(pal, idx, axis=1)
    return blocks_to_texture(texels[:, :, None], W, H, D)


def decode_bc7(data, W, H, D):
    """BC7 UNORM to 8-bit RGBA lanes / 255 (Pillow's BCn decoder, slice by slice)."""
    try:
        from PIL import Image  # Debian python3-pil
    except ImportError:
        raise VpakError("cannot decode BC7: install python3-pil") from None
    # Slices are stored one after another, blocks row-major: the same bytes form one
    # W x (H*D) image, so one Pillow call decodes every slice.
    img = Image.frombytes("RGBA", (W, H * D), bytes(data), "bcn", 7)
    return np.asarray(img, dtype=np.uint8).reshape(D, H, W, 4).astype(np.float32) / np.float32(255)


def blocks_to_texture(texels, W, H, D):
    """(blocks, 16, lanes) in storage order -> (D, H, W, lanes) texel array."""
    lanes = texels.shape[-1]
    t = texels.reshape(D, H // 4, W // 4, 4, 4, lanes)  # k = row*4 + col
    return t.transpose(0, 1, 3, 2, 4, 5).reshape(D, H, W, lanes)


def texture_shape(pl, a):
    """(W, H, D) texels of atlas a of plane `pl`, and its bytes (format.md, "Validation")."""
    bx, by, bz = pl["atlases"][a]["bricks"]
    W, H, D = 8 * bx, 8 * by, (8 // pl["z_per_texel"]) * bz
    if pl["format"] in (BC4, BC7):
        return W, H, D, (W // 4) * (H // 4) * D * (8 if pl["format"] == BC4 else 16)
    return W, H, D, W * H * D * pl["lanes"] * {F32: 4, F16: 2, UNORM8: 1, UNORM16: 2}[pl["format"]]
