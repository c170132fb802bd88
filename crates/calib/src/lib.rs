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

#![deny(missing_docs)]

pub mod blooming;
mod error;
pub mod fit;
pub mod fpn;
pub mod gain_series;
pub mod manifest;
pub mod normality;
pub mod ptc;
pub mod report;
pub mod stats;
mod summary;

mod calibrate;

pub use calibrate::{calibrate, total_frames, BiasLevel, Calibration, Options};
pub use error::{Error, Result};
pub use manifest::Manifest;
pub use stats::{Progress, Silent};
