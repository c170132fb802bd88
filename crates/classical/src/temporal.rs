//! Classical denoising of a movie frame from the frames around it. Block matching follows the
//! motion: each 8×8 block of frame `t` is looked for in frame `t ± 1` within a few pixels of
//! where it was, then in `t ± 2` around where it was found in `t ± 1`, and so on outward. The
//! frames' single-frame estimates propose each move; the noisy frames, after the generalized
//! Anscombe transform (noise about 1 at every level, so one threshold tells a match from a
//! mismatch), decide between it and staying, and accept the match or end the track. The
//! matched blocks are averaged in
//! the data's own units — a motion-compensated mean that holds about `N` frames' photons
//! wherever `N` frames matched — and the mean is denoised by iterative BM3D at the noise of a
//! mean of `N` frames (gain α/N, read noise σ/√N).
//!
//! Where the neighbours hold nothing like frame `t` (a particle that moved off its track, a
//! spot that blinked, a scene cut), no block passes the threshold; there the estimate falls
//! back, pixel by pixel and in proportion to the frames that matched, to iterative BM3D of frame
//! `t` alone. The mean is taken in the data's units and both estimates invert the transform
//! with its exact unbiased inverse, so the mean over a region stays the signal's (within 1 %
//! in the tests, down to half a count per pixel).

use rayon::prelude::*;

use crate::bm3d::{kaiser, positions};
use crate::vst::{bm3d_adaptive, forward, PoissonGaussian};

/// Block side, px.
const N: usize = 8;
/// Distance between reference blocks, px.
const STEP: usize = 2;
/// Half-width of the search in a neighbouring frame around the block's last position, px.
const SEARCH: isize = 4;
/// The match threshold on a block's summed squared difference after the transform, in units
/// of the noise: two blocks of the same content differ by 2·N² on average with a standard
/// deviation of 2·√(2·N²); three of those above is a mismatch (about 0.3 % of true matches are
/// refused).
fn threshold() -> f64 {
    let n2 = (N * N) as f64;
    2.0 * n2 + 3.0 * 2.0 * (2.0 * n2).sqrt()
}

/// How much a matched block counts in the mean, from its summed squared difference `d` to the
/// reference (noise 1): fully up to what two blocks of the same content differ by on average
/// (2·N²), then less, linearly, to nothing at the match threshold. A block that differs by more
/// than noise is partly another content; it adds its photons but also its difference.
fn weight(d: f64) -> f64 {
    let typical = 2.0 * (N * N) as f64;
    ((threshold() - d) / (threshold() - typical)).clamp(0.0, 1.0)
}

/// Frame `t`'s motion-compensated mean over its window and, per pixel, how many frames it holds.
#[derive(Clone, Debug)]
pub struct MotionMean {
    /// The mean, in the frames' units.
    pub mean: Vec<f32>,
    /// Frames averaged at each pixel (1 where no neighbour matched; a weighted count where
    /// overlapping blocks matched in different numbers of frames).
    pub frames: Vec<f32>,
}

