//! The fixed pattern against exposure (paper §3.2, Fig. 3): `ln FPN_t = σ(ln t; θ)` with the
//! four-parameter logistic `σ(u) = θ0 + θ1/(1 + exp(−θ2(u − θ3)))`, fitted per pixel and in the
//! shared form `ln FPN_t(p) = ln base(p) + σ(u) − σ(u0)` on the base map at the shortest
//! exposure (θ0 cancels there and is fixed at 0), beside the constant form (no exposure
//! dependence: one map pooled over every exposure).
//!
//! The form the profile uses is chosen by leave-one-exposure-out error: each form is fitted to all
//! exposures but one (an interior one) and scored on the one left out. Scored on the exposures they were fitted
//! to, four per-pixel coefficients always win — with five exposures they fit the maps' noise and
//! come out below the noise floor — so in-sample errors are shown but never decide.

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
    /// Held out: the shared form fitted to the other exposures, mean |predicted − measured| here
    /// (on the scored pixels, see [`FpnResult::heldout_pixels`]), DN; NaN at the shortest and
    /// longest exposure, which are never left out (that would score extrapolation).
    pub shared_heldout_dn: f64,
    /// Held out: the per-pixel form, same (NaN without per-pixel fits), DN.
    pub per_pixel_heldout_dn: f64,
    /// Held out: the other exposures' pooled map, same, DN.
    pub constant_heldout_dn: f64,
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
    /// Pixels the held-out errors are averaged over (a regular subset of at most
    /// [`HELDOUT_PIXELS`], the same for every form).
    pub heldout_pixels: usize,
    /// Mean held-out error over the interior exposures per form, DN: constant, shared, per-pixel
    /// (NaN when not fitted).
    pub heldout_mean_dn: [f64; 3],
    /// The form with the lowest mean held-out error (ties go to the simpler form), written into
    /// the profile.
    pub chosen: FpnForm,
    /// Example pixel.
    pub example: PixelCurve,
    /// Per-pixel θ maps (4 planes), empty unless `per_pixel`.
    #[serde(skip)]
    pub theta_maps: Vec<f32>,
    /// The constant form's map: every exposure's bias mean, weighted by its frames, DN.
    #[serde(skip)]
    pub pooled: Vec<f32>,
}

/// An FPN error for reports: DN to three decimals, a dash where it was not computed (NaN: the
/// end exposures are never held out; no per-pixel fit with fewer than five exposures).
pub fn error_text(v: f64) -> String {
    if v.is_nan() {
        "—".to_string()
    } else {
        format!("{v:.3}")
    }
}

/// A shared coefficient with its standard error, or a note that the exposures do not identify
/// it (a standard error past 10³ times the value, or none: a curve fitted to a bias that hardly
/// changes with exposure, whose θ can be anything).
pub fn theta_text(theta: f64, se: f64) -> String {
    if se.is_finite() && se <= 1e3 * theta.abs().max(1.0) {
        format!("{theta:.4} ± {se:.4}")
    } else {
        format!("{theta:.4} (not identified by these exposures)")
    }
}

/// At most this many pixels (a regular subset) are refitted per held-out exposure: the mean
/// error over them is a precise estimate of the mean over all, at a fraction of the time.
pub const HELDOUT_PIXELS: usize = 16384;

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

/// The shared curve through `points` (mean log ratios to the map at `u[0]`): a grid start (θ1 by
/// linear least squares for each θ2, θ3), then Levenberg–Marquardt.
fn fit_shared(u: &[f64], points: &[f64]) -> crate::fit::LsqFit<3> {
    let (umin, umax) = (u[0], u[u.len() - 1]);
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
            let t1 = g.iter().zip(points).map(|(a, b)| a * b).sum::<f64>() / gg;
            let sse: f64 = g
                .iter()
                .zip(points)
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
    levenberg_marquardt(
        u,
        points,
        best.1,
        |x, t| shared_model(x, u[0], t),
        clamp3,
        200,
    )
}

