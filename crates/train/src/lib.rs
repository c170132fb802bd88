//! Training EMCCD denoising networks: pairs synthesized on the fly from clean images with the
//! camera model's exact noise chain ([`train`]), the training loop with checkpoints that resume
//! and validation on held-out images, and adaptation of a model to a user's own recording
//! without clean data ([`adapt`], with the frames a recording gives in [`recorded`]).
//!
//! The networks, their files and their inference are `emccd-nn`'s; this crate adds autodiff
//! and the optimizer. The device a run trains on is the caller's choice ([`Run::new`]).

#![deny(missing_docs)]

pub mod adapt;
mod crops;
pub mod recorded;
pub mod train;

pub use adapt::{adapt, AdaptConfig, AdaptData, AdaptRun};
pub use recorded::{AdaptMethod, FrameMean, FrameSet};
pub use train::{meta_for_run, train, Run, RunPaths, StepReport, TrainImages};
