//! Denoising a raw frame: preprocess with the profile (paper eq. 4: `B⁻¹(D) − FPN_t`), build the
//! camera-independent input, run the network tiled, and return the photo-signal in DN above bias.
//! A hybrid network first gets the classical estimate its model file names (one BM3D + GAT pass,
//! [`bm3d_estimate`], or iterative BM3D, [`crate::Base`]) and refines it.

use burn::prelude::*;
use emccd_camera::Ablation;
use emccd_profile::CameraProfile;

use crate::model::{Denoiser, Inputs};
use crate::norm::{prepare, prepare_hybrid, signal_scale};
use crate::tile::{run_ensemble, Planes, Tiling};
use crate::{Error, Result};

/// A model ready for inference with the profile it is applied through.
pub struct Pipeline<'a> {
    /// Network (inference copy).
    pub model: &'a Denoiser,
    /// Camera profile.
    pub profile: &'a CameraProfile,
    /// Tiling.
    pub tiling: Tiling,
    /// Orientations averaged (geometric self-ensemble, 1–8; 1 = plain inference).
    pub ensemble: usize,
    /// Device.
    pub device: Device,
}

/// Checks that the profile has what denoising needs: a slope and bias maps (a gain-series
/// calibration has neither).
pub(crate) fn can_denoise(p: &CameraProfile) -> Result<()> {
    p.require_complete()
        .map_err(|e| Error::Data(format!("this profile cannot denoise: {e}")))
}

/// Checks that the profile can correct and describe a frame of `len` pixels at `exposure_s`:
/// it has a slope and bias maps (a gain-series calibration has neither), the sizes agree, and
/// the exposure is a positive number of seconds (a header or flag can say anything).
fn usable(p: &CameraProfile, len: usize, exposure_s: f64) -> Result<()> {
    can_denoise(p)?;
    if len != p.len() {
        return Err(Error::Data(format!(
            "frame has {len} pixels, the profile's sensor {}×{} = {}",
            p.width,
            p.height,
            p.len()
        )));
    }
    Ok(emccd_profile::check_exposure(exposure_s)?)
}

/// The preprocessed frame (DN above bias) at `exposure_s`: blooming and FPN removed.
pub fn preprocess(p: &CameraProfile, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
    preprocess_ablated(p, raw, exposure_s, Ablation::default())
}

/// [`preprocess`] without the corrections `ablate` switches off (the paper's ablations): `fpn`
/// subtracts the bias frame of the shortest exposure instead of the exposure's modeled fixed
/// pattern; `blooming` leaves the blooming in.
pub fn preprocess_ablated(
    p: &CameraProfile,
    raw: &[f32],
    exposure_s: f64,
    ab: Ablation,
) -> Result<Vec<f32>> {
    usable(p, raw.len(), exposure_s)?;
    let fpn = if !ab.fpn {
        p.maps.fpn_base.clone()
    } else {
        let mut f = vec![0f32; p.len()];
        p.fpn_at(exposure_s, &mut f);
        f
    };
    let x = if !ab.blooming {
        0.0
    } else {
        p.blooming_factor(exposure_s)
    };
    let mut d = raw.to_vec();
    emccd_profile::preprocess(&mut d, p.width, x, &fpn);
    Ok(d)
}

/// The profile's Poisson–Gaussian noise at `exposure_s` ([`CameraProfile::vst_params`]),
/// with [`usable`]'s message when the profile cannot describe a frame.
pub(crate) fn vst_params(
    p: &CameraProfile,
    exposure_s: f64,
) -> Result<emccd_profile::PoissonGaussian> {
    usable(p, p.len(), exposure_s)?;
    Ok(p.vst_params(exposure_s)?)
}

/// BM3D after the generalized Anscombe transform, with the exact unbiased inverse, on a
/// preprocessed frame (DN above bias) of the profile's size.
pub fn bm3d_estimate(p: &CameraProfile, dn: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
    classical_estimate(p, dn, exposure_s, crate::Base::Bm3d)
}

/// The classical estimate `base` of a preprocessed frame (DN above bias) of the profile's size,
/// with the profile's noise parameters: what `denoise --method bm3d|ivst` returns, and what a
/// hybrid network refines.
pub fn classical_estimate(
    p: &CameraProfile,
    dn: &[f32],
    exposure_s: f64,
    base: crate::Base,
) -> Result<Vec<f32>> {
    usable(p, dn.len(), exposure_s)?;
    Ok(base.estimate(dn, p.width, p.height, vst_params(p, exposure_s)?))
}

