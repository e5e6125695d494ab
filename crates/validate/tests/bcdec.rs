//! shaders/bcdec.wgsl, the WGSL BC4/BC7 block decoder, against bcdec_rs:
//! every texel of many thousands of random blocks (every BC7 mode, partition,
//! rotation and index selector) and of blocks from the real encoder.

use std::sync::OnceLock;
use vdbcook_encode::{encode_bricks, Format, Quality, BRICK_VOXELS};
use vdbcook_testkit::Rng;

const LIBRARY: &str = include_str!("../../../shaders/bcdec.wgsl");

/// Test entry points: one invocation per texel, 16 per block, in block order.
const ENTRIES: &str = r#"
@group(0) @binding(0) var<storage, read> blocks: array<u32>;
@group(0) @binding(1) var<storage, read_write> texels: array<vec4<f32>>;

@compute @workgroup_size(64)
fn test_bc7(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= arrayLength(&texels) {
        return;
    }
    let b = 4u * (i / 16u);
    texels[i] = bc7_texel(vec4<u32>(blocks[b], blocks[b + 1u], blocks[b + 2u], blocks[b + 3u]), i % 16u);
}

@compute @workgroup_size(64)
fn test_bc4(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= arrayLength(&texels) {
        return;
    }
    let b = 2u * (i / 16u);
    texels[i] = vec4<f32>(bc4_texel(vec2<u32>(blocks[b], blocks[b + 1u]), i % 16u), 0.0, 0.0, 0.0);
}
"#;

fn shader() -> String {
    format!("{LIBRARY}\n{ENTRIES}")
}

fn validate(src: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(src).unwrap_or_else(|e| panic!("WGSL parses: {}", e.emit_to_string(src)));
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all()).validate(&module).expect("WGSL validates");
    module
}

#[test]
fn wgsl_parses_and_validates() {
    // The library on its own: no bindings, no entry points, only the two
    // public functions unprefixed.
    let module = validate(LIBRARY);
    assert!(module.entry_points.is_empty());
    assert!(!LIBRARY.contains("@group") && !LIBRARY.contains("@binding"));
    for (_, var) in module.global_variables.iter() {
        assert!(var.binding.is_none());
        assert!(var.name.as_deref().unwrap_or("").starts_with("bcdec_"), "{:?}", var.name);
    }
    let mut names = Vec::new();
    for (_, f) in module.functions.iter() {
        let name = f.name.clone().unwrap_or_default();
        assert!(name.starts_with("bcdec_") || name == "bc4_texel" || name == "bc7_texel", "{name}");
        names.push(name);
    }
    for (name, arg, result) in [("bc4_texel", "vec2<u32>", "f32"), ("bc7_texel", "vec4<u32>", "vec4<f32>")] {
        assert!(names.iter().any(|n| n == name), "{name} missing");
        let signature = format!("fn {name}(block: {arg}, texel: u32) -> {result}");
        assert!(LIBRARY.contains(&signature), "{signature}");
    }
    // And with the test's entry points.
    let module = validate(&shader());
    assert_eq!(module.entry_points.len(), 2);
}

// ---------------------------------------------------------------------------
// GPU

struct Gpu {
    device: wgpu::Device,
    queue: wgpu::Queue,
    layout: wgpu::BindGroupLayout,
    bc7: wgpu::ComputePipeline,
    bc4: wgpu::ComputePipeline,
}

