//! A camera characterized from a recording itself: no bias, flat or blooming stacks.
//!
//! At EMCCD light levels a recording carries its own calibration (Harpsøe et al. 2012, Foi et
//! al. 2008, applied to the EM register):
//!
//! 1. **The darkest pixels** are chosen by their neighbours' mean (never by their own values,
//!    so the choice leaves their distribution as it is).
//! 2. **The register's gain and the read noise**: their differences — two frames of one pixel
//!    in a movie, two neighbouring pixels in one frame — cancel the bias and the fixed pattern;
//!    the Gaussian core is the read noise, the exponential tails the single electrons' mean
//!    output `K` in DN ([`em::Form::Differences`]).
//! 3. **The bias**: the zero-electron peak of the same pixels' values, with `K` known
//!    ([`em::Form::Values`]).
//! 4. **The photon-transfer slope** `s = K·f²`: in a movie, the temporal variance of blocks
//!    against their level ([`ptc`]), where the scene holds still; in one frame, `2K` (the
//!    theoretical excess noise of a many-stage register, `f² = 2`).
//!
//! What cannot be estimated is said (no dark pixels: no bias; too few electrons in them: no
//! gain), never guessed.

pub mod bias_map;
pub mod check;
pub mod em;
pub mod ptc;
pub mod report;
pub mod smear;

use emccd_profile::{CameraProfile, FpnFit, FpnForm, ProfileMaps, Provenance};
use rayon::prelude::*;
use serde::Serialize;

use crate::{Error, Result};

/// A number and its standard error (NaN where none could be given).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Estimate {
    /// The value.
    pub value: f64,
    /// Its standard error.
    pub se: f64,
}

impl Estimate {
    fn new(value: f64, se: f64) -> Estimate {
        Estimate { value, se }
    }
}

/// Where the photon-transfer slope came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SlopeFrom {
    /// The movie's temporal mean–variance line.
    TemporalPtc,
    /// Twice the register's single-electron gain (one frame: `f² = 2` assumed).
    EmTail,
}

/// The relative spread of the excess noise `f² = 2 − 1/G` about 2 among registers whose
/// single-electron tail is measurable (G of 50 and up): the error `2K` carries as a slope.
const F2_SPREAD: f64 = 0.02;

/// The fewest values of dark pixels a characterization uses.
pub const MIN_DARK_VALUES: usize = 2000;
/// Electrons a frame in the darkest tenth above which the register's gain is measured on the
/// darkest fortieth as well (see `characterize`).
const DARKER_ABOVE: f64 = 0.3;
/// The largest number of values held ([`frames_to_hold`]): 32 M, 128 MB of `f32`.
pub const MAX_VALUES: usize = 1 << 25;

/// How many of a recording's `frames` of `width × height` a characterization reads: all, up to
/// [`MAX_VALUES`] values (at least one frame).
pub fn frames_to_hold(frames: usize, width: usize, height: usize) -> usize {
    frames.min((MAX_VALUES / (width * height).max(1)).max(1))
}

/// What a recording says about its camera.
#[derive(Clone, Debug, Serialize)]
pub struct Characterization {
    /// Frame width, px.
    pub width: usize,
    /// Frame height, px.
    pub height: usize,
    /// Frames used.
    pub frames: usize,
    /// The bias (the zero-electron peak of the darkest pixels), DN.
    pub bias_dn: Estimate,
    /// The bias across the frame (tiles' zero-electron peaks), the profile's bias map.
    #[serde(skip)]
    pub bias_map: bias_map::BiasMap,
    /// The read noise of one value, DN: in a movie the temporal read noise (the fixed pattern
    /// cancelled); in one frame the read noise and the pixel-to-pixel pattern together.
    pub read_noise_dn: Estimate,
    /// The spread of the bias from pixel to pixel, DN, where a movie separates it.
    pub pattern_dn: Option<f64>,
    /// The register's mean output per electron, DN (`K`, the EM tail's scale).
    pub gain_dn: Option<Estimate>,
    /// The photon-transfer slope `s = K·f²`, DN per DN.
    pub slope_dn: Estimate,
    /// Where the slope came from.
    pub slope_from: SlopeFrom,
    /// `f² = s/K`, where both were measured.
    pub excess_f2: Option<Estimate>,
    /// Electrons per frame in the darkest pixels (their light, dark current and clock-induced
    /// charge: an upper bound on the spurious charge).
    pub dark_electrons: Estimate,
    /// The recording's mean light level, photoelectrons per pixel per frame (`s/2` DN each, the
    /// profile's conversion).
    pub mean_electrons: f64,
    /// The value at which the recording saturates, where it reaches one.
    pub saturation_dn: Option<f64>,
    /// Frame-transfer smear, where the frame is large enough to look for it ([`smear`]).
    pub smear: Option<smear::Smear>,
    /// The pooled values of the dark pixels, and their fit.
    #[serde(skip)]
    pub values: em::Histogram,
    /// The values' fit.
    #[serde(skip)]
    pub values_fit: em::Fit,
    /// The dark pixels' differences, and their fit.
    #[serde(skip)]
    pub differences: em::Histogram,
    /// The differences' fit.
    #[serde(skip)]
    pub differences_fit: em::Fit,
    /// The movie's photon-transfer curve.
    #[serde(skip)]
    pub curve: Option<ptc::Curve>,
    /// What a reader should know: assumptions made, what could not be measured.
    pub notes: Vec<String>,
}