/// The motion-compensated mean of `window[center]` (frames `w × h` with noise `p`, in time
/// order; the window may be clipped at a stack's ends). `guides` are the frames' single-frame
/// estimates, which propose where each block went; the noisy frames decide and
/// accept, since their difference's noise is what the threshold knows.
pub fn motion_mean(
    window: &[&[f32]],
    guides: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
) -> MotionMean {
    assert_eq!(window.len(), guides.len(), "a guide for every frame");
    for f in window.iter().chain(guides) {
        assert_eq!(f.len(), w * h, "frame size");
    }
    let own = window[center];
    if window.len() == 1 || w < N || h < N {
        return MotionMean {
            mean: own.to_vec(),
            frames: vec![1.0; w * h],
        };
    }
    let gat: Vec<Vec<f32>> = window
        .iter()
        .map(|f| f.iter().map(|&z| forward(z as f64, p) as f32).collect())
        .collect();
    let win = kaiser(N);
    let limit = threshold();
    let (xs, ys) = (positions(w, N, STEP), positions(h, N, STEP));
    // Per worker, over the frame: Σ k·(the matched blocks' values), Σ k·m and Σ k, for the
    // window weight k of each block and its m matched frames.
    let zero = || (vec![0f64; w * h], vec![0f64; w * h], vec![0f64; w * h]);
    let (num, den, cnt) = ys
        .par_iter()
        .fold(zero, |(mut num, mut den, mut cnt), &y| {
            for &x in &xs {
                let mut matched: Vec<(usize, usize, usize, f64)> = vec![(center, x, y, 1.0)];
                for dir in [-1isize, 1] {
                    let (mut px, mut py) = (x, y);
                    let mut f = center as isize + dir;
                    while f >= 0 && (f as usize) < window.len() {
                        let found = track(
                            (&gat[center], &gat[f as usize]),
                            (guides[center], guides[f as usize]),
                            w,
                            h,
                            (x, y),
                            (px, py),
                        );
                        match found {
                            Some((d, bx, by)) if d <= limit => {
                                matched.push((f as usize, bx, by, weight(d)));
                                (px, py) = (bx, by);
                            }
                            _ => break,
                        }
                        f += dir;
                    }
                }
                let m: f64 = matched.iter().map(|b| b.3).sum();
                for r in 0..N {
                    for q in 0..N {
                        let k = win[r * N + q];
                        let i = (y + r) * w + x + q;
                        let sum: f64 = matched
                            .iter()
                            .map(|&(f, bx, by, wt)| wt * window[f][(by + r) * w + bx + q] as f64)
                            .sum();
                        num[i] += k * sum;
                        den[i] += k * m;
                        cnt[i] += k;
                    }
                }
            }
            (num, den, cnt)
        })
        .reduce(zero, |mut a, b| {
            for (x, y) in a.0.iter_mut().zip(&b.0) {
                *x += y;
            }
            for (x, y) in a.1.iter_mut().zip(&b.1) {
                *x += y;
            }
            for (x, y) in a.2.iter_mut().zip(&b.2) {
                *x += y;
            }
            a
        });
    let mean = (0..w * h)
        .map(|i| {
            if den[i] > 0.0 {
                (num[i] / den[i]) as f32
            } else {
                own[i]
            }
        })
        .collect();
    // The frames a pixel holds: the blocks' m, weighted as the blocks are.
    let frames = (0..w * h)
        .map(|i| {
            if cnt[i] > 0.0 {
                (den[i] / cnt[i]) as f32
            } else {
                1.0
            }
        })
        .collect();
    MotionMean { mean, frames }
}

/// Where the block at `at` of frame `t` went in another frame, searched around its last
/// position `around`, and the summed squared difference there after the transform (noise 1).
/// The guides (the frames' single-frame estimates) propose the move: on them noise cannot pull a
/// match off its place among a search's many positions, but below a photon or so per pixel they
/// are too smooth to say where a block went. So the noisy frames decide between the two
/// positions, staying and the guides' (a choice of two, which noise barely biases).
/// Requiring the move to win by a margin kept still scenes better aligned at the lowest light
/// but lost drifting ones (measured: a margin of one standard deviation of the difference of
/// two sums gave +1.5 dB more on a still scene at 0.5 photons per pixel and −3 dB on a
/// 2.5 px/frame drift at 2).
fn track(
    (own, other): (&[f32], &[f32]),
    (own_guide, other_guide): (&[f32], &[f32]),
    w: usize,
    h: usize,
    at: (usize, usize),
    around: (usize, usize),
) -> Option<(f64, usize, usize)> {
    let stay = ssd(own, other, w, at, around);
    let (_, gx, gy) = best_match(own_guide, other_guide, w, h, at, around)?;
    if (gx, gy) == around {
        return Some((stay, gx, gy));
    }
    let moved = ssd(own, other, w, at, (gx, gy));

    Some(if moved < stay {
        (moved, gx, gy)
    } else {
        (stay, around.0, around.1)
    })
}

/// The summed squared difference of the blocks at `a` in `one` and at `b` in `other`.
fn ssd(one: &[f32], other: &[f32], w: usize, a: (usize, usize), b: (usize, usize)) -> f64 {
    (0..N)
        .map(|r| {
            let x = &one[(a.1 + r) * w + a.0..(a.1 + r) * w + a.0 + N];
            let y = &other[(b.1 + r) * w + b.0..(b.1 + r) * w + b.0 + N];
            x.iter()
                .zip(y)
                .map(|(p, q)| ((p - q) as f64).powi(2))
                .sum::<f64>()
        })
        .sum()
}