/// One pixel's own curve through its log bias `y` at `u`, started from the shared shape
/// (θ2, θ3) with θ0, θ1 by linear least squares.
fn fit_pixel(u: &[f64], y: &[f64], t2: f64, t3: f64) -> [f64; 4] {
    let e = u.len() as f64;
    let s: Vec<f64> = u.iter().map(|&x| sig(x, t2, t3)).collect();
    let (ms, my) = (s.iter().sum::<f64>() / e, y.iter().sum::<f64>() / e);
    let sxx: f64 = s.iter().map(|v| (v - ms).powi(2)).sum();
    let a1 = if sxx > 0.0 {
        s.iter()
            .zip(y)
            .map(|(a, b)| (a - ms) * (b - my))
            .sum::<f64>()
            / sxx
    } else {
        0.0
    };
    let (umin, umax) = (u[0], u[u.len() - 1]);
    let clamp4 = |t: &mut [f64; 4]| {
        t[2] = t[2].clamp(0.01, 20.0);
        t[3] = t[3].clamp(umin - 15.0, umax + 15.0);
    };
    levenberg_marquardt(u, y, [my - a1 * ms, a1, t2, t3], pixel_model, clamp4, 30).params
}

/// The frame-weighted mean of the maps `idx` at pixel `p`.
fn pooled_at(means: &[Vec<f32>], frames: &[usize], idx: &[usize], p: usize) -> f64 {
    let w: f64 = idx.iter().map(|&i| frames[i].max(1) as f64).sum();
    idx.iter()
        .map(|&i| frames[i].max(1) as f64 * means[i][p] as f64)
        .sum::<f64>()
        / w
}

/// The usable pixels that follow the crowd: at every exposure, a pixel's log ratio to the base
/// map lies within 6 robust standard deviations of the median ratio.
fn inliers(means: &[Vec<f32>], usable: &[bool]) -> Vec<bool> {
    let n = usable.len();
    let ratio = |i: usize, p: usize| (means[i][p] as f64).ln() - (means[0][p] as f64).ln();
    let mut inlier = usable.to_vec();
    for i in 1..means.len() {
        let r: Vec<f64> = (0..n).filter(|&p| usable[p]).map(|p| ratio(i, p)).collect();
        let crate::fit::Robust {
            median: m,
            sigma: mad,
        } = median_mad(&r);
        // Floor the scale at 1e-4 (0.02 DN at 200 DN) so a noiseless map does not reject everything.
        let lim = 6.0 * mad.max(1e-4);
        for p in 0..n {
            if inlier[p] && (ratio(i, p) - m).abs() > lim {
                inlier[p] = false;
            }
        }
    }
    inlier
}

/// The pixels the held-out scores are taken on: about [`HELDOUT_PIXELS`] of the `n`, at a
/// stride sharing no factor with the width, so they walk through every column (a stride of 16
/// on a 512-wide sensor would see only columns 0, 16, 32, … and miss column-periodic patterns
/// such as even/odd readout channels).
fn scored_pixels(n: usize, width: usize) -> Vec<usize> {
    let gcd = |mut a: usize, mut b: usize| {
        while b != 0 {
            (a, b) = (b, a % b);
        }
        a
    };
    let mut stride = n.div_ceil(HELDOUT_PIXELS).max(1);
    while stride > 1 && gcd(stride, width.max(1)) != 1 {
        stride += 1;
    }
    (0..n).step_by(stride).collect()
}

/// The example pixel of the report: the paper shows (195, 5); take it when the sensor is that
/// large and the pixel is an inlier, else the first inlier near the centre.
fn example_pixel(inlier: &[bool], width: usize) -> usize {
    let n = inlier.len();
    let h = n / width.max(1);
    [(195usize, 5usize), (width / 2, h / 2)]
        .into_iter()
        .filter(|&(x, y)| x < width && y < h)
        .map(|(x, y)| y * width + x)
        .chain(0..n)
        .find(|&p| inlier[p])
        .unwrap_or(0)
}

