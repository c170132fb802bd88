//! The calibration run: checks every input first, then bias → FPN fit → blooming → flats →
//! gain series, and assembles the profile.

use std::path::{Path, PathBuf};

use emccd_profile::{CameraProfile, FpnFit, FpnForm, PgnParams, ProfileMaps, Provenance};
use serde::Serialize;

use crate::blooming::{self, BloomLevel, BloomingResult};
use crate::fpn::{self, FpnResult};
use crate::gain_series::{self, GainSeriesResult, SettingData};
use crate::manifest::{Entry, Manifest};
use crate::normality::{normal_plot, NormalPlot};
use crate::ptc::{self, FlatLevel, LevelStatus, PtcResult};
use rayon::prelude::*;

use crate::spurious::SpuriousFit;
use crate::stats::{accumulate, Progress};
use crate::{Error, Result};

/// Tunables, with the paper's values as defaults (also `emccd calibrate`'s flags).
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct Options {
    /// Side of the central crop for the median–variance regression, px (the paper's 256).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Options::default().crop))]
    pub crop: usize,
    /// Side of the sliding window of the blooming search, px (the paper's 32).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Options::default().window))]
    pub window: usize,
    /// Most pixels (a central block) fitted in a gain series.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Options::default().gain_pixels))]
    pub gain_pixels: usize,
}

impl Options {
    /// The options with each raised to its smallest meaningful value (a crop and a window of
    /// 2 px, one gain-series pixel): what [`calibrate`] runs with.
    pub fn floored(&self) -> Options {
        Options {
            crop: self.crop.max(2),
            window: self.window.max(2),
            gain_pixels: self.gain_pixels.max(1),
        }
    }
}

impl Default for Options {
    fn default() -> Options {
        Options {
            crop: 256,
            window: 32,
            gain_pixels: 16,
        }
    }
}

/// The bias statistics at one exposure.
#[derive(Clone, Debug, Serialize)]
pub struct BiasLevel {
    /// Stack file.
    pub file: PathBuf,
    /// Exposure, s.
    pub exposure_s: f64,
    /// Frames.
    pub frames: usize,
    /// Median of the FPN map, DN.
    pub median_dn: f64,
    /// Median of the read-noise std map, DN.
    pub read_noise_median_dn: f64,
    /// √(mean per-pixel variance), DN: unbiased in σ² for any frame count, where the median of
    /// per-pixel stds runs low for few frames (×0.67 for two).
    pub read_noise_rms_dn: f64,
    /// Pixel-wise mean (FPN_t), DN.
    #[serde(skip)]
    pub mean: Vec<f32>,
    /// Pixel-wise std after removing the mean (read noise), DN.
    #[serde(skip)]
    pub std: Vec<f32>,
    /// Differences of paired frames (the spurious-charge fit's data).
    #[serde(skip)]
    pub differences: Option<crate::spurious::Differences>,
}

/// Everything one calibration run measured.
#[derive(Clone, Debug, Serialize)]
pub struct Calibration {
    /// Camera name.
    pub camera: String,
    /// EM gain of the bias, flat and blooming stacks.
    pub em_gain: f64,
    /// Manifest path.
    pub manifest: PathBuf,
    /// Frame width (0 when only a gain series was given).
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// ADC maximum used for saturation checks, DN.
    pub adc_max_dn: f64,
    /// Bias statistics, ascending exposure.
    pub bias: Vec<BiasLevel>,
    /// FPN exposure fit.
    pub fpn: Option<FpnResult>,
    /// Normal probability plots of sample pixels.
    pub normality: Vec<NormalPlot>,
    /// Median–variance regression.
    pub ptc: Option<PtcResult>,
    /// Blooming factors and fit.
    pub blooming: Option<BloomingResult>,
    /// Gain-series fit.
    pub gain_series: Option<GainSeriesResult>,
    /// Clock-induced charge, dark current and the read noise beneath them, from the bias
    /// stacks' paired-frame differences (needs the photon-transfer slope).
    pub spurious: Option<SpuriousFit>,
    /// What could not be calibrated and why.
    pub missing: Vec<String>,
    /// Things a person should know (truncated files, header/manifest disagreements).
    pub warnings: Vec<String>,
}

struct Checked {
    file: PathBuf,
    exposure_s: f64,
}

/// Frames the run will read (for a progress bar), from the file headers alone.
pub fn total_frames(m: &Manifest) -> u64 {
    let count = |p: &Path| emccd_io::open(p).map_or(0, |r| r.info().frames as u64);
    let mut t: u64 = m
        .bias
        .iter()
        .chain(&m.flat)
        .chain(&m.blooming)
        .map(|e| count(&e.file))
        .sum();
    if let Some(gs) = &m.gain_series {
        for s in &gs.settings {
            t += count(&s.file) + s.no_signal.as_deref().map_or(0, count);
        }
    }
    t
}

