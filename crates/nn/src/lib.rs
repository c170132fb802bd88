//! Denoising networks for EMCCD frames (burn 0.22): the architectures, the camera-independent
//! input, tiled inference on frames of any size, model files with metadata, and training on
//! pairs synthesized on the fly from the camera model.
//!
//! Network code has no backend type: burn 0.22 tensors carry their backend in their `Device`.
//! The pure-Rust `flex` CPU backend is the default feature; `vulkan`/`wgpu` add burn's wgpu
//! GPU backend (no build-time downloads), picked by [`device`] when present.
//!
//! A frame from the virtual camera denoised as `emccd evaluate --method bm3d` does it, through
//! the profile it was recorded with ([`registry::Estimator`]; a bundled network is named the
//! same way, e.g. `lowlight` or `lowlight@8`):
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use emccd_camera::{PhysicalParams, VirtualCamera};
//! use emccd_nn::registry::{self, Estimator};
//! let profile = emccd_profile::default_profile().crop(emccd_profile::Roi::corner(64, 64))?;
//! let cam = VirtualCamera::new(profile.clone(), PhysicalParams::default())?;
//! let scene: Vec<f32> = (0..64 * 64).map(|i| if (i / 64) % 16 < 8 { 1.0 } else { 0.2 }).collect();
//! let pair = cam.test_pair(&scene, 200.0, 0.01, 1);
//! let mut raw = vec![0f32; 64 * 64];
//! pair.frame(0, &mut raw);
//! let peak = pair.truth.iter().copied().fold(0f32, f32::max) as f64;
//! let input = Estimator::parse("input", registry::load)?.run(&profile, &raw, 0.01)?;
//! let bm3d = Estimator::parse("bm3d", registry::load)?.run(&profile, &raw, 0.01)?;
//! let gain = emccd_eval::psnr(&bm3d, &pair.truth, peak) - emccd_eval::psnr(&input, &pair.truth, peak);
//! assert!(gain > 3.0, "BM3D gains {gain:.1} dB");
//! # Ok(())
//! # }
//! ```

#![deny(missing_docs)]

pub mod adapt;
pub mod bench;
mod error;
pub mod model;
pub mod norm;
pub mod pipeline;
pub mod registry;
pub mod stack;
pub mod tile;
pub mod train;
pub mod uformer;
pub mod unet;

pub use error::{Error, Result};
pub use model::{Arch, Base, Denoiser, Inputs, ModelMeta, Net};
pub use norm::Scale;
pub use registry::{FrameDenoiser, Method, Units};
pub use uformer::{Uformer, UformerConfig};
pub use unet::{UNet, UNetConfig};

use burn::prelude::Device;

/// The flex CPU backend.
pub fn cpu() -> Device {
    Device::flex()
}

/// The device inference and training run on: the GPU when the binary was built with a GPU
/// backend (`--features vulkan` or `wgpu`) and a GPU answers, else the flex CPU backend.
/// `BURN_DEVICE=flex` (or `vulkan`, `wgpu`) overrides the choice at run time.
///
/// A GPU build on a machine whose driver cannot be loaded (no Vulkan ICD, or NVIDIA's without
/// the glvnd libraries it links) would otherwise abort at the first tensor, from a thread of the
/// GPU runtime; it is tried once here and, failing, the run goes on on the CPU with a warning.
pub fn device() -> Device {
    #[cfg(any(feature = "vulkan", feature = "wgpu"))]
    {
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
        if std::env::var("BURN_DEVICE").is_ok_and(|v| v != "flex") {
            eprintln!("warning: BURN_DEVICE is set but this build has only the flex CPU backend");
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
        "flex CPU backend".into()
    } else if d.contains("Wgpu") {
        "wgpu GPU backend".into()
    } else {
        d.chars().take(60).collect()
    }
}
