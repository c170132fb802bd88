//! Camera calibration (paper §3.2 and appendix A): from a camera's bias, flat-field, blooming
//! and (optionally) gain-series stacks to a [`CameraProfile`] and the numbers a report shows.
//!
//! Order matters and follows the physics: bias stacks give the fixed pattern `FPN_t` and the
//! read-noise maps; the FPN fit then predicts the pattern at any exposure, which the blooming
//! frames need subtracted; the blooming factor in turn corrects the flat fields' signal
//! (`B⁻¹`) before the median–variance regression. Any subset works: what is missing is
//! reported, not invented.
//!
//! Written here (no maintained crate does these): the streaming statistics, the fits and the
//! gain-series likelihood. FFTs come from `realfft`, plots from `plotters`.
//!
//! Dark stacks at four exposures, written with `emccd-io` and calibrated: the read noise comes
//! back (frames of a 5 DN Gaussian around a 500 DN bias).
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use rand::SeedableRng;
//! use rand_distr::{Distribution, Normal};
//! let dir = tempfile::tempdir()?;
//! let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
//! let noise = Normal::new(500.0f32, 5.0)?;
//! let mut manifest = String::from("camera = \"example\"\nem_gain = 300\n");
//! for (i, t) in [0.001, 0.01, 0.1, 1.0].into_iter().enumerate() {
//!     let file = format!("bias{i}.tif");
//!     let mut w = emccd_io::StackWriter::create(
//!         dir.path().join(&file), 32, 32, emccd_io::SampleFormat::F32, Some(16))?;
//!     for _ in 0..16 {
//!         let frame: Vec<f32> = (0..32 * 32).map(|_| noise.sample(&mut rng)).collect();
//!         w.write_frame(&frame)?;
//!     }
//!     w.finish()?;
//!     manifest += &format!("[[bias]]\nfile = \"{file}\"\nexposure_s = {t}\n");
//! }
//! let path = dir.path().join("calibration.toml");
//! let m = emccd_calib::Manifest::parse(&manifest, &path)?;
//! let cal = emccd_calib::calibrate(&m, &Default::default(), &emccd_calib::Silent)?;
//! let rn = cal.bias[0].read_noise_rms_dn;
//! assert!((rn / 5.0 - 1.0).abs() < 0.05, "read noise {rn} DN");
//! print!("{}", cal.summary()); // what `emccd calibrate` prints
//! # Ok(())
//! # }
//! ```

#![deny(missing_docs)]

pub mod blooming;
mod error;
pub mod fit;
pub mod fpn;
pub mod gain_series;
/// The calibration manifest (its home is `emccd_profile::manifest`, which the acquisition that
/// writes it shares).
pub use emccd_profile::manifest;
pub mod normality;
pub mod ptc;
pub mod read_noise;
pub mod recording;
pub mod report;
pub mod spurious;
pub mod stats;
mod summary;

mod calibrate;

pub use calibrate::{calibrate, total_frames, BiasLevel, Calibration, Options};
pub use error::{Error, Result};
pub use manifest::Manifest;
pub use stats::{Progress, Silent};
