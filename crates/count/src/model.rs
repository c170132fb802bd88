//! What a threshold does to one pixel: the probability that a frame's pixel reads above it,
//! given how many electrons entered the EM register, and from that the event rate as a function
//! of the light, its inverse and its uncertainty. Written here: the register's output for `n`
//! electrons is a gamma distribution (shape `n`, mean `n·g` DN), read noise adds a normal one,
//! and no maintained crate gives the probabilities of their sum.

/// The most electrons per pixel per frame the model follows; beyond it a pixel is an event in
/// every frame whatever the threshold (the gamma tail below any threshold of a few `g` is gone).
const N_MAX: usize = 64;

/// The standard normal's cumulative distribution.
pub fn normal_cdf(z: f64) -> f64 {
    0.5 * libm::erfc(-z / std::f64::consts::SQRT_2)
}

/// The probability that a pixel that received `n` electrons reads at most `t` DN above bias:
/// EM output gamma(n, mean `g` DN per electron) plus read noise N(0, `sigma`²).
///
/// `n = 0`: read noise alone, Φ(t/σ). `n = 1`: closed form, the exponential's tail convolved
/// with the normal, 1 − Q(t/σ) − e^(σ²/2g² − t/g)·Φ((t − σ²/g)/σ). `n ≥ 2`: the gamma's
/// distribution function (a finite sum for an integer shape) averaged over the read noise by
/// the trapezoid rule on ±8σ (error far under 10⁻⁹ for the smooth integrand).
pub fn below(n: usize, t: f64, g: f64, sigma: f64) -> f64 {
    let sigma = sigma.max(1e-9);
    match n {
        0 => normal_cdf(t / sigma),
        1 => {
            let q = 1.0 - normal_cdf(t / sigma);
            let tail = (sigma * sigma / (2.0 * g * g) - t / g).exp()
                * normal_cdf((t - sigma * sigma / g) / sigma);
            (1.0 - q - tail).clamp(0.0, 1.0)
        }
        _ => {
            let gamma_cdf = |x: f64| -> f64 {
                if x <= 0.0 {
                    return 0.0;
                }
                let u = x / g;
                // 1 − e^(−u)·Σ_{j<n} u^j/j!
                let (mut term, mut sum) = (1.0, 1.0);
                for j in 1..n {
                    term *= u / j as f64;
                    sum += term;
                }
                (1.0 - (-u).exp() * sum).clamp(0.0, 1.0)
            };
            let steps = 320;
            let h = 16.0 * sigma / steps as f64;
            let mut acc = 0.0;
            for k in 0..=steps {
                let y = -8.0 * sigma + k as f64 * h;
                let w = if k == 0 || k == steps { 0.5 } else { 1.0 };
                let density = (-0.5 * (y / sigma).powi(2)).exp()
                    / (sigma * (2.0 * std::f64::consts::PI).sqrt());
                acc += w * density * gamma_cdf(t - y);
            }
            (acc * h).clamp(0.0, 1.0)
        }
    }
}

/// One pixel at one threshold: `below[n]`, the probability of no event when `n` electrons
/// entered the register, and `spurious`, the electrons a frame adds without light (clock-induced
/// charge and dark current), which the register amplifies as it does photo-electrons.
#[derive(Clone, Debug)]
pub struct PixelModel {
    below: Vec<f64>,
    spurious: f64,
}

impl PixelModel {
    /// The model of a pixel with read noise `sigma` (DN) at threshold `t` (DN above bias), EM
    /// output `g` DN per electron, `spurious` electrons per frame.
    pub fn new(t: f64, g: f64, sigma: f64, spurious: f64) -> PixelModel {
        let mut below_n = Vec::with_capacity(8);
        for n in 0..=N_MAX {
            let b = below(n, t, g, sigma);
            below_n.push(b);
            // The gamma's mass below t only shrinks with n.
            if n >= 2 && b < 1e-15 {
                break;
            }
        }
        PixelModel {
            below: below_n,
            spurious,
        }
    }

    /// Probability of no event with `n` electrons in the register.
    fn below_n(&self, n: usize) -> f64 {
        self.below.get(n).copied().unwrap_or(0.0)
    }

    /// Σₙ Pois(n; μ)·a(n) for the photo-electron rate `lambda` (μ = λ + spurious).
    fn expect(&self, lambda: f64, a: impl Fn(usize) -> f64) -> f64 {
        let mu = (lambda + self.spurious).max(0.0);
        let mut p = (-mu).exp();
        let mut acc = 0.0;
        let mut mass = 0.0;
        for n in 0..=N_MAX {
            if n > 0 {
                p *= mu / n as f64;
            }
            acc += p * a(n);
            mass += p;
            if n > self.below.len() && 1.0 - mass < 1e-15 {
                break;
            }
        }
        acc
    }

    /// The probability that a frame's pixel is an event at `lambda` photo-electrons per frame.
    pub fn event(&self, lambda: f64) -> f64 {
        1.0 - self.expect(lambda, |n| self.below_n(n))
    }

    /// d event / dλ: Σₙ Pois(n)·(below(n) − below(n+1)).
    pub fn slope(&self, lambda: f64) -> f64 {
        self.expect(lambda, |n| self.below_n(n) - self.below_n(n + 1))
    }

