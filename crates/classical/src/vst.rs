//! Variance stabilization for Poisson–Gaussian data (`Var(z) = α·(z − μ) + σ²`, the
//! preprocessed EMCCD frame with `α = s`): the generalized Anscombe transform and the closed-form
//! approximation of its exact unbiased inverse (Mäkitalo & Foi 2013), so that a Gaussian
//! denoiser (BM3D) can be applied with σ = 1.

pub use emccd_profile::PoissonGaussian;

use crate::noise::Covariance;

/// Generalized Anscombe transform: noise std ≈ 1 afterwards.
pub fn forward(z: f64, p: PoissonGaussian) -> f64 {
    let a = p.alpha * z + 0.375 * p.alpha * p.alpha + p.sigma * p.sigma - p.alpha * p.mu;
    if a > 0.0 {
        2.0 / p.alpha * a.sqrt()
    } else {
        0.0
    }
}

/// Closed-form approximation of the exact unbiased inverse. Below the transform of a zero signal
/// the estimate is 0 (the expansion diverges there).
pub fn inverse(d: f64, p: PoissonGaussian) -> f64 {
    let s = p.sigma / p.alpha;
    let d0 = 2.0 * (0.375 + s * s).sqrt();
    if d <= d0 {
        return p.mu;
    }
    let r = (1.5f64).sqrt();
    let i = 0.25 * d * d + 0.25 * r / d - 1.375 / (d * d) + 0.625 * r / (d * d * d) - 0.125 - s * s;
    p.alpha * i.max(0.0) + p.mu
}

/// BM3D after the transform, back to the data's units (one pass, no binning).
pub fn bm3d_poisson_gaussian(frame: &[f32], w: usize, h: usize, p: PoissonGaussian) -> Vec<f32> {
    bm3d_iterative(frame, w, h, p, &Schedule::single().0)
}

/// One pass of [`bm3d_iterative`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pass {
    /// Weight of the noisy data in the pass's input `λ·z + (1 − λ)·ŷ` (the first pass uses 1).
    pub lambda: f64,
    /// Side of the square bins summed before denoising (1 = none).
    pub bin: usize,
}

/// The passes of [`bm3d_iterative`], written `λ/b,λ/b,…` (weight of the data / bin side, e.g.
/// `1/3,0.6/2,0.4/1`; `λ` alone means no binning).
#[derive(Clone, Debug, PartialEq)]
pub struct Schedule(pub Vec<Pass>);

impl Schedule {
    /// One pass, no binning: plain BM3D + GAT.
    pub fn single() -> Schedule {
        Schedule(vec![Pass {
            lambda: 1.0,
            bin: 1,
        }])
    }

    /// The schedule for a frame with `counts` mean effective counts per pixel (mean signal over
    /// the gain α: half the photoelectrons for an EM register). Chosen on held-out validation
    /// frames (an emccd-detect camera on scenes outside the low-light suite, docs/results.md):
    /// binning pays below about one count and costs detail above, so the passes and bins shrink
    /// as the light grows, and from 4 counts one plain pass is as good.
    pub fn for_counts(counts: f64) -> Schedule {
        let spec: &[(f64, usize)] = if counts < 0.35 {
            &[(1.0, 4), (0.75, 3), (0.5, 2), (0.3, 1)]
        } else if counts < 1.0 {
            &[(1.0, 3), (0.7, 2), (0.4, 1)]
        } else if counts < 4.0 {
            &[(1.0, 2), (0.7, 1), (0.5, 1)]
        } else {
            &[(1.0, 1)]
        };
        Schedule(
            spec.iter()
                .map(|&(lambda, bin)| Pass { lambda, bin })
                .collect(),
        )
    }
}

/// BM3D with iterative variance stabilization, the schedule chosen from the frame's mean count
/// ([`Schedule::for_counts`]).
pub fn bm3d_adaptive(frame: &[f32], w: usize, h: usize, p: PoissonGaussian) -> Vec<f32> {
    bm3d_adaptive_correlated(frame, w, h, p, &Covariance::white())
}

/// [`bm3d_adaptive`] of a frame whose noise, once transformed, has the covariance `noise`
/// (variance 1 a pixel; a motion-compensated mean's, coarser than white).
pub fn bm3d_adaptive_correlated(
    frame: &[f32],
    w: usize,
    h: usize,
    p: PoissonGaussian,
    noise: &Covariance,
) -> Vec<f32> {
    let passes = Schedule::for_counts(mean_counts(frame, p)).0;
    bm3d_iterative_spaced(frame, w, h, p, &passes, 1, noise)
}