// XDG_RUNTIME_DIR (which Mesa wants) is exported by scripts/test.sh, as for
// the other GPU tests; setting it here would race with other test threads.
fn open() -> Result<Gpu, String> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        force_fallback_adapter: false,
        compatible_surface: None,
        ..Default::default()
    }))
    .map_err(|e| format!("no adapter ({e})"))?;
    let info = adapter.get_info();
    eprintln!("bcdec test adapter: {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("bcdec test"),
        required_features: wgpu::Features::empty(),
        required_limits: adapter.limits(),
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }))
    .map_err(|e| format!("no device ({e})"))?;
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor { label: Some("bcdec test"), source: wgpu::ShaderSource::Wgsl(shader().into()) });
    let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Storage { read_only }, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    };
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("bcdec test"), entries: &[storage(0, true), storage(1, false)] });
    let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor { label: Some("bcdec test"), bind_group_layouts: &[Some(&layout)], immediate_size: 0 });
    let make = |entry: &str| {
        device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: Some(&pl),
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        })
    };
    let (bc7, bc4) = (make("test_bc7"), make("test_bc4"));
    if let Some(e) = pollster::block_on(scope.pop()) {
        panic!("pipeline creation failed: {e}");
    }
    Ok(Gpu { device, queue, layout, bc7, bc4 })
}

/// The shared device, or None (with a note) where there is no adapter; on CI
/// a missing adapter is a failure.
fn gpu() -> Option<&'static Gpu> {
    static GPU: OnceLock<Result<Gpu, String>> = OnceLock::new();
    match GPU.get_or_init(open) {
        Ok(g) => Some(g),
        Err(e) => {
            assert!(std::env::var("CI").ok().as_deref() != Some("true"), "CI=true and no GPU adapter: {e}");
            eprintln!("note: skipping GPU test: {e}");
            None
        }
    }
}

impl Gpu {
    /// Decodes every texel of `blocks` (raw block bytes, back to back) with
    /// the entry point for `format`: 16 RGBA values per block.
    fn decode(&self, format: Format, blocks: &[u8]) -> Vec<[f32; 4]> {
        use wgpu::util::DeviceExt;
        let (pipeline, block_bytes) = if format == Format::Bc7 { (&self.bc7, 16) } else { (&self.bc4, 8) };
        assert_eq!(blocks.len() % block_bytes, 0);
        let texels = (blocks.len() / block_bytes * 16) as u64;
        let words: Vec<u32> = blocks.chunks_exact(4).map(|w| u32::from_le_bytes(w.try_into().unwrap())).collect();
        let input = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("blocks"), contents: bytemuck::cast_slice(&words), usage: wgpu::BufferUsages::STORAGE });
        let bytes = texels * 16;
        let out =
            self.device.create_buffer(&wgpu::BufferDescriptor { label: Some("texels"), size: bytes, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC, mapped_at_creation: false });
        let read =
            self.device.create_buffer(&wgpu::BufferDescriptor { label: Some("readback"), size: bytes, usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST, mapped_at_creation: false });
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bcdec test"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: input.as_entire_binding() }, wgpu::BindGroupEntry { binding: 1, resource: out.as_entire_binding() }],
        });
        let groups = u32::try_from(texels.div_ceil(64)).unwrap();
        assert!(groups <= self.device.limits().max_compute_workgroups_per_dimension, "too many blocks for one dispatch");
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("bcdec test") });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("bcdec test"), timestamp_writes: None });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(groups, 1, 1);
        }
        enc.copy_buffer_to_buffer(&out, 0, &read, 0, bytes);
        self.queue.submit([enc.finish()]);
        if let Some(e) = pollster::block_on(scope.pop()) {
            panic!("dispatch failed: {e}");
        }
        let (tx, rx) = std::sync::mpsc::channel();
        read.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device.poll(wgpu::PollType::wait_indefinitely()).expect("poll");
        rx.recv().expect("map callback").expect("map");
        let values: Vec<[f32; 4]> = {
            let view = read.slice(..).get_mapped_range().expect("mapped range");
            bytemuck::cast_slice(&view).to_vec()
        };
        read.unmap();
        values
    }
}

// ---------------------------------------------------------------------------
// Blocks

/// xorshift64*: deterministic test data.
/// A random 16-byte block.
fn block(rng: &mut Rng) -> u128 {
    u128::from(rng.next_u64()) | u128::from(rng.next_u64()) << 64
}

/// Replaces `width` bits of `block` at bit `at` with `value`.
fn set_bits(block: u128, at: u32, width: u32, value: u128) -> u128 {
    let mask = ((1u128 << width) - 1) << at;
    (block & !mask) | ((value << at) & mask)
}

