//! A network applied to a raw frame through its camera profile: preprocess with the profile
//! (paper eq. 4: `B⁻¹(D) − FPN_t`), build the camera-independent input, run the network tiled,
//! and return the photo-signal in DN above bias. A hybrid network first gets the classical
//! estimate its model file names ([`crate::Classical`]) and refines it.

use emccd_profile::CameraProfile;

use crate::model::{Inputs, Model};
use crate::norm::{prepare, prepare_hybrid, prepare_movie, signal_scale, Prepared};
use crate::tile::{run_ensemble, Planes, Tiling};
use crate::{Error, Result};
use emccd_classical::frame::{preprocess_ablated, usable};

/// A model ready for inference with the profile it is applied through.
pub struct Inference<'a> {
    /// Network (inference copy).
    pub model: &'a Model,
    /// Camera profile.
    pub profile: &'a CameraProfile,
    /// Tiling.
    pub tiling: Tiling,
    /// Orientations averaged (geometric self-ensemble, 1–8; 1 = plain inference).
    pub ensemble: usize,
}

impl<'a> Inference<'a> {
    /// Plain inference of `model` through `profile`: default tiling, no self-ensemble, on the
    /// model's device.
    pub fn new(model: &'a Model, profile: &'a CameraProfile) -> Inference<'a> {
        Inference {
            model,
            profile,
            tiling: Tiling::default(),
            ensemble: 1,
        }
    }
}

impl Inference<'_> {
    /// The preprocessed frame (DN above bias) at `exposure_s`: blooming and FPN removed, unless
    /// the model was made for an ablation that skips them.
    pub fn preprocess(&self, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        Ok(preprocess_ablated(
            self.profile,
            raw,
            exposure_s,
            self.model.meta.ablate,
        )?)
    }

    /// Denoises a preprocessed frame (DN above bias) of the profile's size with a single-frame
    /// network (a temporal one takes [`Inference::denoise_window`]).
    pub fn denoise_preprocessed(&self, dn: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        let p = self.profile;
        usable(p, dn.len(), exposure_s)?;
        let slope = p.slope()?;
        let rn = p.read_noise_near(exposure_s);
        let prep = match self.model.meta.inputs {
            Inputs::Noisy => prepare(dn, p.width, slope, rn, self.model.meta.scale),
            Inputs::Hybrid => {
                let est = self.model.meta.base.of_frame(p, dn, exposure_s)?;
                let scale =
                    signal_scale(&est.iter().map(|v| v / slope as f32).collect::<Vec<f32>>());
                prepare_hybrid(dn, &est, slope, rn, scale)
            }
            Inputs::Movie => {
                return Err(Error::Model(
                    "a temporal network denoises a frame with the frames around it, not alone"
                        .into(),
                ))
            }
        };
        Ok(self.run(prep))
    }

    /// Denoises the centre frame of `window`, preprocessed frames (DN above bias) of the
    /// profile's size in time order, with a temporal network ([`Inputs::Movie`]: the frame and
    /// [`crate::MOVIE_WINDOW`] each side; a movie's ends filled by [`crate::norm::mirror`]).
    pub fn denoise_window(&self, window: &[&[f32]], exposure_s: f64) -> Result<Vec<f32>> {
        let p = self.profile;
        let inputs = self.model.meta.inputs;
        if inputs != Inputs::Movie {
            return Err(Error::Model(format!(
                "a {} network denoises frames alone, not a movie's window (--method temporal-net \
                 takes a temporal model, `emccd train --inputs movie`)",
                inputs.name()
            )));
        }
        if window.len() != inputs.frames() {
            return Err(Error::Model(format!(
                "a window of {} frames for a network that takes {}",
                window.len(),
                inputs.frames()
            )));
        }
        for f in window {
            usable(p, f.len(), exposure_s)?;
        }
        let prep = prepare_movie(
            window,
            window.len() / 2,
            p.width,
            p.slope()?,
            p.read_noise_near(exposure_s),
            self.model.meta.scale,
        );
        Ok(self.run(prep))
    }

    /// The network over a prepared frame, tiled and self-ensembled, back in DN.
    fn run(&self, prep: Prepared) -> Vec<f32> {
        let p = self.profile;
        let inputs = self.model.meta.inputs;
        let multiple = self.model.meta.multiple();
        let planes = Planes {
            data: &prep.input,
            channels: inputs.channels(),
            width: p.width,
            height: p.height,
        };
        let out = run_ensemble(
            &self.model.net,
            planes,
            multiple,
            self.tiling,
            self.ensemble,
            self.model.device(),
        );
        out.into_iter().map(|v| v * prep.to_dn).collect()
    }

    /// Preprocesses and denoises a raw frame.
    pub fn denoise_raw(&self, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        let d = self.preprocess(raw, exposure_s)?;
        self.denoise_preprocessed(&d, exposure_s)
    }
}
