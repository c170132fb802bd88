//! Blooming factor (paper appendix A.2, Fig. 11): on the averaged, FPN-subtracted frame of a
//! bright source covering part of the sensor, `x = (v2 − v3)/(c1 − v2)` with `v1` the bright
//! area, `v2` the bloomed area in the same columns, `v3` a dark area in other columns and `c1`
//! the mean of the columns holding `v2`. Each value is the mean of the lowest-std window found
//! by a sliding-window search. Across exposures `x(t) = a·t^b`, fitted on log–log axes.

use std::path::PathBuf;

use emccd_profile::percentile;
use serde::Serialize;

use crate::fit::{line, LineFit};
use crate::{Error, Result};

/// A window found by the search.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Window {
    /// Left column.
    pub x: usize,
    /// Top row.
    pub y: usize,
    /// Side (columns), px.
    pub w: usize,
    /// Side (rows), px.
    pub h: usize,
    /// Mean, DN.
    pub mean: f64,
    /// Standard deviation of its pixels, DN.
    pub std: f64,
}

/// One blooming exposure.
#[derive(Clone, Debug, Serialize)]
pub struct BloomLevel {
    /// Stack file.
    pub file: PathBuf,
    /// Exposure, s.
    pub exposure_s: f64,
    /// Frames averaged.
    pub frames: usize,
    /// Bright window.
    pub v1: Window,
    /// Bloomed window (same columns as the source, outside it).
    pub v2: Window,
    /// Dark window (other columns).
    pub v3: Window,
    /// Mean of the columns holding v2, DN.
    pub c1: f64,
    /// Blooming factor.
    pub x: f64,
    /// Its standard error from the windows' noise.
    pub x_se: f64,
}

/// All exposures and the power-law fit.
#[derive(Clone, Debug, Serialize)]
pub struct BloomingResult {
    /// Per exposure, ascending.
    pub levels: Vec<BloomLevel>,
    /// `x(t) = a·t^b`.
    pub a: f64,
    /// Exponent.
    pub b: f64,
    /// Log–log line (slope = b, intercept = ln a) with standard errors and r².
    pub loglog: LineFit,
    /// Whether FPN was subtracted.
    pub fpn_subtracted: bool,
}

impl BloomingResult {
    /// The law as the profile stores it, valid over the measured exposures.
    pub fn law(&self) -> emccd_profile::BloomingFit {
        let lo = self
            .levels
            .iter()
            .map(|l| l.exposure_s)
            .fold(f64::INFINITY, f64::min);
        let hi = self.levels.iter().map(|l| l.exposure_s).fold(0.0, f64::max);
        emccd_profile::BloomingFit {
            a: self.a,
            b: self.b,
            range_s: Some([lo, hi]),
        }
    }
}

/// Lowest-std `win × win` window inside the rectangle `[x0, x1) × [y0, y1)` of `img`, using
/// summed-area tables so every position costs O(1).
pub fn lowest_std_window(
    img: &[f32],
    width: usize,
    rect: [usize; 4],
    win: usize,
) -> Option<Window> {
    let [x0, y0, x1, y1] = rect;
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let (rw, rh) = (x1 - x0, y1 - y0);
    let (ww, wh) = (win.min(rw), win.min(rh));
    let stride = rw + 1;
    let mut s1 = vec![0f64; (rw + 1) * (rh + 1)];
    let mut s2 = vec![0f64; (rw + 1) * (rh + 1)];
    for y in 0..rh {
        let (mut r1, mut r2) = (0.0, 0.0);
        for x in 0..rw {
            let v = img[(y0 + y) * width + x0 + x] as f64;
            r1 += v;
            r2 += v * v;
            s1[(y + 1) * stride + x + 1] = s1[y * stride + x + 1] + r1;
            s2[(y + 1) * stride + x + 1] = s2[y * stride + x + 1] + r2;
        }
    }
    let box_sum = |s: &[f64], x: usize, y: usize| {
        s[(y + wh) * stride + x + ww] - s[y * stride + x + ww] - s[(y + wh) * stride + x]
            + s[y * stride + x]
    };
    let m = (ww * wh) as f64;
    let mut best: Option<Window> = None;
    for y in 0..=rh - wh {
        for x in 0..=rw - ww {
            let a = box_sum(&s1, x, y);
            let b = box_sum(&s2, x, y);
            let mean = a / m;
            let var = ((b - a * a / m) / (m - 1.0).max(1.0)).max(0.0);
            if best.is_none_or(|w| var.sqrt() < w.std) {
                best = Some(Window {
                    x: x0 + x,
                    y: y0 + y,
                    w: ww,
                    h: wh,
                    mean,
                    std: var.sqrt(),
                });
            }
        }
    }
    best
}

/// Longest run of `true`, as `[start, end)`.
fn longest_run(flags: &[bool]) -> Option<(usize, usize)> {
    let mut best: Option<(usize, usize)> = None;
    let mut start = None;
    for (i, &f) in flags.iter().chain(std::iter::once(&false)).enumerate() {
        match (f, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                if best.is_none_or(|(a, b)| i - s > b - a) {
                    best = Some((s, i));
                }
                start = None;
            }
            _ => {}
        }
    }
    best
}

/// What one blooming frame gives (the fields of [`BloomLevel`] of the same names).
#[derive(Clone, Debug)]
pub struct Measurement {
    /// Window inside the bright source.
    pub v1: Window,
    /// Window in the bloomed area beside the source (its columns, off its rows).
    pub v2: Window,
    /// Window in the dark columns.
    pub v3: Window,
    /// Mean of the columns holding v2, DN.
    pub c1: f64,
}

