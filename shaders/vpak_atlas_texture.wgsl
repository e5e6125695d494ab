// vpak_atlas_texture.wgsl: brick atlases as 3D textures (include after vpak.wgsl).
//
// Formats f32, f16 and unorm8 are R32Float, R16Float and R8Unorm textures;
// bc4 is Bc4RUnorm and bc7 is Bc7RgbaUnorm (four z-slices of a brick in RGBA),
// decoded by the texture unit.

@group(0) @binding(8) var vpak_atlas0: texture_3d<f32>;
@group(0) @binding(11) var vpak_atlas1: texture_3d<f32>;
@group(0) @binding(12) var vpak_atlas2: texture_3d<f32>;
@group(0) @binding(13) var vpak_atlas3: texture_3d<f32>;

// Texel `t` of atlas `atlas`.
fn vpak_texel(info: VpakInfo, atlas: u32, t: vec3<i32>) -> vec4<f32> {
    if (!VPAK_MULTI_ATLAS || atlas == 0u) {
        return textureLoad(vpak_atlas0, t, 0);
    }
    switch atlas {
        case 1u: { return textureLoad(vpak_atlas1, t, 0); }
        case 2u: { return textureLoad(vpak_atlas2, t, 0); }
        default: { return textureLoad(vpak_atlas3, t, 0); }
    }
}
