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

#![deny(missing_docs)]

pub mod acquisition;
pub mod noise;
pub mod rng;
pub mod virtual_camera;

pub use noise::{Ablation, EldModel, Moments, NoiseModel, NoiseModelKind, OursModel, PgnModel};
pub use virtual_camera::{Exposure, PhysicalParams, VirtualCamera};

/// Errors from building a model with invalid parameters.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A parameter is outside its valid range.
    #[error("{0}")]
    Parameter(String),
}
