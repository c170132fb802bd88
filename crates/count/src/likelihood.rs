//! The rate from every value a pixel read, not only from whether each cleared a threshold.
//!
//! A threshold keeps one bit of each frame's pixel. Between "surely no electron" and "surely
//! one" lie the values a few read-noise σ above the bias, where an electron's output and the
//! read noise overlap: a threshold calls them all one or the other. Here each frame's value goes
//! into one of [`BINS`] bins — half a read-noise σ wide from −2.5σ to 4σ, half the register's
//! gain wide above — and the rate is the one that makes the pixel's bin counts most likely under
//! the exact model: `n ~ Poisson(λ + spurious)` electrons, the register's gamma output, the
//! read noise ([`crate::model::below`]). On the bundled camera (10 DN per electron, 3 DN read
//! noise) the Fisher information says it is worth about +0.5 dB over the best threshold at 0.1
//! photo-electrons per pixel per frame. Bin counts take `BINS` 16-bit counters a pixel, so an
//! output frame holds at most 65535 input frames.

use crate::model::below;

/// Core edges: (−2.5 + 0.5·j)·σ for j = 0 … 13, from −2.5σ to 4σ.
const CORE: usize = 14;
/// Tail edges: 4σ + k·g/2 for k = 1 … 15.
const TAIL: usize = 15;
/// Bins a pixel's values fall into: below the first edge, between edges, above the last.
pub const BINS: usize = CORE + TAIL + 1;
/// Electrons the model follows in one frame.
const N_MAX: usize = 40;
/// The most frames one output may hold (the counters are 16-bit).
pub const MAX_FRAMES: usize = u16::MAX as usize;

/// Where one pixel's values fall: its read noise, the register's gain and where the true zero
/// lies above the preprocessed one (the spurious signal the fixed pattern removed), in DN.
#[derive(Clone, Copy, Debug)]
pub struct Binning {
    inv_sigma: f32,
    four_sigma: f32,
    inv_half_g: f32,
    shift: f32,
}

impl Binning {
    /// For a pixel of read noise `sigma` behind a register of `g` DN per electron, whose
    /// preprocessed zero lies `shift` DN below the true one.
    pub fn new(sigma: f64, g: f64, shift: f64) -> Binning {
        let sigma = sigma.max(1e-3);
        Binning {
            inv_sigma: (1.0 / sigma) as f32,
            four_sigma: (4.0 * sigma) as f32,
            inv_half_g: (2.0 / g) as f32,
            shift: shift as f32,
        }
    }

    /// The bin of a preprocessed value `v`.
    #[inline]
    pub fn bin(&self, v: f32) -> usize {
        let x = v + self.shift;
        let u = x * self.inv_sigma;
        if u <= -2.5 || u.is_nan() {
            0
        } else if x <= self.four_sigma {
            (((u + 2.5) * 2.0).ceil() as usize).clamp(1, CORE - 1)
        } else {
            // Capped before the cast: a value far beyond the last edge is in the last bin.
            let k = ((x - self.four_sigma) * self.inv_half_g)
                .ceil()
                .min((TAIL + 1) as f32) as usize;
            (CORE - 1 + k.max(1)).min(BINS - 1)
        }
    }

    /// The bins' edges in DN above the true zero, ascending.
    fn edges(sigma: f64, g: f64) -> [f64; BINS - 1] {
        let mut e = [0.0; BINS - 1];
        for (j, v) in e.iter_mut().enumerate().take(CORE) {
            *v = (-2.5 + 0.5 * j as f64) * sigma;
        }
        for k in 1..=TAIL {
            e[CORE - 1 + k] = 4.0 * sigma + k as f64 * g / 2.0;
        }
        e
    }
}

/// The probability of each bin for 0, 1, 2, … electrons in the register, for one read noise
/// and one spurious charge: what a pixel's bin counts are weighed against.
#[derive(Clone, Debug)]
pub struct BinModel {
    /// `q[n][b]`: the probability that a frame with n electrons falls in bin b.
    q: Vec<[f64; BINS]>,
    spurious: f64,
}

