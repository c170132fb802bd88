//! A denoising request resolved to its method and model ([`resolve`]), and [`Denoiser`], which
//! turns one raw frame into the output. The CLI, the Python package and library users share
//! this, so `emccd denoise` and `emccd.denoise` give the same frames for the same request.

use emccd_classical::frame::preprocess;
use emccd_nn::tile::Tiling;
use emccd_nn::{Classical, Error, Inference, Inputs, Model, Result, MOVIE_WINDOW};
use emccd_profile::CameraProfile;

use crate::method::{Method, Units, DEFAULT_METHOD, DEFAULT_MOVIE_METHOD};

/// What a request runs ([`resolve`]).
pub struct Resolved {
    /// The method.
    pub method: Method,
    /// The network, for the methods that run one.
    pub model: Option<Model>,
    /// The model argument it was loaded from, as given or defaulted (a bundled name or a
    /// file): what provenance names and hashes.
    pub model_name: Option<String>,
    /// Neither a method nor a model was asked: a recording of more than one frame then runs
    /// [`DEFAULT_MOVIE_METHOD`] instead of `method` ([`Resolved::method_for`]).
    pub defaulted: bool,
}

impl Resolved {
    /// The warning for running its model on frames of `profile`'s camera when the model was
    /// trained for another ([`profile_mismatch`]); none for a classical method.
    pub fn profile_warning(&self, profile: &CameraProfile) -> Option<String> {
        self.model
            .as_ref()
            .and_then(|m| profile_mismatch(m, profile))
    }

    /// The method a recording of `frames` frames runs with `window` frames each side:
    /// [`DEFAULT_MOVIE_METHOD`] on a movie when neither a method nor a model was asked (and the
    /// window is not 0: `--window 0` is the frame-by-frame default), else the method.
    pub fn method_for(&self, frames: usize, window: usize) -> Method {
        if self.defaulted && frames > 1 && window > 0 {
            DEFAULT_MOVIE_METHOD
        } else {
            self.method
        }
    }

    /// The frames each side a temporal method uses: `asked`, or [`DEFAULT_WINDOW`] (0 for a
    /// method that denoises each frame alone; the temporal network's own, [`MOVIE_WINDOW`],
    /// which is the only one it takes); an error when a window is asked of such a method. The default method takes one for the movies it denoises temporally.
    pub fn window(&self, asked: Option<usize>) -> Result<usize> {
        if self.method == Method::TemporalNet {
            return match asked {
                None => Ok(MOVIE_WINDOW),
                Some(w) if w == MOVIE_WINDOW => Ok(w),
                Some(w) => Err(Error::Model(format!(
                    "--window {w}: --method temporal-net's network sees {MOVIE_WINDOW} frames \
                     each side, no other number (--method temporal takes any window)"
                ))),
            };
        }
        match (self.method.temporal() || self.defaulted, asked) {
            (true, w) => Ok(w.unwrap_or(DEFAULT_WINDOW)),
            (false, None | Some(0)) => Ok(0),
            (false, Some(_)) => Err(Error::Model(format!(
                "--window: --method {} denoises each frame alone; --method temporal uses the \
                 neighbouring frames",
                self.method.name()
            ))),
        }
    }

    /// What runs on a recording of `frames` frames of `profile`'s camera
    /// ([`Resolved::method_for`]), with `window` frames each side for a temporal method
    /// ([`Resolved::window`]); an error when the profile lacks what denoising needs (a
    /// gain-series calibration has no slope or bias maps).
    pub fn denoiser<'a>(
        &'a self,
        profile: &'a CameraProfile,
        frames: usize,
        tiling: Tiling,
        ensemble: usize,
        units: Units,
        window: usize,
    ) -> Result<Denoiser<'a>> {
        emccd_classical::frame::can_denoise(profile)?;
        let method = self.method_for(frames, window);
        Ok(Denoiser {
            profile,
            method,
            model: self.model.as_ref().filter(|_| method.uses_model()),
            tiling,
            ensemble,
            units,
            window: if method.temporal() { window } else { 0 },
        })
    }

    /// The note for a window asked (`--window`, `asked`) of a recording of one frame, which
    /// has no neighbours: it is denoised alone, by the method that says.
    pub fn lone_frame_note(&self, frames: usize, asked: Option<usize>) -> Option<String> {
        let w = asked.filter(|&w| w > 0 && frames == 1)?;
        let method = self.method_for(frames, w);
        Some(format!(
            "one frame: --window {w} finds no neighbours, so the frame is denoised alone \
             (--method {}{})",
            method.name(),
            if method.temporal() {
                ", its single-frame estimate"
            } else {
                ""
            }
        ))
    }

    /// The note for running the default on a movie (`frames` frames) temporally, if it does.
    pub fn movie_note(&self, frames: usize, window: usize) -> Option<String> {
        (self.method_for(frames, window) != self.method).then(|| {
            format!(
                "{frames} frames: each estimated with the {window} before and after it too \
                 (--method {}; --method {} denoises each frame alone)",
                DEFAULT_MOVIE_METHOD.name(),
                self.method.name()
            )
        })
    }
}

