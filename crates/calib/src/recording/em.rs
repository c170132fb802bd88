//! The EM register's output on whole-DN histograms: the zero-electron peak and the tail of a few
//! electrons, fitted by maximum likelihood.
//!
//! A dim pixel's value is `x = b + N(0, σ²) + E(n)`, `n ~ Poisson(λ)` electrons, each leaving the
//! register as about an exponential of mean `g` DN (Gamma of shape 1: the register's excess
//! noise at high gain), rounded to whole DN. The pixels pooled differ in their light: `λ` is
//! taken as Gamma-distributed among them, of mean `c` and relative variance `ν` (a negative
//! binomial count; `ν = 0` is one Poisson rate). Two forms are fitted:
//!
//! - [`Form::Values`]: the values themselves (the peak at the bias `b`, of width `σ`);
//! - [`Form::Differences`]: differences of two values of the same charge level (two frames of a
//!   pixel, or two neighbouring pixels of a flat region), where the bias and any fixed pattern
//!   cancel and the tail on both sides holds the single-electron scale `g`.
//!
//! Both densities come from their characteristic functions by one real FFT per evaluation, as in
//! [`crate::spurious`]; a share `ε` of the values spread evenly over the window stands for what
//! neither form describes (hot pixels, cosmic rays, a bright neighbour's edge).

use realfft::num_complex::Complex64;
use realfft::RealFftPlanner;

use crate::fit::{invert, nelder_mead};

/// Which histogram is fitted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Form {
    /// The values: `b + N(0, σ²) + E(n)`.
    Values,
    /// Differences of two independent values of one level: `N(0, 2σ²) + E(n₁) − E(n₂)`.
    Differences,
}

/// A histogram in whole DN: `counts[i]` values equal to `origin + i`.
#[derive(Clone, Debug)]
pub struct Histogram {
    /// The value of the first bin, DN.
    pub origin: i64,
    /// Counts per DN.
    pub counts: Vec<f64>,
}

impl Histogram {
    /// The histogram of `values` (rounded to whole DN) between `lo` and `hi` inclusive; values
    /// outside are left out.
    pub fn of(values: impl IntoIterator<Item = f64>, lo: i64, hi: i64) -> Histogram {
        let mut counts = vec![0.0; (hi - lo + 1).max(1) as usize];
        for v in values {
            let k = v.round();
            if k >= lo as f64 && k <= hi as f64 {
                counts[(k as i64 - lo) as usize] += 1.0;
            }
        }
        Histogram { origin: lo, counts }
    }

    /// Values counted.
    pub fn total(&self) -> f64 {
        self.counts.iter().sum()
    }
}

/// The parameters of either form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// The bias (the zero-electron peak), DN; 0 for differences.
    pub bias: f64,
    /// The read noise of one value, DN (before rounding).
    pub sigma: f64,
    /// Electrons per value (per frame and pixel), the mean over the pixels pooled.
    pub electrons: f64,
    /// The relative variance of the pixels' electron rates about that mean.
    pub spread: f64,
    /// DN per electron out of the register.
    pub gain: f64,
    /// The share of outliers.
    pub outliers: f64,
}

/// A fit with its standard errors (NaN where the curvature does not give one).
#[derive(Clone, Copy, Debug)]
pub struct Fit {
    /// The most likely parameters.
    pub params: Params,
    /// Their standard errors.
    pub se: Params,
    /// Values in the window.
    pub values: f64,
}

/// The density model of one form on a histogram's window.
struct Model<'a> {
    form: Form,
    hist: &'a Histogram,
    /// FFT length: the window plus room on each side so the cyclic density does not wrap.
    n: usize,
    /// Where the window's first bin sits on the cyclic grid.
    offset: usize,
    plan: std::sync::Arc<dyn realfft::ComplexToReal<f64>>,
    /// The spectrum of one bin (a sinc) at each frequency: the same for every evaluation.
    sinc: Vec<f64>,
    scratch: std::cell::RefCell<(Vec<Complex64>, Vec<f64>, Vec<Complex64>)>,
}