/// Characterizes the camera from `frames` (each `width × height`, raw DN, one or more).
pub fn characterize(frames: &[Vec<f32>], width: usize, height: usize) -> Result<Characterization> {
    let n = width * height;
    if frames.is_empty() {
        return Err(Error::Fit("the recording holds no frames".into()));
    }
    if let Some(f) = frames.iter().position(|f| f.len() != n) {
        return Err(Error::Fit(format!(
            "frame {} holds {} values, not {width}×{height}",
            f + 1,
            frames[f].len()
        )));
    }
    if width < 8 || height < 8 || frames.len() * n < 4 * MIN_DARK_VALUES {
        return Err(Error::Fit(format!(
            "{width}×{height} px × {} frame(s) is too little to characterize a camera from: it needs at least {} values (e.g. 32×32 px × 8 frames), so that its darkest pixels hold {MIN_DARK_VALUES}; calibrate the camera (`emccd calibrate`) or pass --profile",
            frames.len(),
            4 * MIN_DARK_VALUES
        )));
    }
    if let Some((f, i)) = frames
        .iter()
        .enumerate()
        .find_map(|(f, v)| v.iter().position(|x| !x.is_finite()).map(|i| (f, i)))
    {
        let v = frames[f][i];
        return Err(Error::Fit(format!(
            "frame {}: a non-finite value at pixel ({}, {}) ({v}{})",
            f + 1,
            i % width,
            i / width,
            if v.is_infinite() {
                "; a float64 beyond float32's ±3.4e38 reads as ±inf"
            } else {
                ""
            }
        )));
    }
    let mut notes = Vec::new();
    let (saturation, saturated) = match saturation(frames) {
        Some((max, at)) => (Some(max), at),
        None => (None, 0),
    };
    let ceiling = saturation.unwrap_or(f64::INFINITY);
    if saturated * 2 > frames.len() * n {
        return Err(Error::Fit(format!(
            "{:.0} % of the values are at the recording's maximum ({} DN): it is saturated, and a saturated pixel says nothing about the camera's noise; record at a lower light level or EM gain, or pass --profile",
            100.0 * saturated as f64 / (frames.len() * n) as f64,
            ceiling
        )));
    }

    // 1. The darkest pixels, chosen by their neighbours.
    let means = pixel_means(frames, ceiling);
    let (ranked, ranked_pairs) = darkest(&means, width, height);
    let dark = darkest_share(&ranked, 10, frames.len());
    let dark_pairs = darkest_share(&ranked_pairs, 10, 1);
    let movie = frames.len() >= 2;

    // 2. Differences: the register's gain and the read noise.
    let diffs: Vec<f64> = if movie {
        frame_differences(frames, &dark)
    } else {
        dark_pairs
            .iter()
            .map(|&i| frames[0][i + 1] as f64 - frames[0][i] as f64)
            .collect()
    };
    if diffs.len() < MIN_DARK_VALUES / 2 {
        return Err(Error::Fit(format!(
            "only {} differences of dark pixels: too few to measure the read noise and the register's gain; a longer recording, a larger frame, or --profile",
            diffs.len()
        )));
    }
    let (differences, d0) = difference_start(&diffs);
    let mut differences_fit = em::fit(em::Form::Differences, &differences, d0, em::Free { gain: true, spread: false })
        .ok_or_else(|| Error::Fit("the dark pixels' differences could not be fitted (no Gaussian core of read noise): this does not look like an EMCCD recording; pass --profile".into()))?;
    // Where the darkest tenth holds more than a third of an electron a frame, their rates differ
    // enough in a structured scene that the register's tail comes out steep (a mixed Poisson
    // count has more events of two and more electrons than one rate gives: 93.7 DN for 75 on
    // cells drifting at 16 e⁻): the darkest fortieth is fitted as well, and its fit kept where
    // it holds under three quarters of the tenth's electrons (their rates do differ: under a
    // flat background the fortieth is as bright, and only noisier) and enough to measure the
    // gain.
    if movie && differences_fit.params.electrons > DARKER_ABOVE {
        let darker = darkest_share(&ranked, 40, frames.len());
        let (hist, start) = difference_start(&frame_differences(frames, &darker));
        if let Some(f) = em::fit(
            em::Form::Differences,
            &hist,
            start,
            em::Free {
                gain: true,
                spread: false,
            },
        ) {
            if f.params.electrons < 0.75 * differences_fit.params.electrons
                && f.params.electrons * f.values * 2.0 >= 300.0
                && f.se.gain < 0.25 * f.params.gain
            {
                differences_fit = f;
            }
        }
    }
    let df = differences_fit.params;
    let events = df.electrons * differences_fit.values * 2.0;
    let gain_known = events >= 300.0 && differences_fit.se.gain < 0.25 * df.gain;
    // Bias frames (shutter closed, or the EM register off): too few electrons in the dark
    // pixels for the register's tail and no light anywhere. Their bias and read noise are
    // measured, the DN per electron cannot be.
    if !gain_known {
        if let Some((bias, sigma)) = no_light(frames, df.sigma, ceiling) {
            return Err(Error::Fit(format!(
                "these frames hold no measurable light (bias frames, or too dim): bias {bias:.2} DN, read noise {sigma:.3} DN{}; the DN per photoelectron needs electrons: characterize a recording with light (or `emccd calibrate` with flat stacks)",
                if movie { " (the frame differences')" } else { " (neighbouring pixels', the pattern included)" }
            )));
        }
    }
    if !gain_known {
        notes.push(format!(
            "the dark pixels hold about {events:.0} electrons: too few to measure the register's gain from its tail"
        ));
    }

    // 3. The zero-electron peak of their values: the bias.
    let values: Vec<f64> = dark
        .iter()
        .flat_map(|&i| frames.iter().map(move |f| f[i] as f64))
        .collect();
    let (values_hist, v0) = value_start(&values, df.sigma, df.gain, WHOLE_TAIL);
    let values_fit = em::fit(em::Form::Values, &values_hist, v0, em::Free { gain: !gain_known, spread: false })
        .ok_or_else(|| Error::Fit("the dark pixels' values have no zero-electron peak that could be fitted; pass --profile".into()))?;
    let vf = values_fit.params;
    let zeros = (-vf.electrons).exp() * values_fit.values;
    if zeros < 500.0 || !(values_fit.se.bias < vf.sigma) {
        return Err(Error::Fit(format!(
            "no zero-electron peak: the darkest pixels hold about {:.1} electrons a frame, so the bias cannot be told from the signal (a recording with a dark background, or a few frames with the shutter closed, shows it); calibrate the camera (`emccd calibrate`) or pass --profile",
            vf.electrons
        )));
    }

    // The bias across the frame, each tile's peak with the whole frame's width and gain.
    let bias_map = bias_map::fit(frames, &means, width, height, vf.bias, vf.sigma, vf.gain);
    if bias_map.fitted > 1 && bias_map.range_dn > 0.5 * vf.sigma {
        notes.push(format!(
            "the bias drifts across the frame by {:.1} DN (the zero-electron peaks of {} of {} tiles of {} px): the profile's bias map follows it",
            bias_map.range_dn, bias_map.fitted, bias_map.tiles, bias_map.tile
        ));
    }

    let (read_noise_dn, pattern_dn) = if movie {
        let temporal = Estimate::new(df.sigma, differences_fit.se.sigma);
        let peak = Estimate::new(vf.sigma, values_fit.se.sigma);
        // Where the dark pixels hold a few electrons a frame the differences' core is small:
        // the peak's width (an upper bound, holding the pattern) is taken where it is the
        // better measured.
        let better = |e: Estimate| e.se.is_finite() && e.se < 0.1 * e.value;
        if better(temporal) || !better(peak) {
            if !better(temporal) {
                notes.push(format!(
                    "the read noise is poorly measured ({:.2} ± {:.2} DN): the darkest pixels hold {:.1} electrons a frame",
                    temporal.value, temporal.se, df.electrons
                ));
            }
            (
                temporal,
                Some((vf.sigma.powi(2) - df.sigma.powi(2)).max(0.0).sqrt()),
            )
        } else {
            notes.push(format!(
                "the read noise is the zero-electron peak's width ({:.2} ± {:.2} DN, the pixel-to-pixel pattern included): the frame differences' core, {:.2} ± {:.2} DN, is poorly measured where the darkest pixels hold {:.1} electrons a frame",
                peak.value, peak.se, temporal.value, temporal.se, df.electrons
            ));
            (peak, None)
        }
    } else {
        notes.push(
            "from one frame the read noise holds the pixel-to-pixel fixed pattern too".into(),
        );
        (Estimate::new(df.sigma, differences_fit.se.sigma), None)
    };

    // Each pixel's own bias, in a movie whose pixel-to-pixel pattern shows beyond the peaks'
    // errors: laid on the smooth map.
    let mut bias_map = bias_map;
    let pixel_bias = if movie && pattern_dn.is_some() {
        bias_map::refine(frames, &mut bias_map, df.sigma, vf.gain, ceiling)
    } else {
        None
    };
    if let Some(pb) = pixel_bias {
        notes.push(format!(
            "each pixel's own bias (its zero-electron frames' peak) is laid on the smooth map: a pixel-to-pixel pattern of {:.2} DN, the median pixel keeping {:.0} % of its own offset",
            pb.pattern_dn,
            100.0 * pb.kept
        ));
    }
    // 4. The photon-transfer slope, its levels above the pixels' own bias where a movie gives
    // it (a pixel pattern left in the levels flattens the line: camera A's 17 DN took 4 % off
    // at 0.5 e⁻).
    let curve = if movie {
        ptc::curve(frames, width, height, ceiling, &bias_map.values)
    } else {
        None
    };
    // Where the register's tail gives K from dark pixels holding less than an electron a frame,
    // the movie's line is used where it is the more precise of the two (the tail's `2K` carries
    // K's error and 2 % for the register's f², 1.96–2 at the gains a measurable tail takes) and
    // a register can make it with that K: f² = s/K within 1.85–2.5 beyond three errors
    // (f² = 2 − 1/G). A flat or dim scene flattens the line (its levels span little more than
    // the bias map's own errors: 0.4 of the slope at 0.05 e⁻); point sources drifting through
    // the blocks faster than the motion test sees bend it (121–129 DN for 150 at 1 px a frame on
    // emccd-detect camera A, f² 1.6–1.7), and spread it over the frame's strips, which its
    // jackknife error shows. Where the dark pixels hold half an electron or more a frame the
    // tail's K runs high in a structured scene, their rates differing (93.7 for 75 on cells
    // drifting at 16 e⁻, 0.87 e⁻ in the darkest; 86 and 112 for still cells at 4 and 16 e⁻),
    // though not under a flat background (73.2 under particles at 4 e⁻, 3.9 e⁻ in the darkest):
    // the line is then taken where it is within 5 % (or as precise as the tail) and no steeper
    // than a register allows with that K (a high K only widens the bound); blinking and
    // diffusing particles leave it imprecise where the tail is not.
    let tail_se =
        2.0 * df.gain * ((differences_fit.se.gain / df.gain).powi(2) + F2_SPREAD.powi(2)).sqrt();
    let tail_reliable = gain_known && df.electrons < 0.5;
    // f² = s/K within three errors of 1.85 (above) and of 2.5 (below).
    let f2_within = |c: &ptc::Curve| -> (bool, bool) {
        let f2 = c.slope / df.gain;
        let se = f2
            * ((c.slope_se / c.slope).powi(2) + (differences_fit.se.gain / df.gain).powi(2)).sqrt();
        (f2 + 3.0 * se >= 1.85, f2 - 3.0 * se <= 2.5)
    };
    let plausible = |c: &ptc::Curve| -> bool { f2_within(c) == (true, true) };
    let emccd_like = |c: &ptc::Curve| -> bool {
        if tail_reliable {
            c.slope_se <= tail_se && plausible(c)
        } else if gain_known {
            c.slope_se <= tail_se.max(0.05 * c.slope) && f2_within(c).1
        } else {
            true
        }
    };
    let (slope, slope_from) = match &curve {
        Some(c)
            if c.slope > 0.0
                && c.slope_se.is_finite()
                && c.slope_se < 0.2 * c.slope
                && emccd_like(c) =>
        {
            (Estimate::new(c.slope, c.slope_se), SlopeFrom::TemporalPtc)
        }
        Some(c) if gain_known && c.slope > 0.0 && c.slope_se < 0.2 * c.slope => {
            notes.push(if if tail_reliable { plausible(c) } else { f2_within(c).1 } {
                format!(
                    "the movie's mean–variance slope, {:.2} ± {:.2} DN, is less precise than twice the register's gain ({:.2} DN per electron), which is taken",
                    c.slope, c.slope_se, df.gain
                )
            } else {
                format!(
                    "the movie's mean–variance slope, {:.2} ± {:.2} DN, is no EM register's with the gain its tail shows ({:.2} DN per electron: f² = {:.2}; the scene moves or is flat); the slope is twice the register's gain",
                    c.slope, c.slope_se, df.gain, c.slope / df.gain
                )
            });
            notes.push("the photon-transfer slope is 2K: the excess noise of a many-stage register (f² = 2) is assumed, not measured".into());
            (
                Estimate::new(2.0 * df.gain, tail_se),
                SlopeFrom::EmTail,
            )
        }
        _ if gain_known => {
            if movie {
                notes.push("the movie's mean–variance line could not be fitted (too little still scene): the slope is twice the register's gain".into());
            }
            notes.push("the photon-transfer slope is 2K: the excess noise of a many-stage register (f² = 2) is assumed, not measured".into());
            (
                Estimate::new(2.0 * df.gain, tail_se),
                SlopeFrom::EmTail,
            )
        }
        _ => {
            return Err(Error::Fit(format!(
                "the DN per photoelectron could not be measured: the dark pixels hold too few electrons for the register's tail{}; a longer movie of a still scene, or --profile",
                if movie { " and the movie too little still scene for its mean–variance line" } else { ", and one frame has no mean–variance line" }
            )))
        }
    };
    // Smear: a share of each column's mean in all its pixels, measured above each pixel's bias, its
    // noise from the slope.
    let smear = smear::estimate(
        frames,
        &means,
        &bias_map.values,
        width,
        height,
        (df.sigma, slope.value),
    );
    match smear {
        Some(sm) if sm.significant => notes.push(format!(
            "frame-transfer smear: each pixel holds {:.2} ± {:.2} % of its column's mean (from {} columns), removed as the profile's blooming",
            100.0 * sm.factor.value,
            100.0 * sm.factor.se,
            sm.columns
        )),
        Some(sm) if sm.factor.se.is_finite() && sm.factor.se < 0.01 => {}
        Some(sm) => notes.push(format!(
            "frame-transfer smear could not be measured{}: the scene has no compact bright objects whose columns stand out from their neighbours'; none is removed",
            if sm.factor.se.is_finite() {
                format!(" ({:.1} ± {:.1} %)", 100.0 * sm.factor.value, 100.0 * sm.factor.se)
            } else {
                String::new()
            }
        )),
        None => {}
    }
    let gain_dn = gain_known.then(|| Estimate::new(df.gain, differences_fit.se.gain));
    let excess_f2 = gain_dn
        .filter(|_| slope_from == SlopeFrom::TemporalPtc)
        .map(|g| {
            let f2 = slope.value / g.value;
            Estimate::new(
                f2,
                f2 * ((slope.se / slope.value).powi(2) + (g.se / g.value).powi(2)).sqrt(),
            )
        });
    let map_mean = bias_map.values.iter().map(|&v| v as f64).sum::<f64>() / n as f64;

    // The light level, in the profile's photoelectrons (s/2 DN each).
    let (mean, _) = mean_below(frames, ceiling);
    let mean_electrons = (mean - map_mean) / (slope.value / 2.0);
    if saturated > 0 {
        notes.push(format!(
            "{saturated} values at the recording's maximum ({ceiling} DN) were left out as saturated"
        ));
    }
    Ok(Characterization {
        width,
        height,
        frames: frames.len(),
        bias_dn: Estimate::new(vf.bias, values_fit.se.bias),
        bias_map,
        read_noise_dn,
        // Where the read noise is the frame differences' core (the pattern then measurable),
        // the pixels' own peaks measure the pattern better than the peak's width.
        pattern_dn: pattern_dn.map(|p| pixel_bias.map_or(p, |b| b.pattern_dn)),
        gain_dn,
        slope_dn: slope,
        slope_from,
        excess_f2,
        dark_electrons: Estimate::new(df.electrons, differences_fit.se.electrons),
        mean_electrons,
        saturation_dn: saturation,
        smear,
        values: values_hist,
        values_fit,
        differences,
        differences_fit,
        curve,
        notes,
    })
}