/// The method and model a request runs: `method` and `model` as given (either may be absent),
/// with `load` turning a model argument into a model ([`crate::bundled::load`], or another
/// loader). The model a method takes by default is [`Method::default_model`] (`hybrid` for
/// [`Method::Hybrid`], `movie` for [`Method::TemporalNet`], else `lowlight`, the best
/// network); a model alone picks the method it was trained for. An error where a model does not fit the method.
pub fn resolve(
    method: Option<Method>,
    model: Option<&str>,
    load: impl Fn(&str) -> Result<Model>,
) -> Result<Resolved> {
    let classical = |method| Resolved {
        method,
        model: None,
        model_name: None,
        defaulted: false,
    };
    match (method, model) {
        (None, None) if !DEFAULT_METHOD.uses_model() => Ok(classical(DEFAULT_METHOD)),
        (Some(c), Some(m)) if !c.uses_model() => Err(Error::Model(format!(
            "--model {m}: --method {} runs no network",
            c.name()
        ))),
        (Some(c), None) if !c.uses_model() => Ok(classical(c)),
        (None, Some(name)) => {
            let m = load(name)?;
            let method = match m.meta.inputs {
                Inputs::Hybrid => Method::Hybrid,
                Inputs::Movie => Method::TemporalNet,
                Inputs::Noisy => Method::Net,
            };
            Ok(Resolved {
                method,
                model: Some(m),
                model_name: Some(name.to_string()),
                defaulted: false,
            })
        }
        (method, name) => {
            let defaulted = method.is_none() && name.is_none();
            let method = method.unwrap_or(DEFAULT_METHOD);
            let name = name.unwrap_or(method.default_model());
            let m = load(name)?;
            if m.meta.inputs != method.inputs() {
                return Err(Error::Model(format!(
                    "--model {name}: a {} model, not one for --method {}",
                    m.meta.inputs.name(),
                    match method {
                        Method::Hybrid => "hybrid (train one with `emccd train --inputs hybrid`)",
                        Method::TemporalNet =>
                            "temporal-net (train one with `emccd train --inputs movie`)",
                        other => other.name(),
                    }
                )));
            }
            Ok(Resolved {
                method,
                model: Some(m),
                model_name: Some(name.to_string()),
                defaulted,
            })
        }
    }
}

/// The warning a request deserves when its model was trained for another camera profile
/// (its fingerprint differs from `profile`'s), if it was.
pub fn profile_mismatch(model: &Model, profile: &CameraProfile) -> Option<String> {
    let profile_fp = profile.fingerprint_hex();
    (model.meta.profile_fingerprint != profile_fp).then(|| {
        format!(
            "the model was trained for profile {} and is applied through profile {profile_fp}; the network input is camera-independent, but fine-tuning on this camera (`emccd train --init`) may gain a little",
            model.meta.profile_fingerprint
        )
    })
}

/// What turns one raw frame into the output: the method, model and profile, fixed for a run.
pub struct Denoiser<'a> {
    /// The camera profile the frames are corrected and described with.
    pub profile: &'a CameraProfile,
    /// The method.
    pub method: Method,
    /// The network, for the methods that run one.
    pub model: Option<&'a Model>,
    /// Tiling of large frames.
    pub tiling: Tiling,
    /// Orientations the network is averaged over (1, 2, 4 or 8).
    pub ensemble: usize,
    /// The output's units.
    pub units: Units,
    /// Frames each side of a frame that a temporal method uses (0 for the others: each frame
    /// alone).
    pub window: usize,
}

/// The frames each side `--method temporal` uses when no window is given: 25 frames in all.
/// Chosen on the movie suite's validation camera (`tools/movie_suite.py --cameras tune`,
/// docs/journal.md), on 32-frame movies so that a frame in the middle has its 12 each side: over
/// 6, 8 / 10 / 12 each side gave +0.12 / +0.17 / +0.19 dB (still, bleaching and jittered scenes
/// up to +1.3, the deformation −0.4 / −0.8 / −1.1 at 1 e⁻), and once a block's own moves were
/// held to what the guides' noise cannot propose (`temporal`'s move gain), 12 each side +0.39 dB
/// over 6 with the same gain. Before, 6 each side was chosen over 4 (+0.14 dB) and 4 over 2.
/// Its cost: on camera A's 256² rotation (larger moves at the corners) far frames lost up to
/// 0.9 dB against 6 each side, before small moves confirmed by the blocks around won back
/// +0.7 dB of it at 0.5 e⁻ (docs/results.md#movies).
pub const DEFAULT_WINDOW: usize = 12;

