//! Denoising EMCCD recordings, the product's front door: the methods a user picks
//! ([`Method`]), the bundled models ([`bundled`]), a request resolved to its method and model
//! ([`resolve`]), [`Denoiser`], which turns one raw frame into calibrated output, the methods
//! `evaluate` compares ([`Estimator`]), and whole stacks written to TIFF, FITS or OME-Zarr with
//! their provenance ([`stack`]). The CLI and the Python package call this crate; the classical
//! estimates are `emccd-classical`'s and the networks `emccd-nn`'s.
//!
//! A frame from the virtual camera denoised as `emccd evaluate --method bm3d` does it, through
//! the profile it was recorded with (a bundled network is named the same way, e.g. `lowlight`
//! or `lowlight@8`):
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use emccd_camera::{PhysicalParams, VirtualCamera};
//! use emccd_denoise::Estimator;
//! let device = emccd_nn::cpu();
//! let load = |name: &str| emccd_denoise::bundled::load(name, &device);
//! let profile = emccd_profile::default_profile().crop(emccd_profile::Roi::corner(64, 64))?;
//! let cam = VirtualCamera::new(profile.clone(), PhysicalParams::default())?;
//! let scene: Vec<f32> = (0..64 * 64).map(|i| if (i / 64) % 16 < 8 { 1.0 } else { 0.2 }).collect();
//! let pair = cam.test_pair(&scene, 200.0, 0.01, 1);
//! let mut raw = vec![0f32; 64 * 64];
//! pair.frame(0, &mut raw);
//! let peak = pair.truth.iter().copied().fold(0f32, f32::max) as f64;
//! let input = Estimator::parse("input", load)?.run(&profile, &raw, 0.01)?;
//! let bm3d = Estimator::parse("bm3d", load)?.run(&profile, &raw, 0.01)?;
//! let gain = emccd_eval::psnr(&bm3d, &pair.truth, peak) - emccd_eval::psnr(&input, &pair.truth, peak);
//! assert!(gain > 3.0, "BM3D gains {gain:.1} dB");
//! # Ok(())
//! # }
//! ```

#![deny(missing_docs)]

pub mod bundled;
pub mod denoiser;
pub mod estimator;
pub mod method;
pub mod movie;
pub mod stack;

pub use denoiser::{profile_mismatch, resolve, Denoiser, Resolved, DEFAULT_WINDOW, MAX_WINDOW};
pub use emccd_nn::{Error, Result};
pub use estimator::Estimator;
pub use method::{
    check_ensemble, ensemble_size, Method, ModelSpec, Units, DEFAULT_METHOD, DEFAULT_MOVIE_METHOD,
};
