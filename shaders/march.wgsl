// march.wgsl: the validation ray-marcher (include vpak.wgsl first).
//
// One invocation per pixel. A camera ray is marched through the asset's
// bounding box in fixed steps; every sample lies on the same lattice
// (t0 + (k + 1/2)·step), so skipping empty space never changes which samples
// are taken: an empty L1 or L2 slot (hierarchical DDA over the masks) moves
// the ray to the first lattice point past that slot. Shading is
// emission-absorption fog lit by ambient light and one directional light.
// Light reaching a point comes from a shadow grid computed once per frame
// (`shadow_main`: one shadow ray from the centre of each cell, marching and
// skipping the same way) and read with trilinear interpolation, so all views
// of a frame share it. Fire glows: a temperature and a flames channel (when
// the asset has them) add emission along the ray, temperature through a
// blackbody-like ramp (black, red, orange, yellow, white as it rises) and
// flames in a fixed orange, each normalised by its channel's largest value
// (temperature weighted by its square, so only hot gas glows brightly). Smoke
// (a density channel) scatters light; without one, flames or temperature give
// extinction but do not scatter: fire absorbs and glows.
// The image is RGB. No randomness: the image depends only on the data, so
// two assets can be compared exactly.

struct Params {
    info: VpakInfo,
    eye: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    forward: vec4<f32>,     // w: tan(fov / 2)
    box_min: vec4<f32>,     // w: step (voxels)
    box_max: vec4<f32>,     // w: shadow step (voxels)
    light: vec4<f32>,       // xyz: direction towards the light, w: density scale
    size: vec4<u32>,        // width, height, max steps, skip empty space (0/1)
    shadow: vec4<f32>,      // shadow grid cells along x, y, z (as floats), cell edge in voxels
    channels: vec4<u32>,    // x: the channel that gives extinction; y, z: temperature, flames (or VPAK_NONE)
    emission: vec4<f32>,    // x, y: 1 / largest temperature, flames; z: emission per voxel at full scale; w: albedo
}

@group(0) @binding(0) var<uniform> params: Params;
// True when the scene has emission channels (params.channels.y or .z): the
// emission code folds away at pipeline creation otherwise.
override GLOWS: bool = true;
// The texture slots of the shown channels (params.channels x, y, z) when
// their plane has a single atlas, else VPAK_NONE: a known slot folds the
// texture selection away at pipeline creation (a switch per fetch costs on
// a CPU driver).
override SLOT_X: u32 = 0xffffffffu;
override SLOT_Y: u32 = 0xffffffffu;
override SLOT_Z: u32 = 0xffffffffu;
// RGB per pixel, row-major from the top.
@group(0) @binding(9) var<storage, read_write> image: array<f32>;
// Optical depth towards the light at each shadow cell centre, x fastest.
@group(0) @binding(10) var<storage, read_write> shadow: array<f32>;

@compute @workgroup_size(64, 1, 1)
fn shadow_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = vec3<u32>(params.shadow.xyz);
    let n = g.x * g.y * g.z;
    let i = gid.x;
    if (i >= n) { return; }
    let c = vec3<u32>(i % g.x, (i / g.x) % g.y, i / (g.x * g.y));
    let p = params.box_min.xyz + (vec3<f32>(c) + vec3<f32>(0.5)) * params.shadow.w;
    shadow[i] = shadow_depth(p);
}

// Trilinear read of the shadow grid at `p` (clamped to the cell centres).
fn shadow_at(p: vec3<f32>) -> f32 {
    let g = vec3<i32>(params.shadow.xyz);
    let f = clamp((p - params.box_min.xyz) / params.shadow.w - vec3<f32>(0.5), vec3<f32>(0.0), vec3<f32>(g - vec3<i32>(1)));
    let i0 = vec3<i32>(floor(f));
    let i1 = min(i0 + vec3<i32>(1), g - vec3<i32>(1));
    let w = f - vec3<f32>(i0);
    var acc = 0.0;
    for (var k = 0; k < 8; k += 1) {
        let sel = vec3<bool>((k & 1) != 0, (k & 2) != 0, (k & 4) != 0);
        let c = select(i0, i1, sel);
        let wk = select(vec3<f32>(1.0) - w, w, sel);
        acc += shadow[u32((c.z * g.y + c.y) * g.x + c.x)] * wk.x * wk.y * wk.z;
    }
    return acc;
}