/// Measures one exposure. `img` is the averaged frame with FPN subtracted. The source is found
/// from the column and row profiles; regions keep a margin of `margin` px from its edges.
pub fn measure(
    img: &[f32],
    width: usize,
    height: usize,
    win: usize,
    file: &std::path::Path,
) -> Result<Measurement> {
    let bad = |m: &str| Error::input(file, m.to_string());
    let margin = 2usize;
    let cm: Vec<f64> = (0..width)
        .map(|x| (0..height).map(|y| img[y * width + x] as f64).sum::<f64>() / height as f64)
        .collect();
    // Nearest-rank quantiles of the column and row means: finite whenever the frame is.
    let quantile = |v: &[f64], q| percentile(v.iter().copied(), q).unwrap_or(f64::NAN);
    let (lo, hi) = (quantile(&cm, 0.05), quantile(&cm, 0.95));
    let (bx0, bx1) = longest_run(&cm.iter().map(|&c| c > 0.5 * (lo + hi)).collect::<Vec<_>>())
        .ok_or_else(|| bad("blooming frame: no bright columns found"))?;
    let rm: Vec<f64> = (0..height)
        .map(|y| (bx0..bx1).map(|x| img[y * width + x] as f64).sum::<f64>() / (bx1 - bx0) as f64)
        .collect();
    let (rlo, rhi) = (quantile(&rm, 0.05), quantile(&rm, 0.95));
    let (by0, by1) = longest_run(
        &rm.iter()
            .map(|&r| r > 0.5 * (rlo + rhi))
            .collect::<Vec<_>>(),
    )
    .ok_or_else(|| bad("blooming frame: no bright rows found"))?;
    if bx1 - bx0 == width || by1 - by0 == height {
        return Err(bad("blooming frame: the bright source must leave some columns and some rows of its columns dark"));
    }
    // The source must stand well clear of the noise, or there is nothing to measure.
    let noise = (0..width)
        .map(|x| (cm[x] - lo).abs())
        .fold(0.0, f64::max)
        .max(1e-9);
    if !(rhi - rlo > 0.0) || hi - lo < 1e-6 * noise {
        return Err(bad("blooming frame: no bright source stands out"));
    }
    let shrink = |a: usize, b: usize, n: usize| -> (usize, usize) {
        (
            if a == 0 { 0 } else { a + margin },
            if b == n { n } else { b.saturating_sub(margin) },
        )
    };
    let (sx0, sx1) = shrink(bx0, bx1, width);
    let (sy0, sy1) = shrink(by0, by1, height);
    // Bloomed area: the larger side of the source's columns above or below it.
    let above = by0.saturating_sub(margin);
    let below_start = (by1 + margin).min(height);
    let bloom_rect = if above >= height - below_start {
        [sx0, 0, sx1, above]
    } else {
        [sx0, below_start, sx1, height]
    };
    // Dark area: the larger side of the other columns.
    let left = bx0.saturating_sub(margin);
    let right_start = (bx1 + margin).min(width);
    let dark_rect = if left >= width - right_start {
        [0, 0, left, height]
    } else {
        [right_start, 0, width, height]
    };
    let v1 = lowest_std_window(img, width, [sx0, sy0, sx1, sy1], win)
        .ok_or_else(|| bad("blooming frame: bright area too small"))?;
    let v2 = lowest_std_window(img, width, bloom_rect, win)
        .ok_or_else(|| bad("blooming frame: no bloomed area beside the source"))?;
    let v3 = lowest_std_window(img, width, dark_rect, win)
        .ok_or_else(|| bad("blooming frame: no dark columns"))?;
    let c1 = (v2.x..v2.x + v2.w).map(|x| cm[x]).sum::<f64>() / v2.w as f64;
    Ok(Measurement { v1, v2, v3, c1 })
}

/// Fits `x(t) = a·t^b` on log–log axes.
pub fn fit(levels: Vec<BloomLevel>, fpn_subtracted: bool) -> Result<BloomingResult> {
    let ok: Vec<&BloomLevel> = levels.iter().filter(|l| l.x > 0.0).collect();
    if ok.len() < 2 {
        return Err(Error::Fit(format!(
            "the blooming fit needs ≥ 2 exposures with a positive factor, got {}",
            ok.len()
        )));
    }
    let lx: Vec<f64> = ok.iter().map(|l| l.exposure_s.ln()).collect();
    let ly: Vec<f64> = ok.iter().map(|l| l.x.ln()).collect();
    let f = line(&lx, &ly, None)
        .ok_or_else(|| Error::Fit("blooming exposures are all equal".into()))?;
    Ok(BloomingResult {
        a: f.intercept.exp(),
        b: f.slope,
        loglog: f,
        levels,
        fpn_subtracted,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn measures_an_exact_blooming_frame() {
        // Source in the bottom-left quadrant, uniform stray light, exact B[Y] = Y + x·colmean(Y).
        let (w, h, x) = (128usize, 128usize, 0.037);
        let mut y = vec![5.0f32; w * h];
        for r in h / 2..h {
            for c in 0..w / 2 {
                y[r * w + c] = 3000.0;
            }
        }
        let cm: Vec<f32> = (0..w)
            .map(|c| (0..h).map(|r| y[r * w + c]).sum::<f32>() / h as f32)
            .collect();
        let img: Vec<f32> = (0..w * h).map(|i| y[i] + x as f32 * cm[i % w]).collect();
        let Measurement { v2, v3, c1, .. } =
            measure(&img, w, h, 32, std::path::Path::new("t.tif")).unwrap();
        let est = (v2.mean - v3.mean) / (c1 - v2.mean);
        assert!((est - x).abs() < 1e-5, "{est}");
        assert!(v2.y + v2.h <= h / 2 && v2.x + v2.w <= w / 2 && v3.x >= w / 2);
    }
}
