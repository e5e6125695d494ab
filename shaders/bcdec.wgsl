// Block decoders for BC4 (unorm) and BC7, for GPUs that cannot sample
// block-compressed textures: the caller fetches a block's raw bytes (as
// little-endian u32 words, word 0 = bytes 0..3) and asks for one texel,
// numbered y * 4 + x inside the 4×4 block. Only that texel is decoded.
//
// BC7 results are bit-exact with bcdec_rs (8-bit values / 255); BC4 results
// equal its float decoder up to float rounding. A library: no bindings and
// no entry points; every helper and table is prefixed `bcdec_`.

// `count` (< 32) bits of the 128-bit block, starting at bit `start` (bit 0 is
// the lowest bit of word 0). A field may straddle two words.
fn bcdec_bits(block: vec4<u32>, start: u32, count: u32) -> u32 {
    let word = start >> 5u;
    let shift = start & 31u;
    var v = block[word] >> shift;
    if shift + count > 32u {
        v |= block[word + 1u] << (32u - shift);
    }
    return v & ((1u << count) - 1u);
}

// ---------------------------------------------------------------------------
// BC4: 8 bytes. Byte 0 and byte 1 are the endpoints e0 and e1; bits 16..63
// hold one 3-bit palette index per texel, texel 0 first. Palette entries 0
// and 1 are the endpoints. If e0 > e1, entries 2..7 step from e0 to e1 in
// sevenths; otherwise entries 2..5 step in fifths, 6 is 0.0 and 7 is 1.0.

// Value of texel `texel` of a BC4 (unorm) block, in [0, 1].
fn bc4_texel(block: vec2<u32>, texel: u32) -> f32 {
    let e0 = block.x & 0xffu;
    let e1 = (block.x >> 8u) & 0xffu;
    let i = bcdec_bits(vec4<u32>(block, 0u, 0u), 16u + 3u * texel, 3u);
    let a = f32(e0) / 255.0;
    let b = f32(e1) / 255.0;
    if i == 0u {
        return a;
    }
    if i == 1u {
        return b;
    }
    if e0 > e1 {
        return (f32(8u - i) * a + f32(i - 1u) * b) / 7.0;
    }
    if i >= 6u {
        return f32(i - 6u);
    }
    return (f32(6u - i) * a + f32(i - 1u) * b) / 5.0;
}

// ---------------------------------------------------------------------------
// BC7: a 128-bit stream read from bit 0 upwards, fields in this order:
//
//   mode       m zero bits, then a one bit (mode m = 0..7). A block whose
//              first byte is zero has no mode and decodes to (0, 0, 0, 0).
//   partition  which shape splits the texels into 2 or 3 subsets.
//   rotation   modes 4, 5: 2 bits; 1, 2, 3 swap alpha with R, G, B at the end.
//   selector   mode 4: 1 bit; if set, the 3-bit index set drives colour and
//              the 2-bit set drives alpha (the other way round if clear).
//   endpoints  two per subset; the R values of all endpoints, then G, then B,
//              then A (modes with alpha only).
//   p-bits     a shared extra low bit: one per endpoint (modes 0, 3, 6, 7) or
//              one per subset (mode 1, RGB only).
//   indices    one per texel, texel order. Each subset's anchor texel (texel 0
//              for subset 0, table entries for the others) stores its index
//              with one bit less: that top bit is known to be 0.
//   indices 2  modes 4 and 5: a second index set; texel 0 is its anchor.
//
// Endpoints are widened to 8 bits by appending the p-bit and then repeating
// their top bits; a texel interpolates its subset's two endpoints with weight
// round(64 · index / (2^bits − 1)).

// Per-mode parameters, one hex digit per mode: the digit `mode` places from
// the right (so mode 0 is the last digit, mode 7 the first).
//                                         mode: 76543210
const BCDEC_SUBSETS: u32        = 0x21112323u; // subsets
const BCDEC_PARTITION_BITS: u32 = 0x60006664u; // partition field width
const BCDEC_COLOR_BITS: u32     = 0x57757564u; // bits per R, G or B endpoint value
const BCDEC_ALPHA_BITS: u32     = 0x57860000u; // bits per A endpoint value (0: opaque)
const BCDEC_PBITS: u32          = 0x11001021u; // p-bits: 0 none, 1 per endpoint, 2 per subset
const BCDEC_INDEX_BITS: u32     = 0x24222233u; // bits per index
const BCDEC_INDEX2_BITS: u32    = 0x00230000u; // bits per second-set index (0: none)

fn bcdec_digit(table: u32, mode: u32) -> u32 {
    return (table >> (4u * mode)) & 15u;
}