impl BinModel {
    /// The model of a pixel of read noise `sigma` (DN) behind `g` DN per electron, with
    /// `spurious` electrons a frame (their mean signal removed or not: the bins are placed on
    /// the true zero by [`Binning`]'s shift).
    pub fn new(sigma: f64, g: f64, spurious: f64) -> BinModel {
        let edges = Binning::edges(sigma.max(1e-3), g);
        let mut q = Vec::with_capacity(N_MAX + 3);
        for n in 0..=N_MAX + 2 {
            // Once n electrons' output is all above the last edge, so is more electrons'.
            if q.last()
                .is_some_and(|p: &[f64; BINS]| p[BINS - 1] > 1.0 - 1e-15)
            {
                let mut top = [0.0; BINS];
                top[BINS - 1] = 1.0;
                q.push(top);
                continue;
            }
            let mut cdf = [1.0; BINS];
            for (b, &t) in edges.iter().enumerate() {
                cdf[b] = below(n, t, g, sigma);
            }
            let mut p = [0.0; BINS];
            let mut prev = 0.0;
            for b in 0..BINS {
                p[b] = (cdf[b] - prev).max(0.0);
                prev = cdf[b];
            }
            q.push(p);
        }
        BinModel { q, spurious }
    }

    /// The Poisson weights of 0, 1, 2, … electrons at mean `mu`, up to where the rest of the
    /// mass is negligible; returns how many.
    fn weights(mu: f64, w: &mut [f64; N_MAX + 1]) -> usize {
        let mut p = (-mu).exp();
        let mut mass = 0.0;
        for n in 0..=N_MAX {
            if n > 0 {
                p *= mu / n as f64;
            }
            w[n] = p;
            mass += p;
            if n as f64 > mu && 1.0 - mass < 1e-13 {
                return n + 1;
            }
        }
        N_MAX + 1
    }

    /// Bin `b`'s probability and its first two derivatives in μ, from the weights.
    #[inline]
    fn bin_terms(&self, b: usize, w: &[f64]) -> (f64, f64, f64) {
        let (mut p0, mut p1, mut p2) = (0.0, 0.0, 0.0);
        for (n, &wn) in w.iter().enumerate() {
            let (q0, q1, q2) = (self.q[n][b], self.q[n + 1][b], self.q[n + 2][b]);
            p0 += wn * q0;
            p1 += wn * (q1 - q0);
            p2 += wn * (q2 - 2.0 * q1 + q0);
        }
        (p0.max(1e-300), p1, p2)
    }

    /// The log-likelihood's first and second derivatives in μ (electrons a frame, spurious
    /// ones included) for the occupied bins `nz` (bin, count).
    fn score(&self, nz: &[(usize, f64)], mu: f64) -> (f64, f64) {
        let mut w = [0.0; N_MAX + 1];
        let k = Self::weights(mu, &mut w);
        let (mut d1, mut d2) = (0.0, 0.0);
        for &(b, c) in nz {
            let (p0, p1, p2) = self.bin_terms(b, &w[..k]);
            d1 += c * p1 / p0;
            d2 += c * (p2 / p0 - (p1 / p0).powi(2));
        }
        (d1, d2)
    }

    /// The Fisher information of one frame at μ.
    fn information(&self, mu: f64) -> f64 {
        let mut w = [0.0; N_MAX + 1];
        let k = Self::weights(mu, &mut w);
        (0..BINS)
            .map(|b| {
                let (p0, p1, _) = self.bin_terms(b, &w[..k]);
                p1 * p1 / p0
            })
            .sum()
    }