/// A frame's mean effective counts per pixel: its mean signal over the gain α (finite values;
/// 0 for a frame at or below the offset).
pub fn mean_counts(frame: &[f32], p: PoissonGaussian) -> f64 {
    let finite = frame.iter().filter(|v| v.is_finite());
    let mean = finite.clone().map(|&v| v as f64).sum::<f64>() / finite.count().max(1) as f64;
    ((mean - p.mu) / p.alpha).max(0.0)
}

impl std::str::FromStr for Schedule {
    type Err = String;

    fn from_str(s: &str) -> Result<Schedule, String> {
        let passes = s
            .split(',')
            .enumerate()
            .map(|(k, t)| {
                let (l, b) = t.trim().split_once('/').unwrap_or((t.trim(), "1"));
                let lambda: f64 = l
                    .parse()
                    .map_err(|_| format!("pass {t:?}: λ is not a number"))?;
                let bin: usize = b
                    .parse()
                    .map_err(|_| format!("pass {t:?}: the bin is not a whole number"))?;
                if !(lambda > 0.0 && lambda <= 1.0) || !(1..=8).contains(&bin) {
                    return Err(format!("pass {t:?}: λ must be in (0, 1] and the bin 1–8"));
                }
                if k == 0 && lambda != 1.0 {
                    return Err(format!(
                        "pass {t:?}: the first pass has no estimate to mix in; its λ is 1"
                    ));
                }
                Ok(Pass { lambda, bin })
            })
            .collect::<Result<Vec<_>, _>>()?;
        if passes.is_empty() {
            return Err("a schedule has at least one pass".into());
        }
        Ok(Schedule(passes))
    }
}

impl std::fmt::Display for Schedule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (k, p) in self.0.iter().enumerate() {
            write!(f, "{}{}/{}", if k > 0 { "," } else { "" }, p.lambda, p.bin)?;
        }
        Ok(())
    }
}

/// Iterative variance stabilization (Azzari & Foi 2016, "Variance stabilization for
/// noisy+estimate combination in iterative Poisson denoising"): each pass denoises the convex
/// combination `λ·z + (1 − λ)·ŷ` of the data and the previous estimate, optionally summed over
/// `bin × bin` blocks. Taking ŷ as exact, the combination has the data's mean and `λ²` times its
/// variance, i.e. it is Poisson–Gaussian with gain `λ²α` and Gaussian σ `λσ` (`b` times that for
/// a `b × b` sum, whose mean is `b²` times the pixels'), so the generalized Anscombe transform
/// with those parameters stabilizes it. At a few counts per pixel, where the transform of the
/// raw data is far from Gaussian, both the combination and the binning raise the counts the
/// transform sees; this is why the method gains most in the dimmest frames.
pub fn bm3d_iterative(
    frame: &[f32],
    w: usize,
    h: usize,
    p: PoissonGaussian,
    passes: &[Pass],
) -> Vec<f32> {
    bm3d_iterative_spaced(frame, w, h, p, passes, 1, &Covariance::white())
}

/// [`bm3d_iterative`] with the reference blocks of its full-resolution passes at least
/// `min_step` px apart ([`crate::bm3d::bm3d_spaced`]); a binned pass's grid is already
/// coarser in the frame's pixels, and costs a fraction of a full pass. Once transformed, the
/// frame's noise has the covariance `noise` ([`Covariance::white`] for a camera frame); a
/// binned pass is told its bins' ([`Covariance::binned`]).
pub fn bm3d_iterative_spaced(
    frame: &[f32],
    w: usize,
    h: usize,
    p: PoissonGaussian,
    passes: &[Pass],
    min_step: usize,
    noise: &Covariance,
) -> Vec<f32> {
    assert_eq!(frame.len(), w * h, "image size");
    let mut est: Option<Vec<f32>> = None;
    for (k, pass) in passes.iter().enumerate() {
        let lambda = if k == 0 {
            1.0
        } else {
            pass.lambda.clamp(1e-3, 1.0)
        };
        let mixed: Vec<f32> = match &est {
            Some(y) if lambda < 1.0 => frame
                .iter()
                .zip(y)
                .map(|(&z, &y)| (lambda * z as f64 + (1.0 - lambda) * y as f64) as f32)
                .collect(),
            _ => frame.to_vec(),
        };
        let b = pass.bin.max(1);
        let (summed, bw, bh) = bin_sum(&mixed, w, h, b);
        let q = PoissonGaussian {
            alpha: lambda * lambda * p.alpha,
            sigma: lambda * p.sigma * b as f64,
            mu: p.mu * (b * b) as f64,
        };
        let t: Vec<f32> = summed
            .iter()
            .map(|&z| forward(z as f64, q) as f32)
            .collect();
        let range = t.iter().copied().fold(0f32, f32::max).max(1.0) as f64;
        let step = if b == 1 { min_step } else { 1 };
        let d = crate::bm3d::bm3d_spaced(&t, bw, bh, 1.0, range, step, &noise.binned(b));
        let back: Vec<f32> = d
            .into_iter()
            .map(|v| (inverse(v as f64, q) / (b * b) as f64) as f32)
            .collect();
        est = Some(if b == 1 {
            back
        } else {
            unbin(&back, bw, bh, b, w, h)
        });
    }
    est.unwrap_or_else(|| frame.to_vec())
}