/// The position within [`SEARCH`] px of `around` in `other` whose block is closest to the block
/// at `at` in `own`, with its summed squared difference.
fn best_match(
    own: &[f32],
    other: &[f32],
    w: usize,
    h: usize,
    at: (usize, usize),
    around: (usize, usize),
) -> Option<(f64, usize, usize)> {
    let span = |c: usize, len: usize| {
        (
            (c as isize - SEARCH).max(0) as usize,
            ((c as isize + SEARCH) as usize).min(len - N),
        )
    };
    let ((x0, x1), (y0, y1)) = (span(around.0, w), span(around.1, h));
    let mut best: Option<(f64, usize, usize)> = None;
    for cy in y0..=y1 {
        for cx in x0..=x1 {
            let mut d = 0.0;
            let bound = best.map_or(f64::INFINITY, |b| b.0);
            for r in 0..N {
                let a = &own[(at.1 + r) * w + at.0..(at.1 + r) * w + at.0 + N];
                let b = &other[(cy + r) * w + cx..(cy + r) * w + cx + N];
                d += a
                    .iter()
                    .zip(b)
                    .map(|(p, q)| ((p - q) as f64).powi(2))
                    .sum::<f64>();
                if d >= bound {
                    break;
                }
            }
            // Ties go to the position nearest the prediction (a still scene stays put).
            let nearer = |b: &(f64, usize, usize)| {
                let dist = |x: usize, y: usize| {
                    (x as isize - around.0 as isize).pow(2)
                        + (y as isize - around.1 as isize).pow(2)
                };
                dist(cx, cy) < dist(b.1, b.2)
            };
            if best.is_none_or(|b| d < b.0 || (d == b.0 && nearer(&b))) {
                best = Some((d, cx, cy));
            }
        }
    }
    best
}

/// The estimate of `window[center]` (DN above bias, noise `p`) from its window: iterative BM3D
/// of the motion-compensated mean at a mean's noise, falling back to `singles[center]` (the
/// frame's own estimate) where fewer frames matched. `singles` are the window's single-frame
/// estimates, [`single`] of each frame (a stack computes each once).
pub fn estimate(
    window: &[&[f32]],
    singles: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
) -> Vec<f32> {
    let pooled = |mean: &[f32], frames: f64| {
        Ok::<_, std::convert::Infallible>(bm3d_adaptive(mean, w, h, p.of_mean(frames)))
    };
    match estimate_with(window, singles, center, w, h, p, pooled) {
        Ok(v) => v,
        Err(never) => match never {},
    }
}

/// [`estimate`] with another estimator of the motion-compensated mean: `pooled(mean, n)`
/// denoises a mean of about `n` frames (its noise is `p.of_mean(n)`), and `singles` hold the
/// same estimator's output on each frame alone, which tracking is guided by and the estimate
/// falls back to. One frame's worth of matches or fewer gives `singles[center]` unchanged.
pub fn estimate_with<E>(
    window: &[&[f32]],
    singles: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
    pooled: impl FnOnce(&[f32], f64) -> Result<Vec<f32>, E>,
) -> Result<Vec<f32>, E> {
    let single = singles[center];
    let mm = motion_mean(window, singles, center, w, h, p);
    let typical = emccd_profile::median(mm.frames.iter().copied()).unwrap_or(1.0) as f64;
    if typical < 1.5 {
        return Ok(single.to_vec());
    }
    let pooled = pooled(&mm.mean, typical)?;
    Ok(pooled
        .iter()
        .zip(single)
        .zip(&mm.frames)
        .map(|((&a, &b), &n)| {
            let wt = ((n as f64 - 1.0) / (typical - 1.0)).clamp(0.0, 1.0) as f32;
            wt * a + (1.0 - wt) * b
        })
        .collect())
}

/// A frame's single-frame estimate (DN above bias, noise `p`): iterative BM3D, what
/// [`estimate`] tracks motion on and falls back to.
pub fn single(frame: &[f32], w: usize, h: usize, p: PoissonGaussian) -> Vec<f32> {
    bm3d_adaptive(frame, w, h, p)
}