fn box_hit(o: vec3<f32>, d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
    let inv = 1.0 / d;
    let a = (lo - o) * inv;
    let b = (hi - o) * inv;
    let tmin = min(a, b);
    let tmax = max(a, b);
    return vec2<f32>(max(max(tmin.x, tmin.y), max(tmin.z, 0.0)), min(min(tmax.x, tmax.y), tmax.z));
}

// Distance along the ray to the exit of the `dim`-sized cell containing `p`.
fn cell_exit(p: vec3<f32>, d: vec3<f32>, dim: f32) -> f32 {
    let lo = floor(p / dim) * dim;
    let hi = lo + vec3<f32>(dim);
    let inv = 1.0 / d;
    let t = max((lo - p) * inv, (hi - p) * inv);
    return min(min(t.x, t.y), t.z);
}

// Optical depth from `o` towards the light. Steps grow by 1.25 each sample
// (about 20 samples cross 256 voxels): shadows are smooth, and both assets
// are rendered with the same march, so the approximation cancels out.
fn shadow_depth(o: vec3<f32>) -> f32 {
    let d = params.light.xyz;
    let hit = box_hit(o, d, params.box_min.xyz, params.box_max.xyz);
    var step = params.box_max.w;
    var t = 0.5 * step;
    var depth = 0.0;
    var n = 0u;
    loop {
        // Past an optical depth of 8 the light is gone (transmittance < 0.04 %).
        if (t >= hit.y || n >= params.size.z || depth > 8.0) { break; }
        n += 1u;
        let p = o + d * t;
        let q = vpak_query(params.info, vec3<i32>(floor(p)), params.channels.x);
        if (q.empty_dim > 0u && params.size.w == 1u) {
            t += cell_exit(p, d, f32(q.empty_dim)) + 0.5 * step;
            continue;
        }
        depth += max(q.value, 0.0) * params.light.w * step;
        t += step;
        step *= 1.25;
    }
    return depth;
}

// Blackbody-like colour of a normalised temperature t in [0, 1]: red first,
// then green, then blue rise, so hot cores turn yellow and white.
fn fire_ramp(t: f32) -> vec3<f32> {
    return clamp(vec3<f32>(3.0 * t, 3.0 * t - 1.0, 3.0 * t - 2.0), vec3<f32>(0.0), vec3<f32>(1.0));
}

// `bc` in texture slot `slot` when that is known (not VPAK_NONE).
fn in_slot(bc: VpakBrickChannel, slot: u32) -> VpakBrickChannel {
    var b = bc;
    if (slot != VPAK_NONE) {
        b.slot = slot;
    }
    return b;
}

// Channel `c` (whose brick channel in the cell is `bc`, background `bg`) at
// voxel `ip` of the cell `leaf` describes, `on` saying whether the voxel is active.
fn cell_value(leaf: VpakLeaf, bc: VpakBrickChannel, on: bool, ip: vec3<i32>, c: u32, bg: f32) -> f32 {
    if (!on) {
        return bg;
    }
    if (leaf.tile != VPAK_NONE) {
        return vpak_active_value(params.info, leaf, ip, c);
    }
    return vpak_brick_channel_value(bc, vec3<u32>(ip) & vec3<u32>(7u));
}

