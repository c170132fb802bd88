//! The fixed pattern against exposure (paper §3.2, Fig. 3): `ln FPN_t = σ(ln t; θ)` with the
//! four-parameter logistic `σ(u) = θ0 + θ1/(1 + exp(−θ2(u − θ3)))`, fitted per pixel and in the
//! shared form `ln FPN_t(p) = ln base(p) + σ(u) − σ(u0)` on the base map at the shortest
//! exposure (θ0 cancels there and is fixed at 0).

use rayon::prelude::*;
use serde::Serialize;

use crate::fit::{levenberg_marquardt, median_mad};
use crate::{Error, Result};
use emccd_profile::FpnForm;

/// Mean absolute prediction error of both forms at one calibrated exposure.
#[derive(Clone, Debug, Serialize)]
pub struct FpnError {
    /// Exposure, s.
    pub exposure_s: f64,
    /// Shared form, mean |predicted − measured| over all pixels, DN.
    pub shared_mae_dn: f64,
    /// Per-pixel form, same, DN (NaN when the per-pixel form could not be fitted).
    pub per_pixel_mae_dn: f64,
    /// Shared form over the pixels kept by outlier removal, DN.
    pub shared_mae_inliers_dn: f64,
    /// What a perfect prediction would still show: the measured map's own noise,
    /// mean over pixels of √(2/π)·σ/√N, DN.
    pub noise_floor_dn: f64,
}

/// One pixel's curve for the report (paper Fig. 3b).
#[derive(Clone, Debug, Serialize)]
pub struct PixelCurve {
    /// Pixel column.
    pub x: usize,
    /// Pixel row.
    pub y: usize,
    /// Measured FPN per calibrated exposure, DN.
    pub measured_dn: Vec<f64>,
    /// The pixel's own θ (NaN when not fitted).
    pub theta: [f64; 4],
    /// The pixel's base value (shared form), DN.
    pub base_dn: f64,
}

/// Both FPN fits and their errors.
#[derive(Clone, Debug, Serialize)]
pub struct FpnResult {
    /// Calibrated exposures, ascending, s.
    pub exposures_s: Vec<f64>,
    /// Shared θ (θ0 = 0).
    pub shared_theta: [f64; 4],
    /// Standard errors of the shared θ.
    pub shared_se: [f64; 4],
    /// Mean log ratio ln(FPN_t/base) over inlier pixels per exposure (the shared fit's data).
    pub shared_points: Vec<f64>,
    /// Pixels excluded from the shared fit as outliers (hot pixels, defects).
    pub outliers: usize,
    /// Whether per-pixel θ maps were fitted (needs ≥ 5 exposures).
    pub per_pixel: bool,
    /// Errors per exposure.
    pub errors: Vec<FpnError>,
    /// The form with the lower mean error, written into the profile.
    pub chosen: FpnForm,
    /// Example pixel.
    pub example: PixelCurve,
    /// Per-pixel θ maps (4 planes), empty unless `per_pixel`.
    #[serde(skip)]
    pub theta_maps: Vec<f32>,
}

#[inline]
fn sig(u: f64, th2: f64, th3: f64) -> f64 {
    1.0 / (1.0 + (-th2 * (u - th3)).exp())
}

/// Shared-curve model `θ1(s(u) − s(u0))` with its gradient in (θ1, θ2, θ3).
fn shared_model(u: f64, u0: f64, t: &[f64; 3]) -> (f64, [f64; 3]) {
    let (s, s0) = (sig(u, t[1], t[2]), sig(u0, t[1], t[2]));
    let (d, d0) = (s * (1.0 - s), s0 * (1.0 - s0));
    (
        t[0] * (s - s0),
        [
            s - s0,
            t[0] * (d * (u - t[2]) - d0 * (u0 - t[2])),
            -t[0] * t[1] * (d - d0),
        ],
    )
}

/// Per-pixel model `θ0 + θ1·s(u)` with its gradient.
fn pixel_model(u: f64, t: &[f64; 4]) -> (f64, [f64; 4]) {
    let s = sig(u, t[2], t[3]);
    let d = s * (1.0 - s);
    (
        t[0] + t[1] * s,
        [1.0, s, t[1] * d * (u - t[3]), -t[1] * t[2] * d],
    )
}