/// The recording's maximum, where enough values sit on it to be a ceiling (at least 3, and one
/// in 10⁵): an ADC's or a full well's, not a bright pixel's; with the number of values on it.
fn saturation(frames: &[Vec<f32>]) -> Option<(f64, usize)> {
    let max = frames
        .par_iter()
        .map(|f| f.iter().copied().fold(f32::MIN, f32::max))
        .reduce(|| f32::MIN, f32::max);
    let at = frames
        .par_iter()
        .map(|f| f.iter().filter(|&&v| v == max).count())
        .sum::<usize>();
    let all = frames.len() * frames[0].len();
    (at >= 3 && at * 100_000 >= all).then_some((max as f64, at))
}

/// Each pixel's mean over the frames (NaN where one of its values is at or above `ceiling`,
/// saturated): what the darkest pixels are chosen by, through their neighbours.
fn pixel_means(frames: &[Vec<f32>], ceiling: f64) -> Vec<f64> {
    let nf = frames.len() as f64;
    (0..frames[0].len())
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
        .collect()
}

/// The mean of all values below `ceiling`, and their number: per frame in parallel, then summed
/// in order, the same for any thread count.
fn mean_below(frames: &[Vec<f32>], ceiling: f64) -> (f64, usize) {
    let per_frame: Vec<(f64, usize)> = frames
        .par_iter()
        .map(|f| {
            f.iter()
                .filter(|&&v| (v as f64) < ceiling)
                .fold((0.0, 0usize), |(s, c), &v| (s + v as f64, c + 1))
        })
        .collect();
    let (sum, count) = per_frame
        .iter()
        .fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    (sum / count.max(1) as f64, count)
}

