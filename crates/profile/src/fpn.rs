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

/// A fitted FPN curve set, wherever it is kept (a profile's maps, or a calibration's fit before
/// it becomes one): the one evaluation of paper eq. 2 both use.
#[derive(Clone, Copy, Debug)]
pub struct FpnCurves<'a> {
    /// The form to evaluate.
    pub form: FpnForm,
    /// The base map (DN): the bias at `base_exposure_s`, or for [`FpnForm::Constant`] the map
    /// pooled over every exposure.
    pub base: &'a [f32],
    /// Per-pixel coefficients, four planes of `base.len()` (empty without a per-pixel fit); a
    /// pixel whose θ0 is NaN (not fitted) keeps its base value.
    pub theta: &'a [f32],
    /// The shared coefficients.
    pub shared: [f64; 4],
    /// Exposure of the base map, s.
    pub base_exposure_s: f64,
}

impl FpnCurves<'_> {
    /// FPN at `exposure_s`, written into `out` (DN). A per-pixel form without per-pixel
    /// coefficients falls back to the shared curve.
    pub fn eval(&self, exposure_s: f64, out: &mut [f32]) {
        let u = exposure_s.ln();
        let n = self.base.len();
        assert_eq!(out.len(), n, "output buffer must hold one frame");
        match self.form {
            FpnForm::Constant => out.copy_from_slice(self.base),
            FpnForm::PerPixel if self.theta.len() == 4 * n => {
                let t = self.theta;
                for (i, o) in out.iter_mut().enumerate() {
                    let th = [t[i], t[n + i], t[2 * n + i], t[3 * n + i]].map(f64::from);
                    *o = if th[0].is_nan() {
                        self.base[i]
                    } else {
                        logistic(u, th).exp() as f32
                    };
                }
            }
            _ => {
                let th = self.shared;
                let ratio = (logistic(u, th) - logistic(self.base_exposure_s.ln(), th)).exp();
                for (o, &b) in out.iter_mut().zip(self.base) {
                    *o = (b as f64 * ratio) as f32;
                }
            }
        }
    }
}

impl CameraProfile {
    /// FPN at exposure `t` in the profile's chosen form, written into `out` (DN).
    pub fn fpn_at(&self, exposure_s: f64, out: &mut [f32]) {
        self.fpn_at_form(self.fpn.form, exposure_s, out)
    }

    /// FPN at exposure `t` in a given form (for comparing the two forms).
    pub fn fpn_at_form(&self, form: FpnForm, exposure_s: f64, out: &mut [f32]) {
        assert_eq!(out.len(), self.len(), "output buffer must hold one frame");
        // A profile without bias frames (a gain series alone) has no pattern: `out` is left as
        // it is (callers check `require_complete` first).
        if self.maps.fpn_base.is_empty() {
            return;
        }
        FpnCurves {
            form,
            base: &self.maps.fpn_base,
            theta: &self.maps.fpn_theta,
            shared: self.fpn.shared_theta,
            base_exposure_s: self.fpn.base_exposure_s,
        }
        .eval(exposure_s, out)
    }
}
