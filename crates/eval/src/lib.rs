//! Scoring any denoiser: image-quality metrics, the noisy/clean test pairs and their manifest,
//! and evaluation tables over methods, cameras and light levels (the denoisers are the
//! caller's: this crate runs none of its own). The metrics agree with the reference
//! implementations users compare against: PSNR with an explicit data range, and SSIM as in Wang
//! et al. (2004) with a Gaussian window, matching scikit-image's `structural_similarity(
//! gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=R)` (tested against
//! values it computed).
//!
//! ```
//! let truth: Vec<f32> = (0..64 * 64).map(|i| ((i % 64) * 4) as f32).collect();
//! let noisy: Vec<f32> = truth.iter().enumerate().map(|(i, v)| v + [-8.0, 8.0][i % 2]).collect();
//! // PSNR with the truth's peak as data range: 20·log10(252 / 8)
//! let p = emccd_eval::psnr(&noisy, &truth, 252.0);
//! assert!((p - 20.0 * (252f64 / 8.0).log10()).abs() < 1e-9);
//! let s = emccd_eval::ssim(&noisy, &truth, 64, 64, 252.0, Default::default());
//! assert!(s > 0.0 && s < 1.0); // structure kept, noise not
//! ```

#![deny(missing_docs)]

pub mod evaluation;
pub mod pairs;
pub mod scores;
pub mod virtual_pairs;

pub use pairs::{Pair, PairFrames, PairsManifest};
pub use scores::{LevelUnit, Score, Summaries, Summary};

use rayon::prelude::*;

/// What went wrong reading a pairs folder, writing one, or evaluating on it: the file and the
/// cause, in words (the causes of lower layers are joined into the message).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Error(pub String);

impl From<String> for Error {
    fn from(s: String) -> Error {
        Error(s)
    }
}

impl From<&str> for Error {
    fn from(s: &str) -> Error {
        Error(s.to_string())
    }
}

/// This crate's results.
pub type Result<T> = std::result::Result<T, Error>;

/// Mean squared difference of two images of one size.
pub fn mse(test: &[f32], reference: &[f32]) -> f64 {
    assert_eq!(test.len(), reference.len(), "images differ in size");
    test.iter()
        .zip(reference)
        .map(|(a, b)| (*a as f64 - *b as f64).powi(2))
        .sum::<f64>()
        / test.len().max(1) as f64
}

/// Peak signal-to-noise ratio in dB for data range `r`: `10·log10(r² / MSE)`.
pub fn psnr(test: &[f32], reference: &[f32], r: f64) -> f64 {
    10.0 * (r * r / mse(test, reference).max(1e-300)).log10()
}

/// SSIM constants and window.
#[derive(Clone, Copy, Debug)]
pub struct SsimParams {
    /// Gaussian σ of the window, px.
    pub sigma: f64,
    /// Window half-width in σ (scikit-image/scipy `truncate`).
    pub truncate: f64,
    /// K1.
    pub k1: f64,
    /// K2.
    pub k2: f64,
}

impl Default for SsimParams {
    fn default() -> SsimParams {
        SsimParams {
            sigma: 1.5,
            truncate: 3.5,
            k1: 0.01,
            k2: 0.03,
        }
    }
}

/// Mirror index (scipy's `reflect`: d c b a | a b c d | d c b a).
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    let mut i = i;
    loop {
        if i < 0 {
            i = -i - 1;
        } else if i >= n {
            i = 2 * n - i - 1;
        } else {
            return i as usize;
        }
    }
}

/// Separable Gaussian filter of a row-major image.
fn gaussian(img: &[f64], w: usize, h: usize, k: &[f64]) -> Vec<f64> {
    let r = (k.len() / 2) as isize;
    let mut tmp = vec![0f64; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            *o = k
                .iter()
                .enumerate()
                .map(|(j, kv)| kv * img[y * w + reflect(x as isize + j as isize - r, w)])
                .sum();
        }
    });
    let mut out = vec![0f64; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            *o = k
                .iter()
                .enumerate()
                .map(|(j, kv)| kv * tmp[reflect(y as isize + j as isize - r, h) * w + x])
                .sum();
        }
    });
    out
}

/// Mean SSIM of `test` against `reference` (`w × h`, row-major) with data range `r`, averaged over
/// the pixels at least one window radius from the border.
pub fn ssim(test: &[f32], reference: &[f32], w: usize, h: usize, r: f64, p: SsimParams) -> f64 {
    assert_eq!(test.len(), w * h, "test image size");
    assert_eq!(reference.len(), w * h, "reference image size");
    let rad = (p.truncate * p.sigma + 0.5) as usize;
    let mut k: Vec<f64> = (0..=2 * rad)
        .map(|i| (-((i as f64 - rad as f64).powi(2)) / (2.0 * p.sigma * p.sigma)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    let x: Vec<f64> = test.iter().map(|&v| v as f64).collect();
    let y: Vec<f64> = reference.iter().map(|&v| v as f64).collect();
    let prod = |a: &[f64], b: &[f64]| -> Vec<f64> { a.iter().zip(b).map(|(p, q)| p * q).collect() };
    let (ux, uy) = (gaussian(&x, w, h, &k), gaussian(&y, w, h, &k));
    let uxx = gaussian(&prod(&x, &x), w, h, &k);
    let uyy = gaussian(&prod(&y, &y), w, h, &k);
    let uxy = gaussian(&prod(&x, &y), w, h, &k);
    let (c1, c2) = ((p.k1 * r).powi(2), (p.k2 * r).powi(2));
    let (mut sum, mut n) = (0.0, 0usize);
    for yy in rad..h.saturating_sub(rad) {
        for xx in rad..w.saturating_sub(rad) {
            let i = yy * w + xx;
            let (vx, vy, vxy) = (
                uxx[i] - ux[i] * ux[i],
                uyy[i] - uy[i] * uy[i],
                uxy[i] - ux[i] * uy[i],
            );
            let num = (2.0 * ux[i] * uy[i] + c1) * (2.0 * vxy + c2);
            let den = (ux[i] * ux[i] + uy[i] * uy[i] + c1) * (vx + vy + c2);
            sum += num / den;
            n += 1;
        }
    }
    sum / n.max(1) as f64
}