/// Where `frames` hold no light at all, their bias (the median value) and read noise (the
/// standard deviation of frame differences over √2, or of neighbouring pixels' in one frame):
/// the whole recording's mean within half the dark pixels' read noise `sigma` of its median, as
/// a Gaussian's is. None where anything is lit.
fn no_light(frames: &[Vec<f32>], sigma: f64, ceiling: f64) -> Option<(f64, f64)> {
    let (mean, count) = mean_below(frames, ceiling);
    let median = emccd_profile::median(frames.iter().flatten().copied())?;
    if (mean - median).abs() >= 0.5 * sigma {
        return None;
    }
    // And symmetric, as read noise is: electrons through the register skew the values
    // (2.1/√λ at λ electrons a pixel, 0.42 for a flat at 25), a bias frame's are not (−0.07 on
    // the real iXon 897's).
    let (m2, m3) = frames
        .iter()
        .flatten()
        .filter(|&&v| (v as f64) < ceiling)
        .fold((0.0, 0.0), |(a, b), &v| {
            let d = v as f64 - mean;
            (a + d * d, b + d * d * d)
        });
    let skew = (m3 / count.max(1) as f64) / (m2 / count.max(1) as f64).powf(1.5);
    if !(skew.abs() < 0.2) {
        return None;
    }
    let pairs: Vec<(f32, f32)> = if frames.len() >= 2 {
        frames
            .chunks_exact(2)
            .flat_map(|p| p[0].iter().copied().zip(p[1].iter().copied()))
            .collect()
    } else {
        frames[0].chunks_exact(2).map(|p| (p[0], p[1])).collect()
    };
    let d: Vec<f64> = pairs
        .into_iter()
        .filter(|&(a, b)| (a as f64) < ceiling && (b as f64) < ceiling)
        .map(|(a, b)| (a - b) as f64)
        .collect();
    let m = d.iter().sum::<f64>() / d.len().max(1) as f64;
    let var = d.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (d.len().max(2) - 1) as f64;
    Some((median, (var / 2.0).sqrt()))
}

