// vpak_atlas_buffer.wgsl: BC4/BC7 brick atlases as storage buffers, decoded in
// the shader (include after vpak.wgsl and bcdec.wgsl).
//
// For GPUs without block-compressed 3D textures. Each buffer holds an atlas
// section exactly as stored in the asset: 4×4 blocks, row by row, slice by
// slice (8 bytes a BC4 block, 16 a BC7 block), so the texel a textureLoad
// would return is decoded from its block alone.

@group(0) @binding(8) var<storage, read> vpak_blocks0: array<u32>;
@group(0) @binding(11) var<storage, read> vpak_blocks1: array<u32>;
@group(0) @binding(12) var<storage, read> vpak_blocks2: array<u32>;
@group(0) @binding(13) var<storage, read> vpak_blocks3: array<u32>;

// Word `i` of atlas `atlas`.
fn vpak_block_word(atlas: u32, i: u32) -> u32 {
    if (!VPAK_MULTI_ATLAS || atlas == 0u) {
        return vpak_blocks0[i];
    }
    switch atlas {
        case 1u: { return vpak_blocks1[i]; }
        case 2u: { return vpak_blocks2[i]; }
        default: { return vpak_blocks3[i]; }
    }
}

// Texel `t` of atlas `atlas`, as textureLoad on the BC texture returns it.
fn vpak_texel(info: VpakInfo, atlas: u32, t: vec3<i32>) -> vec4<f32> {
    let u = vec3<u32>(t);
    // Blocks per row and per slice of this atlas (8×8 texels a brick).
    var size = info.atlas_bricks.xy;
    if (atlas == info.last_atlas.x) {
        size = info.last_atlas.yz;
    }
    let row = size.x * 2u;
    let slice = row * size.y * 2u;
    let block = u.z * slice + (u.y >> 2u) * row + (u.x >> 2u);
    let texel = ((u.y & 3u) << 2u) | (u.x & 3u);
    if (info.format == VPAK_BC7) {
        let w = block * 4u;
        let b = vec4<u32>(vpak_block_word(atlas, w), vpak_block_word(atlas, w + 1u), vpak_block_word(atlas, w + 2u), vpak_block_word(atlas, w + 3u));
        return bc7_texel(b, texel);
    }
    let w = block * 2u;
    return vec4<f32>(bc4_texel(vec2<u32>(vpak_block_word(atlas, w), vpak_block_word(atlas, w + 1u)), texel), 0.0, 0.0, 1.0);
}
