//! The wgpu side: device, pipeline, asset upload, one dispatch per image.

use crate::{AssetData, Error, Image, Model, Scene, View};
use vdbcook_vpak::{Asset, GpuChannel, GPU_CHANNEL_WORDS};
use wgpu::util::DeviceExt;

macro_rules! shader {
    ($($file:literal),*) => {
        concat!($(include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shaders/", $file)), "\n"),*)
    };
}

/// The renderer with brick atlases as textures, and with BC4/BC7 atlases as
/// storage buffers decoded in the shader.
const TEXTURE_SHADER: &str = shader!("vpak.wgsl", "vpak_atlas_texture.wgsl", "march.wgsl");
const BUFFER_SHADER: &str = shader!("vpak.wgsl", "bcdec.wgsl", "vpak_atlas_buffer.wgsl", "march.wgsl");

/// The WGSL sources of the renderer: atlases as textures, and BC atlases decoded in the shader.
pub fn shader_sources() -> [&'static str; 2] {
    [TEXTURE_SHADER, BUFFER_SHADER]
}

/// Where BC4/BC7 bricks are decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BcDecode {
    /// The texture unit of a GPU that can sample BC 3D textures; the shader on
    /// other adapters and on CPU drivers (whose "texture unit" is software, and
    /// several times slower than the shader for BC7).
    #[default]
    Auto,
    /// Block-compressed 3D textures, decoded by the texture unit.
    Texture,
    /// Storage buffers of raw blocks, decoded by `shaders/bcdec.wgsl`.
    Shader,
}

/// What an adapter offers for BC bricks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BcSupport {
    /// TEXTURE_COMPRESSION_BC and TEXTURE_COMPRESSION_BC_SLICED_3D.
    pub textures: bool,
    /// The adapter is a CPU driver (lavapipe, SwiftShader, WARP).
    pub cpu: bool,
}

impl BcDecode {
    /// Whether bricks are decoded in the shader, for a block-compressed format
    /// or not, when the atlases fit the adapter's storage buffers or not;
    /// `None` when the texture unit is asked for and cannot do it.
    pub fn in_shader(self, block_compressed: bool, adapter: BcSupport, fits_buffers: bool) -> Option<bool> {
        if !block_compressed {
            return Some(false);
        }
        match self {
            BcDecode::Auto => Some(!adapter.textures || (adapter.cpu && fits_buffers)),
            BcDecode::Shader => Some(true),
            BcDecode::Texture => adapter.textures.then_some(false),
        }
    }
}

/// Bindings of texture slots 0 to 7 (`vpak_atlas_texture.wgsl`, `vpak_atlas_buffer.wgsl`).
const SLOT_BINDINGS: [u32; crate::MAX_TEXTURES] = [8, 11, 12, 13, 15, 16, 17, 18];
/// Bindings of the channel table and the brick tables (`vpak.wgsl`).
const CHANNEL_BINDING: u32 = 14;
/// Records of the channel table's uniform array (`VPAK_CHANNEL_RECORDS`): one per channel and per alternate plane.
const CHANNEL_RECORDS: usize = 2 * vdbcook_vpak::MAX_CHANNELS;
const TABLE_BINDING: u32 = 19;
/// Storage buffers of the asset, in the order `GpuAsset::buffers` holds them.
const BUFFER_BINDINGS: [u32; 9] = [1, 2, 3, 4, 5, 6, 7, CHANNEL_BINDING, TABLE_BINDING];

