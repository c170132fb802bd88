//! Photon-transfer slope by median–variance regression (paper §3.2, appendix A.1, Fig. 10):
//! per flat-field stack, on a central crop, the median signal and the temporal variance;
//! `Var = s·Median + c` over the levels gives `s = K·f²`.

use std::path::PathBuf;

use serde::Serialize;

use crate::fit::{line, median_mad, LineFit};
use crate::{Error, Result};

/// How a flat level entered the fit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LevelStatus {
    /// Used.
    Included,
    /// Excluded: samples at the ADC maximum.
    Saturated,
    /// Excluded: off the line by more than the other levels allow.
    NonLinear,
}

/// One flat-field level.
#[derive(Clone, Debug, Serialize)]
pub struct FlatLevel {
    /// Stack file.
    pub file: PathBuf,
    /// Exposure, s.
    pub exposure_s: f64,
    /// Frames in the stack.
    pub frames: usize,
    /// Median over crop pixels of the temporal mean, after FPN and blooming removal, DN.
    pub median_dn: f64,
    /// Mean over crop pixels of the temporal variance (outlier pixels removed), DN².
    pub variance_dn2: f64,
    /// Standard error of `variance_dn2` from its spread over pixels, DN².
    pub variance_se_dn2: f64,
    /// Crop pixels kept.
    pub pixels: usize,
    /// Fraction of all samples at the ADC maximum.
    pub saturated_fraction: f64,
    /// Whether and why it entered the fit.
    pub status: LevelStatus,
}

/// The regression.
#[derive(Clone, Debug, Serialize)]
pub struct PtcResult {
    /// All levels, in manifest order.
    pub levels: Vec<FlatLevel>,
    /// `Var = slope·Median + intercept` over the included levels (weights 1/Var²).
    pub fit: LineFit,
    /// Central crop used: x0, y0, width, height.
    pub crop: [usize; 4],
    /// Whether an FPN map was subtracted before taking the median.
    pub fpn_subtracted: bool,
    /// Whether blooming was removed (B⁻¹) before taking the median.
    pub blooming_removed: bool,
}

/// The central crop of side `min(side, width, height)`.
pub fn central_crop(width: usize, height: usize, side: usize) -> [usize; 4] {
    let (cw, ch) = (side.min(width).max(1), side.min(height).max(1));
    [(width - cw) / 2, (height - ch) / 2, cw, ch]
}

/// One flat's point of the photon-transfer curve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelStats {
    /// Median signal over the crop's kept pixels, DN above bias.
    pub median_dn: f64,
    /// Mean temporal variance over the kept pixels, DN².
    pub variance_dn2: f64,
    /// Its standard error from the spread over pixels, DN².
    pub variance_se_dn2: f64,
    /// Pixels kept (outliers in signal or variance removed).
    pub pixels: usize,
}

/// Median signal and robust mean variance of one flat on `crop`. `signal` is the per-pixel
/// temporal mean already corrected for FPN and blooming; `var` the temporal variance.
pub fn level_stats(signal: &[f32], var: &[f32], width: usize, crop: [usize; 4]) -> LevelStats {
    let [x0, y0, cw, ch] = crop;
    let mut s = Vec::with_capacity(cw * ch);
    let mut v = Vec::with_capacity(cw * ch);
    for y in y0..y0 + ch {
        for x in x0..x0 + cw {
            s.push(signal[y * width + x] as f64);
            v.push(var[y * width + x] as f64);
        }
    }
    // Hot pixels, defects and dust shadows are far from the crowd in signal or variance.
    let (s_rob, v_rob) = (median_mad(&s), median_mad(&v));
    let (ms, ss, mv, sv) = (s_rob.median, s_rob.sigma, v_rob.median, v_rob.sigma);
    let keep: Vec<usize> = (0..s.len())
        .filter(|&i| {
            (s[i] - ms).abs() <= 6.0 * ss.max(1e-6 * ms.abs().max(1.0))
                && (v[i] - mv).abs() <= 6.0 * sv.max(1e-6 * mv.abs().max(1.0))
        })
        .collect();
    let k = keep.len().max(1) as f64;
    let kept_s: Vec<f64> = keep.iter().map(|&i| s[i]).collect();
    let med = emccd_profile::median(kept_s.iter().copied()).unwrap_or(f64::NAN);
    let mean_v = keep.iter().map(|&i| v[i]).sum::<f64>() / k;
    let sd_v =
        (keep.iter().map(|&i| (v[i] - mean_v).powi(2)).sum::<f64>() / (k - 1.0).max(1.0)).sqrt();
    LevelStats {
        median_dn: med,
        variance_dn2: mean_v,
        variance_se_dn2: sd_v / k.sqrt(),
        pixels: keep.len(),
    }
}

/// Fits the included levels; excludes non-linear ones (worst first) while more than three remain.
pub fn fit(levels: &mut [FlatLevel]) -> Result<LineFit> {
    loop {
        let inc: Vec<usize> = (0..levels.len())
            .filter(|&i| levels[i].status == LevelStatus::Included)
            .collect();
        if inc.len() < 3 {
            return Err(Error::Fit(format!(
                "the median–variance fit needs ≥ 3 unsaturated flat levels, {} usable of {}",
                inc.len(),
                levels.len()
            )));
        }
        let x: Vec<f64> = inc.iter().map(|&i| levels[i].median_dn).collect();
        let y: Vec<f64> = inc.iter().map(|&i| levels[i].variance_dn2).collect();
        // Relative precision of a variance is about the same at every level, so weight by 1/Var².
        let w: Vec<f64> = y.iter().map(|v| 1.0 / v.max(1e-9).powi(2)).collect();
        let f = line(&x, &y, Some(&w))
            .ok_or_else(|| Error::Fit("flat levels all have the same median".into()))?;
        let rel: Vec<f64> = x
            .iter()
            .zip(&y)
            .map(|(a, b)| {
                (b - (f.slope * a + f.intercept)) / (f.slope * a + f.intercept).abs().max(1e-9)
            })
            .collect();
        let scale = median_mad(&rel).sigma;
        let (worst, r) = rel
            .iter()
            .enumerate()
            .map(|(k, r)| (k, r.abs()))
            .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        if inc.len() > 3 && r > (5.0 * scale).max(0.05) {
            levels[inc[worst]].status = LevelStatus::NonLinear;
            continue;
        }
        return Ok(f);
    }
}