/// The differences of non-overlapping pairs of frames (1 − 0, 3 − 2, …) at each of `pixels`.
fn frame_differences(frames: &[Vec<f32>], pixels: &[usize]) -> Vec<f64> {
    pixels
        .iter()
        .flat_map(|&i| {
            frames
                .chunks_exact(2)
                .map(move |p| p[1][i] as f64 - p[0][i] as f64)
        })
        .collect()
}

/// The pixels ranked from the darkest by their neighbours' mean over all frames (their eight
/// neighbours'), and the horizontal pairs `(i, i + 1)` ranked by their ten neighbours' mean:
/// each with that mean, darkest first. Pixels with a saturated value are left out.
fn darkest(mean: &[f64], width: usize, height: usize) -> (Vec<(f64, usize)>, Vec<(f64, usize)>) {
    let at = |x: usize, y: usize| mean[y * width + x];
    let mut centre = Vec::new();
    let mut pairs = Vec::new();
    for y in 1..height - 1 {
        for x in 1..width - 1 {
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
                s += at(x + dx - 1, y + dy - 1);
            }
            if at(x, y).is_finite() && s.is_finite() {
                centre.push((s / 8.0, y * width + x));
            }
            // The pair (x, x + 1) on even columns, judged by the ring of ten around it.
            if x % 2 == 1 && x + 2 < width {
                let mut r = 0.0;
                for dx in 0..4 {
                    r += at(x - 1 + dx, y - 1) + at(x - 1 + dx, y + 1);
                }
                r += at(x - 1, y) + at(x + 2, y);
                if at(x, y).is_finite() && at(x + 1, y).is_finite() && r.is_finite() {
                    pairs.push((r / 10.0, y * width + x));
                }
            }
        }
    }
    for v in [&mut centre, &mut pairs] {
        v.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    }
    (centre, pairs)
}

/// The darkest `1/one_in` of a [`darkest`] ranking (more where that holds too few values, with
/// `per` values each), in pixel order.
fn darkest_share(ranked: &[(f64, usize)], one_in: usize, per: usize) -> Vec<usize> {
    let want = (ranked.len() / one_in)
        .max(MIN_DARK_VALUES.div_ceil(per) * 2)
        .min(ranked.len() / 2)
        .max(1);
    let mut keep: Vec<usize> = ranked.iter().take(want).map(|p| p.1).collect();
    keep.sort_unstable();
    keep
}

/// The widest histogram window a fit is made on, DN: the cost of every likelihood evaluation
/// grows with it.
const MAX_WINDOW: f64 = 16_384.0;

