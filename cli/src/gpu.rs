//! The GPU flags of `validate`, `render`, `view` and `bake`.

use anyhow::Result;
use vdbcook_validate::{BcDecode, Gpu, Renderer};

/// The GPU options of `validate`, `render` and `view`.
#[derive(clap::Args, Clone, Default)]
pub struct GpuArgs {
    /// Use the first GPU adapter whose name contains NAME (e.g. "llvmpipe").
    #[arg(long, value_name = "NAME")]
    pub adapter: Option<String>,
    /// Where BC4/BC7 bricks are decoded: the GPU's texture unit, the shader (raw blocks
    /// decoded in WGSL), or auto: the texture unit of a GPU with BC 3D textures, the
    /// shader on other adapters and on CPU drivers (faster there).
    #[arg(long, value_name = "WHERE", value_enum, default_value_t = BcDecodeArg::Auto)]
    pub bc_decode: BcDecodeArg,
}

#[derive(clap::ValueEnum, Clone, Copy, Default)]
pub enum BcDecodeArg {
    #[default]
    Auto,
    Texture,
    Shader,
}

impl GpuArgs {
    pub fn renderer(&self) -> Result<Renderer> {
        Ok(Renderer::new(self.adapter.as_deref())?.with_bc_decode(self.decode()))
    }

    /// A renderer on a device the caller opened (`view`: one that can present to its window).
    pub fn renderer_on(&self, gpu: Gpu) -> Renderer {
        Renderer::from_device(gpu).with_bc_decode(self.decode())
    }

    fn decode(&self) -> BcDecode {
        match self.bc_decode {
            BcDecodeArg::Auto => BcDecode::Auto,
            BcDecodeArg::Texture => BcDecode::Texture,
            BcDecodeArg::Shader => BcDecode::Shader,
        }
    }
}
