//! Each pixel's threshold and model: the camera's numbers at an exposure ([`Camera`]), how the
//! threshold is set ([`Threshold`], [`choose_k`]) and the per-pixel models that turn counts into
//! rates ([`Plan`]).

use rayon::prelude::*;

use emccd_profile::CameraProfile;

use crate::likelihood::{BinModel, Binning};
use crate::model::PixelModel;
use crate::{Error, Result};

/// How each pixel's threshold is set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Threshold {
    /// `k` times the pixel's read noise, `k` chosen to make the rate's error smallest at the
    /// stack's own light level ([`choose_k`]).
    Auto,
    /// `k` times the pixel's read noise (`3sigma`).
    Sigma(f64),
    /// The same number of DN above bias for every pixel (`25DN`).
    Dn(f64),
    /// No single threshold: each frame's value in one of [`crate::likelihood::BINS`] bins and
    /// the rate the most likely under the exact model (`likelihood`).
    Likelihood,
}

impl std::str::FromStr for Threshold {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Threshold, String> {
        let t = s.trim().to_ascii_lowercase();
        let number = |v: &str| {
            v.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| *v > 0.0 && v.is_finite())
        };
        if t == "auto" {
            Ok(Threshold::Auto)
        } else if t == "likelihood" {
            Ok(Threshold::Likelihood)
        } else if let Some(k) = t.strip_suffix("sigma").and_then(number) {
            Ok(Threshold::Sigma(k))
        } else if let Some(d) = t.strip_suffix("dn").and_then(number) {
            Ok(Threshold::Dn(d))
        } else {
            Err(format!(
                "'{s}': a threshold is `auto`, `likelihood`, `<k>sigma` (k times each pixel's read noise, e.g. 3sigma) or `<n>DN` (e.g. 25DN), with a positive number"
            ))
        }
    }
}

/// Which read noise a pixel's threshold and model use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ReadNoise {
    /// `Pixel` where the profile's std maps at two exposures agree pixel by pixel (their
    /// squares correlate over 0.5 once hot pixels are left out: the texture is the sensor's),
    /// else `Camera` (what differs between two stacks is their sampling noise and spurious
    /// events).
    #[default]
    Auto,
    /// The camera's one read noise: the calibration's fit beneath the spurious charge
    /// (`[pgn] read_sigma_dn`, with the ADC's rounding), else the median of the std map. An
    /// EMCCD reads every pixel through one amplifier, and a bias stack's per-pixel std also
    /// holds each pixel's few spurious events.
    Camera,
    /// Each pixel's std map at the exposure, as measured.
    Pixel,
}

/// How much two of the profile's std maps agree: the correlation of their squares over the
/// pixels neither holds as noisy (1.5 times its median); None with fewer than two maps. The
/// maps nearest `exposure_s` are compared.
pub fn texture_agreement(profile: &CameraProfile, exposure_s: f64) -> Option<f64> {
    let maps = &profile.maps.read_noise;
    if maps.len() < 2 {
        return None;
    }
    let mut order: Vec<usize> = (0..maps.len()).collect();
    order.sort_by(|&a, &b| {
        let d = |i: usize| (profile.exposures_s[i].ln() - exposure_s.ln()).abs();
        d(a).total_cmp(&d(b))
    });
    let (a, b) = (&maps[order[0]], &maps[order[1]]);
    let limit = |m: &[f32]| 1.5 * emccd_profile::median(m.iter().copied()).unwrap_or(f64::INFINITY);
    let (la, lb) = (limit(a), limit(b));
    let pairs: Vec<(f64, f64)> = a
        .iter()
        .zip(b.iter())
        .map(|(&x, &y)| (x as f64, y as f64))
        .filter(|&(x, y)| x <= la && y <= lb)
        .map(|(x, y)| (x * x, y * y))
        .collect();
    let n = pairs.len() as f64;
    if n < 3.0 {
        return None;
    }
    let (mx, my) = (
        pairs.iter().map(|p| p.0).sum::<f64>() / n,
        pairs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for &(x, y) in &pairs {
        sxy += (x - mx) * (y - my);
        sxx += (x - mx).powi(2);
        syy += (y - my).powi(2);
    }
    (sxx > 0.0 && syy > 0.0).then(|| sxy / (sxx * syy).sqrt())
}

impl std::str::FromStr for ReadNoise {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<ReadNoise, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(ReadNoise::Auto),
            "camera" => Ok(ReadNoise::Camera),
            "pixel" => Ok(ReadNoise::Pixel),
            _ => Err(format!(
                "'{s}': the read noise is `auto`, `camera` (one for every pixel) or `pixel` (each pixel's map)"
            )),
        }
    }
}