    /// d² event / dλ².
    fn curvature(&self, lambda: f64) -> f64 {
        let d = |n: usize| self.below_n(n) - self.below_n(n + 1);
        self.expect(lambda, |n| d(n + 1) - d(n))
    }

    /// The events a frame shows without light (read noise above the threshold, CIC, dark).
    pub fn false_events(&self) -> f64 {
        self.event(0.0)
    }

    /// The probability that one photo-electron alone is missed (its EM output plus read noise
    /// stays under the threshold).
    pub fn missed(&self) -> f64 {
        self.below_n(1)
    }

    /// The photo-electron rate whose event probability is `p` ([`PixelModel::event`] inverted).
    /// Below the false-event rate the line through it is followed (a negative rate: the mean
    /// over pixels stays unbiased where light is absent).
    pub fn rate(&self, p: f64) -> f64 {
        let p0 = self.event(0.0);
        if p <= p0 {
            return (p - p0) / self.slope(0.0).max(1e-300);
        }
        // Bracket, then bisect (event() increases with λ).
        let (mut lo, mut hi) = (0.0, 1.0);
        while self.event(hi) < p && hi < N_MAX as f64 {
            lo = hi;
            hi *= 2.0;
        }
        if self.event(hi) < p {
            return hi;
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.event(mid) < p {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// The rate from `k` events in `frames` frames: the inverse at k/N less its first-order bias
    /// (E[h(p̂)] ≈ h(p) + h″(p)·p(1−p)/2N for the inverse h, h″ = −P″/P′³), and the standard
    /// error √(p(1−p)/N) / P′. At k = N the estimate is the model's limit, and flagged by an
    /// infinite error.
    pub fn estimate(&self, k: u32, frames: u32) -> (f64, f64) {
        let n = frames.max(1) as f64;
        if k >= frames {
            return (self.rate(1.0 - 0.5 / n), f64::INFINITY);
        }
        let p = k as f64 / n;
        let lambda = self.rate(p);
        let at = lambda.max(0.0);
        let d1 = self.slope(at).max(1e-300);
        let d2 = self.curvature(at);
        let var_p = p * (1.0 - p) / n;
        let corrected = lambda + d2 / d1.powi(3) * var_p / 2.0;
        // The error at the estimate; where no event was seen, the binomial's at one event in
        // 2N (not zero).
        let var_p = var_p.max(0.5 / n * (1.0 - 0.5 / n) / n);
        (corrected, var_p.sqrt() / d1)
    }

    /// The variance of the rate from `frames` frames at `lambda` (p(1−p)/N/P′²): what a
    /// threshold is chosen to make small.
    pub fn variance(&self, lambda: f64, frames: u32) -> f64 {
        let p = self.event(lambda);
        let d1 = self.slope(lambda).max(1e-300);
        p * (1.0 - p) / frames.max(1) as f64 / (d1 * d1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed forms against sums and integrals done another way: with no read noise the
    /// register's output is plainly gamma, and Φ, the exponential and the convolution agree
    /// with a brute-force double sum.
    #[test]
    fn below_matches_brute_force() {
        let (g, sigma): (f64, f64) = (10.0, 3.0);
        for t in [0.0, 5.0, 9.0, 20.0, 40.0] {
            for n in 0..5 {
                // Brute force: the gamma(n) + normal density integrated on a fine grid.
                let want = if n == 0 {
                    normal_cdf(t / sigma)
                } else {
                    let (dx, mut acc): (f64, f64) = (0.01, 0.0);
                    let mut x = dx / 2.0;
                    let fact: f64 = (1..n).map(|j| j as f64).product();
                    while x < 60.0 * g {
                        let gd = x.powi(n as i32 - 1) * (-x / g).exp() / (g.powi(n as i32) * fact);
                        acc += gd * dx * normal_cdf((t - x) / sigma);
                        x += dx;
                    }
                    acc
                };
                let got = below(n, t, g, sigma);
                assert!((got - want).abs() < 2e-4, "n={n} t={t}: {got} vs {want}");
            }
        }
        // Without read noise one electron is missed with probability 1 − e^(−t/g).
        let got = below(1, 9.0, 10.0, 1e-9);
        assert!((got - (1.0 - (-0.9f64).exp())).abs() < 1e-9, "{got}");
    }

    /// The inverse undoes the event probability, and the slope is its derivative.
    #[test]
    fn rate_inverts_event() {
        let m = PixelModel::new(9.0, 10.0, 3.0, 0.01);
        for lambda in [0.0, 0.02, 0.1, 0.5, 1.0, 3.0] {
            let p = m.event(lambda);
            assert!((m.rate(p) - lambda).abs() < 1e-9, "{lambda}");
            let h = 1e-5;
            let num = (m.event(lambda + h) - m.event((lambda - h).max(0.0))) / (lambda.min(h) + h);
            assert!(
                (m.slope(lambda) - num).abs() < 1e-5 * num.max(1.0),
                "{lambda}"
            );
        }
        // Below the false-event rate, the line through it: negative rates, continuous at 0.
        let p0 = m.false_events();
        assert!(m.rate(p0 * 0.5) < 0.0 && m.rate(p0).abs() < 1e-12);
    }
}
