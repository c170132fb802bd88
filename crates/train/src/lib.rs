//! Training EMCCD denoising networks: pairs synthesized on the fly from clean images with the
//! camera model's exact noise chain ([`train()`]), the training loop with checkpoints that resume
//! and validation on held-out images, and adaptation of a model to a user's own recording
//! without clean data ([`adapt()`], with the frames a recording gives in [`recorded`]).
//!
//! The networks, their files and their inference are `emccd-nn`'s; this crate adds autodiff
//! and the optimizer. The device a run trains on is the caller's choice ([`Run::new`]).
//!
//! Three steps of a small U-Net on pairs synthesized from one clean image through the bundled
//! camera profile, written as a model file:
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use emccd_nn::{Arch, Inputs, TrainConfig, UNetConfig};
//! use emccd_train::{meta_for_run, train, Image, Run, RunPaths, TrainImages};
//! let dir = tempfile::tempdir()?;
//! let profile = emccd_profile::default_profile().crop(emccd_profile::Roi::corner(64, 64))?;
//! let image = |k: usize| Image {
//!     width: 48,
//!     height: 48,
//!     data: (0..48 * 48).map(|i| ((i % 48 + k) % 12) as f32 / 12.0).collect(),
//! };
//! let images = TrainImages { train: vec![image(0)], val: vec![image(5)] };
//! let cfg = TrainConfig { steps: 3, batch: 2, crop: 32, ..TrainConfig::default() };
//! let unet = UNetConfig { channels: 4, levels: 2, ..UNetConfig::DEFAULT };
//! let arch = Arch::for_training("unet", Inputs::Noisy, unet)?;
//! let meta = meta_for_run(arch, Inputs::Noisy, &cfg, &profile, &images);
//! let paths = RunPaths::beside(&dir.path().join("model.safetensors"));
//! let model = train(images, Run::new(&profile, cfg, meta, &paths, &emccd_nn::cpu()), &mut |_| true)?;
//! assert_eq!(model.meta.steps, 3);
//! assert!(paths.out.is_file());
//! # Ok(())
//! # }
//! ```

#![deny(missing_docs)]

pub mod adapt;
mod crops;
pub mod motion;
pub mod recorded;
pub mod train;

pub use adapt::{adapt, AdaptConfig, AdaptData, AdaptRun};
pub use recorded::{AdaptMethod, FrameMean, FrameSet};
pub use train::{meta_for_run, train, Image, Run, RunPaths, StepReport, TrainImages};