/// Fits the three forms and scores each on held-out exposures. `means[i]`/`stds[i]` are the
/// bias maps at `exposures[i]` (ascending) from `frames[i]` frames each.
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
    let m = Maps {
        means,
        stds,
        frames,
        u: exposures.iter().map(|t| t.ln()).collect(),
        usable: (0..n).map(|p| means.iter().all(|m| m[p] > 0.0)).collect(),
        n,
    };
    let base = &means[0];
    let ratio = |i: usize, p: usize| (means[i][p] as f64).ln() - (base[p] as f64).ln();
    let inlier = inliers(&means[..e], &m.usable);
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
    let sh = fit_shared(&m.u, &points);
    let [t1, t2, t3] = sh.params;
    let shared_theta = [0.0, t1, t2, t3];
    let shared_se = [0.0, sh.se[0], sh.se[1], sh.se[2]];

    // Per-pixel fits start from the shared curve's shape; they need one exposure more than
    // their four coefficients.
    let per_pixel = e >= 5;
    let theta_maps = if per_pixel {
        m.per_pixel_thetas(t2, t3)
    } else {
        Vec::new()
    };
    let all: Vec<usize> = (0..e).collect();
    let pooled: Vec<f32> = (0..n)
        .map(|p| pooled_at(means, frames, &all, p) as f32)
        .collect();
    let scored = scored_pixels(n, width);
    let heldout = m.heldout(&points, &scored, per_pixel);
    let errors = m.in_sample_errors(exposures, &sh.params, &theta_maps, &inlier, &heldout);
    let heldout_mean_dn: [f64; 3] = std::array::from_fn(|k| {
        heldout[1..e - 1].iter().map(|h| h[k]).sum::<f64>() / (e - 2) as f64
    });
    let chosen = if e < 5 {
        m.few_exposures_form(&points, &inlier, kept)
    } else {
        least_heldout_error(heldout_mean_dn)
    };
    let pick = example_pixel(&inlier, width);
    let example = PixelCurve {
        x: pick % width.max(1),
        y: pick / width.max(1),
        measured_dn: (0..e).map(|i| means[i][pick] as f64).collect(),
        theta: if per_pixel {
            theta_at(&theta_maps, n, pick)
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
        heldout_pixels: scored.len(),
        heldout_mean_dn,
        chosen,
        example,
        theta_maps,
        pooled,
    })
}

/// The bias maps a fit works on (one per exposure, shortest first), with what every part of
/// the fit derives from them.
struct Maps<'a> {
    means: &'a [Vec<f32>],
    stds: &'a [Vec<f32>],
    frames: &'a [usize],
    /// ln of the exposures.
    u: Vec<f64>,
    /// Pixels positive at every exposure (their logarithms exist).
    usable: Vec<bool>,
    /// Pixels per map.
    n: usize,
}