/// What counting needs to know of the camera at one exposure.
#[derive(Clone, Debug)]
pub struct Camera {
    /// Frame width, px.
    pub width: usize,
    /// Frame height, px.
    pub height: usize,
    /// The register's mean output per electron, DN (K = s/2 of the profile).
    pub g: f64,
    /// Each pixel's read noise at this exposure, DN.
    pub sigma: Vec<f32>,
    /// Electrons per pixel per frame without light: clock-induced charge plus dark current.
    pub spurious: f64,
    /// Whether preprocessing already removed the spurious charge's mean signal (the fixed
    /// pattern was measured on dark frames: a calibrated profile).
    pub removed: bool,
    /// Hot pixels: whose dark charge is many times the camera's spurious charge, with their
    /// own spurious electrons per frame at this exposure (pixel index, electrons), ascending.
    pub hot: Vec<(u32, f64)>,
    /// The read noise used: `Camera` or `Pixel`.
    pub read_noise: ReadNoise,
}

/// A pixel is hot when its bias frames' variance puts this many spurious electrons per frame in
/// it beyond the camera's: more than one CIC event's variance in a few frames can mimic.
const HOT_ELECTRONS: f64 = 0.25;

impl Camera {
    /// The camera of `profile` at `exposure_s`; an error naming what the profile lacks.
    /// `spurious`, (clock-induced charge per frame, dark current per second), replaces the
    /// profile's (its `[pgn]` section), for a camera whose calibration did not measure them
    /// (they are on its data sheet).
    pub fn from_profile(
        profile: &CameraProfile,
        exposure_s: f64,
        spurious: Option<(f64, f64)>,
        read_noise: ReadNoise,
    ) -> Result<Camera> {
        let g = profile.dn_per_electron().map_err(|_| {
            Error(
                "the profile has no photon-transfer slope (the EM register's DN per electron): \
                 calibrate it with flat-field stacks"
                    .into(),
            )
        })?;
        if !profile.has_bias() {
            return Err(Error(
                "the profile has no read-noise maps: calibrate it with bias stacks".into(),
            ));
        }
        let (cic, dark) = match (spurious, &profile.pgn) {
            (Some(s), _) => s,
            (None, Some(p)) => (p.cic_e, p.dark_e_per_s),
            (None, None) => {
                return Err(Error(
                    "the profile has no clock-induced charge and dark current (its [pgn] \
                     section): the false-event rate cannot be predicted without them; give \
                     them (--cic, --dark) from the camera's data sheet"
                        .into(),
                ))
            }
        };
        emccd_profile::check_spurious(cic, dark).map_err(|e| Error(e.to_string()))?;
        let map = profile.read_noise_near(exposure_s);
        let one = match &profile.pgn {
            // Measured beneath the spurious charge, before the ADC's rounding.
            Some(p) if profile.fpn_holds_spurious() => {
                (p.read_sigma_dn.powi(2) + profile.quantization_dn.powi(2) / 12.0).sqrt()
            }
            _ => emccd_profile::median(map.iter().copied()).unwrap_or(1.0),
        };
        let spurious = cic + dark * exposure_s;
        let read_noise = match read_noise {
            ReadNoise::Auto => match texture_agreement(profile, exposure_s) {
                Some(r) if r > 0.5 => ReadNoise::Pixel,
                _ => ReadNoise::Camera,
            },
            r => r,
        };
        let (sigma, hot) = match read_noise {
            ReadNoise::Auto => unreachable!("resolved above"),
            ReadNoise::Pixel => (map.to_vec(), Vec::new()),
            ReadNoise::Camera => {
                // A pixel's bias variance beyond the read noise is its spurious electrons'
                // (2g² each through the register); its dark part scales with the exposure
                // from the map's.
                let t_map = profile.exposure_near(exposure_s);
                let hot = map
                    .iter()
                    .enumerate()
                    .filter_map(|(i, &s)| {
                        let at_map = ((s as f64).powi(2) - one * one) / (2.0 * g * g);
                        let beyond = at_map - (cic + dark * t_map);
                        (beyond > HOT_ELECTRONS)
                            .then(|| (i as u32, spurious + beyond * exposure_s / t_map))
                    })
                    .collect();
                (vec![one as f32; map.len()], hot)
            }
        };
        Ok(Camera {
            width: profile.width,
            height: profile.height,
            g,
            sigma,
            spurious,
            removed: profile.fpn_holds_spurious(),
            hot,
            read_noise,
        })
    }

    /// The spurious electrons per frame still in preprocessed frames' mean (not removed with
    /// the fixed pattern): what the analog estimate subtracts.
    pub fn unremoved(&self) -> f64 {
        if self.removed {
            0.0
        } else {
            self.spurious
        }
    }

