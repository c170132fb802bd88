//! The EMCCD forward models: the noise models that synthesize training pairs and the virtual camera
//! that simulates a whole acquisition with a known truth. (Blooming and the preprocessing that
//! undoes it and the fixed pattern live beside the profile: `emccd_profile::preprocess`.)
//!
//! - [`noise`]: the [`NoiseModel`] trait and its three implementations — [`OursModel`] (paper
//!   eq. 5), [`EldModel`] (Wei et al. 2021's CMOS model) and [`PgnModel`] (Poisson–Gamma–Normal,
//!   Ryan et al. 2021) — each with closed-form moments that the tests check samples against.
//! - [`acquisition`]: a calibration acquisition (dark, flat and blooming stacks) designed for the
//!   virtual camera, and its truth.
//! - [`virtual_camera`]: the full eq. 1 with the physical EM register (Poisson → Gamma), clock-
//!   induced charge, dark current and hot pixels, exposure-dependent FPN, per-pixel read noise,
//!   blooming and a 16-bit ADC.
//!
//! Randomness is drawn from per-row PCG streams derived from one seed, so every frame is
//! reproducible whatever the number of threads.
//!
//! A noisy/clean test pair from the virtual camera, at 20 photons at the scene's peak:
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use emccd_camera::{PhysicalParams, VirtualCamera};
//! let profile = emccd_profile::default_profile().crop(emccd_profile::Roi::corner(32, 32))?;
//! let cam = VirtualCamera::new(profile, PhysicalParams::default())?;
//! let scene: Vec<f32> = (0..32 * 32).map(|i| (i % 32) as f32 / 31.0).collect();
//! let pair = cam.test_pair(&scene, 20.0, 0.01, 7);
//! let mut raw = vec![0f32; 32 * 32];
//! pair.frame(0, &mut raw); // raw DN, as the camera records them
//! assert!(raw.iter().all(|v| v.fract() == 0.0)); // the ADC's integers
//! assert!(pair.truth[31] > pair.truth[0]); // the photo-signal, DN above bias
//! # Ok(())
//! # }
//! ```

#![deny(missing_docs)]

pub mod acquisition;
pub mod noise;
pub mod rng;
pub mod virtual_camera;

pub use noise::{
    Ablation, EldModel, Moments, NoiseModel, NoiseModelKind, OursModel, PgnModel, SceneNoise,
};
pub use virtual_camera::{Exposure, PhysicalParams, VirtualCamera};

/// Errors from building a model with invalid parameters, or from writing what the camera
/// recorded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A parameter is outside its valid range.
    #[error("{0}")]
    Parameter(String),
    /// A recording could not be written.
    #[error(transparent)]
    Write(#[from] emccd_io::Error),
    /// The truth profile could not be written.
    #[error("writing the truth profile: {0}")]
    Truth(#[source] emccd_profile::Error),
}
