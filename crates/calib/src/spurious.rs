//! Spurious charge and the read noise beneath it, from bias stacks.
//!
//! An EMCCD's dark frame is not pure read noise: clock-induced charge (CIC) and dark current put
//! electrons into some pixels of some frames, and the EM register multiplies each into tens or
//! hundreds of DN. A bias stack's per-pixel mean therefore holds their mean signal and its
//! per-pixel std their variance (2·g²·c on top of σ²: at 0.05 e⁻ per frame and a register of three
//! read-noise σ per electron, the std is 40 % high). Photon counting needs both apart: the
//! read noise sets the threshold, the spurious rate is subtracted from the counted one.
//!
//! Differences of two frames of the same pixel remove its fixed pattern exactly, so one
//! histogram pooled over every pixel holds the camera's noise: `d = x₁ − x₂` with
//! `x = N(0, σ²) + (EM output of n ~ Poisson(c) electrons)`, each electron's output
//! Gamma(G/(G−1), g·(G−1)/G) (mean `g` DN, the many-stage register's excess noise) and each
//! frame rounded to whole DN. Its characteristic function is real and even,
//! `φ_d(t) = exp(−σ²t² + 2c(Re φ_E(t) − 1))·sinc²(t/2)`, so the probability of every integer
//! difference comes from one real FFT, and (σ, c) are fitted by maximum likelihood. Frames are
//! paired without overlap (1−2, 3−4, …) so that the differences are independent and the
//! likelihood's curvature gives honest standard errors. Across exposures `c(t) = CIC + dark·t`.

use rayon::prelude::*;
use realfft::num_complex::Complex64;
use realfft::RealFftPlanner;
use serde::Serialize;

use crate::fit::{invert, line, nelder_mead};

/// Half-width of the histogram, DN: differences beyond it are counted, not binned.
const HALF: usize = 1 << 15;
/// Pixels per parallel work item.
const CHUNK: usize = 16 * 1024;

/// Histogram of the differences of paired frames (1−2, 3−4, …), pooled over pixels, in whole DN.
#[derive(Clone, Debug)]
pub struct Differences {
    first: Option<Vec<f32>>,
    /// Pixels left out (hot at a shorter exposure).
    skip: Option<Vec<bool>>,
    /// Counts of `d = −HALF … HALF` (index `d + HALF`).
    bins: Vec<u64>,
    /// Differences beyond ±HALF.
    pub beyond: u64,
    /// Differences binned.
    pub pairs: u64,
}

impl Default for Differences {
    fn default() -> Differences {
        Differences {
            first: None,
            skip: None,
            bins: vec![0; 2 * HALF + 1],
            beyond: 0,
            pairs: 0,
        }
    }
}

impl Differences {
    /// An empty histogram that leaves out the pixels `noisy` at a shorter exposure (their std
    /// there over 1.5 times the median): hot pixels, whose dark charge grows with the exposure
    /// and is not the camera's spurious charge. The choice is made on other frames than these,
    /// so for every other pixel it is independent of the differences kept, and leaves them
    /// unbiased.
    pub fn leaving_out_noisy(std_shorter: &[f32]) -> Differences {
        let m = emccd_profile::median(std_shorter.iter().copied()).unwrap_or(f64::INFINITY);
        Differences {
            skip: Some(std_shorter.iter().map(|&s| s as f64 > 1.5 * m).collect()),
            ..Default::default()
        }
    }

    /// Adds the next frame of the stack: the first of a pair is kept, the second differenced.
    pub fn push(&mut self, frame: &[f32]) {
        let Some(first) = self.first.take() else {
            self.first = Some(frame.to_vec());
            return;
        };
        // Each work item counts into a small window around zero (where almost every
        // difference falls) and lists the rest.
        const LOCAL: i64 = 4096;
        let skip = self.skip.as_deref();
        let parts: Vec<(Vec<u32>, Vec<i64>, u64)> = first
            .par_chunks(CHUNK)
            .zip(frame.par_chunks(CHUNK))
            .enumerate()
            .map(|(c, (a, b))| {
                let mut near = vec![0u32; 2 * LOCAL as usize + 1];
                let mut far = Vec::new();
                let mut used = 0u64;
                for (j, (&a, &b)) in a.iter().zip(b).enumerate() {
                    if skip.is_some_and(|s| s[c * CHUNK + j]) {
                        continue;
                    }
                    used += 1;
                    let d = (b as f64 - a as f64).round();
                    if d.abs() <= LOCAL as f64 {
                        near[(d as i64 + LOCAL) as usize] += 1;
                    } else {
                        // Saturating: beyond ±2⁶³ is as far as beyond the histogram.
                        far.push(d as i64);
                    }
                }
                (near, far, used)
            })
            .collect();
        for (near, far, used) in parts {
            self.pairs += used;
            for (i, &c) in near.iter().enumerate() {
                self.bins[HALF + i - LOCAL as usize] += c as u64;
            }
            for d in far {
                if d.unsigned_abs() as usize <= HALF {
                    self.bins[(d + HALF as i64) as usize] += 1;
                } else {
                    self.beyond += 1;
                }
            }
        }
    }

