//! The window's surface: the renderer's device opened on an adapter that can
//! present to it, and each rendered image copied into the surface texture.
//!
//! The march renders into a buffer that is read back (as `render` does), then
//! encoded to 8-bit sRGB with the HUD drawn in and written into the surface
//! texture by a copy: no render pipeline of its own, and the window shows the
//! bytes `render` writes to its PNG. On a CPU driver (lavapipe) the readback is
//! a memory copy next to the march's cost.

use anyhow::{anyhow, bail, Result};
use std::sync::Arc;
use vdbcook_validate::wgpu;
use vdbcook_validate::{Image, Renderer};
use winit::window::Window;

pub struct Screen {
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    /// The surface's bytes are B, G, R, A (else R, G, B, A).
    bgra: bool,
}

impl Screen {
    /// A surface on `window` and a renderer on a device that presents to it.
    pub fn new(window: Arc<Window>, gpu: &crate::gpu::GpuArgs) -> Result<(Screen, Renderer)> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let size = window.inner_size();
        let surface = instance.create_surface(window).map_err(|e| anyhow!("cannot draw to the window: {e}"))?;
        let adapter = vdbcook_validate::open_adapter(&instance, gpu.adapter.as_deref(), Some(&surface))?;
        let caps = surface.get_capabilities(&adapter);
        if !caps.usages.contains(wgpu::TextureUsages::COPY_DST) {
            bail!("the adapter \"{}\" cannot copy images into the window's surface", adapter.get_info().name);
        }
        // The bytes go in by a copy, untouched: an sRGB surface format and its
        // plain twin show the same picture.
        use wgpu::TextureFormat as F;
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| matches!(f, F::Bgra8Unorm | F::Bgra8UnormSrgb | F::Rgba8Unorm | F::Rgba8UnormSrgb))
            .ok_or_else(|| anyhow!("the window's surface offers no 8-bit RGBA format (it offers {:?})", caps.formats))?;
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::COPY_DST,
            format,
            color_space: Default::default(),
            width: size.width.max(1),
            height: size.height.max(1),
            present_mode: wgpu::PresentMode::AutoVsync,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps.alpha_modes.first().copied().unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: Vec::new(),
        };
        let opened = vdbcook_validate::open_device(&adapter)?;
        let (device, queue) = (opened.device.clone(), opened.queue.clone());
        surface.configure(&device, &config);
        let screen = Screen { surface, device, queue, config, bgra: matches!(format, F::Bgra8Unorm | F::Bgra8UnormSrgb) };
        Ok((screen, gpu.renderer_on(opened)))
    }

    /// The surface's size in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.config.width, self.config.height)
    }

    /// Follows the window to its new size (a zero side, a minimised window, is ignored).
    pub fn resize(&mut self, width: u32, height: u32) {
        if width > 0 && height > 0 && (width, height) != self.size() {
            self.config.width = width;
            self.config.height = height;
            self.surface.configure(&self.device, &self.config);
        }
    }

    /// Shows `img` (of the surface's size) with `hud` drawn over its top left.
    /// False when the surface had no texture to give (the caller draws again later).
    pub fn show(&mut self, img: &Image, hud: &[String]) -> Result<bool> {
        let (w, h) = (img.width as usize, img.height as usize);
        if (img.width, img.height) != self.size() {
            return Ok(false);
        }
        let rgb = vdbcook_validate::flip::srgb8(img);
        let mut bytes = vec![255u8; w * h * 4];
        for (px, c) in bytes.chunks_exact_mut(4).zip(rgb.chunks_exact(3)) {
            px[..3].copy_from_slice(c);
        }
        super::hud::draw(&mut bytes, (w, h), w * 4, hud);
        if self.bgra {
            bytes.chunks_exact_mut(4).for_each(|px| px.swap(0, 2));
        }
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&self.device, &self.config);
                return Ok(false);
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => return Ok(false),
            wgpu::CurrentSurfaceTexture::Validation => bail!("the window's surface refused a frame"),
        };
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo { texture: &frame.texture, mip_level: 0, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
            &bytes,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * img.width), rows_per_image: Some(img.height) },
            wgpu::Extent3d { width: img.width, height: img.height, depth_or_array_layers: 1 },
        );
        // The write is queued: a submission carries it before the texture is shown.
        self.queue.submit([]);
        self.queue.present(frame);
        Ok(true)
    }
}
