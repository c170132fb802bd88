//! The benchmarks `emccd bench` runs: they time the libraries (and, for the archive benchmark,
//! this binary in child processes), so they live with the binary, not in the libraries.

pub mod bsd68;
pub mod calib;
pub mod camera;
pub mod characterize;
pub mod count;
pub mod denoise;
pub mod movie;