/// A pipeline's entry point and override constants: several textures,
/// emission, the shown channels' known slots, the format every plane sampled
/// has (`NONE` when they differ), brick tables or none, the backdrop. The
/// surface model has an entry point of its own.
type PipelineKey = (&'static str, bool, bool, [u32; 3], u32, bool, bool);

/// The bind group layout and the pipelines of one shader, each made on first
/// use for its entry point and the override constants that fold branches
/// away: several textures or one, emission channels or none, the shown
/// channels' slots, one format for every plane sampled, brick tables or none.
struct Pipelines {
    layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    pipeline_layout: wgpu::PipelineLayout,
    /// Each key's pipeline, made once: the map is locked only to find a key's
    /// cell, so one thread can make a pipeline while another renders with a
    /// pipeline made before (see [`Renderer::prepare`]).
    made: std::sync::Mutex<std::collections::HashMap<PipelineKey, std::sync::Arc<std::sync::OnceLock<wgpu::ComputePipeline>>>>,
}

impl Pipelines {
    fn new(device: &wgpu::Device, source: &str, atlas: wgpu::BindingType) -> Pipelines {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor { label: Some("march"), source: wgpu::ShaderSource::Wgsl(source.into()) });
        let entry = |binding: u32, ty: wgpu::BindingType| wgpu::BindGroupLayoutEntry { binding, visibility: wgpu::ShaderStages::COMPUTE, ty, count: None };
        let mut entries = vec![entry(0, wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None })];
        entries.extend(BUFFER_BINDINGS.map(|b| entry(b, if b == CHANNEL_BINDING { uniform() } else { storage(true) })));
        entries.extend(SLOT_BINDINGS.map(|b| entry(b, atlas)));
        entries.extend([9, 10].map(|b| entry(b, storage(false))));
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("vpak"), entries: &entries });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor { label: Some("march"), bind_group_layouts: &[Some(&layout)], immediate_size: 0 });
        Pipelines { layout, module, pipeline_layout, made: Default::default() }
    }

    /// The pipeline of `key`: `entry` for several textures (`multi`) or one,
    /// with emission (`glows`) or without, with the shown channels' texture
    /// slots where known (`slots`, `NONE` where not), the format of every
    /// plane sampled when they share one (`format`, else `NONE`), whether any
    /// plane has a brick table (`tables`), with the backdrop or not.
    fn get(&self, device: &wgpu::Device, key: PipelineKey) -> wgpu::ComputePipeline {
        let (entry, multi, glows, slots, format, tables, backdrop) = key;
        let cell = self.made.lock().unwrap_or_else(|e| e.into_inner()).entry(key).or_default().clone();
        cell.get_or_init(|| {
            let flag = |b: bool| if b { 1.0 } else { 0.0 };
            let [x, y, z] = slots.map(f64::from);
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&self.pipeline_layout),
                module: &self.module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &[
                        ("VPAK_MULTI_ATLAS", flag(multi)),
                        ("GLOWS", flag(glows)),
                        ("SLOT_X", x),
                        ("SLOT_Y", y),
                        ("SLOT_Z", z),
                        ("VPAK_FORMAT", f64::from(format)),
                        ("VPAK_TABLES", flag(tables)),
                        ("BACKDROP", flag(backdrop)),
                    ],
                    ..Default::default()
                },
                cache: None,
            })
        })
        .clone()
    }
}

/// A device with the ray-marching pipelines.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    /// Atlases as textures (every format).
    textures: Pipelines,
    /// BC atlases as storage buffers, made on first use.
    buffers: std::sync::OnceLock<Pipelines>,
    bc: BcSupport,
    decode: BcDecode,
    /// TEXTURE_FORMAT_16BIT_NORM (unorm16 atlases as textures; else decoded in the shader).
    norm16: bool,
    /// "name (backend, device type)".
    pub adapter: String,
}

/// A brick atlas on the GPU (a texture is kept alive with its view).
enum Atlas {
    Texture { _texture: wgpu::Texture, view: wgpu::TextureView },
    Buffer(wgpu::Buffer),
}

/// An asset uploaded for rendering.
pub struct GpuAsset {
    /// The node arrays, brick ranges, channel table and brick tables, in `BUFFER_BINDINGS` order.
    buffers: Vec<wgpu::Buffer>,
    /// Texture slots 0 to 7 (unused ones hold a small empty texture or buffer).
    atlases: Vec<Atlas>,
    /// Every tree, as the frames section lists them (`Metadata::tree_index`).
    frames: Vec<u32>,
    /// The frames' and levels' layout (`Metadata::tree_index`, `missing_level`).
    meta: vdbcook_vpak::Metadata,
    /// Texture slots in use (the atlases of the planes bound).
    slots: usize,
    /// Per channel, whether its plane's atlases are bound.
    bound: Vec<bool>,
    /// Per channel, its texture slot when its plane is bound and has a single atlas, else `NONE`.
    single_slot: Vec<u32>,
    /// Per channel, its plane's format code when it has one plane (no per-brick formats), else `NONE`.
    single_format: Vec<u32>,
    /// Whether any plane has a brick table.
    tables: bool,
    channels: u32,
    /// Each channel's background.
    backgrounds: Vec<f32>,
}

impl GpuAsset {
    /// True when BC bricks are decoded by the shader rather than the texture unit.
    pub fn decodes_in_shader(&self) -> bool {
        matches!(self.atlases.first(), Some(Atlas::Buffer(_)))
    }