/// Iterative BM3D with the given passes ([`emccd_eval::vst::bm3d_iterative`]) instead of the
/// schedule [`crate::Base::Ivst`] picks (for comparing schedules).
pub fn bm3d_passes(
    p: &CameraProfile,
    dn: &[f32],
    exposure_s: f64,
    passes: &[emccd_eval::vst::Pass],
) -> Result<Vec<f32>> {
    usable(p, dn.len(), exposure_s)?;
    Ok(emccd_eval::vst::bm3d_iterative(
        dn,
        p.width,
        p.height,
        vst_params(p, exposure_s)?,
        passes,
    ))
}

impl<'a> Pipeline<'a> {
    /// Plain inference of `model` through `profile`: default tiling, no self-ensemble, on
    /// [`crate::device`].
    pub fn new(model: &'a Denoiser, profile: &'a CameraProfile) -> Pipeline<'a> {
        Pipeline {
            model,
            profile,
            tiling: Tiling::default(),
            ensemble: 1,
            device: crate::device(),
        }
    }
}

impl Pipeline<'_> {
    /// The preprocessed frame (DN above bias) at `exposure_s`: blooming and FPN removed, unless
    /// the model was made for an ablation that skips them.
    pub fn preprocess(&self, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        preprocess_ablated(self.profile, raw, exposure_s, self.model.meta.ablate)
    }

    /// Denoises a preprocessed frame (DN above bias) of the profile's size.
    pub fn denoise_preprocessed(&self, dn: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        let p = self.profile;
        usable(p, dn.len(), exposure_s)?;
        let slope = p.slope()?;
        let rn = p.read_noise_near(exposure_s);
        let inputs = self.model.meta.inputs;
        let prep = match inputs {
            Inputs::Noisy => prepare(dn, p.width, slope, rn, self.model.meta.scale),
            Inputs::Hybrid => {
                let est = classical_estimate(p, dn, exposure_s, self.model.meta.base)?;
                let scale =
                    signal_scale(&est.iter().map(|v| v / slope as f32).collect::<Vec<f32>>());
                prepare_hybrid(dn, &est, slope, rn, scale)
            }
        };
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
            &self.device,
        );
        Ok(out.into_iter().map(|v| v * prep.to_dn).collect())
    }

    /// Preprocesses and denoises a raw frame.
    pub fn denoise_raw(&self, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        let d = self.preprocess(raw, exposure_s)?;
        self.denoise_preprocessed(&d, exposure_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ablations_switch_off_only_their_correction() {
        let p = emccd_profile::default_profile()
            .crop(emccd_profile::Roi::corner(32, 32))
            .unwrap();
        let t = 0.002;
        let raw: Vec<f32> = (0..p.len())
            .map(|i| 300.0 + (i % 7) as f32 * 20.0)
            .collect();
        let full = preprocess(&p, &raw, t).unwrap();
        let none = preprocess_ablated(&p, &raw, t, "fpn,blooming".parse().unwrap()).unwrap();
        // Both off: the raw frame minus the shortest exposure's bias frame, nothing else.
        for ((n, r), b) in none.iter().zip(&raw).zip(&p.maps.fpn_base) {
            assert!((n - (r - b)).abs() < 1e-4);
        }
        // Blooming off alone: the raw frame minus this exposure's FPN.
        let mut fpn = vec![0f32; p.len()];
        p.fpn_at(t, &mut fpn);
        let nb = preprocess_ablated(&p, &raw, t, "blooming".parse().unwrap()).unwrap();
        for ((n, r), f) in nb.iter().zip(&raw).zip(&fpn) {
            assert!((n - (r - f)).abs() < 1e-4);
        }
        // The full preprocessing removes blooming too (x(2 ms) ≈ 6 %): it differs from both.
        assert!(full.iter().zip(&nb).any(|(a, b)| (a - b).abs() > 1.0));
    }

    /// Profiles without bias maps (a gain-series calibration) and exposures that are not a
    /// positive number of seconds are errors, not panics or NaN frames.
    #[test]
    fn unusable_profiles_and_exposures_are_errors() {
        let p = emccd_profile::default_profile()
            .crop(emccd_profile::Roi::corner(16, 16))
            .unwrap();
        let raw = vec![300.0; p.len()];
        for t in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = preprocess(&p, &raw, t).unwrap_err().to_string();
            assert!(e.contains("positive number of seconds"), "{t}: {e}");
            assert!(bm3d_estimate(&p, &raw, t).is_err(), "{t}");
        }
        let mut bare = p.clone();
        bare.exposures_s.clear();
        bare.maps.read_noise.clear();
        bare.maps.fpn_base.clear();
        bare.maps.fpn_theta.clear();
        bare.validate().unwrap();
        for e in [
            preprocess(&bare, &raw, 0.01).unwrap_err(),
            bm3d_estimate(&bare, &raw, 0.01).unwrap_err(),
        ] {
            assert!(e.to_string().contains("cannot denoise"), "{e}");
        }
        assert!(preprocess(&p, &raw[1..], 0.01)
            .unwrap_err()
            .to_string()
            .contains("pixels"));
    }
}