/// The most frames each side a temporal method takes (33 frames held at a time).
pub const MAX_WINDOW: usize = 16;

/// How far beyond its A/D range (a multiple of the range, either sign) a raw value is taken for
/// no reading at all: far past any bias-subtracted or summed float export (a few times the
/// range), near no value a damaged file's 1e20 or 3e38 gets.
pub const IMPOSSIBLE: f64 = 64.0;

impl Denoiser<'_> {
    /// An error when the method needs a model and has none, or has one it does not run.
    pub(crate) fn check_model(&self) -> Result<()> {
        if self.method.uses_model() != self.model.is_some() {
            return Err(Error::Model(format!(
                "--method {} {} a model",
                self.method.name(),
                if self.method.uses_model() {
                    "needs"
                } else {
                    "takes no"
                }
            )));
        }
        Ok(())
    }

    /// An error naming the first pixel of `raw` that is not a finite number, or that no camera
    /// of this profile produces (beyond [`IMPOSSIBLE`] times its A/D range either way: a
    /// float file's 1e20 spoiled the whole frame for the networks, whose input is normalized
    /// by the frame), if one is.
    pub(crate) fn check_finite(&self, raw: &[f32]) -> Result<()> {
        let width = self.profile.width.max(1);
        let bound = IMPOSSIBLE * self.profile.adc_max_dn;
        let at = |i: usize| (i % width, i / width);
        if let Some(i) = raw.iter().position(|v| !v.is_finite()) {
            let (x, y) = at(i);
            return Err(Error::Data(format!(
                "a non-finite value at pixel ({x}, {y}) ({}; a float64 beyond float32's ±3.4e38 reads as ±inf)",
                raw[i]
            )));
        }
        if let Some(i) = raw.iter().position(|&v| (v as f64).abs() > bound) {
            let (x, y) = at(i);
            return Err(Error::Data(format!(
                "the value {:e} at pixel ({x}, {y}) is no camera reading: the profile's A/D converter reads 0 to {} DN, and values beyond ±{bound:e} are refused (a damaged or rescaled file?)",
                raw[i], self.profile.adc_max_dn
            )));
        }
        Ok(())
    }

    /// Denoises one raw frame (DN, the profile's size) taken with `exposure_s`; a frame with a
    /// non-finite value is an error naming the pixel.
    pub fn run(&self, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        self.check_finite(raw)?;
        self.check_model()?;
        let pre = self.preprocess(raw, exposure_s)?;
        let mut d = self.estimate(&pre, exposure_s)?;
        let to_units = self.units.factor(self.profile)?;
        if to_units != 1.0 {
            d.iter_mut().for_each(|v| *v *= to_units);
        }
        Ok(d)
    }

    /// The network run through this profile, tiling and ensemble.
    pub(crate) fn inference<'m>(&'m self, model: &'m Model) -> Inference<'m> {
        Inference {
            model,
            profile: self.profile,
            tiling: self.tiling,
            ensemble: self.ensemble,
        }
    }

    /// A raw frame preprocessed (DN above bias): blooming and the fixed pattern removed, unless
    /// the model was made for an ablation that skips them.
    pub(crate) fn preprocess(&self, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        match self.model {
            Some(m) => self.inference(m).preprocess(raw, exposure_s),
            None => Ok(preprocess(self.profile, raw, exposure_s)?),
        }
    }

    /// The method's estimate of one preprocessed frame (DN above bias) alone: what a per-frame
    /// method outputs, and what a temporal one tracks motion on and falls back to.
    pub(crate) fn estimate(&self, pre: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        match (self.model, self.method.classical()) {
            (Some(m), _) if self.method == Method::TemporalNet => {
                // A lone frame: the frame in every slot of the window.
                let window = vec![pre; m.meta.inputs.frames()];
                self.inference(m).denoise_window(&window, exposure_s)
            }
            (Some(m), _) => {
                let net = self.inference(m).denoise_preprocessed(pre, exposure_s)?;
                if self.method == Method::Blend {
                    let iv = Classical::Ivst.of_frame(self.profile, pre, exposure_s)?;
                    Ok(net.iter().zip(&iv).map(|(a, b)| 0.5 * (a + b)).collect())
                } else {
                    Ok(net)
                }
            }
            (None, Some(base)) => Ok(base.of_frame(self.profile, pre, exposure_s)?),
            (None, None) if self.method == Method::Temporal => {
                let noise = emccd_classical::frame::vst_params(self.profile, exposure_s)?;
                let p = self.profile;
                Ok(emccd_classical::temporal::single(
                    pre, p.width, p.height, noise,
                ))
            }
            (None, None) => Ok(pre.to_vec()),
        }
    }
}
