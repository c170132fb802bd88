//! The photon-transfer curve of a movie: the temporal variance of blocks of pixels against their
//! level, from differences of neighbouring frames.
//!
//! For frames `t` and `t + 1` of a still scene, half the variance of `x_{t+1} − x_t` over a block
//! of pixels is the block's mean noise variance, `s·(level − b) + σ²`, with the fixed pattern
//! cancelled. The block's level is taken from other frames than the two differenced (the two
//! nearest), so that the EM register's skew (a frame's bright value raises both its level and
//! its difference) does not tilt the line. Where the scene moves between the two frames, the
//! difference holds the motion as well: a block whose four quarters' mean differences between the
//! level's two frames disagree more than the line's noise allows is left out (judged on other
//! frames than the variance, so that leaving a block out does not bias it), and a uniform change
//! (bleaching, flicker) by taking the variance about the block's own mean difference.

use rayon::prelude::*;

use crate::fit::line;

/// Block side, px: 64 values a variance, four quarters of 16 for the motion test.
const BLOCK: usize = 8;
/// The 0.1 % point of χ² with 3 degrees of freedom: a block whose quarters' mean differences
/// spread more than this (in units of their noise) is taken to hold motion.
const CHI2_MOTION: f64 = 16.27;

/// One block of one frame pair.
#[derive(Clone, Copy, Debug)]
pub struct Point {
    /// The block's level above the bias from other frames, DN.
    pub level: f64,
    /// Half the variance of the block's frame difference, DN².
    pub variance: f64,
    /// Which of the jackknife's groups the block belongs to.
    pub group: usize,
    /// The motion test's statistic: the spread of the quarters' mean differences between the
    /// level's two frames (or, in a movie of two or three frames, the pair's own), in DN² per
    /// unit of one value's noise variance.
    motion: f64,
    /// Whether `motion` comes from the pair itself (no other two frames).
    own: bool,
    /// Values averaged into the level (pixels × frames): its noise is the variance over it.
    values: f64,
}

/// The fitted line `variance = slope·level + intercept` and its standard errors.
#[derive(Clone, Debug)]
pub struct Curve {
    /// The photon-transfer slope `s = K·f²`, DN per DN.
    pub slope: f64,
    /// Its standard error (delete-a-group jackknife over strips of the frame).
    pub slope_se: f64,
    /// The intercept, the read noise's variance `σ²`, DN².
    pub intercept: f64,
    /// Its standard error.
    pub intercept_se: f64,
    /// The points fitted (a sample, for the report's plot).
    pub points: Vec<Point>,
    /// Block pairs kept.
    pub kept: usize,
    /// Block pairs left out as moving or saturated.
    pub left_out: usize,
}

/// Jackknife groups: horizontal strips of the frame.
const GROUPS: usize = 8;

