// vpak_atlas_buffer.wgsl: atlas planes as storage buffers, decoded in the
// shader (include after vpak.wgsl and bcdec.wgsl).
//
// For GPUs without block-compressed 3D textures. Each buffer holds an atlas
// plane's section exactly as stored in the asset (docs/format.md): texels
// (or 4×4 blocks) row by row, slice by slice, so the texel a textureLoad
// would return is decoded from the bytes that hold it alone. Slot s
// is bound at 8, 11, 12, 13, 15, 16, 17, 18 for s = 0 to 7.

// In 16-byte units (buffers padded to 16 bytes): a BC7 block is one read.
@group(0) @binding(8) var<storage, read> vpak_words0: array<vec4<u32>>;
@group(0) @binding(11) var<storage, read> vpak_words1: array<vec4<u32>>;
@group(0) @binding(12) var<storage, read> vpak_words2: array<vec4<u32>>;
@group(0) @binding(13) var<storage, read> vpak_words3: array<vec4<u32>>;
@group(0) @binding(15) var<storage, read> vpak_words4: array<vec4<u32>>;
@group(0) @binding(16) var<storage, read> vpak_words5: array<vec4<u32>>;
@group(0) @binding(17) var<storage, read> vpak_words6: array<vec4<u32>>;
@group(0) @binding(18) var<storage, read> vpak_words7: array<vec4<u32>>;

// Words `4q` to `4q + 3` of texture slot `slot`.
fn vpak_quad(slot: u32, q: u32) -> vec4<u32> {
    if (!VPAK_MULTI_ATLAS || slot == 0u) {
        return vpak_words0[q];
    }
    switch slot {
        case 0u: { return vpak_words0[q]; }
        case 1u: { return vpak_words1[q]; }
        case 2u: { return vpak_words2[q]; }
        case 3u: { return vpak_words3[q]; }
        case 4u: { return vpak_words4[q]; }
        case 5u: { return vpak_words5[q]; }
        case 6u: { return vpak_words6[q]; }
        default: { return vpak_words7[q]; }
    }
}

// Word `i` of texture slot `slot`.
fn vpak_word(slot: u32, i: u32) -> u32 {
    if (!VPAK_MULTI_ATLAS || slot == 0u) {
        return vpak_words0[i >> 2u][i & 3u];
    }
    switch slot {
        case 0u: { return vpak_words0[i >> 2u][i & 3u]; }
        case 1u: { return vpak_words1[i >> 2u][i & 3u]; }
        case 2u: { return vpak_words2[i >> 2u][i & 3u]; }
        case 3u: { return vpak_words3[i >> 2u][i & 3u]; }
        case 4u: { return vpak_words4[i >> 2u][i & 3u]; }
        case 5u: { return vpak_words5[i >> 2u][i & 3u]; }
        case 6u: { return vpak_words6[i >> 2u][i & 3u]; }
        default: { return vpak_words7[i >> 2u][i & 3u]; }
    }
}

// Byte `b` of texture slot `slot`.
fn vpak_byte(slot: u32, b: u32) -> u32 {
    return (vpak_word(slot, b >> 2u) >> (8u * (b & 3u))) & 0xffu;
}

// Texel `t` of the brick channel `bc`'s texture, as textureLoad on that
// texture returns it.
fn vpak_texel(bc: VpakBrickChannel, t: vec3<i32>) -> vec4<f32> {
    let u = vec3<u32>(t);
    let slot = bc.slot;
    let format = vpak_format(bc.format);
    let lanes = bc.lanes;
    // The atlas's size in texels along x and y (8 a brick).
    let size = bc.size * 8u;
    if (format == VPAK_BC4 || format == VPAK_BC7) {
        let row = size.x / 4u;
        let block = (u.z * (size.y / 4u) + (u.y >> 2u)) * row + (u.x >> 2u);
        let texel = ((u.y & 3u) << 2u) | (u.x & 3u);
        if (format == VPAK_BC7) {
            return bc7_texel(vpak_quad(slot, block), texel);
        }
        let w = block * 2u;
        return vec4<f32>(bc4_texel(vec2<u32>(vpak_word(slot, w), vpak_word(slot, w + 1u)), texel), 0.0, 0.0, 1.0);
    }
    // Uncompressed: `lanes` values of 4, 2 or 1 bytes each, texels x fastest
    // (VPAK_CONSTANT planes have no texels and are never fetched).
    let index = (u.z * size.y + u.y) * size.x + u.x;
    var out = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    for (var l = 0u; l < lanes; l += 1u) {
        let k = index * lanes + l;
        if (format == VPAK_F32) {
            out[l] = bitcast<f32>(vpak_word(slot, k));
        } else if (format == VPAK_F16) {
            out[l] = unpack2x16float(vpak_word(slot, k >> 1u))[k & 1u];
        } else if (format == VPAK_UNORM16) {
            out[l] = f32((vpak_word(slot, k >> 1u) >> (16u * (k & 1u))) & 0xffffu) / 65535.0;
        } else {
            out[l] = f32(vpak_byte(slot, k)) / 255.0;
        }
    }
    return out;
}
