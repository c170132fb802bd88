//! The fixed pattern against exposure: `ln FPN_t = σ(ln t; θ)` with a four-parameter logistic
//! (paper eq. 2), per pixel or with shared coefficients applied to the base map.

use serde::{Deserialize, Serialize};

use crate::CameraProfile;

/// Which FPN form to evaluate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FpnForm {
    /// Four coefficients per pixel.
    PerPixel,
    /// One coefficient set; `ln FPN_t(p) = ln base(p) + σ(ln t) − σ(ln t0)`.
    Shared,
    /// No exposure dependence: `FPN_t(p) = base(p)`, the bias map pooled over every calibrated
    /// exposure (chosen when neither curve predicts a held-out exposure better).
    Constant,
}

/// `σ(u; θ) = θ0 + θ1 / (1 + exp(−θ2·(u − θ3)))`.
#[inline]
pub fn logistic(u: f64, th: [f64; 4]) -> f64 {
    th[0] + th[1] / (1.0 + (-th[2] * (u - th[3])).exp())
}

impl CameraProfile {
    /// FPN at exposure `t` in the profile's chosen form, written into `out` (DN).
    pub fn fpn_at(&self, exposure_s: f64, out: &mut [f32]) {
        self.fpn_at_form(self.fpn.form, exposure_s, out)
    }

    /// FPN at exposure `t` in a given form (for comparing the two forms).
    pub fn fpn_at_form(&self, form: FpnForm, exposure_s: f64, out: &mut [f32]) {
        let u = exposure_s.ln();
        let n = self.len();
        assert_eq!(out.len(), n, "output buffer must hold one frame");
        match form {
            FpnForm::Constant => out.copy_from_slice(&self.maps.fpn_base),
            FpnForm::PerPixel if self.maps.fpn_theta.len() == 4 * n => {
                let t = &self.maps.fpn_theta;
                for (i, o) in out.iter_mut().enumerate() {
                    let th = [
                        t[i] as f64,
                        t[n + i] as f64,
                        t[2 * n + i] as f64,
                        t[3 * n + i] as f64,
                    ];
                    *o = logistic(u, th).exp() as f32;
                }
            }
            _ => {
                let th = self.fpn.shared_theta;
                let ratio = (logistic(u, th) - logistic(self.fpn.base_exposure_s.ln(), th)).exp();
                for (o, &b) in out.iter_mut().zip(&self.maps.fpn_base) {
                    *o = (b as f64 * ratio) as f32;
                }
            }
        }
    }
}