fn adc_max_for(t: emccd_io::PixelType) -> f64 {
    use emccd_io::PixelType::*;
    match t {
        U8 => 255.0,
        I16 => 32767.0,
        U32 | I32 => 4294967295.0,
        _ => 65535.0,
    }
}

/// Checks one group of entries: readable, ≥ 2 frames, one frame size, a known exposure.
fn check(
    entries: &[Entry],
    what: &str,
    dims: &mut Option<(usize, usize)>,
    adc: &mut Option<f64>,
    warnings: &mut Vec<String>,
) -> Result<Vec<Checked>> {
    let mut out = Vec::new();
    for e in entries {
        let r = emccd_io::open(&e.file).map_err(|err| Error::io(&e.file, err))?;
        let info = r.info();
        match dims {
            Some((w, h)) if (*w, *h) != (info.width, info.height) => {
                return Err(Error::input(
                    &e.file,
                    format!(
                        "frames are {}×{}, but the other stacks are {w}×{h}",
                        info.width, info.height
                    ),
                ))
            }
            None => *dims = Some((info.width, info.height)),
            _ => {}
        }
        if info.frames < 2 {
            return Err(Error::input(
                &e.file,
                format!(
                    "holds {} frame(s); {what} statistics need at least 2",
                    info.frames
                ),
            ));
        }
        for w in &info.metadata.warnings {
            warnings.push(format!("{}: {w}", e.file.display()));
        }
        let exposure_s = match (e.exposure_s, info.metadata.exposure_s) {
            (Some(m), Some(h)) => {
                if (m - h).abs() > 0.01 * m {
                    warnings.push(format!(
                        "{}: manifest says {m} s, the file header {h} s; using the manifest",
                        e.file.display()
                    ));
                }
                m
            }
            (Some(m), None) => m,
            (None, Some(h)) if h > 0.0 => h,
            _ => {
                return Err(Error::input(
                    &e.file,
                    "no exposure_s in the manifest and none in the file header",
                ))
            }
        };
        adc.get_or_insert(adc_max_for(info.pixel_type));
        out.push(Checked {
            file: e.file.clone(),
            exposure_s,
        });
    }
    Ok(out)
}

/// The exposure-curve fit of the bias means as they stand (needs ≥ 4 exposures).
fn fit_fpn(bias: &[BiasLevel], width: usize) -> Result<Option<FpnResult>> {
    if bias.len() < 4 {
        return Ok(None);
    }
    let e: Vec<f64> = bias.iter().map(|b| b.exposure_s).collect();
    let means: Vec<Vec<f32>> = bias.iter().map(|b| b.mean.clone()).collect();
    let stds: Vec<Vec<f32>> = bias.iter().map(|b| b.std.clone()).collect();
    let frames: Vec<usize> = bias.iter().map(|b| b.frames).collect();
    Ok(Some(fpn::fit(&e, &means, &stds, &frames, width)?))
}

/// The bias pattern at exposure `t`: the bias mean measured there, else the fit's prediction,
/// else (with a warning) the nearest exposure's mean.
fn pattern_at(
    bias: &[BiasLevel],
    fit: Option<&FpnResult>,
    t: f64,
    warnings: &mut Vec<String>,
) -> Option<Vec<f32>> {
    if let Some(b) = bias.iter().find(|b| (b.exposure_s - t).abs() <= 5e-3 * t) {
        return Some(b.mean.clone());
    }
    if let Some(f) = fit {
        return Some(fpn::predict(f, &bias[0].mean, f.chosen, t));
    }
    let b = bias.iter().min_by(|a, b| {
        (a.exposure_s.ln() - t.ln())
            .abs()
            .total_cmp(&(b.exposure_s.ln() - t.ln()).abs())
    })?;
    warnings.push(format!(
        "FPN at {t} s taken from the bias stack at {} s (no exposure fit)",
        b.exposure_s
    ));
    Some(b.mean.clone())
}

/// Sets every bias level's FPN map to `B⁻¹[raw mean]` under `law`.
fn unbloom(
    bias: &mut [BiasLevel],
    raw: &[Vec<f32>],
    law: &emccd_profile::BloomingFit,
    width: usize,
) {
    for (b, r) in bias.iter_mut().zip(raw) {
        b.mean.clone_from(r);
        emccd_profile::remove_blooming(&mut b.mean, width, law.factor(b.exposure_s));
        b.median_dn = emccd_profile::median(b.mean.iter().copied()).unwrap_or(0.0);
    }
}

