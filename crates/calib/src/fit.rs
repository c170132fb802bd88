//! The small numerical pieces the calibration fits need, written here because each is a few
//! lines and the fits call them millions of times: weighted straight lines, Levenberg–Marquardt
//! for ≤ 4 parameters, Nelder–Mead, a symmetric matrix inverse, and the normal quantile.

use serde::Serialize;

/// A straight-line fit `y = slope·x + intercept` with standard errors.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct LineFit {
    /// Slope.
    pub slope: f64,
    /// Intercept.
    pub intercept: f64,
    /// Standard error of the slope (residual scatter, reduced χ²).
    pub slope_se: f64,
    /// Standard error of the intercept.
    pub intercept_se: f64,
    /// Coefficient of determination of the (weighted) fit.
    pub r2: f64,
}

/// Weighted least squares line; `w` = None for equal weights. Needs ≥ 2 points with distinct x.
pub fn line(x: &[f64], y: &[f64], w: Option<&[f64]>) -> Option<LineFit> {
    let n = x.len();
    if n < 2 || y.len() != n {
        return None;
    }
    let wt = |i: usize| w.map_or(1.0, |w| w[i]);
    let sw: f64 = (0..n).map(wt).sum();
    let mx = (0..n).map(|i| wt(i) * x[i]).sum::<f64>() / sw;
    let my = (0..n).map(|i| wt(i) * y[i]).sum::<f64>() / sw;
    let sxx: f64 = (0..n).map(|i| wt(i) * (x[i] - mx).powi(2)).sum();
    let sxy: f64 = (0..n).map(|i| wt(i) * (x[i] - mx) * (y[i] - my)).sum();
    let syy: f64 = (0..n).map(|i| wt(i) * (y[i] - my).powi(2)).sum();
    if !(sxx > 0.0) {
        return None;
    }
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let sse: f64 = (0..n)
        .map(|i| wt(i) * (y[i] - intercept - slope * x[i]).powi(2))
        .sum();
    let s2 = if n > 2 {
        sse / (n - 2) as f64
    } else {
        f64::NAN
    };
    let slope_se = (s2 / sxx).sqrt();
    let intercept_se = (s2 * (1.0 / sw + mx * mx / sxx)).sqrt();
    let r2 = if syy > 0.0 { 1.0 - sse / syy } else { 1.0 };
    Some(LineFit {
        slope,
        intercept,
        slope_se,
        intercept_se,
        r2,
    })
}

/// Inverts a symmetric positive-definite `p×p` matrix (row-major) by Gauss–Jordan with partial
/// pivoting; None when singular.
pub fn invert(a: &[f64], p: usize) -> Option<Vec<f64>> {
    let mut m = a.to_vec();
    let mut inv = vec![0.0; p * p];
    for i in 0..p {
        inv[i * p + i] = 1.0;
    }
    for c in 0..p {
        let piv = (c..p).max_by(|&i, &j| m[i * p + c].abs().total_cmp(&m[j * p + c].abs()))?;
        if !(m[piv * p + c].abs() > 1e-300) {
            return None;
        }
        for k in 0..p {
            m.swap(c * p + k, piv * p + k);
            inv.swap(c * p + k, piv * p + k);
        }
        let d = m[c * p + c];
        for k in 0..p {
            m[c * p + k] /= d;
            inv[c * p + k] /= d;
        }
        for r in 0..p {
            if r != c {
                let f = m[r * p + c];
                if f != 0.0 {
                    for k in 0..p {
                        m[r * p + k] -= f * m[c * p + k];
                        inv[r * p + k] -= f * inv[c * p + k];
                    }
                }
            }
        }
    }
    Some(inv)
}

/// Result of a least-squares fit.
#[derive(Clone, Debug)]
pub struct LsqFit<const P: usize> {
    /// Fitted parameters.
    pub params: [f64; P],
    /// Sum of squared residuals.
    pub sse: f64,
    /// Standard errors from the Jacobian at the optimum (scaled by the residual variance);
    /// NaN when there are no spare degrees of freedom.
    pub se: [f64; P],
}

