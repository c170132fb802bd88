//! The virtual camera: the full eq. 1 with a known truth, used to write calibration acquisitions
//! and noisy/clean pairs that every estimator and network is tested against.
//!
//! Per pixel `p` and exposure `t`:
//! electrons `n ~ Poisson(QE·φ_p + dark_p·t + CIC)` → EM register `m ~ Gamma(n, G)` →
//! `Y = m/c + FPN_t(p)` (DN) → blooming `B[Y] = Y + x_t·colmean(Y)` →
//! `D = round(B[Y] + N(0, σ_p²))`, clipped to the ADC range. `c = 2G/s` is the electrons per DN
//! that makes the photon-transfer slope equal the profile's `s` (f² = 2 for a full EM register).

use emccd_profile::CameraProfile;
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::noise::em_register;
use crate::rng::stream;
use crate::Error;
use emccd_profile::column_means;

/// Physical parameters that a profile does not hold (with the `clap` feature, `emccd
/// simulate`'s physics flags; the hot-pixel seed is derived from the run's, [`PhysicalParams::seeded`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct PhysicalParams {
    /// Quantum efficiency (photoelectrons per photon).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = PhysicalParams::default().qe))]
    pub qe: f64,
    /// Dark current of ordinary pixels, e⁻ per pixel per second.
    #[cfg_attr(feature = "clap", arg(long = "dark", value_name = "DARK", default_value_t = PhysicalParams::default().dark_e_per_s))]
    pub dark_e_per_s: f64,
    /// Clock-induced charge, e⁻ per pixel per frame.
    #[cfg_attr(feature = "clap", arg(long = "cic", value_name = "CIC", default_value_t = PhysicalParams::default().cic_e))]
    pub cic_e: f64,
    /// Fraction of pixels that are hot (with the hot-pixel dark current).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = PhysicalParams::default().hot_fraction))]
    pub hot_fraction: f64,
    /// Dark current of hot pixels, e⁻ per pixel per second.
    #[cfg_attr(feature = "clap", arg(long = "hot-dark", value_name = "HOT_DARK", default_value_t = PhysicalParams::default().hot_dark_e_per_s))]
    pub hot_dark_e_per_s: f64,
    /// Seed for the hot-pixel positions.
    #[cfg_attr(feature = "clap", arg(skip = PhysicalParams::default().seed))]
    pub seed: u64,
}

impl PhysicalParams {
    /// The default physics with the hot pixels of a run seeded `run_seed` (what `emccd
    /// simulate --seed` and Python's `simulate_pairs(seed=…)` build): the same seed, the same
    /// camera, whichever front end asks. The hot-pixel seed is derived from the run's so that
    /// it differs from the noise streams the run draws with it.
    pub fn seeded(run_seed: u64) -> PhysicalParams {
        PhysicalParams {
            seed: run_seed ^ 0x5eed,
            ..PhysicalParams::default()
        }
    }
}

impl Default for PhysicalParams {
    fn default() -> Self {
        PhysicalParams {
            qe: 0.9,
            dark_e_per_s: 0.001,
            cic_e: 0.005,
            hot_fraction: 2e-4,
            hot_dark_e_per_s: 50.0,
            seed: 7,
        }
    }
}

/// A simulated EMCCD with a known truth.
#[derive(Clone, Debug)]
pub struct VirtualCamera {
    /// The truth profile (slope, FPN, read noise, blooming).
    pub profile: CameraProfile,
    /// Physical parameters.
    pub physics: PhysicalParams,
    /// EM gain G.
    pub em_gain: f64,
    /// Electrons per DN after the EM register, c = 2G/s.
    pub e_per_dn: f64,
    /// Dark current per pixel (hot pixels included), e⁻/s.
    pub dark_map: Vec<f32>,
    /// Indices of hot pixels.
    pub hot_pixels: Vec<usize>,
}

/// Everything that depends only on the exposure, computed once per stack.
pub struct Exposure<'a> {
    cam: &'a VirtualCamera,
    /// Exposure time, s.
    pub exposure_s: f64,
    /// True FPN at this exposure, DN.
    pub fpn: Vec<f32>,
    /// True blooming factor at this exposure.
    pub blooming_x: f64,
    /// True read-noise std map at this exposure, DN.
    pub read_noise: Vec<f32>,
}