/// Reads a single-image map (the first frame of a file).
fn read_map(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let (info, buf) = emccd_io::read_first(path).map_err(|e| Error::io(path, e))?;
    Ok((info.width, info.height, buf))
}

/// Runs the whole calibration with `opts` ([`Options::floored`]). Nothing is written; see
/// [`Calibration::profile`] and [`crate::report::write`].
pub fn calibrate(m: &Manifest, opts: &Options, progress: &dyn Progress) -> Result<Calibration> {
    let opts = &opts.floored();
    let mut warnings = Vec::new();
    let mut missing = Vec::new();
    let mut dims = None;
    let mut adc = m.adc_max_dn;
    let mut bias_in = check(&m.bias, "bias", &mut dims, &mut adc, &mut warnings)?;
    let bloom_in = check(&m.blooming, "blooming", &mut dims, &mut adc, &mut warnings)?;
    let flat_in = check(&m.flat, "flat-field", &mut dims, &mut adc, &mut warnings)?;
    let adc_max = adc.unwrap_or(65535.0);
    let (width, height) = dims.unwrap_or((0, 0));
    let stages = Stages {
        dims,
        width,
        height,
        opts,
        progress,
    };
    bias_in.sort_by(|a, b| a.exposure_s.total_cmp(&b.exposure_s));
    for w in bias_in.windows(2) {
        if (w[1].exposure_s - w[0].exposure_s).abs() <= 1e-3 * w[0].exposure_s {
            return Err(Error::input(
                &w[1].file,
                format!(
                    "a second bias stack at {} s (also {})",
                    w[0].exposure_s,
                    w[0].file.display()
                ),
            ));
        }
    }

    let BiasStage {
        levels: mut bias,
        normality,
    } = stages.bias(&bias_in)?;
    if bias.is_empty() {
        missing.push("FPN and read-noise maps: the manifest has no [[bias]] stacks".into());
    }
    if (1..4).contains(&bias.len()) {
        missing.push(format!(
            "FPN exposure fit: needs bias stacks at ≥ 4 exposures, got {}; the profile holds the FPN as measured (constant in exposure)",
            bias.len()
        ));
    }
    let raw_fit = fit_fpn(&bias, width)?;
    let blooming = if bloom_in.is_empty() {
        missing.push("blooming factor: the manifest has no [[blooming]] stacks (preprocessing will not remove blooming)".into());
        None
    } else {
        Some(stages.blooming(&bloom_in, &mut bias, raw_fit.as_ref(), &mut warnings)?)
    };
    let fpn = if blooming.is_some() {
        fit_fpn(&bias, width)?
    } else {
        raw_fit
    };
    let ptc = if flat_in.is_empty() {
        missing.push("photon-transfer slope: the manifest has no [[flat]] stacks".into());
        None
    } else {
        let fixed = FixedPattern {
            bias: &bias,
            fpn: fpn.as_ref(),
            blooming: blooming.as_ref(),
        };
        Some(stages.photon_transfer(&flat_in, adc_max, &fixed, &mut warnings)?)
    };

    let gain_series = match &m.gain_series {
        None => None,
        Some(gs) => Some(run_gain_series(gs, opts, progress)?),
    };
    let (width, height) = match (&gain_series, width) {
        (Some(g), 0) => {
            missing.retain(|m| !m.starts_with("photon-transfer slope"));
            missing.push(format!(
                "flat fields: none; the photon-transfer slope comes from the gain series at the setting nearest EM gain {} (s = (2 − 1/G)·G/c)",
                m.em_gain
            ));
            g.sensor
        }
        _ => (width, height),
    };
    let mut cal = Calibration {
        camera: m.camera.clone(),
        em_gain: m.em_gain,
        manifest: m.path.clone(),
        width,
        height,
        adc_max_dn: adc_max,
        bias,
        fpn,
        normality,
        ptc,
        blooming,
        gain_series,
        spurious: None,
        missing,
        warnings,
    };
    cal.spurious = spurious_charge(&cal.bias, cal.slope(), cal.em_gain, &mut cal.missing)?;
    Ok(cal)
}

