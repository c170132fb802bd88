//! The bias across the frame: the zero-electron peak of each tile's darkest pixels, fitted with
//! the register's gain held at the whole frame's, and a smooth surface through the peaks. A sensor's bias drifts across it (a gradient from the first rows
//! read to the last, amplifier glow at a corner); a flat bias leaves that drift in the output,
//! several times the signal of a dim background. The pixel-to-pixel pattern beneath the tiles'
//! scale is not separated from the read noise here: it needs frames without light.

use rayon::prelude::*;

use super::{em, value_start, TILE_TAIL};

/// The fewest values of a tile's darkest pixels its peak is fitted from: the peak's position to
/// about a sixth of the read noise (σ/√N₀ with N₀ ≥ 40 zero-electron values); the surface
/// through many tiles averages that down. Small, so that one frame of 128² px still holds
/// sixteen tiles.
const MIN_TILE_VALUES: usize = 100;

/// Tiles across the frame's shorter side, at most.
const MAX_GRID: usize = 8;

/// The fewest zero-electron values a tile's peak is accepted with.
const MIN_TILE_ZEROS: f64 = 40.0;

/// The bias map and how it was made.
#[derive(Clone, Debug)]
pub struct BiasMap {
    /// Per pixel, DN.
    pub values: Vec<f32>,
    /// The tiles' side, px.
    pub tile: usize,
    /// Tiles whose peak was fitted, of all.
    pub fitted: usize,
    /// All tiles.
    pub tiles: usize,
    /// Highest less lowest value of the map, DN.
    pub range_dn: f64,
}

/// The tiles' side for `frames` frames: enough pixels that a tenth of them over all frames
/// holds [`MIN_TILE_VALUES`] values, at least 32 px (32 for any frame count at today's
/// [`MIN_TILE_VALUES`]).
fn tile_side(frames: usize) -> usize {
    let px = (10 * MIN_TILE_VALUES) as f64 / frames.max(1) as f64;
    ((px.sqrt() / 16.0).ceil() as usize * 16).clamp(32, 128)
}

