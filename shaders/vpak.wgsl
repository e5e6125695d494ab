// vpak.wgsl: sample a .vpak asset on the GPU (see docs/format.md).
//
// An engine includes this file and one of the two atlas files, binds the
// asset's sections as storage buffers, and calls `vpak_sample` (channel c's
// value at a voxel) or `vpak_query` (the value plus the size of the empty
// region around it, for hierarchical empty-space skipping). The atlas files
// define `vpak_texel(bc, texel)` (a texel of the brick channel `bc`'s texture):
//   vpak_atlas_texture.wgsl  every atlas of every plane as a 3D texture, read
//                            through the texture unit (BC4/BC7 need
//                            TEXTURE_COMPRESSION_BC and TEXTURE_COMPRESSION_BC_SLICED_3D);
//   vpak_atlas_buffer.wgsl   every atlas as a storage buffer of its section's
//                            bytes, decoded in the shader (include bcdec.wgsl
//                            too), for GPUs without block-compressed 3D textures.
//
// Coordinates are asset index space: source index minus `index_offset`,
// inside [0, 4096)^3. A frame's tree is walked once per 8³ cell (`vpak_leaf`)
// and serves every channel of the voxels in it (`vpak_leaf_value`). A leaf's
// brick has, for each channel, a plane brick in one of the channel's planes
// (through the plane's brick table, when it has one; for a channel stored in
// several planes, per-brick formats, through the channel's table, which also
// picks the plane), which has a range per channel and a place in one of the
// plane's atlases. Atlas a of a channel's plane is texture slot
// `slot + a` (VpakChannel.slot); up to eight slots are bound, so an engine
// binds the atlases of the planes it samples, each plane's in consecutive
// slots, and writes each channel's slot accordingly.

const VPAK_L2_WORDS: u32 = 193u;    // 128 mask words, 64 prefix words, first entry
const VPAK_L3_WORDS: u32 = 3u;      // brick, sub-block states, first sub-mask (after a count)
// No brick table: brick b is plane brick b.
const VPAK_TILE: u32 = 0x80000000u;
const VPAK_NONE: u32 = 0xffffffffu;
// Records of the channel table: a record per channel and per alternate
// plane (at most 256 channels and 256 planes).
const VPAK_CHANNEL_RECORDS: u32 = 512u;

// Plane formats (Format codes).
const VPAK_F32: u32 = 0u;
const VPAK_F16: u32 = 1u;
const VPAK_UNORM8: u32 = 2u;
const VPAK_BC4: u32 = 3u;
const VPAK_BC7: u32 = 4u;
const VPAK_UNORM16: u32 = 5u;
const VPAK_CONSTANT: u32 = 6u;
// Channel table entries: the plane's choice above bit 28, the plane brick below.
const VPAK_CHOICE_SHIFT: u32 = 28u;
const VPAK_PLANE_BRICK: u32 = 0x0fffffffu;

struct VpakInfo {
    // L1 node of the frame being sampled: the word of the L1 array it starts
    // at (at `level`: entry (level − first_level) · frame_count + frame of the
    // frames section).
    l1: u32,
    // Channels of the asset (values per tile).
    channels: u32,
    // Level of detail of that tree (0: the frame itself). `vpak_query` takes
    // level-0 asset coordinates and reads the level's voxel that covers them
    // (level index = asset index >> level); `vpak_leaf` and the functions
    // that take its result work in the level's own coordinates.
    level: u32,
    _pad1: u32,
}

// One channel and its plane, as the metadata describes them (docs/format.md,
// "The channel table").
struct VpakChannel {
    // Texture slot of the plane's first atlas, and the channel's first lane there.
    slot: u32,
    lane: u32,
    // log2 of the consecutive z-slices in one texel's lanes (BC7 packing;
    // else 0), and the slices a brick takes in the plane (8 >> z_shift).
    z_shift: u32,
    slices: u32,
    // The plane's format code and lanes (1, 2 or 4).
    format: u32,
    lanes: u32,
    // 1 when texels are levels over the brick's channel range.
    ranged: u32,
    // The channel's background (f32 bits).
    background: u32,
    // First word of the plane's brick table in vpak_tables, or VPAK_NONE.
    table: u32,
    // First range of the plane in vpak_ranges, and ranges per plane brick.
    range_base: u32,
    range_slots: u32,
    plane: u32,
    // Size in bricks (x, y, z) of the plane's atlases but possibly the last,
    // and the bricks each holds (x·y·z). Brick positions in every atlas follow
    // this shape; the last atlas may be smaller but holds every position used.
    atlas_bricks: vec4<u32>,
    // The plane's last atlas: its number, and its own size in bricks along x
    // and y (the stride of its rows and slices, for vpak_atlas_buffer.wgsl).
    last_atlas: vec3<u32>,
    // For a channel stored in several planes: the record of its first
    // alternate plane (`table` is then its channel table); else VPAK_NONE.
    alternates: u32,
}

