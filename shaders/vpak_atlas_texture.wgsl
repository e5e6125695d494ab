// vpak_atlas_texture.wgsl: atlas planes as 3D textures (include after vpak.wgsl).
//
// f32, f16, unorm16 and unorm8 planes are R/RG/RGBA 32Float, 16Float,
// 16Unorm (wgpu feature TEXTURE_FORMAT_16BIT_NORM) and 8Unorm textures; bc4 planes are Bc4RUnorm and bc7 planes Bc7RgbaUnorm, decoded by
// the texture unit. Slot s is bound at binding 8, 11, 12,
// 13, 15, 16, 17, 18 for s = 0 to 7.

@group(0) @binding(8) var vpak_atlas0: texture_3d<f32>;
@group(0) @binding(11) var vpak_atlas1: texture_3d<f32>;
@group(0) @binding(12) var vpak_atlas2: texture_3d<f32>;
@group(0) @binding(13) var vpak_atlas3: texture_3d<f32>;
@group(0) @binding(15) var vpak_atlas4: texture_3d<f32>;
@group(0) @binding(16) var vpak_atlas5: texture_3d<f32>;
@group(0) @binding(17) var vpak_atlas6: texture_3d<f32>;
@group(0) @binding(18) var vpak_atlas7: texture_3d<f32>;

// Texel `t` of the brick channel `bc`'s texture.
fn vpak_texel(bc: VpakBrickChannel, t: vec3<i32>) -> vec4<f32> {
    if (!VPAK_MULTI_ATLAS || bc.slot == 0u) {
        return textureLoad(vpak_atlas0, t, 0);
    }
    switch bc.slot {
        case 0u: { return textureLoad(vpak_atlas0, t, 0); }
        case 1u: { return textureLoad(vpak_atlas1, t, 0); }
        case 2u: { return textureLoad(vpak_atlas2, t, 0); }
        case 3u: { return textureLoad(vpak_atlas3, t, 0); }
        case 4u: { return textureLoad(vpak_atlas4, t, 0); }
        case 5u: { return textureLoad(vpak_atlas5, t, 0); }
        case 6u: { return textureLoad(vpak_atlas6, t, 0); }
        default: { return textureLoad(vpak_atlas7, t, 0); }
    }
}
