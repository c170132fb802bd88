//! The bias across the frame: the zero-electron peak of each tile's darkest pixels, fitted with
//! the register's gain held at the whole frame's, and a smooth surface through the peaks. A sensor's bias drifts across it (a gradient from the first rows
//! read to the last, amplifier glow at a corner); a flat bias leaves that drift in the output,
//! several times the signal of a dim background. The pixel-to-pixel pattern beneath the tiles'
//! scale is not separated from the read noise here: it needs frames without light.

use rayon::prelude::*;

use super::{em, value_start};

/// The fewest values of a tile's darkest pixels its peak is fitted from: the peak's position to
/// about a sixth of the read noise (σ/√N₀ with N₀ ≥ 40 zero-electron values); the surface
/// through many tiles averages that down. Small, so that one frame of 128² px still holds
/// sixteen tiles.
const MIN_TILE_VALUES: usize = 100;

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
/// holds [`MIN_TILE_VALUES`] values, 32–128 px (32 from one frame on).
fn tile_side(frames: usize) -> usize {
    let px = (10 * MIN_TILE_VALUES) as f64 / frames.max(1) as f64;
    ((px.sqrt() / 16.0).ceil() as usize * 16).clamp(32, 128)
}

/// The bias map of `frames` (`width × height`, values at or above `ceiling` saturated), given
/// the whole frame's peak `bias`, its width `sigma` and the register's gain `gain` (DN per
/// electron): a surface through the tiles' peaks, weighted by their errors — quadratic where
/// twelve tiles or more show a peak, a plane from three, else `bias` flat. A surface rather
/// than the peaks themselves: one frame's tile knows its peak to about half a DN, the surface
/// to a fraction of that.
pub fn fit(
    frames: &[Vec<f32>],
    width: usize,
    height: usize,
    ceiling: f64,
    bias: f64,
    sigma: f64,
    gain: f64,
) -> BiasMap {
    let side = tile_side(frames.len());
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
    let nf = frames.len() as f64;
    let mean: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut s = 0.0;
            for f in frames {
                let v = f[i] as f64;
                if v >= ceiling {
                    return f64::NAN;
                }
                s += v;
            }
            s / nf
        })
        .collect();
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
            let (hist, start) = value_start(&values, sigma, gain);
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
    // The surface's terms in the frame's unit coordinates: 1, x, y (and x², xy, y²).
    let terms = |x: f64, y: f64, p: usize| -> [f64; 6] {
        let t = [
            1.0,
            x - 0.5,
            y - 0.5,
            (x - 0.5).powi(2),
            (x - 0.5) * (y - 0.5),
            (y - 0.5).powi(2),
        ];
        let mut out = [0.0; 6];
        out[..p].copy_from_slice(&t[..p]);
        out
    };
    let p = match fitted {
        0..=2 => return flat(fitted),
        3..=11 => 3,
        _ => 6,
    };
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
    let at = |x: f64, y: f64| -> f64 { terms(x, y, p).iter().zip(&coef).map(|(t, c)| t * c).sum() };
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