/// The bias map of `frames` (`width × height`; `mean` each pixel's mean over
/// them, NaN where a value is saturated), given
/// the whole frame's peak `bias`, its width `sigma` and the register's gain `gain` (DN per
/// electron): a surface through the tiles' peaks, weighted by their errors — quadratic where
/// twelve tiles or more show a peak, a plane from three, else `bias` flat. A surface rather
/// than the peaks themselves: one frame's tile knows its peak to about half a DN, the surface
/// to a fraction of that.
pub fn fit(
    frames: &[Vec<f32>],
    mean: &[f64],
    width: usize,
    height: usize,
    bias: f64,
    sigma: f64,
    gain: f64,
) -> BiasMap {
    // At most 8 tiles across the shorter side (8 × 8 on a square frame): a quadratic surface is
    // fitted through them, and every tile is a likelihood fit (most of the characterization's
    // time on large frames).
    let side = tile_side(frames.len()).max((width.min(height) / MAX_GRID).next_multiple_of(16));
    // Whole tiles of equal size (the last is not a sliver).
    let (gx, gy) = ((width / side).max(1), (height / side).max(1));
    let flat = |fitted| BiasMap {
        values: vec![bias as f32; width * height],
        tile: side,
        fitted,
        tiles: gx * gy,
        range_dn: 0.0,
    };
    if gx * gy < 3 {
        return flat(0);
    }
    let n = width * height;
    let span = |k: usize, g: usize, len: usize| (k * len / g, (k + 1) * len / g);
    // Each tile's own darkest tenth by the eight neighbours' mean (never the pixel's own values,
    // which would pick the pixels whose noise happened to be low).
    let peaks: Vec<Option<(f64, f64, f64, f64)>> = (0..gx * gy)
        .into_par_iter()
        .map(|t| {
            let ((x0, x1), (y0, y1)) = (span(t % gx, gx, width), span(t / gx, gy, height));
            let mut by_ring = Vec::new();
            for y in y0.max(1)..y1.min(height - 1) {
                for x in x0.max(1)..x1.min(width - 1) {
                    let mut s = 0.0;
                    for (dx, dy) in [
                        (0, 0),
                        (1, 0),
                        (2, 0),
                        (0, 1),
                        (2, 1),
                        (0, 2),
                        (1, 2),
                        (2, 2),
                    ] {
                        s += mean[(y + dy - 1) * width + x + dx - 1];
                    }
                    if s.is_finite() && mean[y * width + x].is_finite() {
                        by_ring.push((s, y * width + x));
                    }
                }
            }
            by_ring.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let want = (by_ring.len() / 10).max(MIN_TILE_VALUES.div_ceil(frames.len()));
            if by_ring.len() < want * 2 {
                return None;
            }
            let values: Vec<f64> = by_ring[..want]
                .iter()
                .flat_map(|&(_, i)| frames.iter().map(move |f| f[i] as f64))
                .collect();
            let (hist, start) = value_start(&values, sigma, gain, TILE_TAIL);
            let fit = em::fit(
                em::Form::Values,
                &hist,
                start,
                em::Free {
                    gain: false,
                    spread: false,
                },
            )?;
            let zeros = (-fit.params.electrons).exp() * fit.values;
            // The peak is that of where the chosen pixels lie: where the bias drifts, the
            // darkest are drawn to the tile's low side.
            let (sx, sy) = by_ring[..want].iter().fold((0.0, 0.0), |(a, b), &(_, i)| {
                (a + (i % width) as f64 + 0.5, b + (i / width) as f64 + 0.5)
            });
            (zeros >= MIN_TILE_ZEROS && fit.se.bias < 0.3 * sigma).then(|| {
                (
                    sx / want as f64 / width as f64,
                    sy / want as f64 / height as f64,
                    fit.params.bias,
                    fit.se.bias,
                )
            })
        })
        .collect();
    let peaks: Vec<(f64, f64, f64, f64)> = peaks.into_iter().flatten().collect();
    let fitted = peaks.len();
    // The surface's terms in the frame's unit coordinates: 1, x, y, and from 12 fitted tiles
    // x², xy, y²; a direction gets a term only where the tiles span it (a strip of one row of
    // tiles has no y to fit, and a y² term there would swing the map at its edges).
    let quadratic = fitted >= 12;
    let used: Vec<usize> = [
        (0, true),
        (1, gx >= 2),
        (2, gy >= 2),
        (3, quadratic && gx >= 3),
        (4, quadratic && gx >= 2 && gy >= 2),
        (5, quadratic && gy >= 3),
    ]
    .into_iter()
    .filter_map(|(k, on)| on.then_some(k))
    .collect();
    let p = used.len();
    let terms = |x: f64, y: f64, _: usize| -> [f64; 6] {
        let (u, v) = (x - 0.5, y - 0.5);
        let all = [1.0, u, v, u * u, u * v, v * v];
        let mut out = [0.0; 6];
        for (slot, &k) in used.iter().enumerate() {
            out[slot] = all[k];
        }
        out
    };
    if fitted < p.max(3) {
        return flat(fitted);
    }
    let mut ata = vec![0.0; p * p];
    let mut atb = vec![0.0; p];
    for &(x, y, b, se) in &peaks {
        let w = 1.0 / (se * se).max(1e-6);
        let t = terms(x, y, p);
        for r in 0..p {
            atb[r] += w * t[r] * b;
            for c in 0..p {
                ata[r * p + c] += w * t[r] * t[c];
            }
        }
    }
    let Some(inv) = crate::fit::invert(&ata, p) else {
        return flat(fitted);
    };
    let coef: Vec<f64> = (0..p)
        .map(|r| (0..p).map(|c| inv[r * p + c] * atb[c]).sum())
        .collect();
    // Never beyond the peaks themselves (by more than the read noise): the surface interpolates
    // the tiles, it does not extrapolate a curvature.
    let lo_peak = peaks.iter().map(|q| q.2).fold(f64::INFINITY, f64::min) - sigma;
    let hi_peak = peaks.iter().map(|q| q.2).fold(f64::NEG_INFINITY, f64::max) + sigma;
    let at = |x: f64, y: f64| -> f64 {
        let v: f64 = terms(x, y, p).iter().zip(&coef).map(|(t, c)| t * c).sum();
        v.clamp(lo_peak, hi_peak)
    };
    let values: Vec<f32> = (0..n)
        .into_par_iter()
        .map(|i| {
            at(
                ((i % width) as f64 + 0.5) / width as f64,
                ((i / width) as f64 + 0.5) / height as f64,
            ) as f32
        })
        .collect();
    let (lo, hi) = values
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    BiasMap {
        values,
        tile: side,
        fitted,
        tiles: gx * gy,
        range_dn: (hi - lo) as f64,
    }
}