/// Levenberg–Marquardt for a model `f(x; θ)` returning the value and its gradient in θ.
/// `clamp` keeps parameters inside their valid region after each step.
pub fn levenberg_marquardt<const P: usize>(
    x: &[f64],
    y: &[f64],
    init: [f64; P],
    model: impl Fn(f64, &[f64; P]) -> (f64, [f64; P]),
    clamp: impl Fn(&mut [f64; P]),
    max_iter: usize,
) -> LsqFit<P> {
    let sse_of = |th: &[f64; P]| {
        x.iter()
            .zip(y)
            .map(|(&xi, &yi)| (yi - model(xi, th).0).powi(2))
            .sum::<f64>()
    };
    let mut th = init;
    let mut sse = sse_of(&th);
    let mut lambda = 1e-3;
    for _ in 0..max_iter {
        let mut jtj = [[0.0; P]; P];
        let mut jtr = [0.0; P];
        for (&xi, &yi) in x.iter().zip(y) {
            let (v, g) = model(xi, &th);
            let r = yi - v;
            for a in 0..P {
                jtr[a] += g[a] * r;
                for b in 0..P {
                    jtj[a][b] += g[a] * g[b];
                }
            }
        }
        let mut improved = false;
        for _ in 0..12 {
            let mut m = vec![0.0; P * P];
            for a in 0..P {
                for b in 0..P {
                    m[a * P + b] = jtj[a][b];
                }
                m[a * P + a] += lambda * jtj[a][a].max(1e-12);
            }
            let Some(inv) = invert(&m, P) else {
                lambda *= 10.0;
                continue;
            };
            let mut cand = th;
            for a in 0..P {
                cand[a] += (0..P).map(|b| inv[a * P + b] * jtr[b]).sum::<f64>();
            }
            clamp(&mut cand);
            let s = sse_of(&cand);
            if s.is_finite() && s < sse {
                let rel = (sse - s) / sse.max(1e-300);
                th = cand;
                sse = s;
                lambda = (lambda * 0.3).max(1e-12);
                improved = rel > 1e-12;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    // Standard errors from (JᵀJ)⁻¹·s².
    let dof = x.len() as f64 - P as f64;
    let mut se = [f64::NAN; P];
    if dof > 0.0 {
        let mut m = vec![0.0; P * P];
        for &xi in x {
            let (_, g) = model(xi, &th);
            for a in 0..P {
                for b in 0..P {
                    m[a * P + b] += g[a] * g[b];
                }
            }
        }
        if let Some(inv) = invert(&m, P) {
            let s2 = sse / dof;
            for a in 0..P {
                se[a] = (inv[a * P + a] * s2).max(0.0).sqrt();
            }
        }
    }
    LsqFit {
        params: th,
        sse,
        se,
    }
}

/// Where a minimization ended.
#[derive(Clone, Debug, PartialEq)]
pub struct Minimum {
    /// The point.
    pub x: Vec<f64>,
    /// The function's value there.
    pub value: f64,
}

/// Nelder–Mead minimization of `f` from `x0` with initial simplex steps `step`.
/// Stops when the simplex's function values agree within `ftol` (absolute) or after `max_eval`.
pub fn nelder_mead(
    f: &dyn Fn(&[f64]) -> f64,
    x0: &[f64],
    step: &[f64],
    ftol: f64,
    max_eval: usize,
) -> Minimum {
    let n = x0.len();
    let mut pts: Vec<Vec<f64>> = vec![x0.to_vec()];
    for i in 0..n {
        let mut p = x0.to_vec();
        p[i] += step[i];
        pts.push(p);
    }
    let mut vals: Vec<f64> = pts.iter().map(|p| f(p)).collect();
    let mut evals = n + 1;
    let fv = |v: f64| if v.is_finite() { v } else { f64::INFINITY };
    while evals < max_eval {
        let mut idx: Vec<usize> = (0..=n).collect();
        idx.sort_by(|&a, &b| fv(vals[a]).total_cmp(&fv(vals[b])));
        pts = idx.iter().map(|&i| pts[i].clone()).collect();
        vals = idx.iter().map(|&i| vals[i]).collect();
        if (fv(vals[n]) - fv(vals[0])).abs() <= ftol {
            break;
        }
        let centroid: Vec<f64> = (0..n)
            .map(|j| pts[..n].iter().map(|p| p[j]).sum::<f64>() / n as f64)
            .collect();
        let along = |t: f64| -> Vec<f64> {
            (0..n)
                .map(|j| centroid[j] + t * (pts[n][j] - centroid[j]))
                .collect()
        };
        let xr = along(-1.0);
        let fr = fv(f(&xr));
        evals += 1;
        if fr < vals[0] {
            let xe = along(-2.0);
            let fe = fv(f(&xe));
            evals += 1;
            if fe < fr {
                pts[n] = xe;
                vals[n] = fe;
            } else {
                pts[n] = xr;
                vals[n] = fr;
            }
        } else if fr < vals[n - 1] {
            pts[n] = xr;
            vals[n] = fr;
        } else {
            let (xc, fc) = if fr < vals[n] {
                let x = along(-0.5);
                let v = fv(f(&x));
                (x, v)
            } else {
                let x = along(0.5);
                let v = fv(f(&x));
                (x, v)
            };
            evals += 1;
            if fc < vals[n].min(fr) {
                pts[n] = xc;
                vals[n] = fc;
            } else {
                for i in 1..=n {
                    for j in 0..n {
                        pts[i][j] = pts[0][j] + 0.5 * (pts[i][j] - pts[0][j]);
                    }
                    vals[i] = fv(f(&pts[i]));
                }
                evals += n;
            }
        }
    }
    let best = (0..=n)
        .min_by(|&a, &b| fv(vals[a]).total_cmp(&fv(vals[b])))
        .unwrap_or(0);
    Minimum {
        x: pts[best].clone(),
        value: vals[best],
    }
}

/// Standard normal CDF.
pub fn normal_cdf(z: f64) -> f64 {
    0.5 * libm::erfc(-z / std::f64::consts::SQRT_2)
}

/// Standard normal quantile Φ⁻¹(p): Acklam's rational approximation refined by one Halley step
/// (relative error below 1e-12 on (0, 1)).
pub fn normal_quantile(p: f64) -> f64 {
    if !(p > 0.0 && p < 1.0) {
        return if p <= 0.0 {
            f64::NEG_INFINITY
        } else {
            f64::INFINITY
        };
    }
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383577518672690e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let pl = 0.02425;
    let x = if p < pl {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - pl {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    let e = normal_cdf(x) - p;
    let u = e * (2.0 * std::f64::consts::PI).sqrt() * (x * x / 2.0).exp();
    x - u / (1.0 + x * u / 2.0)
}

/// A robust location and scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Robust {
    /// The median.
    pub median: f64,
    /// The normal-consistent MAD, 1.4826·median|x − median| (σ for normal data).
    pub sigma: f64,
}

/// Median and the normal-consistent MAD, NaNs ignored; NaN for none.
pub fn median_mad(v: &[f64]) -> Robust {
    let m = emccd_profile::median(v.iter().copied()).unwrap_or(f64::NAN);
    let mad = emccd_profile::median(v.iter().map(|x| (x - m).abs())).unwrap_or(f64::NAN);
    Robust {
        median: m,
        sigma: 1.4826 * mad,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_inverts_cdf() {
        for p in [1e-9, 0.001, 0.02, 0.3, 0.5, 0.77, 0.99, 1.0 - 1e-7] {
            let z = normal_quantile(p);
            assert!((normal_cdf(z) - p).abs() < 1e-12 * p.max(1e-3), "{p}");
        }
        assert!((normal_quantile(0.975) - 1.959963984540054).abs() < 1e-10);
    }

    #[test]
    fn line_recovers_exact_data() {
        let x = [1.0, 2.0, 4.0, 8.0];
        let y: Vec<f64> = x.iter().map(|v| 3.0 * v - 2.0).collect();
        let f = line(&x, &y, None).unwrap();
        assert!(
            (f.slope - 3.0).abs() < 1e-12
                && (f.intercept + 2.0).abs() < 1e-12
                && (f.r2 - 1.0).abs() < 1e-12
        );
    }

    #[test]
    fn lm_fits_a_logistic() {
        let th = [1.0, 0.5, 1.3, -2.0];
        let x: Vec<f64> = (0..30).map(|i| -8.0 + i as f64 * 0.4).collect();
        let y: Vec<f64> = x
            .iter()
            .map(|&u| th[0] + th[1] / (1.0 + (-th[2] * (u - th[3])).exp()))
            .collect();
        let model = |u: f64, t: &[f64; 4]| {
            let e = (-t[2] * (u - t[3])).exp();
            let s = 1.0 / (1.0 + e);
            let ds = s * s * e;
            (
                t[0] + t[1] * s,
                [1.0, s, t[1] * ds * (u - t[3]), -t[1] * ds * t[2]],
            )
        };
        let f = levenberg_marquardt(&x, &y, [0.8, 0.7, 1.0, -1.0], model, |_| {}, 200);
        for k in 0..4 {
            assert!((f.params[k] - th[k]).abs() < 1e-6, "{:?}", f.params);
        }
    }

    #[test]
    fn nelder_mead_finds_a_quadratic_minimum() {
        let f =
            |x: &[f64]| (x[0] - 1.0).powi(2) + 10.0 * (x[1] + 2.0).powi(2) + (x[2] - 0.5).powi(2);
        let Minimum { x, value: v } =
            nelder_mead(&f, &[0.0, 0.0, 0.0], &[0.5, 0.5, 0.5], 1e-14, 5000);
        assert!(
            v < 1e-10 && (x[0] - 1.0).abs() < 1e-4 && (x[1] + 2.0).abs() < 1e-4,
            "{x:?}"
        );
    }
}
