//! Denoising networks for EMCCD frames (burn 0.22), inference only: the architectures (U-Net,
//! Uformer), model files with their metadata and the record of how they were made, the
//! camera-independent input, tiled inference with self-ensembles on frames of any size, and a
//! network applied to a raw frame through its camera profile ([`Inference`]). Training is
//! `emccd-train`'s; the methods a user picks are `emccd-denoise`'s.
//!
//! Network code has no backend type: burn 0.22 tensors carry their backend in their `Device`,
//! which the caller chooses ([`device`]) and a [`Model`] keeps. The pure-Rust `flex` CPU
//! backend is the default feature; `vulkan`/`wgpu` add burn's wgpu GPU backend (no build-time
//! downloads).
//!
//! A bundled model run tiled over a frame larger than its tile:
//!
//! ```
//! use emccd_nn::tile::{run, Planes, Tiling};
//! let file = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/default-unet.safetensors");
//! let model = emccd_nn::Model::load(file.as_ref(), &emccd_nn::cpu())?;
//! // The network's input: the frame and its noise level, in the camera-independent units.
//! let frame: Vec<f32> = (0..2 * 96 * 80).map(|i| if i < 96 * 80 { 0.5 } else { 0.1 }).collect();
//! let planes = Planes { data: &frame, channels: 2, width: 96, height: 80 };
//! let tiling = Tiling { tile: 64, overlap: 16 };
//! let out = run(&model.net, planes, model.meta.multiple(), tiling, model.device());
//! assert_eq!(out.len(), 96 * 80);
//! assert!(out.iter().all(|v| v.is_finite()));
//! # Ok::<(), emccd_nn::Error>(())
//! ```

#![deny(missing_docs)]

mod error;
pub mod inference;
pub mod model;
pub mod norm;
pub mod recipe;
pub mod tile;
pub mod uformer;
pub mod unet;

pub use error::{Error, Result};
pub use inference::Inference;
pub use model::{Arch, Classical, Inputs, Model, ModelMeta, ModelSource, Net, MOVIE_WINDOW};
pub use norm::Scale;
pub use recipe::{Adaptation, Loss, TrainConfig};
pub use uformer::{Uformer, UformerConfig};
pub use unet::{UNet, UNetConfig};

use burn::prelude::Device;

/// The flex CPU backend.
pub fn cpu() -> Device {
    Device::flex()
}

/// The device networks run on: the flex CPU backend when `requested` says `flex` (what the CLI
/// and the Python package read from `BURN_DEVICE`), else the GPU when the binary was built with
/// a GPU backend (`--features vulkan` or `wgpu`) and a GPU answers, else the flex CPU backend.
/// (Which GPU API a GPU build opens is burn's `Device::default`, which reads `BURN_DEVICE`
/// itself; the choice is made once per process.)
///
/// A GPU build on a machine whose driver cannot be loaded (no Vulkan ICD, or NVIDIA's without
/// the glvnd libraries it links) would otherwise abort at the first tensor, from a thread of the
/// GPU runtime; it is tried once here and, failing, the run goes on on the CPU with a warning.
pub fn device(requested: Option<&str>) -> Device {
    #[cfg(any(feature = "vulkan", feature = "wgpu"))]
    {
        if requested == Some("flex") {
            return Device::flex();
        }
        static CHOSEN: std::sync::OnceLock<Device> = std::sync::OnceLock::new();
        CHOSEN
            .get_or_init(|| {
                let d = Device::default();
                if format!("{d:?}").contains("Flex") || answers(&d) {
                    d
                } else {
                    eprintln!(
                        "warning: this build runs networks on the GPU, but no GPU adapter could be \
                         opened (is the Vulkan driver installed?); running on the CPU instead"
                    );
                    Device::flex()
                }
            })
            .clone()
    }
    #[cfg(not(any(feature = "vulkan", feature = "wgpu")))]
    {
        if requested.is_some_and(|v| v != "flex") {
            eprintln!(
                "warning: a GPU device was requested (BURN_DEVICE) but this build has only the flex CPU backend"
            );
        }
        Device::flex()
    }
}

/// Whether a small computation on `device` comes back right. The GPU runtime reports a missing
/// adapter by panicking (in its own thread, then in this one): the panic is caught, and its
/// message kept off the terminal, since the caller falls back and says so in one line.
#[cfg(any(feature = "vulkan", feature = "wgpu"))]
fn answers(device: &Device) -> bool {
    use burn::tensor::Tensor;
    emccd_io::catch_quietly_everywhere(|| {
        Tensor::<1>::from_floats([1.0f32, 2.0], device)
            .sum()
            .into_data()
            .try_to_vec::<f32>()
            .is_ok_and(|v| v == [3.0])
    })
    .unwrap_or(false)
}

/// A short name of `device`'s backend, for reports.
pub fn device_name(device: &Device) -> String {
    let d = format!("{device:?}");
    if d.contains("Flex") {
        // A U-Net runs its own forward pass there (`unet::CpuUNet`), other networks burn's.
        "the CPU (U-Nets by their gemm forward pass, others by burn's flex backend)".into()
    } else if d.contains("Wgpu") {
        "wgpu GPU backend".into()
    } else {
        d.chars().take(60).collect()
    }
}
