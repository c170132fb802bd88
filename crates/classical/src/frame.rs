//! A camera frame denoised through its profile: preprocessing (paper eq. 4: `B⁻¹(D) − FPN_t`),
//! the profile's Poisson–Gaussian noise at the frame's exposure, and the classical estimate of
//! the photo-signal in DN above bias (what `denoise --method bm3d|ivst` returns and what a
//! hybrid network refines).

use emccd_camera::Ablation;
use emccd_profile::{CameraProfile, PoissonGaussian};
use serde::{Deserialize, Serialize};

use crate::vst::{bm3d_adaptive, bm3d_iterative, bm3d_poisson_gaussian, Pass};
use crate::{Error, Result};

/// A classical estimate of a preprocessed frame: the two this project uses (and the one a
/// refinement network is given and corrects, recorded as `base` in its model file).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Classical {
    /// BM3D after the generalized Anscombe transform, one pass (files without the key).
    #[default]
    #[cfg_attr(
        feature = "clap",
        value(help = "BM3D after the generalized Anscombe transform, one pass")
    )]
    Bm3d,
    /// BM3D with iterative variance stabilization and binning, the passes chosen from the
    /// frame's light level ([`bm3d_adaptive`]): better below a few counts.
    #[cfg_attr(
        feature = "clap",
        value(
            help = "BM3D with iterative variance stabilization: better below a few photoelectrons"
        )
    )]
    Ivst,
}

impl Classical {
    /// The estimate of a preprocessed frame (DN above bias, `w × h`) with noise `p`.
    pub fn estimate(self, dn: &[f32], w: usize, h: usize, p: PoissonGaussian) -> Vec<f32> {
        match self {
            Classical::Bm3d => bm3d_poisson_gaussian(dn, w, h, p),
            Classical::Ivst => bm3d_adaptive(dn, w, h, p),
        }
    }

    /// The estimate of a preprocessed frame (DN above bias) of the profile's size, with the
    /// profile's noise at `exposure_s`.
    pub fn of_frame(self, p: &CameraProfile, dn: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        usable(p, dn.len(), exposure_s)?;
        Ok(self.estimate(dn, p.width, p.height, vst_params(p, exposure_s)?))
    }

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Classical::Bm3d => "bm3d",
            Classical::Ivst => "ivst",
        }
    }

    /// Every classical estimate, for parsers.
    pub const ALL: [Classical; 2] = [Classical::Bm3d, Classical::Ivst];
}

impl std::str::FromStr for Classical {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Classical, String> {
        Classical::ALL
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| format!("{s:?}: the base estimate is bm3d or ivst"))
    }
}

/// Checks that the profile has what denoising needs: a slope and bias maps (a gain-series
/// calibration has neither).
pub fn can_denoise(p: &CameraProfile) -> Result<()> {
    p.require_complete()
        .map_err(|e| Error(format!("this profile cannot denoise: {e}")))
}

/// Checks that the profile can correct and describe a frame of `len` pixels at `exposure_s`:
/// it has a slope and bias maps (a gain-series calibration has neither), the sizes agree, and
/// the exposure is a positive number of seconds (a header or flag can say anything).
pub fn usable(p: &CameraProfile, len: usize, exposure_s: f64) -> Result<()> {
    can_denoise(p)?;
    if len != p.len() {
        return Err(Error(format!(
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
pub fn vst_params(p: &CameraProfile, exposure_s: f64) -> Result<PoissonGaussian> {
    usable(p, p.len(), exposure_s)?;
    Ok(p.vst_params(exposure_s)?)
}

/// BM3D after the generalized Anscombe transform, with the exact unbiased inverse, on a
/// preprocessed frame (DN above bias) of the profile's size.
pub fn bm3d_estimate(p: &CameraProfile, dn: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
    Classical::Bm3d.of_frame(p, dn, exposure_s)
}

/// Iterative BM3D with the given passes ([`bm3d_iterative`]) instead of the schedule
/// [`Classical::Ivst`] picks (for comparing schedules).
pub fn bm3d_passes(
    p: &CameraProfile,
    dn: &[f32],
    exposure_s: f64,
    passes: &[Pass],
) -> Result<Vec<f32>> {
    usable(p, dn.len(), exposure_s)?;
    Ok(bm3d_iterative(
        dn,
        p.width,
        p.height,
        vst_params(p, exposure_s)?,
        passes,
    ))
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