/// Sums of `b × b` blocks; the frame is mirrored at its right and bottom edges to whole blocks,
/// so every sum has `b²` samples and the mean of the sums is `b²` times the pixels' at the edges
/// too (a mirrored pixel counted twice makes an edge sum's variance somewhat larger than the
/// model's; that touches one row or column of blocks).
fn bin_sum(frame: &[f32], w: usize, h: usize, b: usize) -> (Vec<f32>, usize, usize) {
    if b == 1 {
        return (frame.to_vec(), w, h);
    }
    let (bw, bh) = (w.div_ceil(b), h.div_ceil(b));
    // The reflection holds for bins of any size, even wider than the frame.
    use crate::bm3d::mirror;
    let mut out = vec![0f32; bw * bh];
    for by in 0..bh {
        for bx in 0..bw {
            let mut s = 0f64;
            for y in by * b..(by + 1) * b {
                for x in bx * b..(bx + 1) * b {
                    s += frame[mirror(y, h) * w + mirror(x, w)] as f64;
                }
            }
            out[by * bw + bx] = s as f32;
        }
    }
    (out, bw, bh)
}

/// Back to full resolution: bilinear interpolation between the block centres (clamped at the
/// edges), so the estimate has no block seams.
fn unbin(means: &[f32], bw: usize, bh: usize, b: usize, w: usize, h: usize) -> Vec<f32> {
    let coord = |i: usize, n: usize| {
        let c = ((i as f64 + 0.5) / b as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let i0 = (c.floor() as usize).min(n - 1);
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, c - i0 as f64)
    };
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        let (y0, y1, fy) = coord(y, bh);
        for x in 0..w {
            let (x0, x1, fx) = coord(x, bw);
            let v = |yy: usize, xx: usize| means[yy * bw + xx] as f64;
            let top = v(y0, x0) * (1.0 - fx) + v(y0, x1) * fx;
            let bottom = v(y1, x0) * (1.0 - fx) + v(y1, x1) * fx;
            out[y * w + x] = (top * (1.0 - fy) + bottom * fy) as f32;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_undoes_the_mean_of_the_transform_at_high_counts() {
        // For large signals the unbiased inverse of E[f(z)] returns z: check via the delta
        // method E[f(z)] ≈ f(E z) − f''·Var/2 … simply, a noiseless round trip is close.
        let p = PoissonGaussian {
            alpha: 20.0,
            sigma: 3.0,
            mu: 0.0,
        };
        for z in [500.0, 2000.0, 10000.0] {
            let back = inverse(forward(z, p), p);
            assert!((back - z).abs() / z < 0.02, "{z} → {back}");
        }
        assert_eq!(inverse(0.1, p), 0.0);
    }

    #[test]
    fn binning_keeps_constants_and_sums_blocks() {
        // 7×5 does not divide into 2×2 or 3×3 blocks: the mirrored edge blocks still sum b² samples.
        let (w, h) = (7, 5);
        for b in [2, 3] {
            let (s, bw, bh) = bin_sum(&vec![2.5; w * h], w, h, b);
            assert_eq!((bw, bh), (w.div_ceil(b), h.div_ceil(b)));
            assert!(s.iter().all(|&v| (v - 2.5 * (b * b) as f32).abs() < 1e-5));
            let back = unbin(&vec![1.25; bw * bh], bw, bh, b, w, h);
            assert!(back.iter().all(|&v| (v - 1.25).abs() < 1e-6));
        }
        // Bins wider than the frame (a 1×1 or 2×1 frame in a 4×4 bin) reflect as often as needed.
        for (w, h) in [(1, 1), (2, 1), (1, 3)] {
            let (s, bw, bh) = bin_sum(&vec![1.0; w * h], w, h, 4);
            assert_eq!((bw, bh, s), (1, 1, vec![16.0]));
            let p = PoissonGaussian {
                alpha: 1.0,
                sigma: 0.1,
                mu: 0.0,
            };
            let out = bm3d_adaptive(&vec![0.2; w * h], w, h, p);
            assert!(out.len() == w * h && out.iter().all(|v| v.is_finite()));
        }
        // A ramp in x is reproduced between the block centres (bilinear interpolation).
        let (w, h, b) = (12, 6, 3);
        let ramp: Vec<f32> = (0..w * h).map(|i| (i % w) as f32).collect();
        let (s, bw, bh) = bin_sum(&ramp, w, h, b);
        let means: Vec<f32> = s.iter().map(|v| v / 9.0).collect();
        let back = unbin(&means, bw, bh, b, w, h);
        for x in 1..w - 1 {
            assert!(
                (back[2 * w + x] - x as f32).abs() < 1e-4,
                "x {x}: {}",
                back[2 * w + x]
            );
        }
    }

    /// The reason for the iteration: at half a count per pixel the plain transform is far from
    /// Gaussian and one BM3D pass leaves a large error; passes with binning and the previous
    /// estimate mixed in must do better on a smooth scene (Azzari & Foi report gains of 1 dB and
    /// more at peaks ≤ 2; a smooth scene gains more).
    #[test]
    fn iterating_beats_one_pass_at_half_a_count() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Poisson};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let (w, h) = (64, 64);
        let truth: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
                0.5 * (1.0 + (6.0 * x).sin() * (4.0 * y).cos())
            })
            .collect();
        let noisy: Vec<f32> = truth
            .iter()
            .map(|&m| Poisson::new(m as f64).unwrap().sample(&mut rng) as f32)
            .collect();
        let p = PoissonGaussian {
            alpha: 1.0,
            sigma: 0.0,
            mu: 0.0,
        };
        let one = bm3d_poisson_gaussian(&noisy, w, h, p);
        let passes = [
            Pass {
                lambda: 1.0,
                bin: 3,
            },
            Pass {
                lambda: 0.6,
                bin: 2,
            },
            Pass {
                lambda: 0.4,
                bin: 1,
            },
        ];
        let it = bm3d_iterative(&noisy, w, h, p, &passes);
        let (a, b) = (
            emccd_eval::psnr(&one, &truth, 1.0),
            emccd_eval::psnr(&it, &truth, 1.0),
        );
        assert!(b > a, "one pass {a:.2} dB, iterative {b:.2} dB");
    }

    #[test]
    fn schedules_parse_print_and_refuse_nonsense() {
        let s: Schedule = "1/3, 0.6/2,0.4".parse().unwrap();
        assert_eq!(
            s.0,
            vec![
                Pass {
                    lambda: 1.0,
                    bin: 3
                },
                Pass {
                    lambda: 0.6,
                    bin: 2
                },
                Pass {
                    lambda: 0.4,
                    bin: 1
                }
            ]
        );
        assert_eq!(s.to_string(), "1/3,0.6/2,0.4/1");
        assert_eq!(s.to_string().parse::<Schedule>().unwrap(), s);
        for bad in [
            "",
            "x/2",
            "0/1",
            "1.5/1",
            "1/0",
            "1/9",
            "1/2.5",
            "0.5/2,0.3/1",
        ] {
            assert!(bad.parse::<Schedule>().is_err(), "{bad:?} accepted");
        }
        // Fewer and smaller bins as the light grows; one plain pass at 4 counts and above.
        let bins = |c: f64| {
            Schedule::for_counts(c)
                .0
                .iter()
                .map(|p| p.bin)
                .max()
                .unwrap()
        };
        assert!(bins(0.1) > bins(0.5) && bins(0.5) > bins(2.0) && bins(2.0) > bins(8.0));
        assert_eq!(Schedule::for_counts(8.0), Schedule::single());
        assert!(Schedule::for_counts(0.0)
            .0
            .iter()
            .all(|p| p.lambda > 0.0 && p.lambda <= 1.0));
    }

    /// Unbiasedness, the inverse's purpose: the mean of the transformed samples maps back to the
    /// true signal. 4·10⁵ samples make the sampling error of the mean ≈ 0.0016 (transform units),
    /// i.e. < 0.2 % of the signal at these levels; the closed form's own error is < 1 % above ~2
    /// counts (Mäkitalo & Foi 2013, Fig. 2).
    #[test]
    fn inverse_is_unbiased_for_poisson_gaussian_samples() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal, Poisson};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        for (lambda, sigma) in [(3.0f64, 0.5f64), (10.0, 1.0), (50.0, 2.0)] {
            let p = PoissonGaussian {
                alpha: 1.0,
                sigma,
                mu: 0.0,
            };
            let n = 400_000;
            let po = Poisson::new(lambda).unwrap();
            let no = Normal::new(0.0, sigma).unwrap();
            let m = (0..n)
                .map(|_| forward(po.sample(&mut rng) + no.sample(&mut rng), p))
                .sum::<f64>()
                / n as f64;
            let back = inverse(m, p);
            assert!(
                (back / lambda - 1.0).abs() < 0.015,
                "λ {lambda}, σ {sigma}: {back}"
            );
        }
    }
}