/// Fits both forms. `means[i]`/`stds[i]` are the bias maps at `exposures[i]` (ascending) from
/// `frames[i]` frames each.
pub fn fit(
    exposures: &[f64],
    means: &[Vec<f32>],
    stds: &[Vec<f32>],
    frames: &[usize],
    width: usize,
) -> Result<FpnResult> {
    let e = exposures.len();
    let n = means.first().map_or(0, Vec::len);
    if e < 4 {
        return Err(Error::Fit(format!(
            "the FPN exposure fit needs bias stacks at ≥ 4 exposures (3 shared coefficients), got {e}"
        )));
    }
    let u: Vec<f64> = exposures.iter().map(|t| t.ln()).collect();
    let base = &means[0];
    let usable: Vec<bool> = (0..n).map(|p| means.iter().all(|m| m[p] > 0.0)).collect();
    // Log ratios to the base map; outliers are pixels far from the crowd at any exposure.
    let ratio = |i: usize, p: usize| (means[i][p] as f64).ln() - (base[p] as f64).ln();
    let mut inlier = usable.clone();
    for i in 1..e {
        let r: Vec<f64> = (0..n).filter(|&p| usable[p]).map(|p| ratio(i, p)).collect();
        let (m, mad) = median_mad(&r);
        // Floor the scale at 1e-4 (0.02 DN at 200 DN) so a noiseless map does not reject everything.
        let lim = 6.0 * mad.max(1e-4);
        for p in 0..n {
            if inlier[p] && (ratio(i, p) - m).abs() > lim {
                inlier[p] = false;
            }
        }
    }
    let kept = inlier.iter().filter(|&&k| k).count();
    if kept < n / 2 {
        return Err(Error::Fit(format!(
            "FPN fit: only {kept} of {n} pixels behave consistently across exposures"
        )));
    }
    let points: Vec<f64> = (0..e)
        .map(|i| {
            (0..n)
                .filter(|&p| inlier[p])
                .map(|p| ratio(i, p))
                .sum::<f64>()
                / kept as f64
        })
        .collect();
    // Grid start (θ1 by linear least squares for each θ2, θ3), then Levenberg–Marquardt.
    let (umin, umax) = (u[0], u[e - 1]);
    let mut best = (f64::INFINITY, [0.0, 1.0, 0.5 * (umin + umax)]);
    for &t2 in &[0.2, 0.4, 0.7, 1.0, 1.5, 2.5, 4.0] {
        for k in 0..=40 {
            let t3 = umin - 3.0 + (umax - umin + 6.0) * k as f64 / 40.0;
            let g: Vec<f64> = u
                .iter()
                .map(|&x| sig(x, t2, t3) - sig(u[0], t2, t3))
                .collect();
            let gg: f64 = g.iter().map(|v| v * v).sum();
            if gg <= 0.0 {
                continue;
            }
            let t1 = g.iter().zip(&points).map(|(a, b)| a * b).sum::<f64>() / gg;
            let sse: f64 = g
                .iter()
                .zip(&points)
                .map(|(a, b)| (b - t1 * a).powi(2))
                .sum();
            if sse < best.0 {
                best = (sse, [t1, t2, t3]);
            }
        }
    }
    let clamp3 = |t: &mut [f64; 3]| {
        t[1] = t[1].clamp(0.01, 20.0);
        t[2] = t[2].clamp(umin - 15.0, umax + 15.0);
    };
    let sh = levenberg_marquardt(
        &u,
        &points,
        best.1,
        |x, t| shared_model(x, u[0], t),
        clamp3,
        200,
    );
    let [t1, t2, t3] = sh.params;
    let shared_theta = [0.0, t1, t2, t3];
    let shared_se = [0.0, sh.se[0], sh.se[1], sh.se[2]];

    // Per-pixel fits start from the shared curve's shape.
    let per_pixel = e >= 5;
    let theta_maps: Vec<f32> = if per_pixel {
        let thetas: Vec<[f32; 4]> = (0..n)
            .into_par_iter()
            .map(|p| {
                if !usable[p] {
                    return [f32::NAN; 4];
                }
                let y: Vec<f64> = (0..e).map(|i| (means[i][p] as f64).ln()).collect();
                let s: Vec<f64> = u.iter().map(|&x| sig(x, t2, t3)).collect();
                // Linear start: θ0, θ1 for the shared shape.
                let (ms, my) = (
                    s.iter().sum::<f64>() / e as f64,
                    y.iter().sum::<f64>() / e as f64,
                );
                let sxx: f64 = s.iter().map(|v| (v - ms).powi(2)).sum();
                let a1 = if sxx > 0.0 {
                    s.iter()
                        .zip(&y)
                        .map(|(a, b)| (a - ms) * (b - my))
                        .sum::<f64>()
                        / sxx
                } else {
                    0.0
                };
                let init = [my - a1 * ms, a1, t2, t3];
                let clamp4 = |t: &mut [f64; 4]| {
                    t[2] = t[2].clamp(0.01, 20.0);
                    t[3] = t[3].clamp(umin - 15.0, umax + 15.0);
                };
                let f = levenberg_marquardt(&u, &y, init, pixel_model, clamp4, 30);
                f.params.map(|v| v as f32)
            })
            .collect();
        let mut planes = vec![0f32; 4 * n];
        for (p, th) in thetas.iter().enumerate() {
            for k in 0..4 {
                planes[k * n + p] = th[k];
            }
        }
        planes
    } else {
        Vec::new()
    };

    let pixel_pred = |p: usize, x: f64| -> f64 {
        let th = [
            theta_maps[p],
            theta_maps[n + p],
            theta_maps[2 * n + p],
            theta_maps[3 * n + p],
        ]
        .map(|v| v as f64);
        pixel_model(x, &th).0.exp()
    };
    let shared_pred =
        |p: usize, x: f64| -> f64 { base[p] as f64 * shared_model(x, u[0], &sh.params).0.exp() };
    let errors: Vec<FpnError> = (0..e)
        .map(|i| {
            let (mut es, mut ep, mut ei, mut fl, mut ni) = (0.0, 0.0, 0.0, 0.0, 0usize);
            for p in 0..n {
                let m = means[i][p] as f64;
                let d = (shared_pred(p, u[i]) - m).abs();
                es += d;
                if inlier[p] {
                    ei += d;
                    ni += 1;
                }
                if per_pixel {
                    ep += if usable[p] {
                        (pixel_pred(p, u[i]) - m).abs()
                    } else {
                        m.abs()
                    };
                }
                fl += stds[i][p] as f64;
            }
            let nn = n as f64;
            FpnError {
                exposure_s: exposures[i],
                shared_mae_dn: es / nn,
                per_pixel_mae_dn: if per_pixel { ep / nn } else { f64::NAN },
                shared_mae_inliers_dn: ei / ni.max(1) as f64,
                noise_floor_dn: (2.0 / std::f64::consts::PI).sqrt() * fl
                    / nn
                    / (frames[i].max(1) as f64).sqrt(),
            }
        })
        .collect();
    let mean_err = |f: fn(&FpnError) -> f64| errors.iter().map(f).sum::<f64>() / e as f64;
    let chosen = if per_pixel && mean_err(|x| x.per_pixel_mae_dn) < mean_err(|x| x.shared_mae_dn) {
        FpnForm::PerPixel
    } else {
        FpnForm::Shared
    };
    // Example pixel: the paper shows (195, 5); take it when the sensor is that large and the
    // pixel is an inlier, else the first inlier near the centre.
    let h = n / width.max(1);
    let pick = [(195usize, 5usize), (width / 2, h / 2)]
        .into_iter()
        .filter(|&(x, y)| x < width && y < h)
        .map(|(x, y)| y * width + x)
        .chain(0..n)
        .find(|&p| inlier[p])
        .unwrap_or(0);
    let example = PixelCurve {
        x: pick % width.max(1),
        y: pick / width.max(1),
        measured_dn: (0..e).map(|i| means[i][pick] as f64).collect(),
        theta: if per_pixel {
            [
                theta_maps[pick],
                theta_maps[n + pick],
                theta_maps[2 * n + pick],
                theta_maps[3 * n + pick],
            ]
            .map(|v| v as f64)
        } else {
            [f64::NAN; 4]
        },
        base_dn: base[pick] as f64,
    };
    Ok(FpnResult {
        exposures_s: exposures.to_vec(),
        shared_theta,
        shared_se,
        shared_points: points,
        outliers: n - kept,
        per_pixel,
        errors,
        chosen,
        example,
        theta_maps,
    })
}