impl<'a> Model<'a> {
    fn new(form: Form, hist: &'a Histogram, pad: f64) -> Model<'a> {
        let len = hist.counts.len();
        // Room against wrap-around, but never more than the window itself: a tail scale far
        // beyond the window (a fit wandering off) must not make every evaluation huge.
        let pad = pad.min(len as f64).ceil().max(16.0) as usize;
        let n = (len + 2 * pad).next_power_of_two();
        let plan = RealFftPlanner::<f64>::new().plan_fft_inverse(n);
        let step = 2.0 * std::f64::consts::PI / n as f64;
        let sinc = (0..n / 2 + 1)
            .map(|k| {
                let h = step * k as f64 / 2.0;
                if k == 0 {
                    1.0
                } else {
                    h.sin() / h
                }
            })
            .collect();
        let scratch = std::cell::RefCell::new((
            plan.make_input_vec(),
            plan.make_output_vec(),
            plan.make_scratch_vec(),
        ));
        Model {
            form,
            hist,
            n,
            offset: pad,
            plan,
            sinc,
            scratch,
        }
    }

    /// The probability of each bin of the window (before normalizing to the window), for the
    /// parameters `p`: bin `i` is the value `origin + i`.
    fn pmf(&self, p: &Params) -> Vec<f64> {
        let mut s = self.scratch.borrow_mut();
        let (spec, out, scratch) = &mut *s;
        let n = self.n;
        let step = 2.0 * std::f64::consts::PI / n as f64;
        // The grid's zero is the window's first bin moved `offset` bins right, so value v sits
        // at index v − origin + offset.
        let shift = match self.form {
            Form::Values => p.bias - (self.hist.origin - self.offset as i64) as f64,
            Form::Differences => -(self.hist.origin - self.offset as i64) as f64,
        };
        for (k, (v, &sinc)) in spec.iter_mut().zip(&self.sinc).enumerate() {
            let t = step * k as f64;
            // φ(−t): the inverse FFT sums e^{+itk}, the density needs e^{−itk}.
            let phi_e = Complex64::new(1.0, p.gain * t).inv();
            // The electrons' part, log E_λ[e^{λu}] for λ ~ Gamma(1/ν, cν): c·u as ν → 0.
            let charge = |u: Complex64| -> Complex64 {
                if p.spread < 1e-9 {
                    p.electrons * u
                } else {
                    -(1.0 - p.spread * p.electrons * u).ln() / p.spread
                }
            };
            let (log, q) = match self.form {
                Form::Values => (
                    Complex64::new(-0.5 * p.sigma * p.sigma * t * t, -shift * t)
                        + charge(phi_e - 1.0),
                    sinc,
                ),
                Form::Differences => (
                    Complex64::new(-p.sigma * p.sigma * t * t, -shift * t)
                        + charge(Complex64::new(2.0 * (phi_e.re - 1.0), 0.0)),
                    sinc * sinc,
                ),
            };
            *v = log.exp() * q;
        }
        spec[0].im = 0.0;
        if let Some(last) = spec.last_mut() {
            last.im = 0.0;
        }
        // The plan only fails on wrong buffer lengths, which `make_*_vec` rule out.
        let _ = self.plan.process_with_scratch(spec, out, scratch);
        let len = self.hist.counts.len();
        out[self.offset..self.offset + len]
            .iter()
            .map(|v| (v / n as f64).max(1e-300))
            .collect()
    }

    /// The negative log-likelihood of the histogram under `p` (the model normalized to the
    /// window, with its outlier share); infinite outside the parameters' range.
    fn nll(&self, p: &Params) -> f64 {
        if !(p.sigma > 0.05
            && p.electrons >= 0.0
            && p.electrons < 30.0
            && p.gain > 0.2
            && p.gain < 1e6
            && (0.0..20.0).contains(&p.spread)
            && (0.0..0.5).contains(&p.outliers))
        {
            return f64::INFINITY;
        }
        let pmf = self.pmf(p);
        let mass: f64 = pmf.iter().sum();
        let width = pmf.len() as f64;
        -self
            .hist
            .counts
            .iter()
            .zip(&pmf)
            .filter(|(&h, _)| h > 0.0)
            .map(|(&h, &q)| h * ((1.0 - p.outliers) * q / mass + p.outliers / width).ln())
            .sum::<f64>()
    }
}

/// The counts the fit expects in each bin of `hist` under `p` (the report's curve).
pub fn expected(form: Form, hist: &Histogram, p: &Params) -> Vec<f64> {
    let model = Model::new(form, hist, 12.0 * p.sigma + 8.0 * p.gain);
    let pmf = model.pmf(p);
    let mass: f64 = pmf.iter().sum();
    let total = hist.total();
    let width = pmf.len() as f64;
    pmf.iter()
        .map(|q| total * ((1.0 - p.outliers) * q / mass + p.outliers / width))
        .collect()
}

/// Which parameters a fit leaves free.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Free {
    /// The register's DN per electron.
    pub gain: bool,
    /// The spread of the electron rates among the pixels.
    pub spread: bool,
}