@group(0) @binding(1) var<storage, read> vpak_l1: array<u32>;
@group(0) @binding(2) var<storage, read> vpak_l1_entries: array<u32>;
@group(0) @binding(3) var<storage, read> vpak_l2: array<u32>;
@group(0) @binding(4) var<storage, read> vpak_l2_entries: array<u32>;
@group(0) @binding(5) var<storage, read> vpak_l3: array<u32>;
@group(0) @binding(6) var<storage, read> vpak_tiles: array<u32>;
@group(0) @binding(7) var<storage, read> vpak_ranges: array<vec2<f32>>;
// A uniform buffer (of VPAK_CHANNEL_RECORDS records, unused ones zero): a
// channel's record is read at every sample, and a uniform read is a single
// load where the channel is the same for every invocation.
@group(0) @binding(14) var<uniform> vpak_channels: array<VpakChannel, VPAK_CHANNEL_RECORDS>;
@group(0) @binding(19) var<storage, read> vpak_tables: array<u32>;
// False when the asset has a single texture (one plane, one atlas): the
// texture selection then folds away at pipeline creation (it costs 2-3x on
// a CPU driver otherwise).
override VPAK_MULTI_ATLAS: bool = true;
// The format code of every plane sampled, when the channels a pipeline
// samples are each in one plane (no per-brick formats) of that one format;
// else VPAK_NONE. A known format folds the other formats' decoding, the
// per-brick plane choice and the range test away at pipeline creation: a
// CPU driver runs every branch of a shader, taken or not.
override VPAK_FORMAT: u32 = 0xffffffffu;
// False when no plane has a brick table (vpak_tables is empty): the table
// reads fold away.
override VPAK_TABLES: bool = true;

// The format of the brick channel whose record says `format`.
fn vpak_format(format: u32) -> u32 {
    if (VPAK_FORMAT != VPAK_NONE) {
        return VPAK_FORMAT;
    }
    return format;
}

// Whether texels of `format` are levels over the brick's range (every
// format but f32 and f16).
fn vpak_ranged(format: u32) -> bool {
    return format != VPAK_F32 && format != VPAK_F16;
}

// Entry of slot `s` in the node at `base` with `mask_words` mask words,
// or VPAK_NONE when the slot is empty: the mask bit, then the rank of the
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
        return VPAK_NONE;
    }
    let prefix = (prefix_word >> (16u * (w & 1u))) & 0xffffu;
    let below = countOneBits(word & ((1u << bit) - 1u));
    return first + prefix + below;
}

// (n / d, n % d) for n below 2^28 and d > 0, through float divisions: a CPU
// driver has no vector integer division and divides lane by lane. The first
// quotient is within 100 of n / d (within WGSL's 2.5 ULP), the remainder's
// quotient within 1 of the rest, and one step corrects that.
fn vpak_divmod(n: u32, d: u32) -> vec2<u32> {
    let fd = f32(d);
    var q = i32(f32(n) / fd);
    var r = i32(n) - q * i32(d);
    let c = i32(floor(f32(r) / fd));
    q += c;
    r -= c * i32(d);
    if (r < 0) {
        q -= 1;
        r += i32(d);
    } else if (r >= i32(d)) {
        q += 1;
        r -= i32(d);
    }
    return vec2<u32>(u32(q), u32(r));
}

// Channel `c` of brick `b`, resolved once: its plane brick's texture slot,
// first texel there and the atlas's size, its lanes and its value range. A
// marcher keeps it for a cell.
struct VpakBrickChannel {
    slot: u32,
    origin: vec3<u32>,
    // The atlas's size in bricks along x and y (for vpak_atlas_buffer.wgsl).
    size: vec2<u32>,
    lane: u32,
    z_shift: u32,
    format: u32,
    lanes: u32,
    ranged: u32,
    // min, max - min (ranged formats).
    range: vec2<f32>,
}