impl Maps<'_> {
    /// ln of pixel `p`'s bias at the exposures `idx`.
    fn log_bias(&self, p: usize, idx: &[usize]) -> Vec<f64> {
        idx.iter()
            .map(|&i| (self.means[i][p] as f64).ln())
            .collect()
    }

    /// The per-pixel curves' coefficients as four planes (θ0 of every pixel, then θ1, …),
    /// started from the shared curve's shape (`t2`, `t3`); NaN where a pixel is not usable.
    fn per_pixel_thetas(&self, t2: f64, t3: f64) -> Vec<f32> {
        let (n, all) = (self.n, (0..self.u.len()).collect::<Vec<usize>>());
        let thetas: Vec<[f32; 4]> = (0..n)
            .into_par_iter()
            .map(|p| {
                if !self.usable[p] {
                    return [f32::NAN; 4];
                }
                fit_pixel(&self.u, &self.log_bias(p, &all), t2, t3).map(|v| v as f32)
            })
            .collect();
        let mut planes = vec![0f32; 4 * n];
        for (p, th) in thetas.iter().enumerate() {
            for k in 0..4 {
                planes[k * n + p] = th[k];
            }
        }
        planes
    }

    /// Leave one exposure out: every form refitted to the other exposures predicts this one, on
    /// the `scored` pixels; mean absolute errors (constant, shared, per-pixel) per exposure.
    /// Only interior exposures are left out (NaN at either end): a fold there would score
    /// extrapolation, where per-pixel curves through a few noisy points can run off to absurd
    /// values, while a profile is used inside its calibrated range (and at most 2× beyond it,
    /// on request). The shared form's base is the shortest remaining exposure.
    fn heldout(&self, points: &[f64], scored: &[usize], per_pixel: bool) -> Vec<[f64; 3]> {
        let (means, u, e) = (self.means, &self.u, self.u.len());
        (0..e)
            .into_par_iter()
            .map(|i| {
                if i == 0 || i == e - 1 {
                    return [f64::NAN; 3];
                }
                let rest: Vec<usize> = (0..e).filter(|&j| j != i).collect();
                let j0 = rest[0];
                let ur: Vec<f64> = rest.iter().map(|&j| u[j]).collect();
                let pr: Vec<f64> = rest.iter().map(|&j| points[j] - points[j0]).collect();
                let f = fit_shared(&ur, &pr).params;
                let k = shared_model(u[i], u[j0], &f).0.exp();
                let (mut ec, mut es, mut ep) = (0.0, 0.0, 0.0);
                for &p in scored {
                    let m = means[i][p] as f64;
                    ec += (pooled_at(means, self.frames, &rest, p) - m).abs();
                    es += (means[j0][p] as f64 * k - m).abs();
                    if per_pixel {
                        let pred = if self.usable[p] {
                            let th = fit_pixel(&ur, &self.log_bias(p, &rest), f[1], f[2]);
                            pixel_model(u[i], &th).0.exp()
                        } else {
                            means[j0][p] as f64
                        };
                        ep += (pred - m).abs();
                    }
                }
                let ns = scored.len() as f64;
                [ec / ns, es / ns, if per_pixel { ep / ns } else { f64::NAN }]
            })
            .collect()
    }

    /// Each exposure's errors of the forms fitted to every exposure (all pixels; the shared
    /// form also on its inliers), beside its noise floor and its `heldout` errors.
    fn in_sample_errors(
        &self,
        exposures: &[f64],
        shared: &[f64; 3],
        theta_maps: &[f32],
        inlier: &[bool],
        heldout: &[[f64; 3]],
    ) -> Vec<FpnError> {
        let (means, u, n) = (self.means, &self.u, self.n);
        let per_pixel = !theta_maps.is_empty();
        let pixel_pred = |p: usize, x: f64| pixel_model(x, &theta_at(theta_maps, n, p)).0.exp();
        let shared_pred =
            |p: usize, x: f64| means[0][p] as f64 * shared_model(x, u[0], shared).0.exp();
        (0..exposures.len())
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
                        ep += if self.usable[p] {
                            (pixel_pred(p, u[i]) - m).abs()
                        } else {
                            m.abs()
                        };
                    }
                    fl += self.stds[i][p] as f64;
                }
                let nn = n as f64;
                FpnError {
                    exposure_s: exposures[i],
                    shared_mae_dn: es / nn,
                    per_pixel_mae_dn: if per_pixel { ep / nn } else { f64::NAN },
                    shared_mae_inliers_dn: ei / ni.max(1) as f64,
                    noise_floor_dn: (2.0 / std::f64::consts::PI).sqrt() * fl
                        / nn
                        / (self.frames[i].max(1) as f64).sqrt(),
                    constant_heldout_dn: heldout[i][0],
                    shared_heldout_dn: heldout[i][1],
                    per_pixel_heldout_dn: heldout[i][2],
                }
            })
            .collect()
    }

    /// The form with four exposures, where a fold leaves the shared curve two informative
    /// points for three coefficients, so its held-out score means nothing (nor do the curve's
    /// standard errors): the curve is kept when some exposure's mean log ratio to the base map
    /// (`points`, over the `kept` inliers) is more than 3 standard errors from zero, the error
    /// following from the maps' own noise.
    fn few_exposures_form(&self, points: &[f64], inlier: &[bool], kept: usize) -> FpnForm {
        let (means, stds, frames) = (self.means, self.stds, self.frames);
        let se = |k: usize| {
            let v: f64 = (0..self.n)
                .filter(|&p| inlier[p])
                .map(|p| {
                    let rel = |i: usize| {
                        stds[i][p] as f64 / (frames[i].max(1) as f64).sqrt() / means[i][p] as f64
                    };
                    rel(k).powi(2) + rel(0).powi(2)
                })
                .sum();
            v.sqrt() / kept as f64
        };
        if (1..points.len()).any(|k| points[k].abs() > 3.0 * se(k)) {
            FpnForm::Shared
        } else {
            FpnForm::Constant
        }
    }
}