/// Fits `form` to `hist` from the start `p0`, the bias (for values) and the gain (where `free`
/// says so) free with the read noise, the electrons and the outlier share. `None` when the fit
/// does not settle on finite numbers.
pub fn fit(form: Form, hist: &Histogram, p0: Params, free: Free) -> Option<Fit> {
    let values = hist.total();
    if values < 100.0 {
        return None;
    }
    let model = Model::new(form, hist, 12.0 * p0.sigma + 8.0 * p0.gain);
    // The search runs on logs (positive parameters) and the bias in units of the read noise.
    let unpack = |x: &[f64]| -> Params {
        let mut i = 0;
        let mut next = || {
            i += 1;
            x[i - 1]
        };
        let bias = if form == Form::Values {
            p0.bias + next() * p0.sigma
        } else {
            0.0
        };
        let sigma = next().exp();
        let electrons = next().exp();
        let outliers = next().exp();
        let gain = if free.gain { next().exp() } else { p0.gain };
        let spread = if free.spread { next().exp() } else { p0.spread };
        Params {
            bias,
            sigma,
            electrons,
            spread,
            gain,
            outliers,
        }
    };
    let mut x0 = Vec::new();
    let mut steps = Vec::new();
    if form == Form::Values {
        x0.push(0.0);
        steps.push(0.3);
    }
    x0.extend([
        p0.sigma.ln(),
        p0.electrons.max(1e-4).ln(),
        p0.outliers.max(1e-5).ln(),
    ]);
    steps.extend([0.1, 0.5, 1.0]);
    if free.gain {
        x0.push(p0.gain.ln());
        steps.push(0.2);
    }
    if free.spread {
        x0.push(p0.spread.max(1e-3).ln());
        steps.push(1.0);
    }
    let f = |x: &[f64]| model.nll(&unpack(x));
    let first = nelder_mead(&f, &x0, &steps, 1e-6, 1500);
    let fine: Vec<f64> = steps.iter().map(|s| s * 0.1).collect();
    let second = nelder_mead(&f, &first.x, &fine, 1e-8, 1000);
    let best = if second.value <= first.value {
        second
    } else {
        first
    };
    let params = unpack(&best.x);
    if !best.value.is_finite() || !params.sigma.is_finite() || !params.gain.is_finite() {
        return None;
    }
    Some(Fit {
        params,
        se: standard_errors(&model, &params, form, free),
        values,
    })
}

