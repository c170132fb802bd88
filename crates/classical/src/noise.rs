//! The covariance of stationary noise that is not white, as BM3D needs it to threshold and
//! shrink each transform coefficient at that coefficient's own noise (after Mäkinen, Azzari &
//! Foi 2020, "Collaborative filtering of correlated noise", simplified to the 2-D transform of
//! one block: the blocks of a group are taken as independent).
//!
//! A motion-compensated mean holds neighbours resampled to fractions of a pixel. Resampling
//! low-passes their noise: it keeps a frame's coarse noise whole and takes some of its fine
//! noise, so the mean's noise is weaker in its fine detail than in its coarse.
//! Told a single noise level (the mean's per pixel), BM3D thresholds the coarse coefficients
//! too little and the fine ones too much; a binned pass of iterative BM3D, which sees the coarse
//! noise alone, is told too little altogether.

/// A stationary noise's covariance between pixels `dx`, `dy` apart, a sum of separable terms
/// `Σ a · cx(dx) · cy(dy)` (each a frame resampled by its own kernel, weighted by its share of
/// the mean), in units of the white noise a denoiser is told of: [`Covariance::white`] is that
/// noise itself.
#[derive(Clone, Debug, PartialEq)]
pub struct Covariance {
    terms: Vec<Term>,
}

/// One separable term: its weight and the covariances along x and along y at lags
/// `−(len − 1)/2 ..= (len − 1)/2` (odd lengths, symmetric).
#[derive(Clone, Debug, PartialEq)]
struct Term {
    weight: f64,
    x: Vec<f64>,
    y: Vec<f64>,
}

impl Covariance {
    /// White noise of variance 1.
    pub fn white() -> Covariance {
        Covariance {
            terms: vec![Term {
                weight: 1.0,
                x: vec![1.0],
                y: vec![1.0],
            }],
        }
    }

    /// No terms yet: [`Covariance::add`] builds it up.
    pub fn empty() -> Covariance {
        Covariance { terms: Vec::new() }
    }

    /// Adds `weight` times the separable covariance `x(dx) · y(dy)` (lags centred, odd
    /// lengths).
    pub fn add(&mut self, weight: f64, x: &[f64], y: &[f64]) {
        assert!(
            x.len() % 2 == 1 && y.len() % 2 == 1,
            "covariances are centred"
        );
        if weight > 0.0 {
            self.terms.push(Term {
                weight,
                x: x.to_vec(),
                y: y.to_vec(),
            });
        }
    }

    /// The variance of one pixel.
    pub fn variance(&self) -> f64 {
        self.terms
            .iter()
            .map(|t| t.weight * t.x[t.x.len() / 2] * t.y[t.y.len() / 2])
            .sum()
    }

    /// The same covariance scaled to a pixel variance of 1 ([`Covariance::white`] where it has
    /// none).
    pub fn normalized(mut self) -> Covariance {
        let v = self.variance();
        if !(v > 0.0 && v.is_finite()) {
            return Covariance::white();
        }
        for t in &mut self.terms {
            t.weight /= v;
        }
        self
    }

    /// The covariance of sums of `b × b` bins of this noise, per sum over `b²` (what the sums'
    /// transform is told: `b²` times a pixel's variance). White noise stays white; coarse noise
    /// adds up across a bin's pixels and comes out larger.
    pub fn binned(&self, b: usize) -> Covariance {
        if b <= 1 {
            return self.clone();
        }
        // Along an axis: cov(D) = Σ_{i,j<b} c(b·D + i − j), over b.
        let bin = |c: &[f64]| -> Vec<f64> {
            let half = (c.len() / 2) as isize;
            let b = b as isize;
            let reach = (half + b - 1) / b;
            (-reach..=reach)
                .map(|d| {
                    let mut s = 0.0;
                    for i in 0..b {
                        for j in 0..b {
                            let lag = b * d + i - j;
                            if lag.abs() <= half {
                                s += c[(lag + half) as usize];
                            }
                        }
                    }
                    s / b as f64
                })
                .collect()
        };
        Covariance {
            terms: self
                .terms
                .iter()
                .map(|t| Term {
                    weight: t.weight,
                    x: bin(&t.x),
                    y: bin(&t.y),
                })
                .collect(),
        }
    }

    /// The noise variance of each coefficient of an `n × n` block's separable transform with
    /// analysis rows `rows` (row-major `n × n`; coefficient `[k][l]` is row `k` along y and
    /// row `l` along x), over what white noise of variance 1 gives it (1 everywhere for
    /// [`Covariance::white`]).
    pub fn coefficient_variances(&self, rows: &[f64], n: usize) -> Vec<f64> {
        assert_eq!(rows.len(), n * n, "transform size");
        // A row's variance under one axis's covariance, over its white variance.
        let along = |c: &[f64], k: usize| -> f64 {
            let r = &rows[k * n..][..n];
            let half = (c.len() / 2) as isize;
            let (mut s, mut white) = (0.0, 0.0);
            for i in 0..n {
                white += r[i] * r[i];
                for j in 0..n {
                    let lag = i as isize - j as isize;
                    if lag.abs() <= half {
                        s += r[i] * r[j] * c[(lag + half) as usize];
                    }
                }
            }
            s / white
        };
        let mut out = vec![0.0; n * n];
        for t in &self.terms {
            let (vx, vy): (Vec<f64>, Vec<f64>) =
                (0..n).map(|k| (along(&t.x, k), along(&t.y, k))).unzip();
            for k in 0..n {
                for l in 0..n {
                    out[k * n + l] += t.weight * vy[k] * vx[l];
                }
            }
        }
        out
    }
}

/// The covariance along one axis of independent unit noise filtered by `kernel` (its
/// autocorrelation, lags `−(len − 1) ..= len − 1`).
pub fn filtered(kernel: &[f64]) -> Vec<f64> {
    let n = kernel.len() as isize;
    (-(n - 1)..n)
        .map(|d| {
            (0..n)
                .filter(|&i| (0..n).contains(&(i + d)))
                .map(|i| kernel[i as usize] * kernel[(i + d) as usize])
                .sum()
        })
        .collect()
}

/// The covariance of noise of covariance `a` filtered once more, by a filter whose
/// autocorrelation is `b` (two filterings in turn: the covariances convolve).
pub fn convolved(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}