/// The spurious charge and read noise of every bias exposure (in parallel), and their fit
/// over exposures; None, with the reason in `missing`, without bias stacks, a slope or gain.
fn spurious_charge(
    bias: &[BiasLevel],
    slope: Option<f64>,
    em_gain: f64,
    missing: &mut Vec<String>,
) -> Result<Option<SpuriousFit>> {
    if bias.is_empty() {
        return Ok(None);
    }
    let Some(slope) = slope else {
        missing.push(
            "clock-induced charge and dark current: need the photon-transfer slope (flat fields)"
                .into(),
        );
        return Ok(None);
    };
    if em_gain < 2.0 {
        missing.push(format!(
            "clock-induced charge and dark current: not separable from read noise at EM gain {em_gain}"
        ));
        return Ok(None);
    }
    let fitted: Vec<_> = bias
        .par_iter()
        .filter_map(|b| {
            let d = b.differences.as_ref()?;
            crate::spurious::fit_level(d, b.exposure_s, slope / 2.0, em_gain).map(|l| (b, l))
        })
        .collect();
    // A bias stack is read with the shutter closed: its frame differences hold the clock-induced
    // charge and dark current of a cooled sensor, hundredths of an electron a pixel. One holding
    // over an electron (and two errors above none: the model, made for a few hundredths, fits a
    // lit stack loosely) is lit, a flat listed as a bias, whose "read noise" would be its shot
    // noise (117 DN for 15) and its pattern its scene.
    if let Some((b, l)) = fitted
        .iter()
        .find(|(_, l)| l.electrons > MAX_BIAS_ELECTRONS && l.electrons > 2.0 * l.electrons_se)
    {
        return Err(Error::input(
            &b.file,
            format!(
                "listed as a bias stack, but its frame differences hold {:.2} ± {:.2} electrons per pixel per frame (a bias stack's spurious charge is hundredths): it holds light; is it a flat? List it under [[flat]], or record the bias with the shutter closed",
                l.electrons, l.electrons_se
            ),
        ));
    }
    let fit = crate::spurious::fit_exposures(fitted.into_iter().map(|(_, l)| l).collect());
    if fit.is_none() {
        missing.push(
            "clock-induced charge and dark current: the bias stacks hold too few frame pairs"
                .into(),
        );
    }
    Ok(fit)
}

/// The most spurious charge a bias stack may show, electrons per pixel per frame: a cooled
/// EMCCD's clock-induced charge and dark current are hundredths even over seconds.
const MAX_BIAS_ELECTRONS: f64 = 1.0;

/// What every stage of a calibration reads stacks with: the sensor's size, the options and
/// the progress sink.
struct Stages<'a> {
    dims: Option<(usize, usize)>,
    width: usize,
    height: usize,
    opts: &'a Options,
    progress: &'a dyn Progress,
}

/// The bias stage's result: one level per exposure, and normal-probability plots of a few
/// pixels' read noise.
struct BiasStage {
    levels: Vec<BiasLevel>,
    normality: Vec<NormalPlot>,
}

/// The fixed pattern as far as it is known when the flats are measured.
struct FixedPattern<'a> {
    /// The bias levels, un-bloomed where blooming was measured.
    bias: &'a [BiasLevel],
    /// The pattern's exposure fit, if there is one.
    fpn: Option<&'a FpnResult>,
    /// The blooming fit, if there is one.
    blooming: Option<&'a BloomingResult>,
}

