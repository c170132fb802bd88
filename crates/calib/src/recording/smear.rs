//! Frame-transfer smear from the recording itself, where no blooming stacks were taken.
//!
//! A frame-transfer sensor reads light while its rows move to the storage area, so each pixel
//! gains a share `x` of its column's mean (the profile's blooming, `B[Y] = Y + x·colmean(Y)`):
//! in a column through a bright object the dark background sits higher, above the object and
//! below it alike, by `β·colmean(D)` with `β = x/(1 + x)` (the recorded column holds the smear
//! too).
//!
//! A scene's haze lifts the dark background near bright objects as well, and bright columns
//! hold more of them, so the floor is not regressed on the column's mean as it is. Two
//! contrasts the haze does not make are used instead: across columns, a column's floor less
//! its two neighbours' against its mean less theirs (haze is smooth over a few columns, a
//! compact object's column mean is not), and in a movie, each frame's floor less the column's
//! mean floor against the same frame's column mean less its own mean (objects that move or
//! blink change a column's light from frame to frame). The floor is the darkest tenth of the
//! column's rows (chosen by the rows above and below in all three columns, never by their own
//! values), the column means are taken over the other rows (so the floor's noise is not in
//! both). A scene of smooth, still cells gives neither contrast, and then no smear is
//! measurable: said, and none removed. Written here: no crate does it.

use rayon::prelude::*;

use super::Estimate;

/// Rows a frame needs at least: the floor is the mean of its darkest tenth.
const MIN_ROWS: usize = 32;
/// Column groups of the delete-a-group jackknife (neighbouring columns share the scene).
const GROUPS: usize = 16;
/// Frames a movie needs for the frame-to-frame contrast.
const MIN_FRAMES: usize = 4;
/// A smear is removed where its factor is this many standard errors above zero: a smear that
/// is not there would take a share of every column's mean off the output.
const SIGNIFICANCE: f64 = 4.0;

/// What the recording says about smear.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Smear {
    /// The share of its column's mean each pixel gains, `x`, at the recording's exposure.
    pub factor: Estimate,
    /// Whether it is measurably above zero (else the profile removes none).
    pub significant: bool,
    /// Columns used (those without a saturated pixel in them or their neighbours).
    pub columns: usize,
}

/// Rows above and below a floor pixel that must be dark with it (never the pixel itself).
const REACH: usize = 4;
/// Blocks of frames whose means choose the floor: a pixel must be dark in each.
const BLOCKS: usize = 4;