// The partition tables of the BC7 (BPTC) specification.
// Two subsets: bit t (0..15) is texel t's subset; bits 16..19 hold the anchor
// texel of subset 1.
var<private> bcdec_partition2: array<u32, 64> = array<u32, 64>(
    0x000fccccu, 0x000f8888u, 0x000feeeeu, 0x000fecc8u, 0x000fc880u, 0x000ffeecu, 0x000ffec8u, 0x000fec80u,
    0x000fc800u, 0x000fffecu, 0x000ffe80u, 0x000fe800u, 0x000fffe8u, 0x000fff00u, 0x000ffff0u, 0x000ff000u,
    0x000ff710u, 0x0002008eu, 0x00087100u, 0x000208ceu, 0x0002008cu, 0x00087310u, 0x00083100u, 0x000f8cceu,
    0x0002088cu, 0x00083110u, 0x00026666u, 0x0002366cu, 0x000817e8u, 0x00080ff0u, 0x0002718eu, 0x0002399cu,
    0x000faaaau, 0x000ff0f0u, 0x00065a5au, 0x000833ccu, 0x00023c3cu, 0x000855aau, 0x000f9696u, 0x000fa55au,
    0x000273ceu, 0x000813c8u, 0x0002324cu, 0x00023bdcu, 0x00026996u, 0x000fc33cu, 0x000f9966u, 0x00060660u,
    0x00060272u, 0x000204e4u, 0x00064e40u, 0x00082720u, 0x000fc936u, 0x000f936cu, 0x000239c6u, 0x0002639cu,
    0x000f9336u, 0x000f9cc6u, 0x000f817eu, 0x000fe718u, 0x000fccf0u, 0x00020fccu, 0x00027744u, 0x000fee22u,
);
// Three subsets: bits 2t..2t+1 are texel t's subset.
var<private> bcdec_partition3: array<u32, 64> = array<u32, 64>(
    0xaa685050u, 0x6a5a5040u, 0x5a5a4200u, 0x5450a0a8u, 0xa5a50000u, 0xa0a05050u, 0x5555a0a0u, 0x5a5a5050u,
    0xaa550000u, 0xaa555500u, 0xaaaa5500u, 0x90909090u, 0x94949494u, 0xa4a4a4a4u, 0xa9a59450u, 0x2a0a4250u,
    0xa5945040u, 0x0a425054u, 0xa5a5a500u, 0x55a0a0a0u, 0xa8a85454u, 0x6a6a4040u, 0xa4a45000u, 0x1a1a0500u,
    0x0050a4a4u, 0xaaa59090u, 0x14696914u, 0x69691400u, 0xa08585a0u, 0xaa821414u, 0x50a4a450u, 0x6a5a0200u,
    0xa9a58000u, 0x5090a0a8u, 0xa8a09050u, 0x24242424u, 0x00aa5500u, 0x24924924u, 0x24499224u, 0x50a50a50u,
    0x500aa550u, 0xaaaa4444u, 0x66660000u, 0xa5a0a5a0u, 0x50a050a0u, 0x69286928u, 0x44aaaa44u, 0x66666600u,
    0xaa444444u, 0x54a854a8u, 0x95809580u, 0x96969600u, 0xa85454a8u, 0x80959580u, 0xaa141414u, 0x96960000u,
    0xaaaa1414u, 0xa05050a0u, 0xa0a5a5a0u, 0x96000000u, 0x40804080u, 0xa9a8a9a8u, 0xaaaaaa44u, 0x2a4a5254u,
);
// Anchor texels of subsets 1 and 2 for three subsets: byte k of word j
// describes partition 4j + k, subset 1 in the low digit, subset 2 in the high.
var<private> bcdec_anchor3: array<u32, 16> = array<u32, 16>(
    0x3f8f83f3u, 0x8f3ff3f8u, 0xf6f6f8f8u, 0x83f3f5f6u, 0x3ff883f3u, 0x8af683f3u, 0xa668f835u, 0x8faff5f8u,
    0xa5f33ff8u, 0xaf988aa6u, 0xf58ff36fu, 0x8f6f6f3fu, 0xf5f53ff3u, 0xfaf5f8f5u, 0xfdf8faf5u, 0x83f3fc3fu,
);

// Endpoint value `v` of `n` bits (p-bit included) widened to 8 bits.
fn bcdec_widen(v: u32, n: u32) -> u32 {
    let x = v << (8u - n);
    return x | (x >> n);
}

// Interpolation weight (out of 64) of an index of `n` bits.
fn bcdec_weight(index: u32, n: u32) -> u32 {
    let d = (1u << n) - 1u;
    return (128u * index + d) / (2u * d);
}