impl VirtualCamera {
    /// Builds a camera whose truth is `profile`, with the physics in `physics`.
    pub fn new(profile: CameraProfile, physics: PhysicalParams) -> Result<VirtualCamera, Error> {
        profile
            .validate()
            .map_err(|e| Error::Parameter(e.to_string()))?;
        profile
            .require_complete()
            .map_err(|e| Error::Parameter(format!("virtual camera: {e}")))?;
        let p = &physics;
        // Upper bounds too: a dark current of 10³⁰ e⁻/s is not a camera, and its Poisson draws
        // have no sampler.
        for (name, v, lo, hi) in [
            ("qe", p.qe, f64::MIN_POSITIVE, 1.0),
            ("dark (e⁻ per pixel per s)", p.dark_e_per_s, 0.0, 1e5),
            ("cic (e⁻ per pixel per frame)", p.cic_e, 0.0, 10.0),
            ("hot-fraction", p.hot_fraction, 0.0, 0.999),
            (
                "hot-dark (e⁻ per pixel per s)",
                p.hot_dark_e_per_s,
                0.0,
                1e6,
            ),
        ] {
            if !(v >= lo && v <= hi) {
                return Err(Error::Parameter(format!(
                    "virtual camera: {name} must be {} to {}, got {}",
                    emccd_profile::number(lo.max(0.0)),
                    emccd_profile::number(hi),
                    emccd_profile::number(v)
                )));
            }
        }
        let g = profile.em_gain.max(1.0);
        let c = 2.0 * g
            / profile
                .slope()
                .map_err(|e| Error::Parameter(e.to_string()))?;
        let n = profile.len();
        let mut rng = stream(p.seed, 0x407, 0);
        let mut dark_map = vec![p.dark_e_per_s as f32; n];
        let mut hot_pixels = Vec::new();
        for (i, d) in dark_map.iter_mut().enumerate() {
            if rng.random::<f64>() < p.hot_fraction {
                *d = p.hot_dark_e_per_s as f32;
                hot_pixels.push(i);
            }
        }
        Ok(VirtualCamera {
            profile,
            physics,
            em_gain: g,
            e_per_dn: c,
            dark_map,
            hot_pixels,
        })
    }

    /// A camera over the top-left `width`×`height` of this one's sensor, with the same physics
    /// (hot pixels drawn for that size, as a camera built on the cropped profile draws them).
    pub fn crop(&self, width: usize, height: usize) -> Result<VirtualCamera, Error> {
        let profile = self
            .profile
            .crop(emccd_profile::Roi::corner(width, height))
            .map_err(|e| Error::Parameter(e.to_string()))?;
        VirtualCamera::new(profile, self.physics.clone())
    }

    /// The bundled default profile with default physics.
    pub fn default_camera() -> VirtualCamera {
        VirtualCamera::new(emccd_profile::default_profile(), PhysicalParams::default())
            .expect("default camera is valid")
    }

    /// Frame width.
    pub fn width(&self) -> usize {
        self.profile.width
    }

    /// Frame height.
    pub fn height(&self) -> usize {
        self.profile.height
    }

    /// System gain K = G/c in DN per photoelectron.
    pub fn k_dn(&self) -> f64 {
        self.em_gain / self.e_per_dn
    }

    /// The photons at a scene's full scale (1.0) that give it `mean_electrons`
    /// photoelectrons per pixel on average (`scene` in [0, 1]; the quantum efficiency counts).
    /// Not finite for an all-zero scene.
    pub fn peak_photons(&self, scene: &[f32], mean_electrons: f64) -> f64 {
        let mean = scene.iter().map(|&v| v as f64).sum::<f64>() / scene.len() as f64;
        mean_electrons / (self.physics.qe * mean)
    }

    /// Precomputes the exposure-dependent truth.
    pub fn exposure(&self, exposure_s: f64) -> Exposure<'_> {
        let mut fpn = vec![0f32; self.profile.len()];
        self.profile.fpn_at(exposure_s, &mut fpn);
        Exposure {
            cam: self,
            exposure_s,
            fpn,
            blooming_x: self.profile.blooming_factor(exposure_s),
            read_noise: self.profile.read_noise_near(exposure_s).to_vec(),
        }
    }
}

