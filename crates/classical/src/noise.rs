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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bm3d::dct_matrix as dct;

    #[test]
    fn white_noise_is_one_everywhere_and_binned_stays_white() {
        let w = Covariance::white();
        assert!(w
            .coefficient_variances(&dct(8), 8)
            .iter()
            .all(|&v| v == 1.0));
        for b in 2..4 {
            let binned = w.binned(b);
            assert!(binned
                .coefficient_variances(&dct(8), 8)
                .iter()
                .all(|&v| (v - 1.0).abs() < 1e-12));
        }
    }

    /// Noise smoothed by a two-tap mean [½ ½]: its covariance is ½, and ¼ at lag 1. A DCT
    /// coefficient's variance over white noise's is then the filter's squared response at its
    /// frequency, `cos²(πk/2n)`, less the lag-1 products a block's edge cuts off,
    /// `¼·(r₀² + r₇²)` for the coefficient's row `r` (exactly, for the DCT).
    #[test]
    fn smoothed_noise_keeps_its_coarse_coefficients_and_loses_its_fine() {
        let c = filtered(&[0.5, 0.5]);
        assert_eq!(c, vec![0.25, 0.5, 0.25]);
        let mut cov = Covariance::empty();
        cov.add(1.0, &c, &[1.0]);
        let rows = dct(8);
        let v = cov.coefficient_variances(&rows, 8);
        // Row 0 along y is white: along x the coefficients follow the filter.
        for l in 0..8 {
            let edge = 0.25 * (rows[l * 8].powi(2) + rows[l * 8 + 7].powi(2));
            let want = (std::f64::consts::PI * l as f64 / 16.0).cos().powi(2) - edge;
            assert!(
                (v[l] - want).abs() < 1e-12,
                "coefficient {l}: {} against {want}",
                v[l]
            );
        }
        // Along y white: every row of coefficients is the first.
        assert!((0..64).all(|i| (v[i] - v[i % 8]).abs() < 1e-12));
        // Binned by 2, a pair's sum holds its pixels' covariance: var(a + b) = ½ + ½ + 2·¼ = 1.5,
        // over the 2 that white noise of variance 1 would give along the axis, 0.75 (each pixel
        // was 0.5): the coarse noise is larger than a pixel's says.
        let binned = cov.binned(2);
        assert!(
            (binned.variance() - 0.75).abs() < 1e-12,
            "{}",
            binned.variance()
        );
    }

    #[test]
    fn normalizing_scales_to_unit_variance_and_filters_compose() {
        let mut cov = Covariance::empty();
        cov.add(3.0, &filtered(&[0.5, 0.5]), &[1.0]);
        assert!((cov.normalized().variance() - 1.0).abs() < 1e-12);
        assert_eq!(Covariance::empty().normalized(), Covariance::white());
        // Filtering by [½ ½] twice is filtering by [¼ ½ ¼].
        let twice = convolved(&filtered(&[0.5, 0.5]), &filtered(&[0.5, 0.5]));
        let once = filtered(&[0.25, 0.5, 0.25]);
        assert_eq!(twice.len(), once.len());
        assert!(twice.iter().zip(&once).all(|(a, b)| (a - b).abs() < 1e-15));
    }
}
