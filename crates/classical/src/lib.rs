//! Classical denoising of EMCCD frames, no training involved: BM3D ([`bm3d`], written here: no
//! maintained crate implements the two-stage filter), the generalized Anscombe transform and
//! its exact unbiased inverse with iterative BM3D ([`vst`]), both applied to a camera frame
//! through its calibrated profile ([`frame`]: preprocessing, the profile's noise, the estimate a
//! hybrid network refines), and a movie frame estimated from the frames around it
//! ([`temporal`]: blocks tracked along the motion, averaged, and denoised at a mean's noise;
//! its neighbours moved to a fraction of a pixel by [`resample`], Keys' cubic kernel, which
//! the training movies' motion uses too, so that the mean's noise is coarser than white and
//! BM3D is told its [`noise::Covariance`]).
//!
//! A flat frame with Poisson–Gaussian noise, stabilized, denoised and brought back unbiased:
//!
//! ```
//! use emccd_classical::vst::{bm3d_poisson_gaussian, PoissonGaussian};
//! let p = PoissonGaussian { alpha: 2.0, mu: 0.0, sigma: 3.0 };
//! // A fixed, zero-mean ±2σ-ish pattern on a flat 40 DN.
//! let noisy: Vec<f32> = (0..64 * 64).map(|i| 40.0 + [-9.0, 9.0, -3.0, 3.0][(i * 7) % 4]).collect();
//! let d = bm3d_poisson_gaussian(&noisy, 64, 64, p);
//! let mean = d.iter().map(|&v| v as f64).sum::<f64>() / d.len() as f64;
//! assert!((mean - 40.0).abs() < 1.0, "the mean stays: {mean}");
//! ```

#![deny(missing_docs)]

pub mod bm3d;
pub mod frame;
pub mod noise;
pub mod resample;
pub mod temporal;
pub mod vst;

pub use frame::Classical;

/// Why a frame cannot be denoised through a profile (an incomplete profile, a frame of another
/// size, an exposure that is not a positive number of seconds), in words.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Error(pub String);

impl From<emccd_profile::Error> for Error {
    fn from(e: emccd_profile::Error) -> Error {
        Error(e.to_string())
    }
}

/// This crate's results.
pub type Result<T> = std::result::Result<T, Error>;