/// The differences' histogram (to where the register's tail has fallen far below one count) and
/// a start for their fit: the core's scale from the median |d|, the tail's from the mean
/// excess beyond five core widths.
fn difference_start(d: &[f64]) -> (em::Histogram, em::Params) {
    let abs: Vec<f64> = d.iter().map(|v| v.abs()).collect();
    let med = emccd_profile::median(abs.iter().copied()).unwrap_or(1.0);
    let sigma = (1.4826 * med / std::f64::consts::SQRT_2).max(0.5);
    let t = 5.0 * sigma * std::f64::consts::SQRT_2;
    let beyond: Vec<f64> = abs.iter().filter(|&&a| a > t).map(|a| a - t).collect();
    let gain = if beyond.len() >= 20 {
        (beyond.iter().sum::<f64>() / beyond.len() as f64).max(sigma)
    } else {
        3.0 * sigma
    };
    let share = beyond.len() as f64 / d.len() as f64;
    let electrons = (share / (2.0 * (-t / gain).exp())).clamp(1e-4, 2.0);
    let reach = (emccd_profile::percentile(abs.iter().copied(), 0.9999).unwrap_or(t))
        .max(12.0 * sigma)
        .min(12.0 * sigma + 40.0 * gain)
        .min(MAX_WINDOW)
        .ceil() as i64;
    (
        em::Histogram::of(d.iter().copied(), -reach, reach),
        em::Params {
            bias: 0.0,
            sigma,
            electrons,
            spread: 0.0,
            gain,
            outliers: 1e-4,
        },
    )
}

/// The register's tail in the whole frame's values' window, in its scales: where the dark
/// pixels' electrons are (their number is fitted from it).
const WHOLE_TAIL: f64 = 30.0;
/// The same for a tile's peak, its gain known: the tail's start separates the peak from the
/// electrons, and a short window makes each of the many tiles' fits cheap (the model is
/// normalized to the window).
pub(crate) const TILE_TAIL: f64 = 4.0;

/// The values' histogram and a start for their fit: the peak from the median and the lower
/// quartile (below the peak only read noise reaches), the gain from the differences.
fn value_start(v: &[f64], sigma_d: f64, gain: f64, tail: f64) -> (em::Histogram, em::Params) {
    let med = emccd_profile::median(v.iter().copied()).unwrap_or(0.0);
    let q25 = emccd_profile::percentile(v.iter().copied(), 0.25).unwrap_or(med - sigma_d);
    let q10 = emccd_profile::percentile(v.iter().copied(), 0.10).unwrap_or(med - sigma_d);
    // The lower half of a normal: the 10th percentile is 1.28 σ below its centre.
    let sigma = ((med - q25) / 0.6745).max(sigma_d).max(0.5);
    let bias = (q10 + 1.2816 * sigma).min(med);
    let lo = (bias - 12.0 * sigma).floor() as i64;
    // The register's tail to `tail` scales, the scale taken at most 40 read-noise σ (EM gain
    // 1000 behind a quiet amplifier): a wider window is data that is no EMCCD's.
    let hi = (bias + 12.0 * sigma + tail * gain.min(40.0 * sigma))
        .min(bias + MAX_WINDOW)
        .ceil() as i64;
    let above = v.iter().filter(|&&x| x > bias + 4.0 * sigma).count() as f64 / v.len() as f64;
    (
        em::Histogram::of(v.iter().copied(), lo, hi),
        em::Params {
            bias,
            sigma,
            electrons: above.clamp(1e-4, 3.0),
            spread: 0.0,
            gain,
            outliers: 1e-4,
        },
    )
}

/// The regime a light level is in.
pub fn regime(mean_electrons: f64) -> &'static str {
    if mean_electrons < 0.2 {
        "photon counting"
    } else if mean_electrons <= 30.0 {
        "low light"
    } else {
        "bright (above the EMCCD regime)"
    }
}

impl Characterization {
    /// Writes `profile` (made by [`Characterization::profile`]) into `out` and, where asked, the
    /// report into `report`; a failed run leaves nothing it created. Without `replace`, a
    /// profile found in `out` as it is placed is an error.
    pub fn save(
        &self,
        profile: &CameraProfile,
        source: &str,
        out: &std::path::Path,
        report: Option<&std::path::Path>,
        replace: bool,
    ) -> Result<()> {
        crate::report::save_with_report(profile, out, report, replace, |dir| {
            report::write(self, source, dir)
        })
    }

    /// DN per photoelectron as the profile converts (`s/2`).
    pub fn dn_per_electron(&self) -> f64 {
        self.slope_dn.value / 2.0
    }

    /// One line for a person: the numbers the denoiser will use, and the light level.
    pub fn summary_line(&self) -> String {
        let gain = match self.gain_dn {
            Some(g) => format!(", register {:.1} ± {:.1} DN/e⁻", g.value, g.se),
            None => String::new(),
        };
        format!(
            "{:.2} DN per e⁻ (slope {:.2} ± {:.2} DN from {}{gain}), bias {:.1} ± {:.1} DN, read noise {:.2} ± {:.2} DN; {:.2} e⁻ per pixel per frame: {}; the darkest pixels {:.3} e⁻ per frame (light and spurious charge)",
            self.dn_per_electron(),
            self.slope_dn.value,
            self.slope_dn.se,
            match self.slope_from {
                SlopeFrom::TemporalPtc => format!("{} frames' mean–variance", self.frames),
                SlopeFrom::EmTail => "the EM tail".to_string(),
            },
            self.bias_dn.value,
            self.bias_dn.se,
            self.read_noise_dn.value,
            self.read_noise_dn.se,
            self.mean_electrons,
            regime(self.mean_electrons),
            self.dark_electrons.value
        )
    }