    /// The electrons per frame whose mean signal preprocessing removed: none or all.
    fn removed_of(&self, spurious: f64) -> f64 {
        if self.removed {
            spurious
        } else {
            0.0
        }
    }

    /// Pixel `i`'s spurious electrons per frame: its own where it is hot, else the camera's.
    pub fn spurious_at(&self, i: usize) -> f64 {
        match self.hot.binary_search_by_key(&(i as u32), |h| h.0) {
            Ok(k) => self.hot[k].1,
            Err(_) => self.spurious,
        }
    }

    /// Pixel `i`'s spurious electrons per frame still in preprocessed frames' mean.
    pub fn unremoved_at(&self, i: usize) -> f64 {
        let s = self.spurious_at(i);
        s - self.removed_of(s)
    }

    /// The variance of pixel `i`'s analog estimate from `frames` frames at `rate`
    /// photo-electrons per pixel per frame: the register doubles the Poisson variance of every
    /// electron (f² = 2), spurious ones included, and read noise adds its own.
    pub fn analog_variance(&self, i: usize, rate: f64, frames: f64) -> f64 {
        let electrons = rate + self.spurious_at(i);
        (2.0 * electrons + (self.sigma[i] as f64 / self.g).powi(2)) / frames
    }

    /// The median read noise, DN.
    pub fn median_sigma(&self) -> f64 {
        emccd_profile::median(self.sigma.iter().copied()).unwrap_or(1.0)
    }
}

