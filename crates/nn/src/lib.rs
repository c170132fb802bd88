//! Denoising networks for EMCCD frames (burn 0.22): the architectures, the camera-independent
//! input, tiled inference on frames of any size, model files with metadata, and training on
//! pairs synthesized on the fly from the camera model.
//!
//! Network code has no backend type: burn 0.22 tensors carry their backend in their `Device`.
//! The pure-Rust `flex` CPU backend is the default feature.

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
pub use model::{Denoiser, ModelMeta, Net};
pub use uformer::{Uformer, UformerConfig};
pub use unet::{UNet, UNetConfig};

use burn::prelude::Device;

/// The device inference and training run on: the flex CPU backend.
pub fn cpu() -> Device {
    Device::flex()
}
