//! Resampling a frame to a fraction of a pixel with Keys' cubic convolution kernel (a = −½):
//! what the temporal method registers its neighbours with, and the movies synthesized for
//! training move their scenes with. Its weights sum to 1 (a region's mean is kept) and its
//! taps' squares say how much of independent noise a resampled frame keeps. And the binomial
//! low-pass ([`binomial`]) that frames are registered on.

use rayon::prelude::*;

/// Keys' cubic kernel (a = −½).
fn keys(t: f64) -> f64 {
    let t = t.abs();
    if t < 1.0 {
        1.5 * t * t * t - 2.5 * t * t + 1.0
    } else if t < 2.0 {
        -0.5 * t * t * t + 2.5 * t * t - 4.0 * t + 2.0
    } else {
        0.0
    }
}

/// The kernel's weights for a sample `frac` (0 ≤ frac < 1) px past a pixel, on the pixels at
/// offsets −1, 0, 1 and 2 from it.
pub fn keys_weights(frac: f64) -> [f64; 4] {
    [
        keys(1.0 + frac),
        keys(frac),
        keys(1.0 - frac),
        keys(2.0 - frac),
    ]
}

/// The first pixel's offset and the weights for a sample `e` px along one axis: the sample is
/// `Σₖ weight[k] · pixel[offset − 1 + k]` ([`keys_weights`]).
pub fn taps(e: f64) -> (isize, [f64; 4]) {
    let base = e.floor();
    (base as isize, keys_weights(e - base))
}

/// The fraction of independent noise's variance a frame [`resampled`] by `e` keeps.
pub fn noise_kept(e: (f64, f64)) -> f64 {
    let sq = |e: f64| taps(e).1.iter().map(|w| w * w).sum::<f64>();
    sq(e.0) * sq(e.1)
}

/// The covariance along one axis of independent unit noise resampled by `e` px (lags −3 to 3):
/// what resampling leaves of the noise at each spatial frequency ([`crate::noise`]).
pub fn covariance(e: f64) -> Vec<f64> {
    crate::noise::filtered(&taps(e).1)
}

/// `frame` (`w × h`) sampled `e` px further along each axis (`out(x, y) = frame(x + eₓ, y + e_y)`),
/// with Keys' cubic kernel (a = −½), the edge pixels repeated: its weights sum to 1, so the
/// mean over a region is kept.
pub fn resampled(frame: &[f32], w: usize, h: usize, e: (f64, f64)) -> Vec<f32> {
    let (bx, wx) = taps(e.0);
    let (by, wy) = taps(e.1);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    // Along x, then along y.
    let mut rows = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let v: f64 = (0..4)
                .map(|k| wx[k] * frame[y * w + clamp(x as isize + bx - 1 + k as isize, w)] as f64)
                .sum();
            rows[y * w + x] = v as f32;
        }
    }
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let v: f64 = (0..4)
                .map(|k| wy[k] * rows[clamp(y as isize + by - 1 + k as isize, h) * w + x] as f64)
                .sum();
            out[y * w + x] = v as f32;
        }
    }
    out
}

/// `frame` (`w` px wide) filtered by the binomial kernel (1 4 6 4 1)/16 along each axis (about
/// a Gaussian of σ = 1 px), its edges mirrored. Whole frames are registered on it: at a photon
/// per pixel each shift's sum of squared differences between two raw frames carries its own
/// draw of the pixels' noise, which buries the scene's sub-pixel slope; filtered, the noise
/// varies smoothly from shift to shift as the scene does.
pub fn binomial(frame: &[f32], w: usize) -> Vec<f32> {
    const K: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let w = w.max(1);
    let h = frame.len() / w;
    let at = |i: isize, n: usize| -> usize {
        let n = n as isize;
        (if i < 0 {
            -i
        } else if i >= n {
            2 * n - 2 - i
        } else {
            i
        })
        .clamp(0, n - 1) as usize
    };
    let mut rows = vec![0f32; w * h];
    rows.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, r) in row.iter_mut().enumerate() {
            *r = (0..5)
                .map(|t| K[t] * frame[y * w + at(x as isize + t as isize - 2, w)])
                .sum();
        }
    });
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            *o = (0..5)
                .map(|t| K[t] * rows[at(y as isize + t as isize - 2, h) * w + x])
                .sum();
        }
    });
    out
}