    /// The maximum-likelihood photo-electron rate from bin counts `h` of `frames` frames, and
    /// its standard error (from the Fisher information there), Newton's method started at
    /// `start` (the analog rate, say). Where even no light is less likely than the data say
    /// (fewer high values than the spurious charge makes), the line through zero light is
    /// followed below it, as the threshold's inverse does: the mean over pixels stays unbiased
    /// where light is absent.
    pub fn estimate(&self, h: &[u16], frames: u32, start: f64) -> (f64, f64) {
        let n = frames.max(1) as f64;
        let c = self.spurious;
        let se = |mu: f64| 1.0 / (n * self.information(mu)).max(1e-300).sqrt();
        let mut nz = [(0usize, 0f64); BINS];
        let mut k = 0;
        for (b, &v) in h.iter().enumerate() {
            if v > 0 {
                nz[k] = (b, v as f64);
                k += 1;
            }
        }
        let nz = &nz[..k];
        let (g0, _) = self.score(nz, c);
        if g0 <= 0.0 {
            // The score at zero light over its expected curvature: one Fisher-scoring step.
            let i0 = self.information(c);
            return (g0 / (n * i0).max(1e-300), se(c));
        }
        // The root of the score in μ > c: safeguarded Newton steps inside a bracket that grows
        // until it holds the root.
        let limit = N_MAX as f64 / 2.0;
        if c + 1e-6 >= limit {
            // A pixel this hot is beyond the electrons the model follows: no estimate (the
            // analog mean is taken there).
            return (0.0, f64::INFINITY);
        }
        let (mut lo, mut hi) = (c, f64::INFINITY);
        let mut mu = (c + start.max(0.0)).clamp(c + 1e-6, limit);
        for _ in 0..100 {
            let (d1, d2) = self.score(nz, mu);
            if d2 < 0.0 && (d1 / d2).abs() < 1e-9 * mu {
                break;
            }
            if d1 > 0.0 {
                lo = mu;
            } else {
                hi = mu;
            }
            if hi - lo < 1e-9 * mu {
                break;
            }
            let newton = mu - d1 / d2;
            mu = if d2 < 0.0 && newton > lo && newton < hi {
                newton
            } else if hi.is_finite() {
                0.5 * (lo + hi)
            } else {
                2.0 * mu
            };
            if mu > limit {
                return (limit - c, f64::INFINITY);
            }
        }
        (mu - c, se(mu))
    }

    /// The variance of the rate from `frames` frames at `lambda` photo-electrons a frame.
    pub fn variance(&self, lambda: f64, frames: u32) -> f64 {
        let info = self.information((lambda + self.spurious).max(0.0));
        1.0 / (frames.max(1) as f64 * info).max(1e-300)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bins follow their edges: a value just below an edge is in the bin below it.
    #[test]
    fn bins_follow_the_edges() {
        let (sigma, g) = (3.0, 10.0);
        let b = Binning::new(sigma, g, 0.0);
        let e = Binning::edges(sigma, g);
        for (i, &t) in e.iter().enumerate() {
            assert_eq!(b.bin((t - 1e-3) as f32), i, "edge {i} at {t}");
            assert_eq!(b.bin((t + 1e-3) as f32), i + 1, "edge {i} at {t}");
        }
        // Far beyond the last edge, and NaN: the last and the first bin.
        assert_eq!(b.bin(3e38), BINS - 1);
        assert_eq!(b.bin(f32::NAN), 0);
        // A pixel hotter than the electrons the model follows gets no estimate, not a panic.
        let hot = BinModel::new(sigma, g, 25.0);
        let mut h = [0u16; BINS];
        h[BINS - 1] = 100;
        assert_eq!(hot.estimate(&h, 100, 25.0).1, f64::INFINITY);
        // The model's probabilities of every bin sum to one, for any electron count.
        let m = BinModel::new(sigma, g, 0.01);
        for n in 0..6 {
            let s: f64 = m.q[n].iter().sum();
            assert!((s - 1.0).abs() < 1e-9, "n = {n}: {s}");
        }
    }
}

#[cfg(test)]
mod against_the_model {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Gamma, Normal, Poisson};

    /// Frames drawn from the exact model, binned and estimated: the mean rate over 8000 pixels
    /// of 500 frames comes back within 2 % at 0.02, 0.1 and 0.5 e⁻ (its standard error is
    /// under 0.6 % at 0.02 e⁻ and smaller above: 2 % is more than three of them).
    #[test]
    fn recovers_the_rate_of_the_model() {
        let (sigma, g, c) = (3.0, 10.0, 0.005);
        let m = BinModel::new(sigma, g, c);
        let b = Binning::new(sigma, g, 0.0);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        for lambda in [0.02, 0.1, 0.5] {
            let (pixels, frames) = (8000, 500);
            let pois = Poisson::new(lambda + c).unwrap();
            let noise = Normal::new(0.0, sigma).unwrap();
            let mut sum = 0.0;
            for _ in 0..pixels {
                let mut h = [0u16; BINS];
                for _ in 0..frames {
                    let n = pois.sample(&mut rng) as usize;
                    let em = if n == 0 {
                        0.0
                    } else {
                        Gamma::new(n as f64, g).unwrap().sample(&mut rng)
                    };
                    h[b.bin((em + noise.sample(&mut rng)) as f32)] += 1;
                }
                sum += m.estimate(&h, frames, lambda).0;
            }
            let mean = sum / pixels as f64;
            assert!((mean / lambda - 1.0).abs() < 0.02, "λ {lambda}: {mean}");
        }
    }
}