    /// The bytes this asset holds on the GPU: its buffers and atlases (the
    /// empty ones filling unused slots included), as allocated.
    pub fn resident_bytes(&self) -> u64 {
        let atlas = |a: &Atlas| match a {
            Atlas::Texture { _texture: t, .. } => t.format().theoretical_memory_footprint(t.size()),
            Atlas::Buffer(b) => b.size(),
        };
        self.buffers.iter().map(wgpu::Buffer::size).sum::<u64>() + self.atlases.iter().map(atlas).sum::<u64>()
    }

    /// The format code every one of `channels` (`NONE` ones aside) has in its
    /// single plane, or `NONE` when they differ or one has per-brick formats.
    fn common_format(&self, channels: &[u32]) -> u32 {
        let mut formats = channels.iter().filter(|&&c| c != crate::NONE).map(|&c| self.single_format.get(c as usize).copied().unwrap_or(crate::NONE));
        let first = formats.next().unwrap_or(crate::NONE);
        if formats.all(|f| f == first) {
            first
        } else {
            crate::NONE
        }
    }
}

/// The texture format of a plane: its format and lanes.
fn texture_format(p: &vdbcook_vpak::Plane) -> wgpu::TextureFormat {
    use vdbcook_vpak::Format;
    use wgpu::TextureFormat as T;
    match (p.format, p.lanes) {
        (Format::F32, 1) => T::R32Float,
        (Format::F32, 2) => T::Rg32Float,
        (Format::F32, _) => T::Rgba32Float,
        (Format::F16, 1) => T::R16Float,
        (Format::F16, 2) => T::Rg16Float,
        (Format::F16, _) => T::Rgba16Float,
        (Format::Unorm8, 1) => T::R8Unorm,
        (Format::Unorm8, 2) => T::Rg8Unorm,
        (Format::Unorm8, _) => T::Rgba8Unorm,
        (Format::Unorm16, 1) => T::R16Unorm,
        (Format::Unorm16, 2) => T::Rg16Unorm,
        (Format::Unorm16, _) => T::Rgba16Unorm,
        (Format::Bc4, _) => T::Bc4RUnorm,
        (Format::Bc7, _) => T::Bc7RgbaUnorm,
        // Constant planes have no atlases.
        (Format::Constant, _) => T::R8Unorm,
    }
}

/// The keys of the march's pipeline for `asset` in `scene`, and of the shadow
/// grid's (only scattered light reads it).
fn pipeline_keys(asset: &GpuAsset, scene: &Scene) -> (PipelineKey, Option<PipelineKey>) {
    let multi = asset.slots > 1;
    let glows = scene.channels[1] != crate::NONE || scene.channels[2] != crate::NONE;
    let known = scene.channels.map(|c| asset.single_slot.get(c as usize).copied().unwrap_or(crate::NONE));
    let format = asset.common_format(&scene.channels);
    let backdrop = scene.has_backdrop();
    let shadow = (scene.model() == Model::Scatter).then_some(("shadow_main", multi, false, [crate::NONE; 3], format, asset.tables, false));
    let entry = if scene.model() == Model::Surface { "surface_main" } else { "main" };
    ((entry, multi, glows, known, format, asset.tables, backdrop), shadow)
}

fn uniform() -> wgpu::BindingType {
    wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None }
}

fn storage(kind: bool) -> wgpu::BindingType {
    wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Storage { read_only: kind }, has_dynamic_offset: false, min_binding_size: None }
}

/// An adapter's device and queue, opened with the features and limits the
/// renderer uses where the adapter has them ([`open_gpu`]).
pub struct Gpu {
    pub adapter: wgpu::AdapterInfo,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
}

/// BC textures and their 3D (sliced) use: only both together let BC atlases be textures.
const BC_3D: wgpu::Features = wgpu::Features::TEXTURE_COMPRESSION_BC.union(wgpu::Features::TEXTURE_COMPRESSION_BC_SLICED_3D);

/// The features the renderer uses when a device has them: BC 3D textures and 16-bit norm textures.
pub fn wanted_features() -> wgpu::Features {
    BC_3D | wgpu::Features::TEXTURE_FORMAT_16BIT_NORM
}

/// Opens an adapter, the first whose name contains `filter` (case-insensitive)
/// or else the default one, and a device on it with the adapter's limits and
/// whichever of [`wanted_features`] it has.
pub fn open_gpu(filter: Option<&str>) -> Result<Gpu, Error> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    open_device(&open_adapter(&instance, filter, None)?)
}