/// The curve from `frames` (each `width × height`, at least two), the levels above `bias` (the
/// bias map, DN per pixel), leaving out blocks that hold a value at or above `ceiling`
/// (saturation). `None` without enough blocks to fit a line. The levels are taken above the
/// bias map because a bias that drifts across the frame spreads the raw levels without
/// raising the variance: errors in the levels that flatten the line (a 20 DN drift under a
/// 1 e⁻ scene at 15 DN per electron took it to 0.56 of its slope).
pub fn curve(
    frames: &[Vec<f32>],
    width: usize,
    height: usize,
    ceiling: f64,
    bias: &[f32],
) -> Option<Curve> {
    let nf = frames.len();
    if nf < 2 {
        return None;
    }
    let (bw, bh) = (width / BLOCK, height / BLOCK);
    if bw * bh < 4 {
        return None;
    }
    let sums = BlockSums::new(frames, bias, width, bw, bh, ceiling);
    // Each pair's points in parallel, in a fixed order (the same result for any thread count).
    let per_pair: Vec<(Vec<Point>, usize)> = (0..nf - 1)
        .into_par_iter()
        .map(|t| {
            let others = level_frames(t, nf);
            let mut pts = Vec::with_capacity(bw * bh);
            let mut left = 0;
            for by in 0..bh {
                for bx in 0..bw {
                    match block(frames, &sums, &others, t, width, bx, by, ceiling) {
                        Some(mut p) => {
                            p.group = by * GROUPS / bh;
                            pts.push(p)
                        }
                        None => left += 1,
                    }
                }
            }
            (pts, left)
        })
        .collect();
    let mut points = Vec::new();
    let mut left_out = 0;
    for (p, l) in per_pair {
        points.extend(p);
        left_out += l;
    }
    // Motion is judged against the noise the line predicts, so the line is fitted to every
    // block first and then again to the still ones.
    let all: Vec<&Point> = points.iter().collect();
    let (mut slope, mut intercept) = weighted(&all)?;
    let mut still: Vec<Point> = Vec::new();
    for _ in 0..2 {
        still = points
            .iter()
            .filter(|p| {
                let var = (slope * p.level + intercept).max(1e-6);
                let scale = if p.own { p.variance } else { var };
                p.motion / scale < CHI2_MOTION
            })
            .copied()
            .collect();
        let refs: Vec<&Point> = still.iter().collect();
        (slope, intercept) = weighted(&refs)?;
    }
    left_out += points.len() - still.len();
    let points = still;
    // Delete-a-group jackknife: blocks of one strip share the scene, so the strips, not the
    // blocks, are the independent units.
    let mut js = Vec::new();
    for g in 0..GROUPS {
        let sub: Vec<&Point> = points.iter().filter(|p| p.group != g).collect();
        if let Some(f) = weighted(&sub) {
            js.push(f);
        }
    }
    let (slope_se, intercept_se) = if js.len() >= 3 {
        let k = js.len() as f64;
        let ms = js.iter().map(|f| f.0).sum::<f64>() / k;
        let mi = js.iter().map(|f| f.1).sum::<f64>() / k;
        let vs = js.iter().map(|f| (f.0 - ms).powi(2)).sum::<f64>() * (k - 1.0) / k;
        let vi = js.iter().map(|f| (f.1 - mi).powi(2)).sum::<f64>() * (k - 1.0) / k;
        (vs.sqrt(), vi.sqrt())
    } else {
        (f64::NAN, f64::NAN)
    };
    let kept = points.len();
    // A sample of the points for the report: every k-th, at most 4000.
    let every = (kept / 4000).max(1);
    let points = points.into_iter().step_by(every).collect();
    Some(Curve {
        slope,
        slope_se,
        intercept,
        intercept_se,
        points,
        kept,
        left_out,
    })
}

/// Frames a block's level is averaged over: enough that its noise is a small part of the
/// spread of the blocks' levels (the line's slope is corrected for what is left).
const LEVEL_FRAMES: usize = 8;

/// The frames a pair `(t, t + 1)`'s level comes from: the [`LEVEL_FRAMES`] nearest others,
/// alternating before and after (so that a steady drift averages to the pair's own time), or
/// the pair itself when the movie has no other frame.
fn level_frames(t: usize, nf: usize) -> Vec<usize> {
    let mut others = Vec::new();
    for step in 1..nf {
        for c in [t as i64 - step as i64, (t + 1 + step) as i64] {
            if others.len() < LEVEL_FRAMES && c >= 0 && (c as usize) < nf {
                others.push(c as usize);
            }
        }
        if others.len() == LEVEL_FRAMES {
            break;
        }
    }
    if others.is_empty() {
        others = vec![t, t + 1];
    }
    others
}

/// Each block's sums in each frame, computed once: a block's level is averaged over eight
/// frames for each of the movie's pairs, and its quarters' means over two.
struct BlockSums {
    /// Blocks per frame.
    blocks: usize,
    /// Per frame and block: the values' sum, or NaN where one is at or above the ceiling.
    sum: Vec<f64>,
    /// Per frame and block: the four quarters' sums.
    quarters: Vec<[f64; 4]>,
    /// Per block: the bias map's sum.
    bias: Vec<f64>,
}

impl BlockSums {
    fn new(
        frames: &[Vec<f32>],
        bias: &[f32],
        width: usize,
        bw: usize,
        bh: usize,
        ceiling: f64,
    ) -> BlockSums {
        let blocks = bw * bh;
        let of = |v: &[f32], k: usize| -> (f64, [f64; 4]) {
            let (bx, by) = (k % bw, k / bw);
            let (mut sum, mut quarter) = (0.0, [0.0f64; 4]);
            for y in 0..BLOCK {
                for x in 0..BLOCK {
                    let value = v[(by * BLOCK + y) * width + bx * BLOCK + x] as f64;
                    sum += if value >= ceiling { f64::NAN } else { value };
                    quarter[(y / (BLOCK / 2)) * 2 + x / (BLOCK / 2)] += value;
                }
            }
            (sum, quarter)
        };
        let (sum, quarters): (Vec<f64>, Vec<[f64; 4]>) = (0..frames.len() * blocks)
            .into_par_iter()
            .map(|j| of(&frames[j / blocks], j % blocks))
            .unzip();
        let bias = (0..blocks).map(|k| of(bias, k).0).collect();
        BlockSums {
            blocks,
            sum,
            quarters,
            bias,
        }
    }
}

