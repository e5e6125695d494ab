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
// (temperature weighted by its square, so only hot gas glows brightly).
// What the channel params.channels.x holds decides the model
// (params.channels.w; the Rust side chooses it, see `Scene::model`):
// - scatter (0): a fog, whatever its name, absorbs and scatters (albedo 1)
//   against black;
// - glow (1): no fog, so flames or temperature give extinction but do not
//   scatter (fire absorbs and glows), in front of a neutral backdrop
//   (`backdrop`, a function of the ray direction) that the absorption darkens;
// - surface (2): a level set, drawn as an opaque lit surface at its first
//   zero crossing along the ray (`surface`) against black.
// Non-finite voxels (NaN, ±inf) count as empty: no extinction, no emission,
// no surface. The surface model has its own entry point (`surface_main`;
// one entry point, with every function inlined into it, would make the
// driver compile the surface code for every fog, only to remove it), and
// the override constant BACKDROP folds the backdrop away, so a plain fog's
// march is what it was before they existed.
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
    channels: vec4<u32>,    // x: the channel that gives extinction (the level set of a surface); y, z: temperature, flames (or VPAK_NONE); w: model
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
// The glow model's backdrop behind the volume.
override BACKDROP: bool = false;
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
        depth += finite_positive(q.value) * params.light.w * step;
        t += step;
        step *= 1.25;
    }
    return depth;
}

// Whether `v` is finite (by its exponent bits: compilers may assume that
// floating-point comparisons never see NaN or infinity).
fn is_finite(v: f32) -> bool {
    return (bitcast<u32>(v) & 0x7f800000u) != 0x7f800000u;
}

// `v` when it is positive and finite, else 0.
fn finite_positive(v: f32) -> f32 {
    return select(0.0, v, v > 0.0 && is_finite(v));
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
        let t = clamp(finite_positive(t_raw) * params.emission.x, 0.0, 1.0);
        e += fire_ramp(t) * t * t;
    }
    if (params.channels.z != VPAK_NONE) {
        let f = clamp(finite_positive(f_raw) * params.emission.y, 0.0, 1.0);
        e += vec3<f32>(1.0, 0.55, 0.15) * f;
    }
    return e * params.emission.z;
}

// The backdrop of the glow model along the ray direction `d`: a neutral
// grey, lighter upwards, with a soft checker (smooth, so rounding never
// flips a cell between the GPU and the CPU twin).
fn backdrop(d: vec3<f32>) -> vec3<f32> {
    let base = 0.2 + 0.1 * d.y;
    let checker = sin(10.0 * d.x) * sin(10.0 * d.y) * sin(10.0 * d.z);
    return vec3<f32>(base * (1.0 + 0.5 * checker));
}

// `v` when it is finite, else `bg`.
fn finite_or(v: f32, bg: f32) -> f32 {
    return select(bg, v, is_finite(v));
}

// The surface model's last 8³ cell of the drawn level: the tree walk and
// the level set's brick channel are done once per cell, not per voxel read.
var<private> ls_cell: vec3<i32> = vec3<i32>(-1 << 30);
var<private> ls_leaf: VpakLeaf;
var<private> ls_bc: VpakBrickChannel;

// Makes `ls_leaf` the cell of voxel `ip` of the drawn level.
fn ls_enter(ip: vec3<i32>) {
    let cell = ip >> vec3<u32>(3u);
    if (any(cell != ls_cell)) {
        ls_cell = cell;
        ls_leaf = vpak_leaf(params.info, ip);
        if (ls_leaf.l3 != VPAK_NONE) {
            ls_bc = in_slot(vpak_brick_channel(params.info, ls_leaf.brick, params.channels.x), SLOT_X);
        }
    }
}

// The level set (params.channels.x) at `p` (level-0 asset coordinates):
// trilinear between the centres of the drawn level's voxels, inactive and
// non-finite voxels reading the background `bg` (positive: outside).
fn ls_field(p: vec3<f32>, bg: f32) -> f32 {
    let q = p / f32(1u << params.info.level) - vec3<f32>(0.5);
    let i0 = vec3<i32>(floor(q));
    let w = q - floor(q);
    var acc = 0.0;
    for (var k = 0; k < 8; k += 1) {
        let sel = vec3<bool>((k & 1) != 0, (k & 2) != 0, (k & 4) != 0);
        let ip = select(i0, i0 + vec3<i32>(1), sel);
        ls_enter(ip);
        let v = finite_or(cell_value(ls_leaf, ls_bc, vpak_leaf_active(ls_leaf, ip), ip, params.channels.x, bg), bg);
        let wk = select(vec3<f32>(1.0) - w, w, sel);
        acc += v * wk.x * wk.y * wk.z;
    }
    return acc;
}

// How far along `d` the point `p` stays inside the cube of edge `dim` that
// contains it, shrunk by `m` on every side; 0 when `p` is not inside that.
fn inset_exit(p: vec3<f32>, d: vec3<f32>, dim: f32, m: f32) -> f32 {
    let lo = floor(p / dim) * dim + vec3<f32>(m);
    let hi = lo + vec3<f32>(dim - 2.0 * m);
    if (any(p < lo) || any(p > hi)) {
        return 0.0;
    }
    let inv = 1.0 / d;
    let t = max((lo - p) * inv, (hi - p) * inv);
    return min(min(t.x, t.y), t.z);
}