impl Stages<'_> {
    /// Bias: the FPN_t and read-noise maps, one streaming pass per stack.
    fn bias(&self, inputs: &[Checked]) -> Result<BiasStage> {
        let (width, height) = (self.width, self.height);
        let probes: Vec<usize> = if width * height > 0 {
            [(1, 1), (1, 3), (3, 1), (3, 3), (2, 2)]
                .iter()
                .map(|&(a, b)| (b * height / 4) * width + a * width / 4)
                .collect()
        } else {
            Vec::new()
        };
        let mut levels: Vec<BiasLevel> = Vec::new();
        let mut best_probes: Vec<(usize, Vec<f32>)> = Vec::new();
        for c in inputs {
            // Ascending exposures: the shorter stack's std map names the hot pixels to leave
            // out of this one's spurious-charge differences.
            let differences = match levels.last() {
                Some(l) => crate::spurious::Differences::leaving_out_noisy(&l.std),
                None => Default::default(),
            };
            let (_, st) = accumulate(
                &c.file,
                self.dims,
                2,
                &probes,
                None,
                Some(differences),
                self.progress,
            )?;
            let mean = st.mean();
            let std = st.std();
            if st.probes.first().map_or(0, |p| p.1.len())
                > best_probes.first().map_or(0, |p| p.1.len())
            {
                best_probes = st.probes.clone();
            }
            levels.push(BiasLevel {
                file: c.file.clone(),
                exposure_s: c.exposure_s,
                frames: st.frames,
                median_dn: emccd_profile::median(mean.iter().copied()).unwrap_or(0.0),
                read_noise_median_dn: emccd_profile::median(std.iter().copied()).unwrap_or(0.0),
                read_noise_rms_dn: (std.iter().map(|&v| (v as f64).powi(2)).sum::<f64>()
                    / std.len().max(1) as f64)
                    .sqrt(),
                mean,
                std,
                differences: st.differences,
            });
        }
        let normality = best_probes
            .iter()
            .filter_map(|(i, v)| normal_plot(i % width.max(1), i / width.max(1), v))
            .collect();
        Ok(BiasStage { levels, normality })
    }

    /// Blooming, on averaged frames with the fixed pattern removed; afterwards the bias
    /// levels hold the un-bloomed pattern.
    ///
    /// The model blooms the fixed pattern too (eq. 1: B[K(I + f·Np) + FPN_t]), so a bias mean
    /// is B[FPN_t]. Pass 1 uses the exposure curve fitted to the bias means as measured
    /// (`raw_fit`), which is enough to subtract the pattern from blooming frames at other
    /// exposures; once x(t) is known the bias means are un-bloomed (FPN_t = B⁻¹[mean]) and the
    /// caller refits the curve. The profile's FPN is then consistent with its own x(t):
    /// preprocessing B⁻¹(D) − FPN_t equals B⁻¹(D − mean_t) exactly at every calibrated exposure.
    fn blooming(
        &self,
        inputs: &[Checked],
        bias: &mut [BiasLevel],
        raw_fit: Option<&FpnResult>,
        warnings: &mut Vec<String>,
    ) -> Result<BloomingResult> {
        let (width, height) = (self.width, self.height);
        let mut means = Vec::new();
        for c in inputs {
            let (_, st) = accumulate(&c.file, self.dims, 2, &[], None, None, self.progress)?;
            means.push((c, st.mean(), st.frames));
        }
        let measure_all = |pattern: &dyn Fn(f64) -> Option<Vec<f32>>| -> Result<BloomingResult> {
            let mut levels = Vec::new();
            let mut fpn_sub = true;
            for (c, mean, frames) in &means {
                let mut img = mean.clone();
                match pattern(c.exposure_s) {
                    Some(f) => img.iter_mut().zip(&f).for_each(|(v, f)| *v -= f),
                    None => fpn_sub = false,
                }
                let blooming::Measurement { v1, v2, v3, c1 } =
                    blooming::measure(&img, width, height, self.opts.window, &c.file)?;
                let den = c1 - v2.mean;
                let x = (v2.mean - v3.mean) / den;
                let se2 = v2.std / ((v2.w * v2.h) as f64).sqrt();
                let se3 = v3.std / ((v3.w * v3.h) as f64).sqrt();
                let x_se = ((se2 * (1.0 + x) / den).powi(2) + (se3 / den).powi(2)).sqrt();
                levels.push(BloomLevel {
                    file: c.file.clone(),
                    exposure_s: c.exposure_s,
                    frames: *frames,
                    v1,
                    v2,
                    v3,
                    c1,
                    x,
                    x_se,
                });
            }
            levels.sort_by(|a, b| a.exposure_s.total_cmp(&b.exposure_s));
            blooming::fit(levels, fpn_sub)
        };
        let raw_means: Vec<Vec<f32>> = bias.iter().map(|b| b.mean.clone()).collect();
        let pass1 = measure_all(&|t| pattern_at(bias, raw_fit, t, &mut Vec::new()))?;
        if !pass1.fpn_subtracted {
            warnings.push("blooming frames: no bias stacks, so no FPN was subtracted (x is exact only for a flat pattern)".into());
        }
        let needs_prediction = inputs.iter().any(|c| {
            !bias
                .iter()
                .any(|b| (b.exposure_s - c.exposure_s).abs() <= 5e-3 * c.exposure_s)
        });
        let result = if needs_prediction && raw_fit.is_some() {
            // Pass 2: the pattern at exposures without a bias stack, predicted from the
            // un-bloomed fit and bloomed with pass 1's law — B[FPN_t] is what the frames hold.
            unbloom(bias, &raw_means, &pass1.law(), width);
            let fit1 = fit_fpn(bias, width)?;
            let law1 = pass1.law();
            let bias = &*bias;
            measure_all(&|t| {
                let mut f = pattern_at(bias, fit1.as_ref(), t, &mut Vec::new())?;
                emccd_profile::apply_blooming(&mut f, width, law1.factor(t));
                Some(f)
            })?
        } else {
            pass1
        };
        unbloom(bias, &raw_means, &result.law(), width);
        Ok(result)
    }

    /// Flats: median–variance of the photo-signal (blooming and the fixed pattern removed)
    /// on the central crop, and the photon-transfer fit.
    fn photon_transfer(
        &self,
        inputs: &[Checked],
        adc_max: f64,
        fixed: &FixedPattern,
        warnings: &mut Vec<String>,
    ) -> Result<PtcResult> {
        let (width, height) = (self.width, self.height);
        let n = width * height;
        let x_at = |t: f64| fixed.blooming.map_or(0.0, |b| b.law().factor(t));
        let crop = ptc::central_crop(width, height, self.opts.crop);
        let mut levels = Vec::new();
        let mut fpn_sub = true;
        for c in inputs {
            let (_, st) = accumulate(
                &c.file,
                self.dims,
                2,
                &[],
                Some(adc_max as f32),
                None,
                self.progress,
            )?;
            let raw = st.mean();
            let var = st.variance();
            let [x0, y0, cw, ch] = crop;
            let raw_crop: Vec<f32> = (y0..y0 + ch)
                .flat_map(|y| raw[y * width + x0..y * width + x0 + cw].iter().copied())
                .collect();
            let raw_median = emccd_profile::median(raw_crop).unwrap_or(0.0);
            if raw_median >= adc_max - 0.5 {
                return Err(Error::input(
                    &c.file,
                    format!("flat field is brighter than the ADC range: median {raw_median:.0} DN at the ADC maximum {adc_max:.0} DN"),
                ));
            }
            let mut signal = raw;
            emccd_profile::remove_blooming(&mut signal, width, x_at(c.exposure_s));
            match pattern_at(fixed.bias, fixed.fpn, c.exposure_s, warnings) {
                Some(f) => signal.iter_mut().zip(&f).for_each(|(v, f)| *v -= f),
                None => fpn_sub = false,
            }
            let ptc::LevelStats {
                median_dn,
                variance_dn2,
                variance_se_dn2,
                pixels,
            } = ptc::level_stats(&signal, &var, width, crop);
            // Every recorded frame carries at least read noise: frames that never vary (a
            // constant or all-zero stack) are not a recording, and would drag the slope anywhere.
            if !(variance_dn2 > 0.0 && variance_dn2.is_finite() && median_dn.is_finite()) {
                return Err(Error::input(
                    &c.file,
                    format!(
                        "not a flat field: its frames do not vary (temporal variance {variance_dn2:.3} DN², median {median_dn:.2} DN above the bias); every recorded frame carries read noise"
                    ),
                ));
            }
            let saturated_fraction = st.saturated as f64 / (st.frames * n) as f64;
            let status = if saturated_fraction > 1e-4 {
                LevelStatus::Saturated
            } else {
                LevelStatus::Included
            };
            levels.push(FlatLevel {
                file: c.file.clone(),
                exposure_s: c.exposure_s,
                frames: st.frames,
                median_dn,
                variance_dn2,
                variance_se_dn2,
                pixels,
                saturated_fraction,
                status,
            });
        }
        // A line through the levels needs levels: flats that all hold one light level (the same
        // file given for each, say) would give any slope at all, with r² = 1.
        let medians: Vec<f64> = levels.iter().map(|l| l.median_dn).collect();
        let (lo, hi) = medians
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &m| {
                (a.min(m), b.max(m))
            });
        if levels.len() > 1 && !(hi - lo > 0.05 * hi.abs().max(1e-9)) {
            let files: Vec<String> = inputs
                .iter()
                .map(|c| c.file.display().to_string())
                .collect();
            return Err(Error::Fit(format!(
                "the flats all hold one light level (medians {lo:.1} to {hi:.1} DN above the bias): the photon-transfer slope needs flats at several levels. The flats: {}",
                files.join(", ")
            )));
        }
        let fit = ptc::fit(&mut levels)?;
        // Shot noise makes a flat's variance rise with its signal; a slope that does not is
        // not a camera's (the same frames given as every level, or stacks that are not flats).
        if !(fit.slope > 0.0) {
            let files: Vec<String> = inputs
                .iter()
                .map(|c| c.file.display().to_string())
                .collect();
            return Err(Error::Fit(format!(
                "the flats' temporal variance does not rise with their signal (photon-transfer slope {:.3} DN): the same frames at every level, or stacks that are not flat fields? The flats: {}",
                fit.slope,
                files.join(", ")
            )));
        }
        Ok(PtcResult {
            levels,
            fit,
            crop,
            fpn_subtracted: fpn_sub,
            blooming_removed: fixed.blooming.is_some(),
        })
    }
}