// RGBA of texel `texel` of a BC7 block; each channel is an 8-bit value / 255.
fn bc7_texel(block: vec4<u32>, texel: u32) -> vec4<f32> {
    let mode = countTrailingZeros(block.x | 0x100u);
    if mode > 7u {
        return vec4<f32>(0.0);
    }
    var pos = mode + 1u;

    // Partition: this texel's subset and the anchor texels of subsets 1 and 2
    // (16 where there is no such subset).
    let subsets = bcdec_digit(BCDEC_SUBSETS, mode);
    let partition_bits = bcdec_digit(BCDEC_PARTITION_BITS, mode);
    let shape = bcdec_bits(block, pos, partition_bits);
    pos += partition_bits;
    var subset = 0u;
    var anchor1 = 16u;
    var anchor2 = 16u;
    if subsets == 2u {
        let p = bcdec_partition2[shape];
        subset = (p >> texel) & 1u;
        anchor1 = p >> 16u;
    } else if subsets == 3u {
        subset = (bcdec_partition3[shape] >> (2u * texel)) & 3u;
        let a = bcdec_anchor3[shape >> 2u] >> (8u * (shape & 3u));
        anchor1 = a & 15u;
        anchor2 = (a >> 4u) & 15u;
    }

    var rotation = 0u;
    var selector = 0u;
    if mode == 4u || mode == 5u {
        rotation = bcdec_bits(block, pos, 2u);
        pos += 2u;
        if mode == 4u {
            selector = bcdec_bits(block, pos, 1u);
            pos += 1u;
        }
    }

    // The texel's endpoints are numbers 2·subset and 2·subset + 1 of `ends`.
    let color_bits = bcdec_digit(BCDEC_COLOR_BITS, mode);
    let alpha_bits = bcdec_digit(BCDEC_ALPHA_BITS, mode);
    let ends = 2u * subsets;
    let e = 2u * subset;
    let pbit_pos = pos + ends * (3u * color_bits + alpha_bits);
    let pbit_kind = bcdec_digit(BCDEC_PBITS, mode);
    var p = vec2<u32>(0u);
    var pbit_count = 0u;
    if pbit_kind == 1u {
        p = vec2<u32>(bcdec_bits(block, pbit_pos + e, 1u), bcdec_bits(block, pbit_pos + e + 1u, 1u));
        pbit_count = ends;
    } else if pbit_kind == 2u {
        p = vec2<u32>(bcdec_bits(block, pbit_pos + subset, 1u));
        pbit_count = subsets;
    }
    let has_p = min(pbit_kind, 1u);

    var lo = vec4<u32>(255u);
    var hi = vec4<u32>(255u);
    let n = color_bits + has_p;
    for (var c = 0u; c < 3u; c++) {
        let at = pos + (c * ends + e) * color_bits;
        lo[c] = bcdec_widen((bcdec_bits(block, at, color_bits) << has_p) | p.x, n);
        hi[c] = bcdec_widen((bcdec_bits(block, at + color_bits, color_bits) << has_p) | p.y, n);
    }
    if alpha_bits > 0u {
        let at = pos + 3u * ends * color_bits + e * alpha_bits;
        let na = alpha_bits + has_p;
        lo.w = bcdec_widen((bcdec_bits(block, at, alpha_bits) << has_p) | p.x, na);
        hi.w = bcdec_widen((bcdec_bits(block, at + alpha_bits, alpha_bits) << has_p) | p.y, na);
    }

    // Index of this texel: every anchor before it is one bit short, and an
    // anchor texel itself is one bit short.
    let index_pos = pbit_pos + pbit_count;
    let index_bits = bcdec_digit(BCDEC_INDEX_BITS, mode);
    let skipped = min(texel, 1u) + u32(anchor1 < texel) + u32(anchor2 < texel);
    let anchor = texel == 0u || texel == anchor1 || texel == anchor2;
    let index = bcdec_bits(block, index_pos + texel * index_bits - skipped, index_bits - u32(anchor));
    var w_color = bcdec_weight(index, index_bits);
    var w_alpha = w_color;

    let index2_bits = bcdec_digit(BCDEC_INDEX2_BITS, mode);
    if index2_bits > 0u {
        // Single subset: the first set has exactly one short anchor index.
        let index2_pos = index_pos + 16u * index_bits - 1u;
        let at = index2_pos + texel * index2_bits - min(texel, 1u);
        let w2 = bcdec_weight(bcdec_bits(block, at, index2_bits - u32(texel == 0u)), index2_bits);
        if selector == 0u {
            w_alpha = w2;
        } else {
            w_color = w2;
        }
    }

    let w = vec4<u32>(vec3<u32>(w_color), w_alpha);
    var rgba = (lo * (64u - w) + hi * w + 32u) >> vec4<u32>(6u);
    switch rotation {
        case 1u: { rgba = rgba.wyzx; }
        case 2u: { rgba = rgba.xwzy; }
        case 3u: { rgba = rgba.xywz; }
        default: {}
    }
    return vec4<f32>(rgba) / 255.0;
}