// The surface model: the first place along the ray where the level set goes
// from positive to not positive (marched on the same lattice as the fog,
// the crossing bracketed between two samples and refined by four bisection
// steps and a final linear interpolation), shaded with the normal of the
// field's central-difference gradient, the scene's light and ambient light,
// at a fixed albedo. Empty regions (the background, positive when size.w is
// 1) are skipped where the trilinear field cannot leave the background: more
// than one of the level's voxels inside them.
fn surface(o: vec3<f32>, d: vec3<f32>, hit: vec2<f32>) -> vec3<f32> {
    if (hit.x >= hit.y) {
        return vec3<f32>(0.0);
    }
    let step = params.box_min.w;
    let voxel = f32(1u << params.info.level);
    let bg = vpak_background(params.channels.x);
    var t_prev = hit.x;
    var v_prev = ls_field(o + d * hit.x, bg);
    var t_hit = -1.0;
    if (v_prev <= 0.0) {
        t_hit = hit.x;
    }
    var k = 0.5;
    var n = 0u;
    loop {
        let t = hit.x + k * step;
        if (t_hit >= 0.0 || t >= hit.y || n >= params.size.z) { break; }
        n += 1u;
        let p = o + d * t;
        if (params.size.w == 1u) {
            ls_enter(vpak_level_point(params.info, vec3<i32>(floor(p))));
            if (ls_leaf.empty_dim > 0u) {
                let deep = inset_exit(p, d, f32(ls_leaf.empty_dim << params.info.level), voxel);
                if (deep > 0.0) {
                    // Every lattice point before t + deep reads the background.
                    let next = max(k + 1.0, ceil((t + deep - hit.x) / step - 0.5) + 0.5);
                    t_prev = hit.x + (next - 1.0) * step;
                    v_prev = bg;
                    k = next;
                    continue;
                }
            }
        }
        let v = ls_field(p, bg);
        if (v_prev > 0.0 && v <= 0.0) {
            var a = t_prev;
            var va = v_prev;
            var b = t;
            var vb = v;
            for (var i = 0; i < 4; i += 1) {
                let m = 0.5 * (a + b);
                let vm = ls_field(o + d * m, bg);
                if (vm > 0.0) {
                    a = m;
                    va = vm;
                } else {
                    b = m;
                    vb = vm;
                }
            }
            t_hit = a + (b - a) * (va / (va - vb));
        }
        t_prev = t;
        v_prev = v;
        k += 1.0;
    }
    if (t_hit < 0.0) {
        return vec3<f32>(0.0);
    }
    let p = o + d * t_hit;
    let h = voxel;
    let g = vec3<f32>(
        ls_field(p + vec3<f32>(h, 0.0, 0.0), bg) - ls_field(p - vec3<f32>(h, 0.0, 0.0), bg),
        ls_field(p + vec3<f32>(0.0, h, 0.0), bg) - ls_field(p - vec3<f32>(0.0, h, 0.0), bg),
        ls_field(p + vec3<f32>(0.0, 0.0, h), bg) - ls_field(p - vec3<f32>(0.0, 0.0, h), bg),
    );
    let len = length(g);
    var normal = -d;
    if (len > 0.0) {
        normal = g / len;
    }
    let lit = max(dot(normal, params.light.xyz), 0.0);
    return vec3<f32>(0.8 * (0.25 + 0.75 * lit));
}

// The direction of the camera ray through pixel `gid` of the image.
fn pixel_ray(gid: vec3<u32>) -> vec3<f32> {
    let w = params.size.x;
    let h = params.size.y;
    let px = (f32(gid.x) + 0.5) / f32(w) * 2.0 - 1.0;
    let py = 1.0 - (f32(gid.y) + 0.5) / f32(h) * 2.0;
    let aspect = f32(w) / f32(h);
    let tf = params.forward.w;
    return normalize(params.forward.xyz + params.right.xyz * (px * tf * aspect) + params.up.xyz * (py * tf));
}

fn write_pixel(gid: vec3<u32>, radiance: vec3<f32>) {
    let pixel = 3u * (gid.y * params.size.x + gid.x);
    image[pixel] = radiance.x;
    image[pixel + 1u] = radiance.y;
    image[pixel + 2u] = radiance.z;
}

// The surface model (params.channels.x is a level set, see `surface`).
@compute @workgroup_size(8, 8, 1)
fn surface_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.size.x || gid.y >= params.size.y) { return; }
    let d = pixel_ray(gid);
    let o = params.eye.xyz;
    let hit = box_hit(o, d, params.box_min.xyz, params.box_max.xyz);
    var radiance = surface(o, d, hit);
    if (BACKDROP) {
        radiance += backdrop(d);
    }
    write_pixel(gid, radiance);
}

// The scatter and glow models.
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.size.x || gid.y >= params.size.y) { return; }
    let d = pixel_ray(gid);
    let o = params.eye.xyz;
    let hit = box_hit(o, d, params.box_min.xyz, params.box_max.xyz);
    var radiance = vec3<f32>(0.0);
    var trans = 1.0;
    if (hit.x < hit.y) {
        let step = params.box_min.w;
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
            let sigma = finite_positive(e) * params.light.w;
            if (sigma > 0.0) {
                let a = 1.0 - exp(-sigma * step);
                let lit = 0.25 + 0.75 * exp(-shadow_at(p));
                radiance += vec3<f32>(trans * a * lit * params.emission.w);
                trans *= 1.0 - a;
            }
            k += 1.0;
        }
    }
    if (BACKDROP) {
        radiance += trans * backdrop(d);
    }
    write_pixel(gid, radiance);
}