// Light emitted per voxel of path by a temperature `t` and a flames value `f`
// (either absent when its channel is VPAK_NONE).
fn emission(t_raw: f32, f_raw: f32) -> vec3<f32> {
    var e = vec3<f32>(0.0);
    if (params.channels.y != VPAK_NONE) {
        let t = clamp(t_raw * params.emission.x, 0.0, 1.0);
        e += fire_ramp(t) * t * t;
    }
    if (params.channels.z != VPAK_NONE) {
        let f = clamp(f_raw * params.emission.y, 0.0, 1.0);
        e += vec3<f32>(1.0, 0.55, 0.15) * f;
    }
    return e * params.emission.z;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = params.size.x;
    let h = params.size.y;
    if (gid.x >= w || gid.y >= h) { return; }
    let px = (f32(gid.x) + 0.5) / f32(w) * 2.0 - 1.0;
    let py = 1.0 - (f32(gid.y) + 0.5) / f32(h) * 2.0;
    let aspect = f32(w) / f32(h);
    let tf = params.forward.w;
    let d = normalize(params.forward.xyz + params.right.xyz * (px * tf * aspect) + params.up.xyz * (py * tf));
    let o = params.eye.xyz;
    let hit = box_hit(o, d, params.box_min.xyz, params.box_max.xyz);
    var radiance = vec3<f32>(0.0);
    if (hit.x < hit.y) {
        let step = params.box_min.w;
        var trans = 1.0;
        var k = 0.5;
        var n = 0u;
        var cell = vec3<i32>(-1 << 30);
        var leaf: VpakLeaf;

        // The shown channels of the cell's brick, resolved once per cell.
        var ext: VpakBrickChannel;
        var temp: VpakBrickChannel;
        var flames: VpakBrickChannel;
        let bg = vec3<f32>(vpak_background(params.channels.x), vpak_background(params.channels.y), vpak_background(params.channels.z));
        loop {
            let t = hit.x + k * step;
            if (t >= hit.y || n >= params.size.z || trans < 1e-3) { break; }
            n += 1u;
            let p = o + d * t;
            // The voxel of the level drawn (params.info.level) that holds the sample.
            let ip = vpak_level_point(params.info, vec3<i32>(floor(p)));
            // The L1/L2 walk is done once per 8³ cell the ray enters.
            if (any((ip >> vec3<u32>(3u)) != cell)) {
                cell = ip >> vec3<u32>(3u);
                leaf = vpak_leaf(params.info, ip);
                if (leaf.l3 != VPAK_NONE) {
                    ext = vpak_brick_channel(params.info, leaf.brick, params.channels.x);
                    if (GLOWS && params.channels.y != VPAK_NONE) {
                        temp = vpak_brick_channel(params.info, leaf.brick, params.channels.y);
                    }
                    if (GLOWS && params.channels.z != VPAK_NONE) {
                        flames = vpak_brick_channel(params.info, leaf.brick, params.channels.z);
                    }
                }
            }
            if (leaf.empty_dim > 0u && params.size.w == 1u) {
                let exit = t + cell_exit(p, d, f32(leaf.empty_dim << params.info.level));
                k = max(k + 1.0, ceil((exit - hit.x) / step - 0.5) + 0.5);
                continue;
            }
            let on = vpak_leaf_active(leaf, ip);
            if (GLOWS) {
                var t = 0.0;
                var f = 0.0;
                if (params.channels.y != VPAK_NONE) {
                    t = cell_value(leaf, in_slot(temp, SLOT_Y), on, ip, params.channels.y, bg.y);
                }
                if (params.channels.z != VPAK_NONE) {
                    f = cell_value(leaf, in_slot(flames, SLOT_Z), on, ip, params.channels.z, bg.z);
                }
                radiance += trans * emission(t, f) * step;
            }
            let e = cell_value(leaf, in_slot(ext, SLOT_X), on, ip, params.channels.x, bg.x);
            let sigma = max(e, 0.0) * params.light.w;
            if (sigma > 0.0) {
                let a = 1.0 - exp(-sigma * step);
                let lit = 0.25 + 0.75 * exp(-shadow_at(p));
                radiance += vec3<f32>(trans * a * lit * params.emission.w);
                trans *= 1.0 - a;
            }
            k += 1.0;
        }
    }
    let pixel = 3u * (gid.y * w + gid.x);
    image[pixel] = radiance.x;
    image[pixel + 1u] = radiance.y;
    image[pixel + 2u] = radiance.z;
}