/// Fewest frames a movie needs for each pixel's own bias: fewer leave each pixel's peak
/// known to worse than half the read noise even where every frame holds no electron.
pub const MIN_PIXEL_FRAMES: usize = 8;

/// The most frames each pixel's bias is estimated from (enough for its error to be a fraction of
/// the pattern's; more only cost time).
const MAX_PIXEL_FRAMES: usize = 64;

/// How each pixel's own bias was estimated ([`refine`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct PixelBias {
    /// The pixel-to-pixel spread of the bias about the smooth map, DN (measured: the spread of
    /// the pixels' own peaks less their errors).
    pub pattern_dn: f64,
    /// The median share of a pixel's own offset kept (the rest is the smooth map's).
    pub kept: f64,
}

/// The odds of one electron against none for a value `x` DN above the bias, tabulated: the
/// per-pixel mixture evaluates them for every frame of every pixel, and the exact form costs
/// two exponentials and an erfc each.
struct Odds {
    /// `one(x) / none(x)` at `x = lo + k·step`.
    odds: Vec<f64>,
    lo: f64,
    step: f64,
}

impl Odds {
    /// Beyond ±`SPAN` read-noise σ the table is clamped: below, the odds are held at their
    /// value at −`SPAN` σ; above, the value is an electron's.
    const SPAN: f64 = 8.0;
    /// Table points per σ: the odds' log changes by at most about `SPAN` per σ, so linear
    /// interpolation between points errs by under (8/256)²/8, about 10⁻⁴ of the odds.
    const PER_SIGMA: f64 = 256.0;

    fn new(sigma: f64, gain: f64) -> Odds {
        let (lo, step) = (-Self::SPAN * sigma, sigma / Self::PER_SIGMA);
        let s2 = sigma * sigma;
        let norm = 1.0 / (sigma * (2.0 * std::f64::consts::PI).sqrt());
        // No electron: N(0, σ²). One electron's output plus read noise: an exponentially
        // modified Gaussian, exp(σ²/2K² − x/K)·Φ(x/σ − σ/K)/K.
        let ln_one = |x: f64| -> f64 {
            let z = x / sigma - sigma / gain;
            s2 / (2.0 * gain * gain) - x / gain
                + (0.5 * libm::erfc(-z / std::f64::consts::SQRT_2))
                    .max(1e-300)
                    .ln()
                - gain.ln()
        };
        let ln_none = |x: f64| norm.ln() - x * x / (2.0 * s2);
        let points = (2.0 * Self::SPAN * Self::PER_SIGMA) as usize + 1;
        let odds = (0..points)
            .map(|k| {
                let x = lo + k as f64 * step;
                (ln_one(x) - ln_none(x)).min(700.0).exp()
            })
            .collect();
        Odds { odds, lo, step }
    }

    /// The share of a value `x` DN above the bias that belongs to the no-electron class, with
    /// `prior` = P(electrons)/P(none).
    fn zero_share(&self, x: f64, prior: f64) -> f64 {
        let t = (x - self.lo) / self.step;
        let last = self.odds.len() - 1;
        let odds = if t <= 0.0 {
            self.odds[0]
        } else if t >= last as f64 {
            return 0.0;
        } else {
            let k = t as usize;
            let f = t - k as f64;
            self.odds[k] + f * (self.odds[k + 1] - self.odds[k])
        };
        1.0 / (1.0 + prior * odds)
    }
}

