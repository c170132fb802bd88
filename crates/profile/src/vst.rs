//! The Poisson–Gaussian description of a preprocessed frame that variance stabilization needs.

use crate::{median, CameraProfile, Result};

/// Noise of a Poisson–Gaussian frame, `Var(z) = α·(z − μ) + σ²`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoissonGaussian {
    /// Variance per unit of signal (the photon-transfer slope for EMCCD data).
    pub alpha: f64,
    /// Standard deviation of the signal-independent part.
    pub sigma: f64,
    /// Offset of the Gaussian part.
    pub mu: f64,
}

impl PoissonGaussian {
    /// From the photon-transfer slope, a read-noise std map (DN) and the quantization step: the
    /// map's median read noise with the quantization's share. Training uses it with the map it
    /// synthesized, so BM3D sees what a calibration would have given.
    pub fn from_read_noise(slope: f64, read_noise: &[f32], quantization_dn: f64) -> Self {
        let rn = median(read_noise.iter().copied()).unwrap_or(0.0);
        Self {
            alpha: slope,
            sigma: (rn * rn + quantization_dn.powi(2) / 12.0).sqrt(),
            mu: 0.0,
        }
    }

    /// The noise of the mean of `n` independent such frames: α/n and σ/√n.
    pub fn of_mean(self, n: f64) -> Self {
        Self {
            alpha: self.alpha / n,
            sigma: self.sigma / n.sqrt(),
            mu: self.mu,
        }
    }
}

impl CameraProfile {
    /// The Poisson–Gaussian noise of a preprocessed frame at `exposure_s`, for the
    /// variance-stabilizing transform: gain = the photon-transfer slope, Gaussian σ = the median
    /// read noise measured nearest that exposure with the quantization's share.
    pub fn vst_params(&self, exposure_s: f64) -> Result<PoissonGaussian> {
        self.require_complete()?;
        crate::check_exposure(exposure_s)?;
        Ok(PoissonGaussian::from_read_noise(
            self.slope()?,
            self.read_noise_near(exposure_s),
            self.quantization_dn,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn read_noise_and_quantization_add_in_quadrature() {
        let p = PoissonGaussian::from_read_noise(20.0, &[3.0, 4.0, 5.0], 1.0);
        assert_eq!(p.alpha, 20.0);
        assert!((p.sigma - (16.0f64 + 1.0 / 12.0).sqrt()).abs() < 1e-12);
        let m = p.of_mean(4.0);
        assert_eq!(m.alpha, 5.0);
        assert!((m.sigma - p.sigma / 2.0).abs() < 1e-12);
    }

    #[test]
    fn the_bundled_profile_describes_its_frames() {
        let p = crate::default_profile();
        let v = p.vst_params(0.01).unwrap();
        assert_eq!(v.alpha, p.slope().unwrap());
        assert!(v.sigma >= p.quantization_dn / 12f64.sqrt() && v.sigma.is_finite());
        assert!(
            p.vst_params(-1.0).is_err(),
            "a negative exposure is refused"
        );
    }
}