    /// Count of difference `d` DN.
    pub fn count(&self, d: i64) -> u64 {
        if d.unsigned_abs() as usize > HALF {
            0
        } else {
            self.bins[(d + HALF as i64) as usize]
        }
    }

    /// The normal-consistent scale of the differences' central part (1.4826 × median |d|).
    fn central_sigma(&self) -> f64 {
        let total: u64 = self.bins.iter().sum::<u64>() + self.beyond;
        let mut acc = self.count(0);
        let mut k = 0i64;
        while 2 * acc < total && (k as usize) < HALF {
            k += 1;
            acc += self.count(k) + self.count(-k);
        }
        1.4826 * (k as f64).max(0.5)
    }
}

/// The spurious charge and read noise at one exposure.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct SpuriousLevel {
    /// Exposure, s.
    pub exposure_s: f64,
    /// Spurious electrons (CIC and dark) per pixel per frame.
    pub electrons: f64,
    /// Its standard error.
    pub electrons_se: f64,
    /// The read noise without them, DN (before the ADC's rounding).
    pub read_sigma_dn: f64,
    /// Its standard error.
    pub read_sigma_se: f64,
    /// Frame pairs × pixels the fit used.
    pub pairs: u64,
    /// The share of differences too wide for read noise and spurious charge (hot pixels).
    pub outliers: f64,
}

