// vpak.wgsl: sample a .vpak asset on the GPU (see docs/format.md).
//
// An engine includes this file and one of the two atlas files, binds the
// asset's sections as storage buffers, and calls `vpak_sample` (the value at a
// voxel) or `vpak_query` (the value plus the size of the empty region around
// it, for hierarchical empty-space skipping). The atlas files define
// `vpak_texel(info, atlas, texel)`:
//   vpak_atlas_texture.wgsl  the brick atlases as 3D textures, read through the
//                            texture unit (BC4/BC7 need TEXTURE_COMPRESSION_BC
//                            and TEXTURE_COMPRESSION_BC_SLICED_3D);
//   vpak_atlas_buffer.wgsl   BC4/BC7 atlases as storage buffers of raw blocks,
//                            decoded in the shader (include bcdec.wgsl too), for
//                            GPUs without block-compressed 3D textures.
//
// Coordinates are asset index space: source index minus `index_offset`,
// inside [0, 4096)^3. Up to four brick atlases are bound; every atlas but the
// last holds the same number of bricks (`atlas_bricks.w` below).

const VPAK_L1_WORDS: u32 = 1537u;   // 1024 mask words, 512 prefix words, first entry
const VPAK_L2_WORDS: u32 = 193u;    // 128 mask words, 64 prefix words, first entry
const VPAK_L3_WORDS: u32 = 3u;      // brick, sub-block states, first sub-mask (after a count)
const VPAK_TILE: u32 = 0x80000000u;

// Voxel formats (Metadata.format).
const VPAK_F32: u32 = 0u;
const VPAK_F16: u32 = 1u;
const VPAK_UNORM8: u32 = 2u;
const VPAK_BC4: u32 = 3u;
const VPAK_BC7: u32 = 4u;

struct VpakInfo {
    // L1 node of the frame being sampled.
    l1: u32,
    format: u32,
    background: f32,
    _pad: u32,
    // Size in bricks (x, y, z) of every atlas but possibly the last, and the
    // bricks each holds (x·y·z). Brick positions in every atlas follow this
    // shape; the last atlas may be smaller but holds every position used.
    atlas_bricks: vec4<u32>,
    // The last atlas: its number, and its own size in bricks along x and y
    // (the stride of its rows and slices, for vpak_atlas_buffer.wgsl).
    last_atlas: vec4<u32>,
}

@group(0) @binding(1) var<storage, read> vpak_l1: array<u32>;
@group(0) @binding(2) var<storage, read> vpak_l1_entries: array<u32>;
@group(0) @binding(3) var<storage, read> vpak_l2: array<u32>;
@group(0) @binding(4) var<storage, read> vpak_l2_entries: array<u32>;
@group(0) @binding(5) var<storage, read> vpak_l3: array<u32>;
@group(0) @binding(6) var<storage, read> vpak_tiles: array<u32>;
@group(0) @binding(7) var<storage, read> vpak_ranges: array<vec2<f32>>;
// False when the asset has a single atlas: the atlas selection then folds
// away at pipeline creation (it costs ~20 % on a CPU driver otherwise).
override VPAK_MULTI_ATLAS: bool = true;
// Entry of slot `s` in the node at `base` with `mask_words` mask words,
// or 0xffffffff when the slot is empty: the mask bit, then the rank of the
// slot among the occupied ones from the per-word prefix counts.
fn vpak_entry_index(nodes_is_l1: bool, base: u32, mask_words: u32, s: u32) -> u32 {
    let w = s >> 5u;
    let bit = s & 31u;
    var word: u32;
    var prefix_word: u32;
    var first: u32;
    if (nodes_is_l1) {
        word = vpak_l1[base + w];
        prefix_word = vpak_l1[base + mask_words + (w >> 1u)];
        first = vpak_l1[base + mask_words + (mask_words >> 1u)];
    } else {
        word = vpak_l2[base + w];
        prefix_word = vpak_l2[base + mask_words + (w >> 1u)];
        first = vpak_l2[base + mask_words + (mask_words >> 1u)];
    }
    if (((word >> bit) & 1u) == 0u) {
        return 0xffffffffu;
    }
    let prefix = (prefix_word >> (16u * (w & 1u))) & 0xffffu;
    let below = countOneBits(word & ((1u << bit) - 1u));
    return first + prefix + below;
}

fn vpak_tile_value(e: u32) -> f32 {
    return bitcast<f32>(vpak_tiles[(e & ~VPAK_TILE) * 2u]);
}

// Where brick `b` lives: its atlas, its first texel there, and the range its
// stored levels map to (0..1 for f32 and f16, which store values).
struct VpakBrick {
    atlas: u32,
    origin: vec3<u32>,
    range: vec2<f32>,
}

fn vpak_brick(info: VpakInfo, b: u32) -> VpakBrick {
    let bx = info.atlas_bricks.x;
    let by = info.atlas_bricks.y;
    var brick: VpakBrick;
    brick.atlas = 0u;
    var i = b;
    if (VPAK_MULTI_ATLAS && b >= info.atlas_bricks.w) {
        brick.atlas = b / info.atlas_bricks.w;
        i = b % info.atlas_bricks.w;
    }
    let pos = vec3<u32>(i % bx, (i / bx) % by, i / (bx * by));
    if (info.format == VPAK_BC7) {
        brick.origin = pos * vec3<u32>(8u, 8u, 2u);
    } else {
        brick.origin = pos * 8u;
    }
    if (info.format == VPAK_F32 || info.format == VPAK_F16) {
        brick.range = vec2<f32>(0.0, 1.0);
    } else {
        brick.range = vpak_ranges[b];
    }
    return brick;
}