/// BC7 subsets and partition field width of each mode.
const SUBSETS: [u32; 8] = [3, 2, 3, 2, 1, 1, 1, 2];
const PARTITION_BITS: [u32; 8] = [4, 6, 6, 6, 0, 0, 0, 6];

/// The header fields of a BC7 block, read independently of the shader:
/// (mode (8: invalid), partition, rotation, index selector).
fn bc7_header(block: u128) -> (usize, u32, u32, u32) {
    let mode = (block as u8).trailing_zeros().min(8) as usize;
    if mode == 8 {
        return (8, 0, 0, 0);
    }
    let at = mode as u32 + 1;
    let field = |at: u32, w: u32| ((block >> at) as u32) & ((1u32 << w) - 1);
    let partition = field(at, PARTITION_BITS[mode]);
    let (rotation, selector) = match mode {
        4 => (field(at, 2), field(at + 2, 1)),
        5 => (field(at, 2), 0),
        _ => (0, 0),
    };
    (mode, partition, rotation, selector)
}

/// Forces a random block into `mode`, spreading partition, rotation and
/// selector over all their values with the counter `k`.
fn force_mode(block: u128, mode: u32, k: u32) -> u128 {
    let mut b = set_bits(block, 0, mode + 1, 1 << mode);
    let at = mode + 1;
    match mode {
        0 => b = set_bits(b, at, 4, u128::from(k % 16)),
        1 | 2 | 3 | 7 => b = set_bits(b, at, 6, u128::from(k % 64)),
        4 => b = set_bits(set_bits(b, at, 2, u128::from(k % 4)), at + 2, 1, u128::from((k / 4) % 2)),
        5 => b = set_bits(b, at, 2, u128::from(k % 4)),
        _ => {}
    }
    b
}

/// Smooth, noisy, sparse and constant bricks.
fn bricks() -> Vec<[f32; BRICK_VOXELS]> {
    let mut rng = Rng::new(0x0dd_b1a5);
    let mut out = Vec::new();
    for k in 0..40 {
        let (fx, fy, fz) = (0.05 + 0.1 * (k % 5) as f32, 0.07 * (k % 3) as f32, 0.3 - 0.04 * (k % 7) as f32);
        let noise = [0.0, 0.02, 0.3, 1.0][k % 4];
        let brick: [f32; BRICK_VOXELS] = std::array::from_fn(|i| {
            let (x, y, z) = ((i / 64) as f32, ((i / 8) % 8) as f32, (i % 8) as f32);
            let smooth = (fx * x + fy * y + fz * z + k as f32).sin() + 0.1 * x * (k % 2) as f32;
            smooth * (1.0 - noise) + noise * rng.unit()
        });
        out.push(brick);
    }
    // Sparse: a small blob in an empty brick; constant; a single spike.
    out.push(std::array::from_fn(|i| {
        let (x, y, z) = ((i / 64) as f32 - 5.0, ((i / 8) % 8) as f32 - 2.0, (i % 8) as f32 - 3.0);
        (1.0 - (x * x + y * y + z * z) / 6.0).max(0.0)
    }));
    out.push([0.25; BRICK_VOXELS]);
    let mut spike = [0.0; BRICK_VOXELS];
    spike[300] = 1.0;
    out.push(spike);
    out
}

fn hex(block: &[u8]) -> String {
    block.iter().map(|b| format!("{b:02x}")).collect()
}

// ---------------------------------------------------------------------------
// BC7