fn vpak_brick_channel(info: VpakInfo, b: u32, c: u32) -> VpakBrickChannel {
    var ch = vpak_channels[c];
    var pb = b;
    if (VPAK_TABLES && VPAK_FORMAT == VPAK_NONE && ch.alternates != VPAK_NONE) {
        // Per-brick formats: the channel table picks the plane and its brick.
        let e = vpak_tables[ch.table + b];
        pb = e & VPAK_PLANE_BRICK;
        let choice = e >> VPAK_CHOICE_SHIFT;
        if (choice != 0u) {
            ch = vpak_channels[ch.alternates + choice - 1u];
        }
    } else if (VPAK_TABLES && ch.table != VPAK_NONE) {
        pb = vpak_tables[ch.table + b];
    }
    var atlas = 0u;
    var i = pb;
    if (VPAK_MULTI_ATLAS && pb >= ch.atlas_bricks.w) {
        atlas = pb / ch.atlas_bricks.w;
        i = pb % ch.atlas_bricks.w;
    }
    // i = x + bx · (y + by · z)
    let qx = vpak_divmod(i, ch.atlas_bricks.x);
    let qy = vpak_divmod(qx.x, ch.atlas_bricks.y);
    var bc: VpakBrickChannel;
    bc.slot = ch.slot + atlas;
    bc.origin = vec3<u32>(qx.y, qy.y, qy.x) * vec3<u32>(8u, 8u, ch.slices);
    bc.size = ch.atlas_bricks.xy;
    if (atlas == ch.last_atlas.x) {
        bc.size = ch.last_atlas.yz;
    }
    bc.lane = ch.lane;
    bc.z_shift = ch.z_shift;
    bc.format = vpak_format(ch.format);
    bc.lanes = ch.lanes;
    bc.ranged = ch.ranged;
    if (vpak_ranged(bc.format)) {
        let r = vpak_ranges[ch.range_base + pb * ch.range_slots + (ch.lane >> ch.z_shift)];
        bc.range = vec2<f32>(r.x, r.y - r.x);
    }
    return bc;
}

// Voxel `v` (0..8 on each axis) of the brick channel `bc`.
fn vpak_brick_channel_value(bc: VpakBrickChannel, v: vec3<u32>) -> f32 {
    let format = vpak_format(bc.format);
    if (format == VPAK_CONSTANT) {
        return bc.range.x;
    }
    let t = bc.origin + vec3<u32>(v.x, v.y, v.z >> bc.z_shift);
    let level = vpak_texel(bc, vec3<i32>(t))[bc.lane + (v.z & ((1u << bc.z_shift) - 1u))];
    if (!vpak_ranged(format)) {
        return level;
    }
    return bc.range.x + level * bc.range.y;
}

// Channel `c` of voxel `v` (0..8 on each axis) of brick `b`.
fn vpak_brick_value(info: VpakInfo, b: u32, v: vec3<u32>, c: u32) -> f32 {
    return vpak_brick_channel_value(vpak_brick_channel(info, b, c), v);
}

// What the tree holds for the 8³ cell of a voxel: an L3 node (`l3` is its
// first word), a tile (`tile` is its index), or nothing (`empty_dim` is the
// edge of the empty region: 128 for an empty L1 slot, 8 for an empty L2 slot).
// A marcher keeps it while it stays in the same cell and skips the L1/L2 walk.
struct VpakLeaf {
    l3: u32,
    // The L3 node's sub-block states and the index of its first sub-mask.
    states: u32,
    masks: u32,
    tile: u32,
    empty_dim: u32,
    // The L3 node's brick (when `l3` is set).
    brick: u32,
}

