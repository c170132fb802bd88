//! A denoising request resolved to its method and model ([`resolve`]), and [`Denoiser`], which
//! turns one raw frame into the output. The CLI, the Python package and library users share
//! this, so `emccd denoise` and `emccd.denoise` give the same frames for the same request.

use emccd_classical::frame::preprocess;
use emccd_nn::tile::Tiling;
use emccd_nn::{Classical, Error, Inference, Inputs, Model, Result};
use emccd_profile::CameraProfile;

use crate::method::{Method, Units, DEFAULT_METHOD};

/// What a request runs ([`resolve`]).
pub struct Resolved {
    /// The method.
    pub method: Method,
    /// The network, for the methods that run one.
    pub model: Option<Model>,
    /// The model argument it was loaded from, as given or defaulted (a bundled name or a
    /// file): what provenance names and hashes.
    pub model_name: Option<String>,
}

impl Resolved {
    /// The warning for running its model on frames of `profile`'s camera when the model was
    /// trained for another ([`profile_mismatch`]); none for a classical method.
    pub fn profile_warning(&self, profile: &CameraProfile) -> Option<String> {
        self.model
            .as_ref()
            .and_then(|m| profile_mismatch(m, profile))
    }

    /// The frames each side this method uses: `asked`, or [`DEFAULT_WINDOW`] for a temporal
    /// method and 0 for the others; an error when a window is asked of a method that denoises
    /// each frame alone.
    pub fn window(&self, asked: Option<usize>) -> Result<usize> {
        match (self.method.temporal(), asked) {
            (true, w) => Ok(w.unwrap_or(DEFAULT_WINDOW)),
            (false, None | Some(0)) => Ok(0),
            (false, Some(_)) => Err(Error::Model(format!(
                "--window: --method {} denoises each frame alone; --method temporal and \
                 temporal-blend use the neighbouring frames",
                self.method.name()
            ))),
        }
    }

    /// What runs this method and model on frames of `profile`'s camera, with `window` frames
    /// each side for a temporal method ([`Resolved::window`]); an error when the profile lacks
    /// what denoising needs (a gain-series calibration has no slope or bias maps).
    pub fn denoiser<'a>(
        &'a self,
        profile: &'a CameraProfile,
        tiling: Tiling,
        ensemble: usize,
        units: Units,
        window: usize,
    ) -> Result<Denoiser<'a>> {
        emccd_classical::frame::can_denoise(profile)?;
        Ok(Denoiser {
            profile,
            method: self.method,
            model: self.model.as_ref(),
            tiling,
            ensemble,
            units,
            window,
        })
    }
}

/// The method and model a request runs: `method` and `model` as given (either may be absent),
/// with `load` turning a model argument into a model ([`crate::bundled::load`], or a loader that also knows
/// models embedded in a program). The model a method takes by default is `hybrid` for
/// [`Method::Hybrid`], `lowlight` for [`Method::Blend`], `default` for [`Method::Net`]; a model alone picks the method it was
/// trained for. An error where a model does not fit the method.
pub fn resolve(
    method: Option<Method>,
    model: Option<&str>,
    load: impl Fn(&str) -> Result<Model>,
) -> Result<Resolved> {
    let hybrid = |m: &Model| m.meta.inputs == Inputs::Hybrid;
    let classical = |method| Resolved {
        method,
        model: None,
        model_name: None,
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
            let method = if hybrid(&m) {
                Method::Hybrid
            } else {
                Method::Net
            };
            Ok(Resolved {
                method,
                model: Some(m),
                model_name: Some(name.to_string()),
            })
        }
        (method, name) => {
            let method = method.unwrap_or(DEFAULT_METHOD);
            let name = name.unwrap_or(match method {
                Method::Hybrid => "hybrid",
                Method::Blend | Method::TemporalBlend => "lowlight",
                _ => "default",
            });
            let m = load(name)?;
            if hybrid(&m) != (method == Method::Hybrid) {
                return Err(Error::Model(format!(
                    "--model {name}: a {} model, not one for --method {}",
                    m.meta.inputs.name(),
                    match method {
                        Method::Hybrid => "hybrid (train one with `emccd train --inputs hybrid`)",
                        other => other.name(),
                    }
                )));
            }
            Ok(Resolved {
                method,
                model: Some(m),
                model_name: Some(name.to_string()),
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

/// The frames each side `--method temporal` uses when no window is given: 5 frames in all,
/// where a still scene at 1 photoelectron per pixel gains about 2.6 dB over one frame and a
/// drift of up to 2.5 px per frame is still followed (`emccd-classical`'s temporal tests).
pub const DEFAULT_WINDOW: usize = 2;

/// The most frames each side a temporal method takes (33 frames held at a time).
pub const MAX_WINDOW: usize = 16;

impl Denoiser<'_> {
    /// An error naming the first pixel of `raw` that is not a finite number, if one is.
    pub(crate) fn check_finite(&self, raw: &[f32]) -> Result<()> {
        let width = self.profile.width.max(1);
        match raw.iter().position(|v| !v.is_finite()) {
            Some(i) => Err(Error::Data(format!(
                "a non-finite value at pixel ({}, {})",
                i % width,
                i / width
            ))),
            None => Ok(()),
        }
    }

    /// Denoises one raw frame (DN, the profile's size) taken with `exposure_s`; a frame with a
    /// non-finite value is an error naming the pixel.
    pub fn run(&self, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        self.check_finite(raw)?;
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
        let pre = self.preprocess(raw, exposure_s)?;
        let mut d = self.estimate(&pre, exposure_s)?;
        let to_units = self.units.factor(self.profile)?;
        if to_units != 1.0 {
            d.iter_mut().for_each(|v| *v *= to_units);
        }
        Ok(d)
    }

    /// The network run through this profile, tiling and ensemble.
    fn inference<'m>(&'m self, model: &'m Model) -> Inference<'m> {
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
            (Some(m), _) => {
                let net = self.inference(m).denoise_preprocessed(pre, exposure_s)?;
                if self.method.blends() {
                    let iv = Classical::Ivst.of_frame(self.profile, pre, exposure_s)?;
                    Ok(net.iter().zip(&iv).map(|(a, b)| 0.5 * (a + b)).collect())
                } else {
                    Ok(net)
                }
            }
            (None, Some(base)) => Ok(base.of_frame(self.profile, pre, exposure_s)?),
            (None, None) => Ok(pre.to_vec()),
        }
    }

    /// A temporal method's estimate of a motion-compensated `mean` of about `frames` frames
    /// (DN above bias) at noise `noise` of one frame: iterative BM3D at a mean's noise, and for
    /// `temporal-blend` averaged with the network's estimate of the frames' sum (what the
    /// network knows: one frame at `frames` times the light), divided back.
    pub(crate) fn estimate_mean(
        &self,
        mean: &[f32],
        frames: f64,
        noise: emccd_profile::PoissonGaussian,
        exposure_s: f64,
    ) -> Result<Vec<f32>> {
        let (w, h) = (self.profile.width, self.profile.height);
        let iv = emccd_classical::vst::bm3d_adaptive(mean, w, h, noise.of_mean(frames));
        match self.model {
            Some(m) if self.method.blends() => {
                let sum: Vec<f32> = mean.iter().map(|v| v * frames as f32).collect();
                let net = self.inference(m).denoise_preprocessed(&sum, exposure_s)?;
                let back = 1.0 / frames as f32;
                Ok(net
                    .iter()
                    .zip(&iv)
                    .map(|(a, b)| 0.5 * (a * back + b))
                    .collect())
            }
            _ => Ok(iv),
        }
    }
}