/// The `k` (threshold in read-noise σ, from 0.5 to 8 in steps of 0.05) whose rate estimate from
/// `frames` frames has the smallest variance at `lambda` photo-electrons per pixel per frame,
/// for a pixel of the camera's median read noise: the per-camera choice (each pixel then uses
/// `k` times its own σ).
pub fn choose_k(camera: &Camera, lambda: f64, frames: u32) -> f64 {
    let sigma = camera.median_sigma();
    let lambda = lambda.max(1e-4);
    (10..=160)
        .map(|i| i as f64 * 0.05)
        .map(|k| {
            let shift = camera.removed_of(camera.spurious) * camera.g;
            let m = PixelModel::new(k * sigma + shift, camera.g, sigma, camera.spurious);
            (k, m.variance(lambda, frames))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(3.0, |(k, _)| k)
}

/// Each pixel's threshold and its model. Pixels share models: each is given the model of the
/// nearest of a log-spaced grid of read-noise values (0.2 % apart), which moves its predicted
/// false-event rate by far less than its counts' noise.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Each pixel's threshold, DN above bias.
    pub thresholds: Vec<f32>,
    /// `k` where the thresholds are `k` times each pixel's read noise.
    pub k_sigma: Option<f64>,
    models: Vec<PixelModel>,
    index: Vec<u32>,
    /// With [`Threshold::Likelihood`]: each model's bin probabilities, and each pixel's bins.
    likelihood: Option<(Vec<BinModel>, Vec<Binning>)>,
}

/// Relative spacing of the read-noise grid.
const GRID_STEP: f64 = 0.002;

impl Plan {
    /// The thresholds of `threshold` (`Auto` must be resolved first, by [`choose_k`]).
    pub fn new(camera: &Camera, threshold: Threshold) -> Plan {
        let k = match threshold {
            Threshold::Auto | Threshold::Likelihood => 3.0,
            Threshold::Sigma(k) => k,
            Threshold::Dn(_) => f64::NAN,
        };
        let lo = camera
            .sigma
            .iter()
            .copied()
            .fold(f32::INFINITY, f32::min)
            .max(1e-3) as f64;
        let slot =
            |s: f32| ((s.max(1e-3) as f64 / lo).ln() / (1.0 + GRID_STEP).ln()).round() as u32;
        let slots = camera.sigma.iter().map(|&s| slot(s)).max().unwrap_or(0) + 1;
        let sigma_of = |i: u32| lo * (1.0 + GRID_STEP).powi(i as i32);
        let t_of = |s: f64| match threshold {
            Threshold::Dn(d) => d,
            _ => k * s,
        };
        // Preprocessing removed the spurious charge's mean signal with the fixed pattern, so a
        // threshold T above the preprocessed zero is T + that mean above the true bias.
        let shift = camera.removed_of(camera.spurious) * camera.g;
        let mut models: Vec<PixelModel> = (0..slots)
            .into_par_iter()
            .map(|i| {
                let s = sigma_of(i);
                PixelModel::new(t_of(s) + shift, camera.g, s, camera.spurious)
            })
            .collect();
        let mut index: Vec<u32> = camera.sigma.iter().map(|&s| slot(s)).collect();
        // Each hot pixel its own model, with its own dark charge.
        let hot: Vec<PixelModel> = camera
            .hot
            .par_iter()
            .map(|&(i, e)| {
                let s = camera.sigma[i as usize] as f64;
                PixelModel::new(t_of(s) + camera.removed_of(e) * camera.g, camera.g, s, e)
            })
            .collect();
        for (&(i, _), m) in camera.hot.iter().zip(hot) {
            index[i as usize] = models.len() as u32;
            models.push(m);
        }
        let likelihood = (threshold == Threshold::Likelihood).then(|| {
            // The same slots: the grid's read noise and the camera's spurious charge, then
            // each hot pixel's own.
            let mut bm: Vec<BinModel> = (0..slots)
                .into_par_iter()
                .map(|i| BinModel::new(sigma_of(i), camera.g, camera.spurious))
                .collect();
            bm.extend(
                camera
                    .hot
                    .par_iter()
                    .map(|&(i, e)| BinModel::new(camera.sigma[i as usize] as f64, camera.g, e))
                    .collect::<Vec<_>>(),
            );
            let binning = (0..camera.sigma.len())
                .map(|i| {
                    let shift = camera.removed_of(camera.spurious_at(i)) * camera.g;
                    Binning::new(camera.sigma[i] as f64, camera.g, shift)
                })
                .collect();
            (bm, binning)
        });
        Plan {
            thresholds: camera
                .sigma
                .iter()
                .map(|&s| t_of(s as f64) as f32)
                .collect(),
            k_sigma: matches!(threshold, Threshold::Auto | Threshold::Sigma(_)).then_some(k),
            models,
            index,
            likelihood,
        }
    }

    /// The model pixel `i` is counted with.
    pub fn model(&self, i: usize) -> &PixelModel {
        &self.models[self.index[i] as usize]
    }

    /// Each pixel's bins, with [`Threshold::Likelihood`].
    pub fn binning(&self) -> Option<&[Binning]> {
        self.likelihood.as_ref().map(|l| l.1.as_slice())
    }

    /// The bin model pixel `i` is estimated with, with [`Threshold::Likelihood`].
    pub fn bin_model(&self, i: usize) -> Option<&BinModel> {
        self.likelihood
            .as_ref()
            .map(|l| &l.0[self.index[i] as usize])
    }

    /// The maximum-likelihood rate and its standard error at every pixel from its bin counts
    /// (`BINS` a pixel, one after another) of `frames` frames, each solved from `start` (its
    /// analog rate, say), in parallel; None without [`Threshold::Likelihood`].
    pub fn estimate_binned(
        &self,
        bins: &[u16],
        frames: u32,
        start: &[f32],
    ) -> Option<(Vec<f32>, Vec<f32>)> {
        let (models, _) = self.likelihood.as_ref()?;
        let b = crate::likelihood::BINS;
        Some(
            bins.par_chunks(b)
                .zip(start.par_iter())
                .enumerate()
                .map(|(i, (h, &s))| {
                    let (r, se) = models[self.index[i] as usize].estimate(h, frames, s as f64);
                    (r as f32, se as f32)
                })
                .unzip(),
        )
    }

    /// The median over pixels of the false-event rate (events per frame without light) and of
    /// the probability that one photo-electron is missed.
    pub fn predicted(&self) -> (f64, f64) {
        let f = emccd_profile::median(
            self.index
                .iter()
                .map(|&i| self.models[i as usize].false_events()),
        );
        let m = emccd_profile::median(self.index.iter().map(|&i| self.models[i as usize].missed()));
        (f.unwrap_or(f64::NAN), m.unwrap_or(f64::NAN))
    }

    /// The rate and its standard error at every pixel from `counts` events in `frames` frames.
    /// Pixels that share a model and a count share the computation.
    pub fn estimate(&self, counts: &[u32], frames: u32) -> (Vec<f32>, Vec<f32>) {
        let k_max = counts.iter().copied().max().unwrap_or(0) as usize;
        // Which (model, count) pairs occur, then each computed once.
        let mut needed = vec![false; self.models.len() * (k_max + 1)];
        for (i, &c) in counts.iter().enumerate() {
            needed[self.index[i] as usize * (k_max + 1) + c as usize] = true;
        }
        let table: Vec<(f32, f32)> = needed
            .par_iter()
            .enumerate()
            .map(|(j, &need)| {
                if !need {
                    return (0.0, 0.0);
                }
                let (m, c) = (j / (k_max + 1), j % (k_max + 1));
                let (r, se) = self.models[m].estimate(c as u32, frames);
                (r as f32, se as f32)
            })
            .collect();
        counts
            .iter()
            .enumerate()
            .map(|(i, &c)| table[self.index[i] as usize * (k_max + 1) + c as usize])
            .unzip()
    }
}
