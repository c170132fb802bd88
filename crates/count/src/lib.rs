//! Photon counting: below a few tenths of a photo-electron per pixel per frame, an EMCCD frame's
//! pixel holds zero or one electron almost always, and thresholding it into "event" or "no
//! event" removes the EM register's excess noise (its factor √2 in SNR) at the price of the
//! electrons the threshold misses and of coincidences. From a calibrated profile each pixel
//! gets its threshold (k times its read noise, or a fixed DN), and the events counted over N
//! frames give the photo-electron rate by inverting the exact probability of an event at that
//! threshold ([`model::PixelModel`]: the register's gamma output and the pixel's read noise,
//! coincidences, clock-induced charge and dark current), with its first-order small-sample
//! bias removed and a standard error per pixel. [`Threshold::Auto`] takes the `k` that makes
//! that error smallest at the stack's own light level.
//!
//! A pixel of read noise 3 DN behind a register of 10 DN per electron, at a 3σ threshold:
//!
//! ```
//! use emccd_count::model::PixelModel;
//! let m = PixelModel::new(9.0, 10.0, 3.0, 0.005);
//! // One electron alone clears 9 DN about e^(−0.9) of the time.
//! assert!((1.0 - m.missed() - (-0.9f64).exp()).abs() < 0.02);
//! // 40 events in 1000 frames.
//! let (rate, se) = m.estimate(40, 1000);
//! assert!(rate > 0.05 && rate < 0.15 && se < 0.03, "{rate} ± {se}");
//! ```

#![deny(missing_docs)]

pub mod likelihood;
pub mod model;
pub mod plan;
pub mod stack;
pub mod tally;

pub use model::PixelModel;
pub use plan::{choose_k, Camera, Plan, ReadNoise, Threshold};
pub use stack::{count_stack, Counted, Request, LEVEL_FRAMES};
pub use tally::{
    check_level, count_outputs, light_level, preprocessed_frames, Counter, Preprocessed, Tally,
};

/// Why a stack cannot be counted, in words.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Error(pub String);

/// Counting's result type.
pub type Result<T> = std::result::Result<T, Error>;