/// Maximum-likelihood (σ, c) of one exposure's differences for a register of `g_dn` DN per
/// electron at EM gain `em_gain`. None when there are too few differences or the fit fails.
pub fn fit_level(
    d: &Differences,
    exposure_s: f64,
    g_dn: f64,
    em_gain: f64,
) -> Option<SpuriousLevel> {
    // NaN fails both comparisons.
    if d.pairs < 1000
        || g_dn.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
        || em_gain.partial_cmp(&1.0) != Some(std::cmp::Ordering::Greater)
    {
        return None;
    }
    let s0 = (d.central_sigma() / std::f64::consts::SQRT_2).max(0.3);
    // The window fitted: the Gaussian core and the register's tail to e^−30; beyond it (hot
    // pixels, cosmic rays) is left out of both data and model.
    let w = ((12.0 * s0 + 30.0 * g_dn).ceil() as usize).min(HALF - 1) as i64;
    let pad = 12.0 * s0 + 20.0 * g_dn;
    let n = (2 * (w as usize + pad.ceil() as usize)).next_power_of_two();
    let hist: Vec<(i64, f64)> = (-w..=w)
        .map(|k| (k, d.count(k) as f64))
        .filter(|&(_, c)| c > 0.0)
        .collect();
    let in_window: f64 = hist.iter().map(|h| h.1).sum();
    // Start: the tail beyond 6 central σ_d is the events' (2c of the differences hold one,
    // beyond T a share e^(−T/g)).
    let t = 6.0 * s0 * std::f64::consts::SQRT_2;
    let tail: f64 = hist
        .iter()
        .filter(|h| (h.0 as f64).abs() > t)
        .map(|h| h.1)
        .sum::<f64>()
        / in_window;
    let c0 = (tail / (2.0 * (-t / g_dn).exp())).clamp(1e-5, 1.0);

    let a = em_gain / (em_gain - 1.0);
    let theta = g_dn / a;
    let mut planner = RealFftPlanner::<f64>::new();
    let plan = planner.plan_fft_inverse(n);
    let scratch_cell = std::cell::RefCell::new((
        plan.make_input_vec(),
        plan.make_output_vec(),
        plan.make_scratch_vec(),
    ));
    let pmf = |sigma: f64, c: f64| -> Vec<f64> {
        let mut s = scratch_cell.borrow_mut();
        let (spec, out, scratch) = &mut *s;
        let step = 2.0 * std::f64::consts::PI / n as f64;
        for (k, v) in spec.iter_mut().enumerate() {
            let t = step * k as f64;
            let sinc = if k == 0 {
                1.0
            } else {
                (t / 2.0).sin() / (t / 2.0)
            };
            let phi_e = Complex64::new(1.0, -theta * t).powf(-a);
            let log = -sigma * sigma * t * t + 2.0 * c * (phi_e.re - 1.0);
            *v = Complex64::new(log.exp() * sinc * sinc, 0.0);
        }
        // The plan only fails on wrong buffer lengths, which `make_*_vec` rule out.
        let _ = plan.process_with_scratch(spec, out, scratch);
        out.iter().map(|v| v / n as f64).collect()
    };
    let at = |p: &[f64], k: i64| p[k.rem_euclid(n as i64) as usize].max(1e-300);
    // A share ε of the differences is spread evenly over the window: hot pixels, whose dark
    // charge is many electrons a frame and whose differences are hundreds of DN wide, are not
    // CIC and must not be read as it.
    let width = (2 * w + 1) as f64;
    let nll_at = |sigma: f64, c: f64, eps: f64| -> f64 {
        if !(sigma > 0.05 && (0.0..20.0).contains(&c) && (0.0..0.5).contains(&eps)) {
            return f64::INFINITY;
        }
        let p = pmf(sigma, c);
        let mass: f64 = (-w..=w).map(|k| at(&p, k)).sum();
        -hist
            .iter()
            .map(|&(k, h)| h * ((1.0 - eps) * at(&p, k) / mass + eps / width).ln())
            .sum::<f64>()
    };
    let nll = |x: &[f64]| nll_at(x[0].exp(), x[1].exp(), x[2].exp());
    let x0 = [s0.ln(), c0.ln(), (1e-4f64).ln()];
    let first = nelder_mead(&nll, &x0, &[0.05, 0.3, 1.0], 1e-6, 900);
    let best = nelder_mead(&nll, &first.x, &[0.01, 0.05, 0.3], 1e-7, 600);
    let best = if best.value < first.value {
        best
    } else {
        first
    };
    let (sigma, c, eps) = (best.x[0].exp(), best.x[1].exp(), best.x[2].exp());
    if !(sigma.is_finite() && c.is_finite()) {
        return None;
    }
    // Curvature in (σ, c, ε), the rates linear so that one at zero keeps its error; the point
    // moved off zero by one step where a rate is smaller than it.
    let h = [1e-3 * sigma, (1e-2 * c).max(1e-6), (1e-2 * eps).max(1e-7)];
    let x = [sigma, c.max(h[1]), eps.max(h[2])];
    let f = |d: [f64; 3]| nll_at(x[0] + d[0], x[1] + d[1], x[2] + d[2]);
    let f0 = f([0.0; 3]);
    let mut hess = [0.0; 9];
    for i in 0..3 {
        for j in i..3 {
            let step = |si: f64, sj: f64| {
                let mut d = [0.0; 3];
                d[i] += si * h[i];
                d[j] += sj * h[j];
                f(d)
            };
            let v = if i == j {
                (step(1.0, 0.0) - 2.0 * f0 + step(-1.0, 0.0)) / (h[i] * h[i])
            } else {
                (step(1.0, 1.0) - step(1.0, -1.0) - step(-1.0, 1.0) + step(-1.0, -1.0))
                    / (4.0 * h[i] * h[j])
            };
            hess[i * 3 + j] = v;
            hess[j * 3 + i] = v;
        }
    }
    // Standard errors from the inverse curvature; NaN where it is not positive definite (a
    // fit that did not settle): such a level is left out of the fit over exposures.
    let (var_s, var_c) = invert(&hess, 3)
        .filter(|m| m[0] > 0.0 && m[4] > 0.0 && m[8] > 0.0)
        .map_or((f64::NAN, f64::NAN), |m| (m[0], m[4]));
    Some(SpuriousLevel {
        exposure_s,
        electrons: c,
        electrons_se: var_c.sqrt(),
        read_sigma_dn: sigma,
        read_sigma_se: var_s.sqrt(),
        pairs: d.pairs,
        outliers: eps,
    })
}