/// Standard errors from the likelihood's curvature in the natural parameters; a rate at or
/// near zero is moved off it by one step so that its error is still given.
fn standard_errors(model: &Model, p: &Params, form: Form, free: Free) -> Params {
    type Get = fn(&Params) -> f64;
    type Set = fn(&mut Params, f64);
    let mut axes: Vec<(Get, Set, f64)> = Vec::new();
    if form == Form::Values {
        axes.push((|p| p.bias, |p, v| p.bias = v, 1e-3 * p.sigma));
    }
    axes.push((|p| p.sigma, |p, v| p.sigma = v, 1e-3 * p.sigma));
    axes.push((
        |p| p.electrons,
        |p, v| p.electrons = v,
        (1e-2 * p.electrons).max(1e-6),
    ));
    axes.push((
        |p| p.outliers,
        |p, v| p.outliers = v,
        (1e-2 * p.outliers).max(1e-7),
    ));
    if free.gain {
        axes.push((|p| p.gain, |p, v| p.gain = v, 1e-3 * p.gain));
    }
    if free.spread {
        axes.push((
            |p| p.spread,
            |p, v| p.spread = v,
            (1e-2 * p.spread).max(1e-4),
        ));
    }
    let k = axes.len();
    let mut at = *p;
    for (get, set, h) in &axes {
        let v = get(&at).max(*h);
        set(&mut at, v);
    }
    let f = |d: &[f64]| {
        let mut q = at;
        for ((get, set, h), di) in axes.iter().zip(d) {
            let v = get(&q) + di * h;
            set(&mut q, v);
        }
        model.nll(&q)
    };
    let f0 = f(&vec![0.0; k]);
    let mut hess = vec![0.0; k * k];
    for i in 0..k {
        for j in i..k {
            let step = |si: f64, sj: f64| {
                let mut d = vec![0.0; k];
                d[i] += si;
                d[j] += sj;
                f(&d)
            };
            let (hi, hj) = (axes[i].2, axes[j].2);
            let v = if i == j {
                (step(1.0, 0.0) - 2.0 * f0 + step(-1.0, 0.0)) / (hi * hi)
            } else {
                (step(1.0, 1.0) - step(1.0, -1.0) - step(-1.0, 1.0) + step(-1.0, -1.0))
                    / (4.0 * hi * hj)
            };
            hess[i * k + j] = v;
            hess[j * k + i] = v;
        }
    }
    let var = invert(&hess, k).filter(|m| (0..k).all(|i| m[i * k + i] > 0.0));
    let mut se = Params {
        bias: f64::NAN,
        sigma: f64::NAN,
        electrons: f64::NAN,
        spread: f64::NAN,
        gain: f64::NAN,
        outliers: f64::NAN,
    };
    if let Some(m) = var {
        for (i, (_, set, _)) in axes.iter().enumerate() {
            set(&mut se, m[i * k + i].sqrt());
        }
    }
    se
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Exp, Normal, Poisson};

    fn sample(p: &Params, n: usize, seed: u64) -> Vec<f64> {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let noise = Normal::new(0.0, p.sigma).unwrap();
        let pois = Poisson::new(p.electrons).unwrap();
        let em = Exp::new(1.0 / p.gain).unwrap();
        (0..n)
            .map(|_| {
                let k = pois.sample(&mut rng) as u32;
                let e: f64 = (0..k).map(|_| em.sample(&mut rng)).sum();
                (p.bias + noise.sample(&mut rng) + e).round()
            })
            .collect()
    }

    /// The model's density sums to one and has the mean b + c·g: the FFT's sign and shift are
    /// right.
    #[test]
    fn the_density_has_the_model_mean() {
        let hist = Histogram {
            origin: 400,
            counts: vec![1.0; 1500],
        };
        let p = Params {
            bias: 500.3,
            sigma: 8.0,
            electrons: 0.4,
            spread: 0.0,
            gain: 60.0,
            outliers: 0.0,
        };
        let m = Model::new(Form::Values, &hist, 200.0);
        let pmf = m.pmf(&p);
        let mass: f64 = pmf.iter().sum();
        let mean: f64 = pmf
            .iter()
            .enumerate()
            .map(|(i, q)| (400 + i as i64) as f64 * q)
            .sum::<f64>()
            / mass;
        assert!((mass - 1.0).abs() < 1e-6, "mass {mass}");
        assert!((mean - (500.3 + 0.4 * 60.0)).abs() < 0.05, "mean {mean}");
    }

    /// Values and differences of a known camera give back its bias, read noise, electrons and
    /// gain within four of the fit's own standard errors.
    #[test]
    fn recovers_a_known_register() {
        let truth = Params {
            bias: 500.0,
            sigma: 11.0,
            electrons: 0.15,
            spread: 0.0,
            gain: 75.0,
            outliers: 0.0,
        };
        let v = sample(&truth, 200_000, 1);
        let hist = Histogram::of(v.iter().copied(), 400, 2500);
        let start = Params {
            bias: 502.0,
            sigma: 10.0,
            electrons: 0.1,
            spread: 0.0,
            gain: 75.0,
            outliers: 1e-4,
        };
        let f = fit(
            Form::Values,
            &hist,
            start,
            Free {
                gain: false,
                spread: false,
            },
        )
        .unwrap();
        assert!(
            (f.params.bias - 500.0).abs() < 4.0 * f.se.bias,
            "{:?} ± {:?}",
            f.params,
            f.se
        );
        assert!((f.params.sigma - 11.0).abs() < 4.0 * f.se.sigma, "{f:?}");

        let w = sample(&truth, 200_000, 2);
        let d: Vec<f64> = v.iter().zip(&w).map(|(a, b)| a - b).collect();
        let hist = Histogram::of(d, -2500, 2500);
        let start = Params {
            bias: 0.0,
            sigma: 9.0,
            electrons: 0.05,
            spread: 0.0,
            gain: 40.0,
            outliers: 1e-4,
        };
        let f = fit(
            Form::Differences,
            &hist,
            start,
            Free {
                gain: true,
                spread: false,
            },
        )
        .unwrap();
        for (got, se, want) in [
            (f.params.sigma, f.se.sigma, 11.0),
            (f.params.electrons, f.se.electrons, 0.15),
            (f.params.gain, f.se.gain, 75.0),
        ] {
            assert!((got - want).abs() < 4.0 * se, "{got} ± {se} vs {want}");
        }
        // 200 000 differences hold about 60 000 electrons: the gain to a few percent.
        assert!(f.se.gain < 0.03 * 75.0, "{:?}", f.se);
    }
}