/// The smear factor of `frames` (`width × height`, raw DN) given each pixel's mean over them
/// (`mean`, NaN where saturated), its bias (`bias`, DN), and the read noise and
/// photon-transfer slope (`noise`: a value's variance is `σ² + s·(value − bias)`, taken out of
/// the column means' spread, whose noise would otherwise pull the factor towards zero); None
/// where the frame is too small (fewer than 32 rows or 34 columns) or too few columns are
/// usable.
pub fn estimate(
    frames: &[Vec<f32>],
    mean: &[f64],
    bias: &[f32],
    width: usize,
    height: usize,
    noise: (f64, f64),
) -> Option<Smear> {
    if height < MIN_ROWS || width < 2 * GROUPS + 2 {
        return None;
    }
    let a = |y: usize, x: usize| mean[y * width + x] - bias[y * width + x] as f64;
    let movie = frames.len() >= MIN_FRAMES;
    let (sigma, slope) = noise;
    let var = |y: usize, x: usize| sigma * sigma + slope * a(y, x).max(0.0);
    // The means of blocks of frames: the floor is dark in each of them, so that an object
    // moving past it in part of the movie does not lift it (and with it, the column's light).
    let blocks: Vec<Vec<f64>> = if movie {
        let per = frames.len().div_ceil(BLOCKS);
        frames
            .par_chunks(per)
            .map(|part| {
                (0..width * height)
                    .map(|i| {
                        part.iter()
                            .map(|f| f[i] as f64 - bias[i] as f64)
                            .sum::<f64>()
                            / part.len() as f64
                    })
                    .collect()
            })
            .collect()
    } else {
        vec![(0..width * height)
            .map(|i| a(i / width, i % width))
            .collect()]
    };
    // Per column: the contrasts' cross-products Σ dF·dC and Σ dC².
    let sums: Vec<Option<(f64, f64)>> = (1..width - 1)
        .into_par_iter()
        .map(|c| {
            if (0..height).any(|y| (c - 1..=c + 1).any(|x| !a(y, x).is_finite())) {
                return None;
            }
            let mut keyed: Vec<(f64, usize)> = (REACH..height - REACH)
                .map(|y| {
                    let k = blocks
                        .iter()
                        .flat_map(|b| {
                            (c - 1..=c + 1).map(move |x| {
                                (1..=REACH)
                                    .map(|d| b[(y - d) * width + x] + b[(y + d) * width + x])
                                    .sum::<f64>()
                                    / (2 * REACH) as f64
                            })
                        })
                        .fold(f64::MIN, f64::max);
                    (k, y)
                })
                .collect();
            keyed.sort_by(|p, q| p.0.total_cmp(&q.0).then(p.1.cmp(&q.1)));
            let take = (keyed.len() / 10).max(3);
            let mut floor = vec![false; height];
            for &(_, y) in &keyed[..take] {
                floor[y] = true;
            }
            let rows: Vec<usize> = (0..height).filter(|&y| floor[y]).collect();
            let rest = |v: &dyn Fn(usize) -> f64| {
                (0..height).filter(|&y| !floor[y]).map(v).sum::<f64>() / height as f64
            };
            // Across columns, on the means over the frames.
            let df = rows
                .iter()
                .map(|&y| a(y, c) - 0.5 * (a(y, c - 1) + a(y, c + 1)))
                .sum::<f64>()
                / rows.len() as f64;
            let level = |x: usize| rest(&|y| a(y, x));
            let dc = level(c) - 0.5 * (level(c - 1) + level(c + 1));
            // The noise of one frame's column level (the rows left), and what it adds to dc².
            let noise = |x: usize| rest(&|y| var(y, x)) / height as f64;
            let t = frames.len() as f64;
            let (mut num, mut den) = (
                df * dc,
                dc * dc - (noise(c) + 0.25 * (noise(c - 1) + noise(c + 1))) / t,
            );
            // Frame to frame, the same contrast across columns (a moving scene's haze is as
            // smooth across columns as a still one's).
            if movie {
                let v = |f: &[f32], y: usize, x: usize| {
                    f[y * width + x] as f64 - bias[y * width + x] as f64
                };
                let per: Vec<(f64, f64)> = frames
                    .iter()
                    .map(|f| {
                        let fl = rows
                            .iter()
                            .map(|&y| v(f, y, c) - 0.5 * (v(f, y, c - 1) + v(f, y, c + 1)))
                            .sum::<f64>()
                            / rows.len() as f64;
                        let lc = |x: usize| rest(&|y| v(f, y, x));
                        (fl, lc(c) - 0.5 * (lc(c - 1) + lc(c + 1)))
                    })
                    .collect();
                let n = per.len() as f64;
                let (mf, mc) = per
                    .iter()
                    .fold((0.0, 0.0), |s, p| (s.0 + p.0 / n, s.1 + p.1 / n));
                for (fl, lc) in per {
                    num += (fl - mf) * (lc - mc);
                    den += (lc - mc).powi(2);
                }
                den -= (n - 1.0) * (noise(c) + 0.25 * (noise(c - 1) + noise(c + 1)));
            }
            Some((num, den))
        })
        .collect();
    // Group sums, in column order (the same for any thread count).
    let mut groups = vec![(0.0, 0.0); GROUPS];
    let mut columns = 0;
    for (i, s) in sums.iter().enumerate() {
        if let Some((n, d)) = s {
            let g = (i + 1) * GROUPS / width;
            groups[g].0 += n;
            groups[g].1 += d;
            columns += 1;
        }
    }
    if columns < 2 * GROUPS {
        return None;
    }
    let (num, den) = groups
        .iter()
        .fold((0.0, 0.0), |s, g| (s.0 + g.0, s.1 + g.1));
    let unmeasurable = Smear {
        factor: Estimate::new(f64::NAN, f64::NAN),
        significant: false,
        columns,
    };
    if !(den > 0.0) {
        // No contrast beyond the noise: nothing to measure the factor by.
        return Some(unmeasurable);
    }
    let b = num / den;
    let parts: Vec<f64> = groups
        .iter()
        .filter(|g| g.1 > 0.0)
        .map(|g| (num - g.0) / (den - g.1))
        .collect();
    let k = parts.len() as f64;
    let m = parts.iter().sum::<f64>() / k;
    let se_b = ((k - 1.0) / k * parts.iter().map(|p| (p - m).powi(2)).sum::<f64>()).sqrt();
    if !(b < 0.5) {
        // A column gaining more than its own light: the contrast is noise.
        return Some(unmeasurable);
    }
    // x = β/(1 − β); its error through the derivative 1/(1 − β)².
    let x = b / (1.0 - b);
    let se = se_b / (1.0 - b).powi(2);
    Some(Smear {
        factor: Estimate::new(x, se),
        significant: se.is_finite() && x > SIGNIFICANCE * se,
        columns,
    })
}