/// Each pixel's own bias in a movie, laid on `map`: the zero-electron peak of the pixel's values
/// over the frames, found by a two-class mixture (no electron: `N(b, σ²)`; electrons: the
/// register's exponential of mean `gain` beyond `b`, blurred by the read noise) with the smooth
/// map as its start, then shrunk towards the map by its error against the pattern's measured
/// spread (`τ²/(τ² + se²)`), so a pixel that holds light in most frames keeps the map and a dark
/// one its own peak. Moving scenes do not bias it: frames in which the pixel holds electrons are
/// the second class, whatever their number. `sigma` is the temporal read noise (the frame
/// differences'), values at or above `ceiling` are left out. None where the pattern is not
/// measurable (no spread beyond the peaks' errors).
pub fn refine(
    frames: &[Vec<f32>],
    map: &mut BiasMap,
    sigma: f64,
    gain: f64,
    ceiling: f64,
) -> Option<PixelBias> {
    if frames.len() < MIN_PIXEL_FRAMES || !(sigma > 0.0 && gain > 0.0) {
        return None;
    }
    let use_frames = &frames[..frames.len().min(MAX_PIXEL_FRAMES)];
    let odds = Odds::new(sigma, gain);
    let nf = use_frames.len();
    // One pixel's mixture over its values (those below the ceiling): its peak and the peak's
    // error.
    let peak = |start: f64, values: &[f64]| -> (f64, f64) {
        let mut b = start;
        let mut w = 0.5;
        let mut weight = 0.0;
        let n = values.len() as f64;
        for _ in 0..6 {
            let (mut sr, mut srv) = (0.0, 0.0);
            let prior = (1.0 - w) / w;
            for &v in values {
                let r = odds.zero_share(v - b, prior);
                sr += r;
                srv += r * v;
            }
            if sr < 1e-9 {
                return (b, f64::INFINITY);
            }
            let step = srv / sr - b;
            b += step;
            w = (sr / n).clamp(0.01, 0.99);
            weight = sr;
            if step.abs() < 1e-3 * sigma {
                break;
            }
        }
        (b, sigma / weight.sqrt())
    };
    // Pixels in runs whose values are gathered frame after frame, so that each pixel's
    // iterations read one contiguous slice.
    const RUN: usize = 512;
    let own: Vec<(f64, f64)> = map
        .values
        .par_chunks(RUN)
        .enumerate()
        .flat_map_iter(|(r, starts)| {
            let first = r * RUN;
            let mut gathered = vec![0.0f64; starts.len() * nf];
            let mut kept = vec![0usize; starts.len()];
            for f in use_frames {
                for (j, &v) in f[first..first + starts.len()].iter().enumerate() {
                    if (v as f64) < ceiling {
                        gathered[j * nf + kept[j]] = v as f64;
                        kept[j] += 1;
                    }
                }
            }
            starts
                .iter()
                .enumerate()
                .map(|(j, &start)| match kept[j] {
                    0 => (start as f64, f64::INFINITY),
                    k => peak(start as f64, &gathered[j * nf..j * nf + k]),
                })
                .collect::<Vec<_>>()
        })
        .collect();
    // The pattern's spread: the own peaks' spread about the map less their errors, over the
    // pixels known to better than the read noise.
    let good: Vec<(f64, f64)> = own
        .iter()
        .zip(&map.values)
        .filter(|((_, se), _)| *se < sigma)
        .map(|(&(b, se), &m)| (b - m as f64, se))
        .collect();
    if good.len() < 100 {
        return None;
    }
    let mean_d = good.iter().map(|g| g.0).sum::<f64>() / good.len() as f64;
    let var = good.iter().map(|g| (g.0 - mean_d).powi(2)).sum::<f64>() / good.len() as f64;
    let noise = good.iter().map(|g| g.1 * g.1).sum::<f64>() / good.len() as f64;
    let tau2 = var - noise;
    if !(tau2 > 0.0) {
        return None;
    }
    let mut kept: Vec<f64> = Vec::with_capacity(own.len());
    for (m, &(b, se)) in map.values.iter_mut().zip(&own) {
        let g = if se.is_finite() {
            tau2 / (tau2 + se * se)
        } else {
            0.0
        };
        *m = (*m as f64 + g * (b - *m as f64)) as f32;
        kept.push(g);
    }
    Some(PixelBias {
        pattern_dn: tau2.sqrt(),
        kept: emccd_profile::median(kept).unwrap_or(0.0),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_hold_enough_values() {
        for frames in [1, 2, 8, 20, 100] {
            let t = tile_side(frames);
            assert!(
                t * t * frames / 10 >= MIN_TILE_VALUES || t == 128,
                "{frames}: {t}"
            );
        }
    }
}