/// The adapter of `instance` [`open_gpu`] would choose; with `surface`, only
/// one that can present to it (a window's surface, made on the same instance).
pub fn open_adapter(instance: &wgpu::Instance, filter: Option<&str>, surface: Option<&wgpu::Surface<'_>>) -> Result<wgpu::Adapter, Error> {
    match filter {
        Some(f) => {
            let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
            let names: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
            let f_low = f.to_lowercase();
            adapters.into_iter().find(|a| a.get_info().name.to_lowercase().contains(&f_low) && surface.is_none_or(|s| a.is_surface_supported(s))).ok_or_else(|| {
                Error::NoAdapter(format!(
                    " matching \"{f}\"{} (adapters: {})",
                    if surface.is_some() { " that can draw to the window" } else { "" },
                    if names.is_empty() { "none".to_string() } else { names.join(", ") }
                ))
            })
        }
        None => pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            ..Default::default()
        }))
        .map_err(|e| Error::NoAdapter(format!(" ({e})"))),
    }
}

/// A device on `adapter` with the adapter's limits and whichever of [`wanted_features`] it has.
pub fn open_device(adapter: &wgpu::Adapter) -> Result<Gpu, Error> {
    let mut features = adapter.features() & wanted_features();
    if !features.contains(BC_3D) {
        features.remove(BC_3D);
    }
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("vdbcook"),
        required_features: features,
        required_limits: adapter.limits(),
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }))
    .map_err(|e| Error::Device(e.to_string()))?;
    Ok(Gpu { adapter: adapter.get_info(), device, queue })
}

impl Renderer {
    /// Opens a device with [`open_gpu`] and renders on it.
    pub fn new(filter: Option<&str>) -> Result<Renderer, Error> {
        Ok(Renderer::from_device(open_gpu(filter)?))
    }