impl Exposure<'_> {
    /// Simulates one raw frame (DN, integer-valued) for the expected photon counts `photons`
    /// (per pixel, during this exposure). `seed` selects the frame's randomness.
    pub fn frame(&self, photons: &[f32], seed: u64, out: &mut [f32]) {
        let cam = self.cam;
        let w = cam.width();
        assert_eq!(
            photons.len(),
            cam.profile.len(),
            "photon map must cover the sensor"
        );
        assert_eq!(out.len(), photons.len(), "output must hold one frame");
        let (qe, cic, t, g, c) = (
            cam.physics.qe,
            cam.physics.cic_e,
            self.exposure_s,
            cam.em_gain,
            cam.e_per_dn,
        );
        // Pass 1: EM-amplified charge plus the fixed pattern, before blooming.
        out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let mut rng = stream(seed, y as u64, 10);
            let base = y * w;
            for (x, o) in row.iter_mut().enumerate() {
                let i = base + x;
                let lambda = qe * photons[i].max(0.0) as f64 + cam.dark_map[i] as f64 * t + cic;
                let n = if lambda > 0.0 {
                    rand_distr::Distribution::sample(
                        &rand_distr::Poisson::new(lambda).unwrap(),
                        &mut rng,
                    )
                } else {
                    0.0
                };
                let m = em_register(&mut rng, n, g);
                *o = (m / c + self.fpn[i] as f64) as f32;
            }
        });
        // Pass 2: blooming, read noise, ADC.
        let cm = column_means(out, w);
        let x = self.blooming_x;
        let adc_max = cam.profile.adc_max_dn as f64;
        out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let mut rng = stream(seed, y as u64, 11);
            let rn = &self.read_noise[y * w..(y + 1) * w];
            for ((o, &m), &sd) in row.iter_mut().zip(&cm).zip(rn) {
                let z: f64 =
                    rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng);
                let v = *o as f64 + x * m + sd as f64 * z;
                *o = v.round().clamp(0.0, adc_max) as f32;
            }
        });
    }

    /// The noise-free raw frame `B[E(Y)]` (no read noise, no rounding): what averaging infinitely
    /// many frames converges to, away from the ADC limits.
    pub fn expected_raw(&self, photons: &[f32]) -> Vec<f32> {
        let mut out = self.expected_signal(photons);
        for (o, &f) in out.iter_mut().zip(&self.fpn) {
            *o += f;
        }
        emccd_profile::apply_blooming(&mut out, self.cam.width(), self.blooming_x);
        out
    }

    /// Everything the EM register outputs on average, in DN: photo-signal plus dark and CIC.
    /// This is what preprocessing (eq. 4) recovers from [`Exposure::expected_raw`].
    pub fn expected_signal(&self, photons: &[f32]) -> Vec<f32> {
        let cam = self.cam;
        let k = cam.k_dn();
        photons
            .iter()
            .zip(&cam.dark_map)
            .map(|(&p, &d)| {
                (k * (cam.physics.qe * p.max(0.0) as f64
                    + d as f64 * self.exposure_s
                    + cam.physics.cic_e)) as f32
            })
            .collect()
    }

    /// The ground truth of a pair: the photo-signal alone, `K·QE·φ` in DN above bias.
    pub fn ground_truth(&self, photons: &[f32]) -> Vec<f32> {
        let k = self.cam.k_dn() * self.cam.physics.qe;
        photons
            .iter()
            .map(|&p| (k * p.max(0.0) as f64) as f32)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use emccd_profile::preprocess;

    #[test]
    fn peak_photons_give_the_mean_photoelectrons_asked_for() {
        let cam = small_camera();
        let scene: Vec<f32> = (0..100).map(|i| i as f32 / 99.0).collect();
        let peak = cam.peak_photons(&scene, 4.0);
        let mean_e: f64 = scene
            .iter()
            .map(|&v| v as f64 * peak * cam.physics.qe)
            .sum::<f64>()
            / scene.len() as f64;
        assert!((mean_e - 4.0).abs() < 1e-9, "{mean_e}");
        assert!(!cam.peak_photons(&[0.0; 4], 1.0).is_finite());
    }

    fn small_camera() -> VirtualCamera {
        let p = emccd_profile::default_profile()
            .crop(emccd_profile::Roi {
                x: 100,
                y: 200,
                width: 64,
                height: 48,
            })
            .unwrap();
        VirtualCamera::new(
            p,
            PhysicalParams {
                hot_fraction: 0.01,
                ..Default::default()
            },
        )
        .unwrap()
    }

    #[test]
    fn preprocessing_is_exact_on_noise_free_frames() {
        let cam = small_camera();
        let n = cam.profile.len();
        let photons: Vec<f32> = (0..n).map(|i| ((i * 7919) % 97) as f32 * 3.0).collect();
        for t in [1e-3, 0.01, 0.1] {
            let e = cam.exposure(t);
            let mut raw = e.expected_raw(&photons);
            let want = e.expected_signal(&photons);
            preprocess(&mut raw, cam.width(), e.blooming_x, &e.fpn);
            let worst = raw
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            // f32 arithmetic on values of a few hundred DN: error at the 1e-4 DN level.
            assert!(worst < 2e-3, "t = {t}: worst error {worst} DN");
        }
    }

    #[test]
    fn frames_are_reproducible_and_integer() {
        let cam = small_camera();
        let n = cam.profile.len();
        let photons = vec![5.0f32; n];
        let e = cam.exposure(0.01);
        let mut a = vec![0f32; n];
        let mut b = vec![0f32; n];
        e.frame(&photons, 42, &mut a);
        e.frame(&photons, 42, &mut b);
        assert_eq!(a, b);
        assert!(a
            .iter()
            .all(|v| v.fract() == 0.0 && (0.0..=65535.0).contains(v)));
        e.frame(&photons, 43, &mut b);
        assert_ne!(a, b);
    }
}