/// Block `(bx, by)` of the pair `(t, t + 1)`: its level, half-variance and motion statistic;
/// `None` where it is saturated or flat (no noise at all).
#[allow(clippy::too_many_arguments)]
fn block(
    frames: &[Vec<f32>],
    sums: &BlockSums,
    others: &[usize],
    t: usize,
    width: usize,
    bx: usize,
    by: usize,
    ceiling: f64,
) -> Option<Point> {
    let (a, b) = (&frames[t], &frames[t + 1]);
    let k = by * (width / BLOCK) + bx;
    let at = |f: usize| f * sums.blocks + k;
    // The motion test's two frames: the level's two, where they are not the pair itself.
    let own = others.len() < 2 || others.contains(&t);
    let (m0, m1) = if own {
        (t, t + 1)
    } else {
        (others[0], others[1])
    };
    let level =
        others.iter().map(|&o| sums.sum[at(o)]).sum::<f64>() / others.len() as f64 - sums.bias[k];
    if !level.is_finite() {
        return None;
    }
    let mut d = [0.0f64; BLOCK * BLOCK];
    for y in 0..BLOCK {
        for x in 0..BLOCK {
            let i = (by * BLOCK + y) * width + bx * BLOCK + x;
            let (va, vb) = (a[i] as f64, b[i] as f64);
            if va >= ceiling || vb >= ceiling {
                return None;
            }
            d[y * BLOCK + x] = vb - va;
        }
    }
    let quarter: [f64; 4] =
        std::array::from_fn(|j| sums.quarters[at(m1)][j] - sums.quarters[at(m0)][j]);
    let n = (BLOCK * BLOCK) as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    if !(var > 0.0) {
        return None;
    }
    // Each quarter's mean difference has the variance 2·Var/16 of one value's noise Var where
    // nothing moves: the statistic is in units of Var, so that it is χ² with 3 degrees of
    // freedom once divided by it.
    let q = n / 4.0;
    let qmean = quarter.iter().sum::<f64>() / n;
    let motion = quarter.iter().map(|s| (s / q - qmean).powi(2)).sum::<f64>() * q / 2.0;
    Some(Point {
        level: level / n,
        variance: var / 2.0,
        group: 0,
        motion,
        own,
        values: n * others.len() as f64,
    })
}

/// Weighted least squares of variance on level, each point weighted by the inverse square of
/// its predicted variance (a sample variance's spread grows with it), iterated from the
/// unweighted line. A level is a mean of noisy values itself, which flattens a plain line
/// (errors in variables): its noise, the predicted variance over the values averaged, is taken
/// out of the levels' spread.
fn weighted(pts: &[&Point]) -> Option<(f64, f64)> {
    if pts.len() < 3 {
        return None;
    }
    let (mut slope, mut intercept) = {
        let x: Vec<f64> = pts.iter().map(|p| p.level).collect();
        let y: Vec<f64> = pts.iter().map(|p| p.variance).collect();
        let f = line(&x, &y, None)?;
        (f.slope, f.intercept)
    };
    let floor = pts
        .iter()
        .map(|p| p.variance)
        .fold(f64::INFINITY, f64::min)
        .max(1e-6);
    for _ in 0..4 {
        let pred = |p: &Point| (slope * p.level + intercept).max(floor);
        let w: Vec<f64> = pts.iter().map(|p| 1.0 / pred(p).powi(2)).collect();
        let sw: f64 = w.iter().sum();
        let mx = pts.iter().zip(&w).map(|(p, w)| w * p.level).sum::<f64>() / sw;
        let my = pts.iter().zip(&w).map(|(p, w)| w * p.variance).sum::<f64>() / sw;
        let sxy: f64 = pts
            .iter()
            .zip(&w)
            .map(|(p, w)| w * (p.level - mx) * (p.variance - my))
            .sum();
        let sxx: f64 = pts
            .iter()
            .zip(&w)
            .map(|(p, w)| w * ((p.level - mx).powi(2) - pred(p) / p.values))
            .sum();
        if !(sxx > 0.0) {
            return None;
        }
        slope = sxy / sxx;
        intercept = my - slope * mx;
    }
    (slope.is_finite() && intercept.is_finite()).then_some((slope, intercept))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_frames_are_the_nearest_others() {
        assert_eq!(level_frames(0, 2), vec![0, 1]);
        assert_eq!(level_frames(0, 3), vec![2]);
        assert_eq!(level_frames(0, 5), vec![2, 3, 4]);
        assert_eq!(level_frames(2, 6), vec![1, 4, 0, 5]);
        assert_eq!(level_frames(10, 40), vec![9, 12, 8, 13, 7, 14, 6, 15]);
    }
}