    /// Renders on the caller's device and queue (each a handle: clones share
    /// them). BC atlases are sampled as textures when the device has BC 3D
    /// textures enabled, unorm16 atlases when it has 16-bit norm textures.
    pub fn from_device(gpu: Gpu) -> Renderer {
        let Gpu { adapter: info, device, queue } = gpu;
        let adapter_name = format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type);
        let features = device.features();
        let bc = BcSupport { textures: features.contains(BC_3D), cpu: info.device_type == wgpu::DeviceType::Cpu };
        let norm16 = features.contains(wgpu::Features::TEXTURE_FORMAT_16BIT_NORM);
        let textures = Pipelines::new(
            &device,
            TEXTURE_SHADER,
            wgpu::BindingType::Texture { sample_type: wgpu::TextureSampleType::Float { filterable: false }, view_dimension: wgpu::TextureViewDimension::D3, multisampled: false },
        );
        Renderer { device, queue, textures, buffers: std::sync::OnceLock::new(), bc, decode: BcDecode::Auto, norm16, adapter: adapter_name }
    }

    /// Chooses where BC4/BC7 bricks of assets uploaded from now on are decoded.
    pub fn with_bc_decode(mut self, decode: BcDecode) -> Renderer {
        self.decode = decode;
        self
    }

    fn buffer_pipelines(&self) -> &Pipelines {
        self.buffers.get_or_init(|| Pipelines::new(&self.device, BUFFER_SHADER, storage(true)))
    }

    /// Whether BC4/BC7 3D textures can be sampled.
    pub fn has_bc(&self) -> bool {
        self.bc.textures
    }

    /// Uploads an asset's node arrays, brick ranges and atlases, binding the
    /// planes of the channels its own scene ([`Scene::for_asset`]) shows.
    pub fn upload(&self, asset: &Asset) -> Result<GpuAsset, Error> {
        self.upload_scene(asset, None)
    }

    /// [`Renderer::upload`], binding the planes of the channels `scene` shows
    /// (a scene of this asset, or of one with the same channels).
    pub fn upload_for(&self, asset: &Asset, scene: &Scene) -> Result<GpuAsset, Error> {
        self.upload_scene(asset, Some(scene))
    }

    fn upload_scene(&self, asset: &Asset, scene: Option<&Scene>) -> Result<GpuAsset, Error> {
        let d = AssetData::new(asset)?;
        let scene = scene.copied().unwrap_or_else(|| Scene::for_asset(d.meta()));
        let limits = self.device.limits();
        let limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        // Out-of-memory and validation errors of the uploads come back here
        // instead of reaching wgpu's default handler (which panics).
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let uploaded = self.upload_in_scope(&d, &scene, limit);
        let errors = [pollster::block_on(scope.pop()), pollster::block_on(oom.pop())];
        if let Some(e) = errors.into_iter().flatten().next() {
            return Err(Error::Gpu(e.to_string()));
        }
        uploaded
    }

    fn upload_in_scope(&self, d: &AssetData, scene: &Scene, limit: u64) -> Result<GpuAsset, Error> {
        let buffer = |what: &'static str, data: &[u8]| -> Result<wgpu::Buffer, Error> {
            if data.len() as u64 > limit {
                return Err(Error::TooLarge { what, bytes: data.len() as u64, limit });
            }
            // Bindings may not be empty and are whole 16-byte units (atlases decoded in
            // the shader are read as vec4<u32>): pad when needed.
            let contents: std::borrow::Cow<[u8]> = if data.len() >= 16 && data.len().is_multiple_of(16) {
                data.into()
            } else {
                let mut v = data.to_vec();
                v.resize(v.len().max(16).next_multiple_of(16), 0);
                v.into()
            };
            Ok(self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(what), contents: &contents, usage: wgpu::BufferUsages::STORAGE }))
        };
        let c = &d.c;
        let meta = &c.meta;
        // Bind the atlases of the planes holding the channels the scene shows
        // (an asset may have more planes than a shader can bind), and point
        // those channels at their slots.
        let mut planes: Vec<usize> = scene.channels.iter().filter(|&&ch| ch != crate::NONE).flat_map(|&ch| meta.channel_planes(ch as usize)).map(|p| p as usize).collect();
        planes.sort_unstable();
        planes.dedup();
        let mut slot_of_plane = vec![u32::MAX; meta.planes.len()];
        let mut sections = Vec::new();
        for &p in &planes {
            slot_of_plane[p] = sections.len() as u32;
            sections.extend((0..meta.planes[p].atlases.len()).map(|a| (p, a)));
        }
        if sections.len() > crate::MAX_TEXTURES {
            return Err(Error::Textures { planes: planes.len(), textures: sections.len() });
        }
        let channels = c.gpu_channels();
        let bound: Vec<bool> = channels.iter().map(|g| slot_of_plane[g.plane as usize] != u32::MAX).collect();
        // A channel in several planes (per-brick formats) changes slots from brick to brick.
        let single_slot: Vec<u32> =
            channels.iter().map(|g| if meta.planes[g.plane as usize].atlases.len() == 1 && g.alternates == u32::MAX { slot_of_plane[g.plane as usize] } else { crate::NONE }).collect();
        let single_format: Vec<u32> = channels.iter().map(|g| if g.alternates == u32::MAX { g.format } else { crate::NONE }).collect();
        let mut channel_words: Vec<u32> = channels.iter().flat_map(|g| GpuChannel { slot: slot_of_plane[g.plane as usize], ..*g }.words()).collect();
        // The channel table is a uniform array of CHANNEL_RECORDS records (`vpak.wgsl`).
        if channel_words.len() > CHANNEL_RECORDS * GPU_CHANNEL_WORDS {
            return Err(Error::Corrupt(format!("{} channel records (at most {CHANNEL_RECORDS})", channels.len())));
        }
        channel_words.resize(CHANNEL_RECORDS * GPU_CHANNEL_WORDS, 0);
        let (ranges, tables) = (c.gpu_ranges(), c.gpu_tables());
        let mut buffers = Vec::new();
        for (what, data) in [
            ("l1 nodes", bytemuck::cast_slice::<u32, u8>(c.l1)),
            ("l1 entries", bytemuck::cast_slice(c.l1_entries)),
            ("l2 nodes", bytemuck::cast_slice(c.l2)),
            ("l2 entries", bytemuck::cast_slice(c.l2_entries)),
            ("l3 nodes", bytemuck::cast_slice(c.l3)),
            ("tiles", bytemuck::cast_slice(c.tiles)),
            ("brick ranges", bytemuck::cast_slice(&ranges)),
            ("channel table", bytemuck::cast_slice(&channel_words)),
            ("brick tables", bytemuck::cast_slice(&tables)),
        ] {
            buffers.push(match what {
                "channel table" => self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(what), contents: data, usage: wgpu::BufferUsages::UNIFORM }),
                _ => buffer(what, data)?,
            });
        }
        let slots: Vec<(vdbcook_vpak::AtlasLayout, &[u8])> = sections.iter().filter_map(|&(p, a)| c.atlas(p, a)).collect();
        let block = slots.iter().any(|(l, _)| l.plane.format.is_block());
        let fits_buffers = slots.iter().all(|(_, a)| a.len() as u64 <= limit);
        // Without 16-bit normalised textures, unorm16 atlases are decoded in the shader.
        let no_norm16 = !self.norm16 && slots.iter().any(|(l, _)| l.plane.format == vdbcook_vpak::Format::Unorm16);
        let in_shader = match no_norm16 {
            true => (self.decode != BcDecode::Texture).then_some(true),
            false => self.decode.in_shader(block, self.bc, fits_buffers),
        }
        .ok_or_else(|| match no_norm16 {
            true => Error::Unsupported { adapter: self.adapter.clone(), format: "unorm16".into(), feature: "TEXTURE_FORMAT_16BIT_NORM (decode them in the shader instead)" },
            false => Error::Unsupported {
                adapter: self.adapter.clone(),
                format: slots.iter().filter(|(l, _)| l.plane.format.is_block()).map(|(l, _)| l.plane.format.name()).collect::<Vec<_>>().join("+"),
                feature: "TEXTURE_COMPRESSION_BC and TEXTURE_COMPRESSION_BC_SLICED_3D (decode them in the shader instead)",
            },
        })?;
        let mut atlases = Vec::with_capacity(crate::MAX_TEXTURES);
        if in_shader {
            // Every slot is bound; unused ones get a small empty buffer.
            for slot in 0..crate::MAX_TEXTURES {
                atlases.push(Atlas::Buffer(buffer("brick atlas (decoded in the shader; cook with a smaller --max-texture-dim)", slots.get(slot).map_or(&[], |(_, b)| b))?));
            }
        } else {
            let max_dim = self.device.limits().max_texture_dimension_3d;
            if let Some((l, _)) = slots.iter().find(|(l, _)| l.texels().iter().any(|&t| t > max_dim)) {
                return Err(Error::Texture { size: l.texels(), limit: max_dim });
            }
            for slot in 0..crate::MAX_TEXTURES {
                // Unused slots get a small empty R8 texture.
                let (size, data, format) = match slots.get(slot) {
                    Some((l, bytes)) => (l.texels(), *bytes, texture_format(&l.plane)),
                    None => ([8, 8, 8], &[][..], wgpu::TextureFormat::R8Unorm),
                };
                let texture = self.device.create_texture(&wgpu::TextureDescriptor {
                    label: Some("atlas"),
                    size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: size[2] },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D3,
                    format,
                    usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                    view_formats: &[],
                });
                if let (Some((l, _)), false) = (slots.get(slot), data.is_empty()) {
                    self.queue.write_texture(
                        wgpu::TexelCopyTextureInfo { texture: &texture, mip_level: 0, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
                        data,
                        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(l.row_bytes() as u32), rows_per_image: Some(l.rows() as u32) },
                        wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: size[2] },
                    );
                }
                let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
                atlases.push(Atlas::Texture { _texture: texture, view });
            }
        }
        Ok(GpuAsset {
            buffers,
            atlases,
            frames: c.frames.to_vec(),
            meta: c.meta.clone(),
            slots: slots.len(),
            bound,
            single_slot,
            single_format,
            tables: !tables.is_empty(),
            channels: meta.channels.len() as u32,
            backgrounds: meta.channels.iter().map(|ch| ch.background).collect(),
        })
    }

    /// Makes the pipelines that rendering `asset` in `scene` needs (what the
    /// first render would otherwise make): called on another thread while
    /// this one renders, the driver's shader compilation overlaps the render.
    pub fn prepare(&self, asset: &GpuAsset, scene: &Scene) {
        let pipelines = if asset.decodes_in_shader() { self.buffer_pipelines() } else { &self.textures };
        let (march, shadow) = pipeline_keys(asset, scene);
        let keys: Vec<PipelineKey> = std::iter::once(march).chain(shadow).collect();
        // Error scopes are the thread's own: a pipeline that fails here is
        // forgotten, so the render makes it again and reports why.
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        for &key in &keys {
            pipelines.get(&self.device, key);
        }
        if pollster::block_on(scope.pop()).is_some() {
            let mut made = pipelines.made.lock().unwrap_or_else(|e| e.into_inner());
            for key in &keys {
                made.remove(key);
            }
        }
    }

    /// Renders frame `frame` of `asset` from `view`.
    pub fn render(&self, asset: &GpuAsset, scene: &Scene, frame: usize, view: &View, width: u32, height: u32) -> Result<Image, Error> {
        let mut v = self.render_views(asset, scene, frame, std::slice::from_ref(view), width, height)?;
        v.pop().ok_or_else(|| Error::Gpu("no image".into()))
    }

    fn params(&self, asset: &GpuAsset, scene: &Scene, (l1, level): (u32, u32), view: &View, width: u32, height: u32) -> wgpu::Buffer {
        let view = view.moved(scene.shift);
        let (r, u, f) = view.basis();
        let tf = (view.fov_deg.to_radians() * 0.5).tan();
        let mut p: Vec<u32> = Vec::with_capacity(56);
        p.extend([l1, asset.channels, level, 0]);
        let v4 = |p: &mut Vec<u32>, v: [f32; 3], w: f32| p.extend([v[0].to_bits(), v[1].to_bits(), v[2].to_bits(), w.to_bits()]);
        v4(&mut p, view.eye, 0.0);
        v4(&mut p, r, 0.0);
        v4(&mut p, u, 0.0);
        v4(&mut p, f, tf);
        v4(&mut p, scene.box_min, scene.step);
        v4(&mut p, scene.box_max, scene.shadow_step);
        v4(&mut p, scene.light, scene.density_scale);
        // Skipping empty space is exact only when empty space is zero (a
        // fog) or positive (outside a level set's surface).
        let bg = asset.backgrounds.get(scene.channels[0] as usize).copied();
        let skip = bg.is_some_and(|b| if scene.model() == Model::Surface { b > 0.0 } else { b == 0.0 });
        p.extend([width, height, scene.max_steps, u32::from(skip)]);
        v4(&mut p, scene.shadow_grid().map(|g| g as f32), scene.shadow_cell);
        p.extend(scene.channels);
        p.push(scene.model().code());
        let [t, f, e, albedo] = scene.emission;
        v4(&mut p, [t, f, e], albedo);
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("params"), contents: bytemuck::cast_slice(&p), usage: wgpu::BufferUsages::UNIFORM })
    }

    /// Renders frame `frame` of `asset` from every view: the shadow grid is
    /// computed once, then one dispatch per view, all in one submission.
    pub fn render_views(&self, asset: &GpuAsset, scene: &Scene, frame: usize, views: &[View], width: u32, height: u32) -> Result<Vec<Image>, Error> {
        self.render_views_level(asset, scene, frame, asset.meta.first_level, views, width, height)
    }

    /// [`Renderer::render_views`] of level of detail `level` of the frame: each
    /// sample reads the level's voxel that covers it (nearest voxel, as at level 0).
    #[allow(clippy::too_many_arguments)]
    pub fn render_views_level(&self, asset: &GpuAsset, scene: &Scene, frame: usize, level: u32, views: &[View], width: u32, height: u32) -> Result<Vec<Image>, Error> {
        if let Some(why) = asset.meta.missing_level(level) {
            return Err(Error::Level(why));
        }
        let level = scene.drawn_level(&asset.meta, level);
        let l1 = *asset.meta.tree_index(frame, level).and_then(|t| asset.frames.get(t)).ok_or(Error::Frame { frame, count: asset.meta.frame_count as usize })?;
        if let Some(&c) = scene.channels.iter().find(|&&c| c != crate::NONE && !asset.bound.get(c as usize).copied().unwrap_or(false)) {
            return Err(Error::NotUploaded(c));
        }
        let [gx, gy, gz] = scene.shadow_grid();
        let cells = u64::from(gx) * u64::from(gy) * u64::from(gz);
        let shadow = self.device.create_buffer(&wgpu::BufferDescriptor { label: Some("shadow"), size: cells * 4, usage: wgpu::BufferUsages::STORAGE, mapped_at_creation: false });
        let bytes = u64::from(width) * u64::from(height) * 12;
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let pipelines = if asset.decodes_in_shader() { self.buffer_pipelines() } else { &self.textures };
        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("march") });
        let mut reads = Vec::with_capacity(views.len());
        for (i, view) in views.iter().enumerate() {
            let params = self.params(asset, scene, (l1, level), view, width, height);
            let out =
                self.device.create_buffer(&wgpu::BufferDescriptor { label: Some("image"), size: bytes, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC, mapped_at_creation: false });
            let read = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut entries = vec![wgpu::BindGroupEntry { binding: 0, resource: params.as_entire_binding() }];
            for (&b, buf) in BUFFER_BINDINGS.iter().zip(&asset.buffers) {
                entries.push(wgpu::BindGroupEntry { binding: b, resource: buf.as_entire_binding() });
            }
            for (k, atlas) in asset.atlases.iter().enumerate() {
                let resource = match atlas {
                    Atlas::Texture { view, .. } => wgpu::BindingResource::TextureView(view),
                    Atlas::Buffer(b) => b.as_entire_binding(),
                };
                entries.push(wgpu::BindGroupEntry { binding: SLOT_BINDINGS[k], resource });
            }
            entries.push(wgpu::BindGroupEntry { binding: 9, resource: out.as_entire_binding() });
            entries.push(wgpu::BindGroupEntry { binding: 10, resource: shadow.as_entire_binding() });
            let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some("vpak"), layout: &pipelines.layout, entries: &entries });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("march"), timestamp_writes: None });
                pass.set_bind_group(0, &group, &[]);
                let (march_key, shadow_key) = pipeline_keys(asset, scene);
                let march = pipelines.get(&self.device, march_key);
                if let (0, Some(key)) = (i, shadow_key) {
                    let shadow_pipeline = pipelines.get(&self.device, key);
                    pass.set_pipeline(&shadow_pipeline);
                    pass.dispatch_workgroups(u32::try_from(cells.div_ceil(64)).map_err(|_| Error::Gpu("shadow grid too large".into()))?, 1, 1);
                }
                pass.set_pipeline(&march);
                pass.dispatch_workgroups(width.div_ceil(8), height.div_ceil(8), 1);
            }
            enc.copy_buffer_to_buffer(&out, 0, &read, 0, bytes);
            reads.push(read);
        }
        self.queue.submit([enc.finish()]);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Gpu(e.to_string()));
        }
        let (tx, rx) = std::sync::mpsc::channel();
        for (i, read) in reads.iter().enumerate() {
            let tx = tx.clone();
            read.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx.send((i, r));
            });
        }
        drop(tx);
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| Error::Gpu(e.to_string()))?;
        for (_, r) in rx.iter() {
            r.map_err(|e| Error::Gpu(e.to_string()))?;
        }
        let mut images = Vec::with_capacity(reads.len());
        for read in &reads {
            let pixels: Vec<f32> = {
                let view = read.slice(..).get_mapped_range().map_err(|e| Error::Gpu(e.to_string()))?;
                bytemuck::cast_slice(&view).to_vec()
            };
            read.unmap();
            images.push(Image { width, height, pixels });
        }
        Ok(images)
    }
}