/// Simplest first; a more complex form must do strictly better on held-out exposures
/// (mean errors: constant, shared, per-pixel).
fn least_heldout_error(heldout_mean_dn: [f64; 3]) -> FpnForm {
    let mut chosen = FpnForm::Constant;
    let mut best = heldout_mean_dn[0];
    for (form, err) in [
        (FpnForm::Shared, heldout_mean_dn[1]),
        (FpnForm::PerPixel, heldout_mean_dn[2]),
    ] {
        if err < best {
            (chosen, best) = (form, err);
        }
    }
    chosen
}

/// Pixel `p`'s four coefficients from the planes of [`Maps::per_pixel_thetas`] (`n` pixels
/// each).
fn theta_at(theta_maps: &[f32], n: usize, p: usize) -> [f64; 4] {
    [
        theta_maps[p],
        theta_maps[n + p],
        theta_maps[2 * n + p],
        theta_maps[3 * n + p],
    ]
    .map(|v| v as f64)
}

/// Predicted FPN at exposure `t` from a fit: evaluated as the profile evaluates its curves
/// ([`emccd_profile::FpnCurves`]; the models above carry gradients for fitting). `base` is the
/// bias map at the shortest exposure; the constant form is the pooled map.
pub fn predict(r: &FpnResult, base: &[f32], form: FpnForm, exposure_s: f64) -> Vec<f32> {
    let mut out = vec![0f32; base.len()];
    emccd_profile::FpnCurves {
        form,
        base: if form == FpnForm::Constant {
            &r.pooled
        } else {
            base
        },
        theta: if r.per_pixel { &r.theta_maps } else { &[] },
        shared: r.shared_theta,
        base_exposure_s: r.exposures_s[0],
    }
    .eval(exposure_s, &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Bias maps at `t` from a per-pixel truth `truth(p, t)` (DN) measured with `frames` frames
    /// of read noise `sigma` each: the maps carry noise σ/√frames.
    fn noisy_maps(
        t: &[f64],
        n: usize,
        sigma: f64,
        frames: usize,
        truth: impl Fn(usize, f64) -> f64,
    ) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(12);
        let noise = Normal::new(0.0, sigma / (frames as f64).sqrt()).unwrap();
        let means = t
            .iter()
            .map(|&x| {
                (0..n)
                    .map(|p| (truth(p, x) + noise.sample(&mut rng)) as f32)
                    .collect()
            })
            .collect();
        (means, vec![vec![sigma as f32; n]; t.len()])
    }

    fn mean(v: impl Iterator<Item = f64>) -> f64 {
        let (s, k) = v.fold((0.0, 0usize), |(s, k), x| (s + x, k + 1));
        s / k as f64
    }

    #[test]
    fn an_unidentified_coefficient_is_reported_as_such() {
        assert_eq!(theta_text(0.1234, 0.0101), "0.1234 ± 0.0101");
        // The review's case: a curve through a bias that hardly changes with exposure.
        assert_eq!(
            theta_text(19.9985, 813407843.6),
            "19.9985 (not identified by these exposures)"
        );
        assert!(theta_text(1.0, f64::NAN).contains("not identified"));
    }

    #[test]
    fn a_flat_bias_is_recognised_though_per_pixel_fits_beat_the_noise_floor_in_sample() {
        // The camera: five exposures, bias that does not change with exposure. Four
        // coefficients per pixel through five noisy points fit the noise: in-sample they come
        // out below the noise floor. Held out, the pooled map wins.
        let t = [0.001, 0.003, 0.01, 0.03, 0.1];
        let n = 4096;
        let (means, stds) = noisy_maps(&t, n, 3.0, 10, |p, _| 160.0 + (p % 64) as f64 * 0.5);
        let r = fit(&t, &means, &stds, &[10; 5], 64).unwrap();
        let floor = mean(r.errors.iter().map(|e| e.noise_floor_dn));
        let in_sample = mean(r.errors.iter().map(|e| e.per_pixel_mae_dn));
        assert!(in_sample < floor, "in-sample {in_sample} vs floor {floor}");
        assert_eq!(r.chosen, FpnForm::Constant, "{:?}", r.heldout_mean_dn);
        // The pooled map is five maps' average: its error to the truth is σ/√(5·10).
        let err = mean((0..n).map(|p| (r.pooled[p] as f64 - 160.0 - (p % 64) as f64 * 0.5).abs()));
        let expect = (2.0 / std::f64::consts::PI).sqrt() * 3.0 / 50f64.sqrt();
        assert!(
            (err / expect - 1.0).abs() < 0.1,
            "pooled error {err} vs {expect}"
        );
        // Its prediction is what the profile evaluates.
        assert_eq!(predict(&r, &means[0], FpnForm::Constant, 0.02), r.pooled);
    }

    #[test]
    fn four_exposures_keep_a_curve_only_when_its_amplitude_is_significant() {
        let t = [1e-3, 1e-2, 0.1, 1.0];
        let n = 4096;
        let (means, stds) = noisy_maps(&t, n, 3.0, 10, |p, _| 160.0 + (p % 64) as f64 * 0.5);
        let r = fit(&t, &means, &stds, &[10; 4], 64).unwrap();
        assert_eq!(
            r.chosen,
            FpnForm::Constant,
            "{:?} ± {:?}",
            r.shared_theta,
            r.shared_se
        );
        let u0 = 0.05f64.ln();
        let curve =
            |p: usize, x: f64| (160.0 + (p % 64) as f64 * 0.5) * (0.1 * sig(x.ln(), 1.5, u0)).exp();
        let (means, stds) = noisy_maps(&t, n, 3.0, 10, curve);
        let r = fit(&t, &means, &stds, &[10; 4], 64).unwrap();
        assert_eq!(
            r.chosen,
            FpnForm::Shared,
            "{:?} ± {:?}",
            r.shared_theta,
            r.shared_se
        );
    }

    #[test]
    fn held_out_exposures_pick_a_curve_when_the_bias_follows_one() {
        let t = [1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0];
        let n = 4096;
        let u0 = 0.3f64.ln();
        // One curve for all pixels: the shared form is the truth, and the per-pixel form
        // contains it; the constant form does not.
        let shared = |p: usize, x: f64| {
            (160.0 + (p % 64) as f64 * 0.5)
                * (0.105 * (sig(x.ln(), 1.2, u0) - sig(1e-4f64.ln(), 1.2, u0))).exp()
        };
        let (means, stds) = noisy_maps(&t, n, 1.0, 10, shared);
        let r = fit(&t, &means, &stds, &[10; 9], 64).unwrap();
        assert_ne!(r.chosen, FpnForm::Constant, "{:?}", r.heldout_mean_dn);
        // Each pixel its own amplitude (θ1 from 0 to 0.3): only the per-pixel form holds it.
        let own = |p: usize, x: f64| {
            let th1 = 0.3 * (p % 97) as f64 / 96.0;
            (170.0 + (p % 64) as f64 * 0.5) * (th1 * sig(x.ln(), 1.2, u0)).exp()
        };
        let (means, stds) = noisy_maps(&t, n, 1.0, 10, own);
        let r = fit(&t, &means, &stds, &[10; 9], 64).unwrap();
        assert_eq!(r.chosen, FpnForm::PerPixel, "{:?}", r.heldout_mean_dn);
    }

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