/// Predicted FPN at exposure `t` from a fit: per-pixel or shared form.
pub fn predict(r: &FpnResult, base: &[f32], form: FpnForm, exposure_s: f64) -> Vec<f32> {
    let n = base.len();
    let u = exposure_s.ln();
    let u0 = r.exposures_s[0].ln();
    match form {
        FpnForm::PerPixel if r.per_pixel => (0..n)
            .map(|p| {
                let t = &r.theta_maps;
                let th = [t[p], t[n + p], t[2 * n + p], t[3 * n + p]].map(|v| v as f64);
                if th[0].is_nan() {
                    base[p]
                } else {
                    pixel_model(u, &th).0.exp() as f32
                }
            })
            .collect(),
        _ => {
            let th = [r.shared_theta[1], r.shared_theta[2], r.shared_theta[3]];
            let k = shared_model(u, u0, &th).0.exp();
            base.iter().map(|&b| (b as f64 * k) as f32).collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_shared_curve_without_noise() {
        let th = [0.0, 0.105, 1.2, 0.3f64.ln()];
        let t: Vec<f64> = vec![1e-5, 1e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0];
        let n = 64;
        let base: Vec<f32> = (0..n).map(|p| 160.0 + p as f32 * 0.5).collect();
        let u0 = t[0].ln();
        let means: Vec<Vec<f32>> = t
            .iter()
            .map(|&x| {
                let k = (crate::fpn::shared_model(x.ln(), u0, &[th[1], th[2], th[3]]).0).exp();
                base.iter().map(|&b| (b as f64 * k) as f32).collect()
            })
            .collect();
        let stds = vec![vec![0.0f32; n]; t.len()];
        let r = fit(&t, &means, &stds, &vec![10; t.len()], 8).unwrap();
        for k in 1..4 {
            assert!(
                (r.shared_theta[k] - th[k]).abs() < 1e-3 * th[k].abs().max(1.0),
                "{:?}",
                r.shared_theta
            );
        }
        assert!(
            r.errors
                .iter()
                .all(|e| e.shared_mae_dn < 1e-3 && e.per_pixel_mae_dn < 1e-2),
            "{:?}",
            r.errors
        );
    }
}