// The stored value of voxel `v` (x·64 + y·8 + z) of `brick`.
fn vpak_brick_texel(info: VpakInfo, brick: VpakBrick, v: vec3<u32>) -> f32 {
    var t: f32;
    if (info.format == VPAK_BC7) {
        // Four consecutive z-slices share a texel, one per channel.
        let texel = vpak_texel(info, brick.atlas, vec3<i32>(brick.origin + vec3<u32>(v.x, v.y, v.z >> 2u)));
        t = texel[v.z & 3u];
    } else {
        t = vpak_texel(info, brick.atlas, vec3<i32>(brick.origin + v)).r;
    }
    return brick.range.x + t * (brick.range.y - brick.range.x);
}

// The stored value of voxel `v` of brick `b`.
fn vpak_brick_value(info: VpakInfo, b: u32, v: vec3<u32>) -> f32 {
    return vpak_brick_texel(info, vpak_brick(info, b), v);
}

// Value at voxel `p`, and the edge of the empty (background) region that
// contains it: 128 for an empty L1 slot, 8 for an empty L2 slot, 0 when the
// voxel is inside an L3 node or a tile.
struct VpakQuery {
    value: f32,
    empty_dim: u32,
}

// What the tree holds for the 8³ cell of a voxel: an L3 node (`l3` is its
// first word), or a constant (tile or empty region, `l3` = 0xffffffff).
// A marcher keeps it while it stays in the same cell and skips the L1/L2 walk.
struct VpakLeaf {
    l3: u32,
    // The L3 node's sub-block states and the index of its first sub-mask.
    states: u32,
    masks: u32,
    value: f32,
    empty_dim: u32,
    // The L3 node's brick (when `l3` is set).
    brick: VpakBrick,
}

fn vpak_leaf(info: VpakInfo, p: vec3<i32>) -> VpakLeaf {
    var leaf: VpakLeaf;
    leaf.l3 = 0xffffffffu;
    leaf.value = info.background;
    leaf.empty_dim = 0u;
    if (any(p < vec3<i32>(0)) || any(p >= vec3<i32>(4096))) {
        leaf.empty_dim = 128u;
        return leaf;
    }
    let u = vec3<u32>(p);
    let s1 = (((u.x >> 7u) & 31u) << 10u) | (((u.y >> 7u) & 31u) << 5u) | ((u.z >> 7u) & 31u);
    let i1 = vpak_entry_index(true, info.l1 * VPAK_L1_WORDS, 1024u, s1);
    if (i1 == 0xffffffffu) {
        leaf.empty_dim = 128u;
        return leaf;
    }
    let e1 = vpak_l1_entries[i1];
    if ((e1 & VPAK_TILE) != 0u) {
        leaf.value = vpak_tile_value(e1);
        return leaf;
    }
    let s2 = (((u.x >> 3u) & 15u) << 8u) | (((u.y >> 3u) & 15u) << 4u) | ((u.z >> 3u) & 15u);
    let i2 = vpak_entry_index(false, e1 * VPAK_L2_WORDS, 128u, s2);
    if (i2 == 0xffffffffu) {
        leaf.empty_dim = 8u;
        return leaf;
    }
    let e2 = vpak_l2_entries[i2];
    if ((e2 & VPAK_TILE) != 0u) {
        leaf.value = vpak_tile_value(e2);
        return leaf;
    }
    leaf.l3 = 1u + e2 * VPAK_L3_WORDS;
    leaf.brick = vpak_brick(info, vpak_l3[leaf.l3]);
    leaf.states = vpak_l3[leaf.l3 + 1u];
    leaf.masks = vpak_l3[leaf.l3 + 2u];
    return leaf;
}

// Voxel `p` of the cell `leaf` describes (from `vpak_leaf` of any voxel in it).
fn vpak_leaf_query(info: VpakInfo, leaf: VpakLeaf, p: vec3<i32>) -> VpakQuery {
    var q: VpakQuery;
    q.value = leaf.value;
    q.empty_dim = leaf.empty_dim;
    if (leaf.l3 == 0xffffffffu) {
        return q;
    }
    let v = vec3<u32>(p) & vec3<u32>(7u);
    // The voxel's 4³ sub-block: no voxel active, all active, or a sub-mask.
    let sb = ((v.x >> 2u) << 2u) | ((v.y >> 2u) << 1u) | (v.z >> 2u);
    let state = (leaf.states >> (2u * sb)) & 3u;
    if (state == 0u) {
        q.value = info.background;
        return q;
    }
    if (state >= 2u) {
        let j = ((v.x & 3u) << 4u) | ((v.y & 3u) << 2u) | (v.z & 3u);
        let below = countOneBits((leaf.states >> 1u) & 0x5555u & ((1u << (2u * sb)) - 1u));
        if (((vpak_l3[leaf.masks + 2u * below + (j >> 5u)] >> (j & 31u)) & 1u) == 0u) {
            q.value = info.background;
            return q;
        }
    }
    q.value = vpak_brick_texel(info, leaf.brick, v);
    return q;
}

fn vpak_query(info: VpakInfo, p: vec3<i32>) -> VpakQuery {
    return vpak_leaf_query(info, vpak_leaf(info, p), p);
}

fn vpak_sample(info: VpakInfo, p: vec3<i32>) -> f32 {
    return vpak_query(info, p).value;
}
