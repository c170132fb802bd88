//! Denoising networks for EMCCD frames (burn 0.22): the architectures, the camera-independent
//! input, tiled inference on frames of any size, model files with metadata, and training on
//! pairs synthesized on the fly from the camera model.
//!
//! Network code has no backend type: burn 0.22 tensors carry their backend in their `Device`.
//! The pure-Rust `flex` CPU backend is the default feature; `vulkan`/`wgpu` add burn's wgpu
//! GPU backend (no build-time downloads), picked by [`device`] when present.

#![deny(missing_docs)]

mod error;
pub mod model;
pub mod norm;
pub mod pipeline;
pub mod tile;
pub mod train;
pub mod uformer;
pub mod unet;

pub use error::{Error, Result};
pub use model::{Base, Denoiser, Inputs, ModelMeta, Net};
pub use uformer::{Uformer, UformerConfig};
pub use unet::{UNet, UNetConfig};

use burn::prelude::Device;

/// The flex CPU backend.
pub fn cpu() -> Device {
    Device::flex()
}

/// The device inference and training run on: the GPU when the binary was built with a GPU
/// backend (`--features vulkan` or `wgpu`), else the flex CPU backend. `BURN_DEVICE=flex`
/// (or `vulkan`, `wgpu`) overrides the choice at run time.
pub fn device() -> Device {
    #[cfg(any(feature = "vulkan", feature = "wgpu"))]
    {
        Device::default()
    }
    #[cfg(not(any(feature = "vulkan", feature = "wgpu")))]
    {
        if std::env::var("BURN_DEVICE").is_ok_and(|v| v != "flex") {
            eprintln!("warning: BURN_DEVICE is set but this build has only the flex CPU backend");
        }
        Device::flex()
    }
}

/// A short name of `device`'s backend, for reports.
pub fn device_name(device: &Device) -> String {
    let d = format!("{device:?}");
    if d.contains("Flex") {
        "flex CPU backend".into()
    } else if d.contains("Wgpu") {
        "wgpu GPU backend".into()
    } else {
        d.chars().take(60).collect()
    }
}