/// Puts a smear factor `x` measured on a recording at `exposure_s` into `profile` as its
/// blooming there (`a = x·t`, `b = −1`, that one exposure's range), for a profile whose
/// calibration measured none. The fixed pattern at that exposure becomes the profile's constant
/// pattern, un-bloomed, so that preprocessing `B⁻¹(D) − FPN` is `B⁻¹(D − FPN)`: the pattern was
/// measured without the scene's light (bias frames) or, from a recording, as the zero-electron
/// peak, which smear (light) does not move. The profile then serves recordings at that
/// exposure.
pub fn into_profile(profile: &mut emccd_profile::CameraProfile, x: f64, exposure_s: f64) {
    let mut fpn = vec![0f32; profile.len()];
    profile.fpn_at(exposure_s, &mut fpn);
    emccd_profile::remove_blooming(&mut fpn, profile.width, x);
    profile.maps.fpn_base = fpn;
    profile.maps.fpn_theta.clear();
    profile.fpn = emccd_profile::FpnFit {
        form: emccd_profile::FpnForm::Constant,
        base_exposure_s: exposure_s,
        shared_theta: [0.0; 4],
    };
    profile.blooming = Some(emccd_profile::BloomingFit {
        a: x * exposure_s,
        b: -1.0,
        range_s: Some([exposure_s, exposure_s]),
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dim background with bright blobs of many brightnesses here and there, each with a
    /// haze around it that lifts the floor near it.
    fn scene(width: usize, height: usize) -> Vec<f64> {
        let mut s = vec![0.5; width * height];
        let mut seed = 12345u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..width / 3 {
            let (cx, cy) = (next() * width as f64, next() * height as f64);
            let peak = 20.0 + 400.0 * next();
            for y in 0..height {
                for x in 0..width {
                    let d2 = (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2);
                    let d = d2.sqrt();
                    s[y * width + x] += peak * ((-d2 / 8.0).exp() + 0.04 * (-d / 10.0).exp());
                }
            }
        }
        s
    }

    fn smeared(s: &[f64], width: usize, x: f64) -> Vec<f64> {
        let height = s.len() / width;
        let mut out = s.to_vec();
        for c in 0..width {
            let m = (0..height).map(|y| s[y * width + c]).sum::<f64>() / height as f64;
            for y in 0..height {
                out[y * width + c] += x * m;
            }
        }
        out
    }

    #[test]
    fn a_smear_is_recovered_and_haze_is_not_taken_for_one() {
        let (w, h) = (128, 128);
        let s = scene(w, h);
        let bias = vec![0f32; w * h];
        // Noiseless: the regression is exact for smear; the haze stays in the own level's term.
        let one = |m: &[f64]| -> Smear {
            let frame: Vec<f32> = m.iter().map(|&v| v as f32).collect();
            estimate(&[frame], m, &bias, w, h, (0.0, 0.0)).unwrap()
        };
        let with = one(&smeared(&s, w, 0.05));
        assert!(with.significant, "{with:?}");
        assert!((with.factor.value - 0.05).abs() < 0.005, "{with:?}");
        let without = one(&s);
        assert!(!without.significant, "{without:?}");
        assert!(without.factor.value.abs() < 0.005, "{without:?}");
    }
}