fn vpak_leaf(info: VpakInfo, p: vec3<i32>) -> VpakLeaf {
    var leaf: VpakLeaf;
    leaf.l3 = VPAK_NONE;
    leaf.tile = VPAK_NONE;
    leaf.empty_dim = 0u;
    if (any(p < vec3<i32>(0)) || any(p >= vec3<i32>(4096))) {
        leaf.empty_dim = 128u;
        return leaf;
    }
    let u = vec3<u32>(p);
    // The L1 node has 2^L slots per axis (L, 2 to 5, is its first word): past them is empty.
    let log2 = vpak_l1[info.l1];
    let c1 = u >> vec3<u32>(7u);
    if (any(c1 >= vec3<u32>(1u << log2))) {
        leaf.empty_dim = 128u;
        return leaf;
    }
    let s1 = (c1.x << (2u * log2)) | (c1.y << log2) | c1.z;
    let i1 = vpak_entry_index(true, info.l1 + 1u, (1u << (3u * log2)) >> 5u, s1);
    if (i1 == VPAK_NONE) {
        leaf.empty_dim = 128u;
        return leaf;
    }
    let e1 = vpak_l1_entries[i1];
    if ((e1 & VPAK_TILE) != 0u) {
        leaf.tile = e1 & ~VPAK_TILE;
        return leaf;
    }
    let s2 = (((u.x >> 3u) & 15u) << 8u) | (((u.y >> 3u) & 15u) << 4u) | ((u.z >> 3u) & 15u);
    let i2 = vpak_entry_index(false, e1 * VPAK_L2_WORDS, 128u, s2);
    if (i2 == VPAK_NONE) {
        leaf.empty_dim = 8u;
        return leaf;
    }
    let e2 = vpak_l2_entries[i2];
    if ((e2 & VPAK_TILE) != 0u) {
        leaf.tile = e2 & ~VPAK_TILE;
        return leaf;
    }
    leaf.l3 = 1u + e2 * VPAK_L3_WORDS;
    leaf.brick = vpak_l3[leaf.l3];
    leaf.states = vpak_l3[leaf.l3 + 1u];
    leaf.masks = vpak_l3[leaf.l3 + 2u];
    return leaf;
}

// Whether voxel `p` of the cell `leaf` describes is active (in a tile, or an
// active voxel of the L3 node).
fn vpak_leaf_active(leaf: VpakLeaf, p: vec3<i32>) -> bool {
    if (leaf.tile != VPAK_NONE) {
        return true;
    }
    if (leaf.l3 == VPAK_NONE) {
        return false;
    }
    let v = vec3<u32>(p) & vec3<u32>(7u);
    // The voxel's 4³ sub-block: no voxel active, all active, or a sub-mask.
    let sb = ((v.x >> 2u) << 2u) | ((v.y >> 2u) << 1u) | (v.z >> 2u);
    let state = (leaf.states >> (2u * sb)) & 3u;
    if (state == 0u) {
        return false;
    }
    if (state >= 2u) {
        let j = ((v.x & 3u) << 4u) | ((v.y & 3u) << 2u) | (v.z & 3u);
        let below = countOneBits((leaf.states >> 1u) & 0x5555u & ((1u << (2u * sb)) - 1u));
        return ((vpak_l3[leaf.masks + 2u * below + (j >> 5u)] >> (j & 31u)) & 1u) != 0u;
    }
    return true;
}

// Channel `c` of voxel `p`, which `vpak_leaf_active` found active in `leaf`.
fn vpak_active_value(info: VpakInfo, leaf: VpakLeaf, p: vec3<i32>, c: u32) -> f32 {
    if (leaf.tile != VPAK_NONE) {
        return bitcast<f32>(vpak_tiles[leaf.tile * info.channels + c]);
    }
    return vpak_brick_value(info, leaf.brick, vec3<u32>(p) & vec3<u32>(7u), c);
}

// Channel `c`'s background (0 for VPAK_NONE).
fn vpak_background(c: u32) -> f32 {
    if (c == VPAK_NONE) {
        return 0.0;
    }
    return bitcast<f32>(vpak_channels[c].background);
}

// Channel `c` of voxel `p` of the cell `leaf` describes.
fn vpak_leaf_value(info: VpakInfo, leaf: VpakLeaf, p: vec3<i32>, c: u32) -> f32 {
    if (vpak_leaf_active(leaf, p)) {
        return vpak_active_value(info, leaf, p, c);
    }
    return vpak_background(c);
}

// Channel `c`'s value at voxel `p`, and the edge of the empty (background)
// region that contains it: 128 for an empty L1 slot, 8 for an empty L2 slot,
// 0 when the voxel is inside an L3 node or a tile.
struct VpakQuery {
    value: f32,
    empty_dim: u32,
}

fn vpak_query(info: VpakInfo, p: vec3<i32>, c: u32) -> VpakQuery {
    let lp = vpak_level_point(info, p);
    let leaf = vpak_leaf(info, lp);
    var q: VpakQuery;
    q.value = vpak_leaf_value(info, leaf, lp, c);
    // The empty region's edge in level-0 voxels.
    q.empty_dim = leaf.empty_dim << info.level;
    return q;
}

// The voxel of `info.level` that covers level-0 asset voxel `p`.
fn vpak_level_point(info: VpakInfo, p: vec3<i32>) -> vec3<i32> {
    return p >> vec3<u32>(info.level);
}

fn vpak_sample(info: VpakInfo, p: vec3<i32>, c: u32) -> f32 {
    return vpak_query(info, p, c).value;
}