    /// The camera profile these numbers make: a bias map, one read-noise map at `exposure_s`,
    /// the slope, the smear as blooming at `exposure_s` where it was measured; `em_gain` from the file's header where it records
    /// one (0: unknown). `source` names the recording(s) in the provenance.
    pub fn profile(
        &self,
        source: &str,
        exposure_s: f64,
        em_gain: Option<f64>,
        adc_max_dn: f64,
    ) -> Result<CameraProfile> {
        let n = self.width * self.height;
        let g = em_gain.unwrap_or(0.0);
        let mut notes = format!(
            "characterized from the recording {source} ({} frames): {}",
            self.frames,
            self.summary_line()
        );
        for note in &self.notes {
            notes.push_str("; ");
            notes.push_str(note);
        }
        let mut p = CameraProfile {
            camera: format!("characterized from {source}"),
            em_gain: g,
            width: self.width,
            height: self.height,
            ptc_slope_dn: Some(self.slope_dn.value),
            f_range: [1.3, std::f64::consts::SQRT_2],
            quantization_dn: 1.0,
            adc_max_dn,
            fpn: FpnFit {
                form: FpnForm::Constant,
                base_exposure_s: exposure_s,
                shared_theta: [0.0; 4],
            },
            blooming: None,
            exposures_s: vec![exposure_s],
            eld: None,
            // The dark pixels' electrons hold their light too, so the spurious charge is not
            // known: counting asks for it (--cic) rather than take an upper bound for it.
            pgn: None,
            provenance: Provenance {
                source: RECORDING_SOURCE.into(),
                notes,
            },
            maps: ProfileMaps {
                fpn_base: self.bias_map.values.clone(),
                fpn_theta: Vec::new(),
                read_noise: vec![vec![self.read_noise_dn.value as f32; n]],
            },
        };
        // Measured smear is the profile's blooming at this one exposure.
        if let Some(s) = self.smear.filter(|s| s.significant) {
            smear::into_profile(&mut p, s.factor.value, exposure_s);
        }
        p.validate()
            .map_err(|e| Error::Fit(format!("the characterized profile is inconsistent: {e}")))?;
        Ok(p)
    }
}

/// The spurious electrons per frame a data sheet's `cic` (e⁻ per frame) and `dark` (e⁻ per
/// second) make at `exposure_s`; an error where they are out of range, or where the dark
/// current counts and the exposure is not known.
pub fn spurious_electrons(cic: f64, dark: f64, exposure_s: Option<f64>) -> Result<f64> {
    emccd_profile::check_spurious(cic, dark).map_err(|e| Error::Fit(e.to_string()))?;
    match exposure_s {
        Some(t) => Ok(cic + dark * t),
        None if dark == 0.0 => Ok(cic),
        None => Err(Error::Fit(
            "the exposure is not known (no header or argument gives it), and so is not the dark current's share: give the exposure, or the dark current as 0".into(),
        )),
    }
}

/// Raises the bias of `profile` (characterized from a recording) by the mean signal of the
/// spurious charge a data sheet gives (`cic` e⁻ per frame, `dark` e⁻ per second): a recording
/// cannot tell it from light, and a calibrated profile's bias frames hold it, so that the
/// output then holds light alone. `exposure_s`: the recording's, where known (the dark current's
/// share needs it). Returns what was removed, in words.
pub fn remove_spurious(
    profile: &mut CameraProfile,
    cic: f64,
    dark: f64,
    exposure_s: Option<f64>,
) -> Result<String> {
    if !profile.from_recording() || profile.exposures_s.len() != 1 {
        return Err(Error::Fit(
            "the spurious charge is removed from a camera characterized from a recording only: a calibrated profile's bias holds its own".into(),
        ));
    }
    let electrons = spurious_electrons(cic, dark, exposure_s)?;
    let exposure = exposure_s.unwrap_or(0.0);
    let dn = electrons
        * profile
            .dn_per_electron()
            .map_err(|e| Error::Fit(e.to_string()))?;
    for b in &mut profile.maps.fpn_base {
        *b += dn as f32;
    }
    Ok(format!(
        "spurious charge removed: {electrons:.4} e⁻ per frame (CIC {cic}, dark current {dark} e⁻/s at {exposure} s), {dn:.2} DN"
    ))
}

/// The frames of one or more recordings of one camera, read for characterization, with what
/// their headers say.
pub struct Frames {
    /// The frames (raw DN), at most [`MAX_VALUES`] values, shared evenly among the files.
    pub frames: Vec<Vec<f32>>,
    /// Frame width, px.
    pub width: usize,
    /// Frame height, px.
    pub height: usize,
    /// The files' exposure, where their headers agree on one.
    pub exposure_s: Option<f64>,
    /// The files' EM gain setting, where their headers agree on one.
    pub em_gain: Option<f64>,
    /// The largest value the files' sample type holds (the ADC's range for integer samples).
    pub adc_max_dn: f64,
    /// The files, for messages and provenance.
    pub source: String,
}

/// Reads the first frames of each of `paths` (one camera: the same frame size), at most
/// [`MAX_VALUES`] values in all.
pub fn read(paths: &[&std::path::Path]) -> Result<Frames> {
    if paths.is_empty() {
        return Err(Error::Fit("no recording to characterize".into()));
    }
    let mut readers = Vec::with_capacity(paths.len());
    for &p in paths {
        let r = emccd_io::open(p).map_err(|e| Error::io(p, e))?;
        readers.push((p, r));
    }
    let first = readers[0].1.info().clone();
    let (width, height) = (first.width, first.height);
    for (p, r) in &readers[1..] {
        let i = r.info();
        if (i.width, i.height) != (width, height) {
            return Err(Error::input(p, format!(
                "frames are {}×{}, those of {} are {width}×{height}: one characterization is for one camera and readout",
                i.width, i.height, paths[0].display()
            )));
        }
    }
    // What the headers that record it say (they agree: checked above).
    let agree = |f: &dyn Fn(&emccd_io::StackInfo) -> Option<f64>| -> Option<f64> {
        readers.iter().find_map(|(_, r)| f(r.info()))
    };
    // One characterization is one camera setting: headers that record different exposures or
    // EM gains are different dark currents and gains, pooled into nonsense.
    for (what, get) in [
        (
            "exposure",
            (|i: &emccd_io::StackInfo| i.metadata.exposure_s) as fn(&_) -> _,
        ),
        ("EM gain", |i: &emccd_io::StackInfo| i.metadata.em_gain),
    ] {
        let recorded: Vec<(&std::path::Path, f64)> = readers
            .iter()
            .filter_map(|(p, r)| get(r.info()).map(|v| (*p, v)))
            .collect();
        let Some(&(p, a)) = recorded.first() else {
            continue;
        };
        if let Some(&(q, b)) = recorded.iter().find(|y| (y.1 - a).abs() > 1e-9 * a.abs()) {
            return Err(Error::input(q, format!(
                "its header records {what} {b}, that of {} {a}: one characterization is for one camera setting; characterize (or denoise) the recordings of each setting apart",
                p.display()
            )));
        }
    }
    let exposure_s = agree(&|i| i.metadata.exposure_s);
    let em_gain = agree(&|i| i.metadata.em_gain);
    let adc_max_dn = readers
        .iter()
        .map(|(_, r)| match r.info().pixel_type {
            emccd_io::PixelType::U8 => 255.0,
            emccd_io::PixelType::U16 | emccd_io::PixelType::I16 => 65535.0,
            _ => 2f64.powi(32),
        })
        .fold(0.0, f64::max);
    let total = frames_to_hold(
        readers.iter().map(|(_, r)| r.info().frames).sum(),
        width,
        height,
    );
    let share = total.div_ceil(readers.len()).max(1);
    let mut frames = Vec::new();
    for (p, r) in &mut readers {
        for _ in 0..share.min(r.info().frames) {
            let mut buf = vec![0f32; width * height];
            if !r.read_frame(&mut buf).map_err(|e| Error::io(p, e))? {
                break;
            }
            frames.push(buf);
        }
    }
    let source = paths
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ");
    Ok(Frames {
        frames,
        width,
        height,
        exposure_s,
        em_gain,
        adc_max_dn,
        source,
    })
}