#[cfg(test)]
mod tests {
    use super::{BcDecode, BcSupport};

    #[test]
    fn bc_decode_falls_back_to_the_shader_only_where_it_must() {
        let gpu = BcSupport { textures: true, cpu: false };
        let no_bc = BcSupport { textures: false, cpu: false };
        let cpu = BcSupport { textures: true, cpu: true };
        // Uncompressed formats always use textures.
        for d in [BcDecode::Auto, BcDecode::Texture, BcDecode::Shader] {
            for a in [gpu, no_bc, cpu] {
                assert_eq!(d.in_shader(false, a, true), Some(false));
            }
        }
        assert_eq!(BcDecode::Auto.in_shader(true, gpu, true), Some(false));
        assert_eq!(BcDecode::Auto.in_shader(true, no_bc, true), Some(true));
        assert_eq!(BcDecode::Auto.in_shader(true, cpu, true), Some(true));
        // A CPU driver keeps the texture unit for atlases too large for a buffer.
        assert_eq!(BcDecode::Auto.in_shader(true, cpu, false), Some(false));
        // Without BC textures the shader is the only way (too large fails later).
        assert_eq!(BcDecode::Auto.in_shader(true, no_bc, false), Some(true));
        assert_eq!(BcDecode::Shader.in_shader(true, gpu, true), Some(true));
        assert_eq!(BcDecode::Texture.in_shader(true, gpu, true), Some(false));
        assert_eq!(BcDecode::Texture.in_shader(true, cpu, true), Some(false));
        assert_eq!(BcDecode::Texture.in_shader(true, no_bc, true), None);
    }
}