#[test]
fn bc7_matches_bcdec_rs_bit_for_bit() {
    let Some(gpu) = gpu() else { return };
    let mut rng = Rng::new(0x9e37_79b9_7f4a_7c15);
    let mut blocks: Vec<u128> = Vec::new();
    // Fully random blocks: random first bytes give every mode (mostly low ones).
    for _ in 0..4000 {
        blocks.push(block(&mut rng));
    }
    // Every mode explicitly, with partitions, rotations and selectors spread.
    for mode in 0..8 {
        for k in 0..1280 {
            blocks.push(force_mode(block(&mut rng), mode, k));
        }
    }
    // Invalid: first byte zero; and extreme patterns.
    for _ in 0..200 {
        blocks.push(block(&mut rng) & !0xff);
    }
    blocks.extend([0, u128::MAX, u128::MAX << 8, 1, 0x80, !0x7f]);
    let random = blocks.len();
    let mut bytes: Vec<u8> = blocks.iter().flat_map(|b| b.to_le_bytes()).collect();

    // The real encoder, at every quality.
    let bricks = bricks();
    for b in &bricks {
        bytes.extend(encode_bricks(Format::Bc7, Quality::Fast, std::slice::from_ref(b)));
    }
    for q in Quality::ALL {
        bytes.extend(encode_bricks(Format::Bc7, q, &bricks));
    }
    let encoded = bytes.len() / 16 - random;

    let started = std::time::Instant::now();
    let gpu_texels = gpu.decode(Format::Bc7, &bytes);
    let gpu_time = started.elapsed();

    let mut blocks_per_mode = [0usize; 9];
    let mut encoder_modes = [0usize; 9];
    let mut partitions = [[0usize; 64]; 8];
    let mut rotations = [[0usize; 4]; 8];
    let mut selectors = [0usize; 2];
    let mut failures = Vec::new();
    for (n, block) in bytes.chunks_exact(16).enumerate() {
        let (mode, partition, rotation, selector) = bc7_header(u128::from_le_bytes(block.try_into().unwrap()));
        blocks_per_mode[mode] += 1;
        if n >= random {
            encoder_modes[mode] += 1;
        }
        if mode < 8 {
            partitions[mode][partition as usize] += 1;
            rotations[mode][rotation as usize] += 1;
            if mode == 4 {
                selectors[selector as usize] += 1;
            }
        }
        let mut want = [0u8; 64];
        bcdec_rs::bc7(block, &mut want, 16);
        for t in 0..16 {
            let got = gpu_texels[n * 16 + t];
            for c in 0..4 {
                let v = got[c] * 255.0;
                let w = want[t * 4 + c];
                // Bit-exact: the shader returns an 8-bit value / 255.
                if (v.round() as i64) != i64::from(w) || (v - v.round()).abs() > 1e-3 {
                    failures.push(format!("block {n} {} mode {mode} partition {partition} rotation {rotation} selector {selector} texel {t} channel {c}: gpu {v} bcdec {w}", hex(block)));
                }
            }
        }
    }
    eprintln!("bc7: {} blocks ({encoded} from the encoder), per mode {blocks_per_mode:?}, encoder modes {encoder_modes:?}, GPU decode {gpu_time:?}", bytes.len() / 16);
    assert!(failures.is_empty(), "{} texel channels differ, e.g.:\n{}", failures.len(), failures[..failures.len().min(20)].join("\n"));

    // Coverage: every mode, partition, rotation and selector value.
    for mode in 0..8 {
        assert!(blocks_per_mode[mode] >= 1000, "mode {mode}: only {} blocks", blocks_per_mode[mode]);
        let shapes = if SUBSETS[mode] == 1 { 1 } else { 1 << PARTITION_BITS[mode] };
        for (p, &count) in partitions[mode][..shapes].iter().enumerate() {
            assert!(count >= 16, "mode {mode} partition {p}: only {count} blocks");
        }
        if mode == 4 || mode == 5 {
            assert!(rotations[mode].iter().all(|&r| r >= 100), "mode {mode} rotations {:?}", rotations[mode]);
        }
    }
    assert!(selectors.iter().all(|&s| s >= 100), "mode 4 selectors {selectors:?}");
    assert!(blocks_per_mode[8] >= 100);
    assert!(encoded >= 1000 && encoder_modes.iter().filter(|&&m| m > 0).count() >= 2, "encoder modes {encoder_modes:?}");
}