/// Exposure a profile made from a recording whose header records none is given: the fixed
/// pattern it holds is the recording's own, flat in exposure, so the number only labels it.
pub const NOMINAL_EXPOSURE_S: f64 = 1.0;

impl Frames {
    /// Frames already in memory (`values`: whole frames of `width × height`, raw DN), the
    /// first [`frames_to_hold`] of them; `source` names them in messages and the provenance.
    pub fn in_memory(
        values: &[f32],
        width: usize,
        height: usize,
        exposure_s: Option<f64>,
        source: &str,
    ) -> Frames {
        let n = (width * height).max(1);
        let frames: Vec<Vec<f32>> = values
            .chunks_exact(n)
            .take(frames_to_hold(values.len() / n, width, height))
            .map(<[f32]>::to_vec)
            .collect();
        let top = frames.iter().flatten().fold(0f32, |m, &v| m.max(v));
        Frames {
            frames,
            width,
            height,
            exposure_s,
            em_gain: None,
            adc_max_dn: if top <= 65535.0 {
                65535.0
            } else {
                2f64.powi(32)
            },
            source: source.to_string(),
        }
    }

    /// What disagrees between `profile` and these frames ([`disagreements`], at the frames'
    /// exposure, else the exposure of a profile made from a recording), with the
    /// characterization it was judged by, or `Err` with why they could not be compared: the
    /// frames do not characterize the camera (bright everywhere, too few), they are not the
    /// profile's size, or no exposure is known.
    pub fn misfit(
        &self,
        profile: &CameraProfile,
    ) -> std::result::Result<(Vec<String>, Characterization), String> {
        if (self.width, self.height) != (profile.width, profile.height) {
            return Err(format!(
                "the frames are {}×{}, the profile's {}×{}",
                self.width, self.height, profile.width, profile.height
            ));
        }
        let exposure = self
            .checked_exposure(profile)
            .ok_or("no exposure is known")?;
        let c = characterize(&self.frames, self.width, self.height).map_err(|e| {
            let why = e.to_string();
            // The advice to pass a profile is no advice here.
            why.split("; calibrate").next().unwrap_or(&why).to_string()
        })?;
        let off = disagreements(&c, profile, exposure, self.em_gain);
        Ok((off, c))
    }

    /// The exposure these frames are compared with `profile` at: theirs, else that of a profile
    /// made from a recording.
    pub fn checked_exposure(&self, profile: &CameraProfile) -> Option<f64> {
        self.exposure_s.or_else(|| {
            (profile.from_recording() && profile.exposures_s.len() == 1)
                .then(|| profile.exposures_s[0])
        })
    }

    /// Characterizes the camera from these frames ([`characterize`]), each error naming the
    /// files.
    pub fn characterize(&self) -> Result<Characterization> {
        characterize(&self.frames, self.width, self.height)
            .map_err(|e| Error::Fit(format!("{}: {e}", self.source)))
    }

    /// The profile of `c` (characterized from these frames) at their exposure (or
    /// [`NOMINAL_EXPOSURE_S`]) and EM gain.
    pub fn profile(&self, c: &Characterization) -> Result<CameraProfile> {
        c.profile(
            &self.source,
            self.exposure_s.unwrap_or(NOMINAL_EXPOSURE_S),
            self.em_gain,
            self.adc_max_dn,
        )
    }
}

pub use check::{disagreements, misfit_message};

/// Where `profile` measured no blooming (no blooming stacks) and `c`, characterized from a
/// recording at `exposure_s`, shows frame-transfer smear, puts it into the profile
/// ([`smear::into_profile`]) and says so; `None` where nothing was added.
pub fn add_measured_smear(
    profile: &mut CameraProfile,
    c: &Characterization,
    exposure_s: f64,
) -> Option<String> {
    let s = c.smear.filter(|s| s.significant)?;
    if profile.blooming.is_some() {
        return None;
    }
    smear::into_profile(profile, s.factor.value, exposure_s);
    Some(format!(
        "frame-transfer smear measured on the recording: each pixel holds {:.2} ± {:.2} % of its column's mean, removed (the profile has no blooming calibration)",
        100.0 * s.factor.value,
        100.0 * s.factor.se
    ))
}
pub use emccd_profile::RECORDING_SOURCE;

#[cfg(test)]
mod tests;