/// The spurious charge across exposures: `c(t) = CIC + dark·t`, and the read noise.
#[derive(Clone, Debug, Serialize)]
pub struct SpuriousFit {
    /// Clock-induced charge, e⁻ per pixel per frame.
    pub cic_e: f64,
    /// Its standard error.
    pub cic_se: f64,
    /// Dark current, e⁻ per pixel per second (0 from a single exposure).
    pub dark_e_per_s: f64,
    /// Its standard error (from two exposures, the points' own errors; NaN from one).
    pub dark_se: f64,
    /// The read noise, DN: the median over exposures.
    pub read_sigma_dn: f64,
    /// Each exposure's fit (those with a standard error: the others are left out).
    pub levels: Vec<SpuriousLevel>,
}

/// Fits `c(t) = CIC + dark·t` over the exposures, weighted by their standard errors; a
/// negative coefficient (noise around zero) is reported as 0.
pub fn fit_exposures(levels: Vec<SpuriousLevel>) -> Option<SpuriousFit> {
    let levels: Vec<SpuriousLevel> = levels
        .into_iter()
        .filter(|l| l.electrons_se.is_finite() && l.electrons_se > 0.0)
        .collect();
    if levels.is_empty() {
        return None;
    }
    let read_sigma_dn = emccd_profile::median(levels.iter().map(|l| l.read_sigma_dn))?;
    let x: Vec<f64> = levels.iter().map(|l| l.exposure_s).collect();
    let y: Vec<f64> = levels.iter().map(|l| l.electrons).collect();
    let w: Vec<f64> = levels
        .iter()
        .map(|l| 1.0 / l.electrons_se.powi(2))
        .collect();
    let (cic, cic_se, dark, dark_se) = match line(&x, &y, Some(&w)) {
        Some(f) if levels.len() >= 2 => {
            // With two exposures the line has no scatter to scale its errors: the points' own,
            // the intercept's variance 1/Σw + x̄²/Σw(x − x̄)² at t = 0.
            let (cs, ds) = if f.intercept_se.is_finite() {
                (f.intercept_se, f.slope_se)
            } else {
                let sw: f64 = w.iter().sum();
                let mx = x.iter().zip(&w).map(|(x, w)| x * w).sum::<f64>() / sw;
                let sxx: f64 = x.iter().zip(&w).map(|(x, w)| w * (x - mx).powi(2)).sum();
                ((1.0 / sw + mx * mx / sxx).sqrt(), (1.0 / sxx).sqrt())
            };
            (f.intercept, cs, f.slope, ds)
        }
        _ => {
            let l = &levels[0];
            (l.electrons, l.electrons_se, 0.0, f64::NAN)
        }
    };
    Some(SpuriousFit {
        cic_e: cic.max(0.0),
        cic_se,
        dark_e_per_s: dark.max(0.0),
        dark_se,
        read_sigma_dn,
        levels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Gamma, Normal, Poisson};

    /// Paired bias frames of a camera with read noise `sigma`, `c` spurious electrons per
    /// frame and `g` DN per electron at EM gain 300, rounded to whole DN, over a fixed pattern.
    fn differences(
        sigma: f64,
        c: f64,
        g: f64,
        frames: usize,
        pixels: usize,
        seed: u64,
    ) -> Differences {
        stack(
            sigma,
            c,
            None,
            g,
            frames,
            pixels,
            seed,
            Differences::default(),
        )
        .1
    }

    /// The same with hot pixels (`hot`: every `.0`-th pixel holds `.1` more electrons a frame),
    /// into `d`; also returns the per-pixel std.
    #[allow(clippy::too_many_arguments)]
    fn stack(
        sigma: f64,
        c: f64,
        hot: Option<(usize, f64)>,
        g: f64,
        frames: usize,
        pixels: usize,
        seed: u64,
        mut d: Differences,
    ) -> (Vec<f32>, Differences) {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let a = 300.0 / 299.0;
        let gamma1 = Gamma::new(a, g / a).unwrap();
        let noise = Normal::new(0.0, sigma).unwrap();
        let pois = (c > 0.0).then(|| Poisson::new(c).unwrap());
        let hot_pois = hot.map(|(every, e)| (every, Poisson::new(e).unwrap()));
        let pattern: Vec<f64> = (0..pixels).map(|i| 500.0 + (i % 97) as f64).collect();
        let (mut s1, mut s2) = (vec![0f64; pixels], vec![0f64; pixels]);
        for _ in 0..frames {
            let frame: Vec<f32> = pattern
                .iter()
                .enumerate()
                .map(|(i, &b)| {
                    let mut n = pois.map_or(0, |p| p.sample(&mut rng) as u32);
                    if let Some((every, p)) = &hot_pois {
                        if i % every == 0 {
                            n += p.sample(&mut rng) as u32;
                        }
                    }
                    let em: f64 = (0..n).map(|_| gamma1.sample(&mut rng)).sum();
                    (b + em + noise.sample(&mut rng)).round() as f32
                })
                .collect();
            for (i, &v) in frame.iter().enumerate() {
                s1[i] += v as f64 - 500.0;
                s2[i] += (v as f64 - 500.0).powi(2);
            }
            d.push(&frame);
        }
        let n = frames as f64;
        let std = s1
            .iter()
            .zip(&s2)
            .map(|(a, b)| ((b - a * a / n) / (n - 1.0)).max(0.0).sqrt() as f32)
            .collect();
        (std, d)
    }

    /// Hot pixels (one in 50, 0.5 e⁻ a frame at the shorter exposure and 3 at this one) would
    /// be read as spurious charge; the shorter stack's std map leaves them out and the camera's
    /// CIC comes back within four standard errors.
    #[test]
    fn hot_pixels_are_left_out() {
        let (sigma, c, g, px) = (6.0, 0.02, 40.0, 30_000);
        let (std, _) = stack(sigma, c, Some((50, 0.5)), g, 16, px, 21, Default::default());
        let fit = |d: Differences| {
            let (_, d) = stack(sigma, c, Some((50, 3.0)), g, 16, px, 22, d);
            fit_level(&d, 0.01, g, 300.0).unwrap()
        };
        let kept = fit(Differences::default());
        let left = fit(Differences::leaving_out_noisy(&std));
        assert!(kept.electrons > c + 6.0 * kept.electrons_se, "{kept:?}");
        assert!(
            (left.electrons - c).abs() < 4.0 * left.electrons_se,
            "{left:?}"
        );
    }

    #[test]
    fn recovers_read_noise_and_spurious_charge() {
        // A register of 3 σ per electron (the hardest of the suite's cameras) and one of 6.
        for (sigma, c, g, seed) in [
            (5.0, 0.05, 15.0, 1),
            (12.0, 0.02, 75.0, 2),
            (3.0, 0.0, 10.0, 3),
        ] {
            let d = differences(sigma, c, g, 16, 40_000, seed);
            let f = fit_level(&d, 0.01, g, 300.0).expect("fit");
            // Four standard errors: the fit's own, from the likelihood's curvature.
            assert!(
                (f.electrons - c).abs() < 4.0 * f.electrons_se + 2e-4,
                "c {} ± {} vs {c}",
                f.electrons,
                f.electrons_se
            );
            assert!(
                (f.read_sigma_dn - sigma).abs() < 4.0 * f.read_sigma_se,
                "σ {} ± {} vs {sigma}",
                f.read_sigma_dn,
                f.read_sigma_se
            );
            // The errors are what 320 000 differences give: c to a few percent.
            if c > 0.0 {
                assert!(f.electrons_se < 0.05 * c, "se {}", f.electrons_se);
            }
        }
    }

    #[test]
    fn dark_current_is_the_slope_over_exposures() {
        let (cic, dark) = (0.03, 0.5);
        let levels: Vec<SpuriousLevel> = [0.001, 0.01, 0.05, 0.1]
            .iter()
            .enumerate()
            .map(|(i, &t)| {
                let d = differences(6.0, cic + dark * t, 40.0, 16, 30_000, 10 + i as u64);
                fit_level(&d, t, 40.0, 300.0).unwrap()
            })
            .collect();
        let f = fit_exposures(levels).unwrap();
        assert!(
            (f.cic_e - cic).abs() < 4.0 * f.cic_se,
            "CIC {} ± {}",
            f.cic_e,
            f.cic_se
        );
        assert!(
            (f.dark_e_per_s - dark).abs() < 4.0 * f.dark_se,
            "dark {} ± {}",
            f.dark_e_per_s,
            f.dark_se
        );
        assert!((f.read_sigma_dn / 6.0 - 1.0).abs() < 0.02);
    }
}