fn run_gain_series(
    gs: &crate::manifest::GainSeries,
    opts: &Options,
    progress: &dyn Progress,
) -> Result<GainSeriesResult> {
    let first = &gs.settings[0].file;
    let r = emccd_io::open(first).map_err(|e| Error::io(first, e))?;
    let (w, h) = (r.info().width, r.info().height);
    drop(r);
    // A central block of at most `gain_pixels` pixels.
    let side = ((opts.gain_pixels as f64).sqrt() as usize).max(1);
    let (bw, bh) = (side.min(w), side.min(h));
    let (x0, y0) = ((w - bw) / 2, (h - bh) / 2);
    let pixels: Vec<(usize, usize)> = (y0..y0 + bh)
        .flat_map(|y| (x0..x0 + bw).map(move |x| (x, y)))
        .collect();
    let idx: Vec<usize> = pixels.iter().map(|&(x, y)| y * w + x).collect();
    let mut data = Vec::new();
    for s in &gs.settings {
        let (info, st) = accumulate(&s.file, Some((w, h)), 100, &idx, None, None, progress)?;
        if info.frames > crate::stats::PROBE_CAP {
            eprintln!(
                "note: {}: fitting the first {} of {} frames",
                s.file.display(),
                crate::stats::PROBE_CAP,
                info.frames
            );
        }
        let (offset, sigma) = match (&s.offset_map, &s.sigma_map, &s.no_signal) {
            (Some(o), Some(g), _) => {
                let (ow, oh, om) = read_map(o)?;
                let (gw, gh, gm) = read_map(g)?;
                for (p, ww, hh) in [(o, ow, oh), (g, gw, gh)] {
                    if (ww, hh) != (w, h) {
                        return Err(Error::input(
                            p,
                            format!(
                                "map is {ww}×{hh}, the stack {} is {w}×{h}",
                                s.file.display()
                            ),
                        ));
                    }
                }
                (
                    idx.iter().map(|&i| om[i] as f64).collect::<Vec<_>>(),
                    idx.iter().map(|&i| gm[i] as f64).collect::<Vec<_>>(),
                )
            }
            (_, _, Some(ns)) => {
                let (_, st0) = accumulate(ns, Some((w, h)), 2, &[], None, None, progress)?;
                let (m0, s0) = (st0.mean(), st0.std());
                (
                    idx.iter().map(|&i| m0[i] as f64).collect(),
                    idx.iter().map(|&i| s0[i] as f64).collect(),
                )
            }
            _ => {
                return Err(Error::input(
                    &s.file,
                    "no offset/sigma maps and no no-signal stack",
                ))
            }
        };
        if let Some(bad) = sigma.iter().position(|v| !(*v > 0.0)) {
            return Err(Error::input(
                &s.file,
                format!("readout σ of pixel {:?} is not positive", pixels[bad]),
            ));
        }
        let samples: Vec<Vec<f32>> = st.probes.into_iter().map(|(_, v)| v).collect();
        // EM-amplified signal only adds to the offset. A stack whose pixels sit, on average,
        // clearly below their offsets was measured against another offset (the wrong map, or a
        // bias that drifted): its gain would be fitted at the bound G = 1 and move e⁻/DN with it.
        let below: Vec<f64> = samples
            .iter()
            .zip(&offset)
            .zip(&sigma)
            .map(|((v, &o), &g)| {
                let m = v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64;
                (o - m) / (g / (v.len().max(1) as f64).sqrt())
            })
            .collect();
        let typical = emccd_profile::median(below.iter().copied()).unwrap_or(0.0);
        if typical > 5.0 {
            let dn = samples
                .iter()
                .zip(&offset)
                .map(|(v, &o)| o - v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64)
                .sum::<f64>()
                / samples.len().max(1) as f64;
            return Err(Error::input(
                &s.file,
                format!(
                    "its frames sit {dn:.1} DN below their offset map on average (the median \
                     pixel by {typical:.0} standard errors): the offset is not this stack's; \
                     give the no-signal stack or maps recorded with it"
                ),
            ));
        }
        data.push(SettingData {
            nominal: s.em_gain,
            file: s.file.clone(),
            samples,
            offset,
            sigma,
        });
    }
    let reference = match &gs.reference_e_per_dn {
        Some(p) => {
            let (rw, _, rm) = read_map(p)?;
            let vals: Vec<f64> = pixels
                .iter()
                .filter_map(|&(x, y)| rm.get(y * rw + x).map(|&v| v as f64))
                .collect();
            let mean = vals.iter().sum::<f64>() / vals.len().max(1) as f64;
            if !(mean > 0.0 && mean.is_finite()) || vals.iter().any(|v| !(*v > 0.0)) {
                return Err(Error::input(
                    p,
                    format!(
                        "reference_e_per_dn: every fitted pixel's electrons per DN must be a \
                         positive number (the map's mean there is {})",
                        emccd_profile::number(mean)
                    ),
                ));
            }
            Some(mean)
        }
        None => None,
    };
    gain_series::fit(data, pixels, (w, h), reference)
}