#[test]
fn invalid_bc7_blocks_decode_to_transparent_black() {
    let Some(gpu) = gpu() else { return };
    let mut rng = Rng::new(7);
    let bytes: Vec<u8> = (0..64).flat_map(|_| (block(&mut rng) & !0xff).to_le_bytes()).collect();
    for (n, block) in bytes.chunks_exact(16).enumerate() {
        let mut want = [0xaau8; 64];
        bcdec_rs::bc7(block, &mut want, 16);
        assert_eq!(want, [0; 64], "bcdec_rs, block {n}");
    }
    assert!(gpu.decode(Format::Bc7, &bytes).iter().all(|t| *t == [0.0; 4]));
}

// ---------------------------------------------------------------------------
// BC4

#[test]
fn bc4_matches_bcdec_rs() {
    let Some(gpu) = gpu() else { return };
    let mut rng = Rng::new(0x5eed_bc40);
    let mut blocks: Vec<u64> = Vec::new();
    for k in 0..24_000u64 {
        let b = rng.next_u64();
        let (e0, e1) = (b & 0xff, (b >> 8) & 0xff);
        // Random, then both endpoint orders explicitly, then equal endpoints.
        blocks.push(match k % 4 {
            0 => b,
            1 => (b & !0xffff) | e0.max(e1) | e0.min(e1) << 8,
            2 => (b & !0xffff) | e0.min(e1) | e0.max(e1) << 8,
            _ if k % 40 == 3 => (b & !0xffff) | e0 | e0 << 8,
            _ => b,
        });
    }
    blocks.extend([0, u64::MAX, 0xff, 0xff00, 0xffff_ffff_ffff_00ff, 0xffff_ffff_ffff_ff00]);
    let random = blocks.len();
    let mut bytes: Vec<u8> = blocks.iter().flat_map(|b| b.to_le_bytes()).collect();
    for b in &bricks() {
        bytes.extend(encode_bricks(Format::Bc4, Quality::Fast, std::slice::from_ref(b)));
    }
    let encoded = bytes.len() / 8 - random;

    let started = std::time::Instant::now();
    let gpu_texels = gpu.decode(Format::Bc4, &bytes);
    let gpu_time = started.elapsed();

    let mut orders = [0usize; 3]; // e0 > e1, e0 < e1, e0 == e1
    let mut indices = [[0usize; 8]; 2];
    let mut worst = 0.0f32;
    let mut failures = Vec::new();
    for (n, block) in bytes.chunks_exact(8).enumerate() {
        let six = block[0] <= block[1];
        orders[usize::from(six) + usize::from(block[0] == block[1])] += 1;
        let bits = u64::from_le_bytes(block.try_into().unwrap()) >> 16;
        for t in 0..16 {
            indices[usize::from(six)][((bits >> (3 * t)) & 7) as usize] += 1;
        }
        let mut want = [0.0f32; 16];
        bcdec_rs::bc4_float(block, &mut want, 4, false);
        for t in 0..16 {
            let got = gpu_texels[n * 16 + t][0];
            let err = (got - want[t]).abs();
            worst = worst.max(err);
            if err.is_nan() || err > 1e-6 {
                failures.push(format!("block {n} {} texel {t}: gpu {got} bcdec {}", hex(block), want[t]));
            }
        }
    }
    eprintln!("bc4: {} blocks ({encoded} from the encoder), endpoint orders [>, <, =] {orders:?}, worst error {worst:e}, GPU decode {gpu_time:?}", bytes.len() / 8);
    assert!(failures.is_empty(), "{} texels differ, e.g.:\n{}", failures.len(), failures[..failures.len().min(20)].join("\n"));
    assert!(orders[0] >= 1000 && orders[1] >= 1000 && orders[2] >= 100, "endpoint orders {orders:?}");
    assert!(indices.iter().flatten().all(|&i| i >= 1000), "indices {indices:?}");
    assert!(encoded >= 1000);
}