impl Calibration {
    /// The photon-transfer slope s, DN: the flats' regression, else the gain series' at the
    /// calibrated EM gain.
    fn slope(&self) -> Option<f64> {
        self.ptc
            .as_ref()
            .map(|p| p.fit.slope)
            .or_else(|| self.gain_series.as_ref().map(|g| g.slope_at(self.em_gain)))
    }

    /// The Poisson–Gamma–Normal parameters measured: EM gain, e⁻/DN from the slope, the
    /// spurious charge and the read noise beneath it (the profile's fixed pattern, measured on
    /// the same bias frames, holds the spurious charge's mean: see
    /// [`CameraProfile::fpn_holds_spurious`]).
    fn pgn(&self) -> Option<PgnParams> {
        let s = self.spurious.as_ref()?;
        let g = self.slope()? / 2.0;
        Some(PgnParams {
            em_gain: self.em_gain,
            e_per_dn: self.em_gain / g,
            cic_e: s.cic_e,
            dark_e_per_s: s.dark_e_per_s,
            read_sigma_dn: s.read_sigma_dn,
        })
    }

    /// The camera profile. Fails only when there is nothing to put in one (no bias, flats or
    /// blooming stacks: a gain series alone does not describe a sensor).
    pub fn profile(&self) -> Result<CameraProfile> {
        if self.width == 0 {
            return Err(Error::Fit(
                "no stacks with a frame size: nothing to build a profile from".into(),
            ));
        }
        let n = self.width * self.height;
        let (fpn_fit, fpn_base, fpn_theta) = match (self.bias.first(), &self.fpn) {
            (Some(b0), Some(f)) => {
                let mut theta = f.theta_maps.clone();
                if !theta.is_empty() {
                    // Pixels that could not be fitted (non-positive FPN) keep their base value.
                    for p in 0..n {
                        if theta[p].is_nan() {
                            let base = b0.mean[p].max(1e-3).ln();
                            for (k, v) in [base, 0.0, 1.0, 0.0].into_iter().enumerate() {
                                theta[k * n + p] = v;
                            }
                        }
                    }
                }
                // The constant form's map is the pool of every exposure (less noise than one),
                // and its curve is flat, so the shared evaluation agrees with it.
                let constant = f.chosen == FpnForm::Constant;
                (
                    FpnFit {
                        form: f.chosen,
                        base_exposure_s: b0.exposure_s,
                        shared_theta: if constant { [0.0; 4] } else { f.shared_theta },
                    },
                    if constant {
                        f.pooled.clone()
                    } else {
                        b0.mean.clone()
                    },
                    theta,
                )
            }
            (Some(b0), None) => (
                FpnFit {
                    form: FpnForm::Shared,
                    base_exposure_s: b0.exposure_s,
                    shared_theta: [0.0; 4],
                },
                b0.mean.clone(),
                Vec::new(),
            ),
            _ => (
                FpnFit {
                    form: FpnForm::Shared,
                    base_exposure_s: 1e-5,
                    shared_theta: [0.0; 4],
                },
                Vec::new(),
                Vec::new(),
            ),
        };
        let mut notes = format!(
            "calibrated by `emccd calibrate` from {}",
            self.manifest.display()
        );
        for m in &self.missing {
            notes.push_str(&format!("; missing: {m}"));
        }
        if let Some(gs) = &self.gain_series {
            notes.push_str(&format!(
                "; gain series: {:.4} ± {:.4} e-/DN, gains {}",
                gs.e_per_dn,
                gs.e_per_dn_se,
                gs.settings
                    .iter()
                    .map(|s| format!("{}x→{:.2}", s.nominal, s.gain))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        let p = CameraProfile {
            camera: self.camera.clone(),
            em_gain: self.em_gain,
            width: self.width,
            height: self.height,
            ptc_slope_dn: self.slope(),
            f_range: [1.3, std::f64::consts::SQRT_2],
            quantization_dn: 1.0,
            adc_max_dn: self.adc_max_dn,
            fpn: fpn_fit,
            blooming: self.blooming.as_ref().map(|b| b.law()),
            exposures_s: self.bias.iter().map(|b| b.exposure_s).collect(),
            eld: None,
            pgn: self.pgn(),
            provenance: Provenance {
                source: "calibrated".into(),
                notes,
            },
            maps: ProfileMaps {
                fpn_base,
                fpn_theta,
                // Few frames leave each pixel's std noisy and their median low: shrunk.
                read_noise: self
                    .bias
                    .iter()
                    .map(|b| crate::read_noise::shrunk(&b.std, b.frames))
                    .collect(),
            },
        };
        p.validate()
            .map_err(|e| Error::Fit(format!("the calibrated profile is inconsistent: {e}")))?;
        Ok(p)
    }
}
