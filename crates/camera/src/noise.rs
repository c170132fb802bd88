//! Noise models behind one trait. Each maps a clean photo-signal `S` (DN above bias, in the
//! preprocessed domain: blooming and FPN already removed) to a noisy frame, and states the
//! closed-form mean, variance and third central moment of one pixel's output, which the tests
//! check samples against.

use std::sync::Arc;

use emccd_profile::CameraProfile;
use rand::Rng;
use rand_distr::{Distribution, Gamma, Poisson, StandardNormal};
use rayon::prelude::*;

use crate::rng::{stream, FRAME_KEY};
use crate::Error;

/// Mean, variance and third central moment of one pixel's output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Moments {
    /// E[D].
    pub mean: f64,
    /// Var[D].
    pub var: f64,
    /// E[(D − E[D])³].
    pub third: f64,
}

impl Moments {
    /// Skewness `third / var^1.5`.
    pub fn skewness(&self) -> f64 {
        self.third / self.var.powf(1.5)
    }
}

/// Which noise model: the one type for synthesis, training, model metadata and the CLI's
/// flags (a `clap::ValueEnum` with the `clap` feature).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum NoiseModelKind {
    /// The paper's EMCCD model (eq. 5).
    Ours,
    /// ELD (CMOS): Poisson + Tukey-lambda read + row noise + quantization.
    Eld,
    /// Poisson–Gamma–Normal, the theoretical EMCCD chain: Poisson → Gamma → Normal → ADC.
    Pgn,
}

impl NoiseModelKind {
    /// Lower-case name, as in flags and model files.
    pub fn name(self) -> &'static str {
        match self {
            NoiseModelKind::Ours => "ours",
            NoiseModelKind::Eld => "eld",
            NoiseModelKind::Pgn => "pgn",
        }
    }

    /// This noise model of the camera `p` (the paper's with the components `ablation` leaves
    /// on; the PGN chain at `exposure_s`, whose dark current depends on it).
    pub fn build(
        self,
        p: &CameraProfile,
        ablation: Ablation,
        exposure_s: f64,
    ) -> Result<Box<dyn NoiseModel>, Error> {
        Ok(match self {
            NoiseModelKind::Ours => Box::new(OursModel::from_profile(p, ablation)?),
            NoiseModelKind::Eld => Box::new(EldModel::from_profile(p)?),
            NoiseModelKind::Pgn => Box::new(PgnModel::from_profile(p, exposure_s)?),
        })
    }
}

/// Components of the paper's model that can be switched off (its Table 2 ablation). FPN and
/// blooming are handled by preprocessing; their switches say whether a pipeline removes them.
///
/// On disk (model files, training checkpoints) it is the list of switched-off component names,
/// `[]` for the full model; `FromStr` takes them comma-separated, as the `--ablate` flags do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ablation {
    /// Multiplicative (excess) noise: off means f = 1 with K unchanged.
    pub multiplicative: bool,
    /// Per-pixel readout noise.
    pub readout: bool,
    /// Quantization noise.
    pub quantization: bool,
    /// FPN removal in preprocessing.
    pub fpn: bool,
    /// Blooming removal in preprocessing.
    pub blooming: bool,
}

impl Default for Ablation {
    fn default() -> Self {
        Ablation {
            multiplicative: true,
            readout: true,
            quantization: true,
            fpn: true,
            blooming: true,
        }
    }
}

impl Ablation {
    /// The component names, as flags and model files spell them.
    pub const COMPONENTS: [&'static str; 5] = [
        "multiplicative",
        "readout",
        "quantization",
        "fpn",
        "blooming",
    ];

    /// The full model with the named components switched off.
    pub fn from_names<S: AsRef<str>>(names: &[S]) -> Result<Ablation, String> {
        let mut a = Ablation::default();
        for n in names {
            match n.as_ref() {
                "multiplicative" => a.multiplicative = false,
                "readout" => a.readout = false,
                "quantization" => a.quantization = false,
                "fpn" => a.fpn = false,
                "blooming" => a.blooming = false,
                other => {
                    return Err(format!(
                        "unknown ablation {other:?} (the components are {})",
                        Ablation::COMPONENTS.join(", ")
                    ))
                }
            }
        }
        Ok(a)
    }
}

impl Ablation {
    /// The switched-off components' names, in [`Ablation::COMPONENTS`] order (empty: the full
    /// model).
    pub fn off(&self) -> Vec<&'static str> {
        let on = [
            self.multiplicative,
            self.readout,
            self.quantization,
            self.fpn,
            self.blooming,
        ];
        Ablation::COMPONENTS
            .iter()
            .zip(on)
            .filter(|(_, on)| !on)
            .map(|(n, _)| *n)
            .collect()
    }

    /// Whether every component is on (no ablation).
    pub fn is_full(&self) -> bool {
        *self == Ablation::default()
    }
}

impl serde::Serialize for Ablation {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        serde::Serialize::serialize(&self.off(), s)
    }
}

impl<'de> serde::Deserialize<'de> for Ablation {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Ablation, D::Error> {
        let names: Vec<String> = serde::Deserialize::deserialize(d)?;
        Ablation::from_names(&names).map_err(serde::de::Error::custom)
    }
}

impl std::fmt::Display for Ablation {
    /// The switched-off components, comma-separated (what `FromStr` reads back).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.off().join(","))
    }
}

impl std::str::FromStr for Ablation {
    type Err = String;

    /// A comma-separated list of components to switch off (empty: the full model).
    fn from_str(s: &str) -> Result<Ablation, String> {
        let names: Vec<&str> = s
            .split(',')
            .map(str::trim)
            .filter(|n| !n.is_empty())
            .collect();
        Ablation::from_names(&names)
    }
}

/// A noise model: clean photo-signal in, noisy frame out.
pub trait NoiseModel: Send + Sync {
    /// Which model this is.
    fn kind(&self) -> NoiseModelKind;

    /// Short name (`ours`, `eld`, `pgn`): its kind's.
    fn name(&self) -> &'static str {
        self.kind().name()
    }

    /// Writes a noisy version of `clean` (row-major, `width` columns, DN above bias) into `out`.
    /// The same `seed` gives the same frame on any number of threads.
    fn synthesize(&self, clean: &[f32], width: usize, out: &mut [f32], seed: u64);

    /// Closed-form moments of pixel `pixel`'s output at clean signal `signal_dn`, averaged over
    /// the model's per-frame random choices.
    fn moments(&self, signal_dn: f64, pixel: usize) -> Moments;
}

#[inline]
fn poisson<R: Rng + ?Sized>(rng: &mut R, lambda: f64) -> f64 {
    if lambda > 0.0 {
        // `Poisson::new` only fails for non-positive or non-finite λ, excluded here.
        Poisson::new(lambda).map(|d| d.sample(rng)).unwrap_or(0.0)
    } else {
        0.0
    }
}

#[inline]
fn normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    StandardNormal.sample(rng)
}

/// E[f^−k] for f uniform on [a, b].
fn inv_moment(a: f64, b: f64, k: i32) -> f64 {
    if (b - a).abs() < 1e-12 {
        return a.powi(-k);
    }
    if k == 1 {
        (b / a).ln() / (b - a)
    } else {
        (a.powi(1 - k) - b.powi(1 - k)) / ((k - 1) as f64 * (b - a))
    }
}

fn check_frame(clean: &[f32], width: usize, out: &[f32]) {
    assert!(
        width > 0 && clean.len() % width == 0,
        "frame is not a whole number of rows"
    );
    assert_eq!(
        clean.len(),
        out.len(),
        "input and output frames differ in size"
    );
}

/// The paper's model (eq. 5): `D̂' = K(I + f·Np) + Nr + Nq`, `I = S/K`, `K = s/f²`,
/// `f ~ U[f_lo, f_hi]` and one read-noise map drawn per frame.
#[derive(Clone)]
pub struct OursModel {
    slope: f64,
    f_range: [f64; 2],
    q: f64,
    read_noise: Arc<Vec<Vec<f32>>>,
    ablation: Ablation,
}

impl OursModel {
    /// Builds the model from a profile's slope, f range, quantization and read-noise maps.
    /// Fails when the profile lacks a slope or read-noise maps (a partial calibration).
    pub fn from_profile(p: &CameraProfile, ablation: Ablation) -> Result<OursModel, Error> {
        p.require_complete()
            .map_err(|e| Error::Parameter(e.to_string()))?;
        OursModel::new(
            p.slope().unwrap_or(f64::NAN),
            p.f_range,
            p.quantization_dn,
            p.maps.read_noise.clone(),
            ablation,
        )
    }

    /// Builds the model from explicit parameters (one or more read-noise maps).
    pub fn new(
        slope: f64,
        f_range: [f64; 2],
        q: f64,
        read_noise: Vec<Vec<f32>>,
        ablation: Ablation,
    ) -> Result<OursModel, Error> {
        if !(slope > 0.0)
            || !(f_range[0] >= 1.0 && f_range[1] >= f_range[0])
            || !(q >= 0.0)
            || read_noise.is_empty()
        {
            return Err(Error::Parameter(format!(
                "ours: need s > 0, 1 ≤ f_lo ≤ f_hi, q ≥ 0 and a read-noise map (s={slope}, f={f_range:?}, q={q})"
            )));
        }
        Ok(OursModel {
            slope,
            f_range,
            q,
            read_noise: Arc::new(read_noise),
            ablation,
        })
    }

    /// The per-frame draws for `seed`: (f, read-noise map index).
    pub fn frame_draws(&self, seed: u64) -> (f64, usize) {
        let mut r = stream(seed, FRAME_KEY, 0);
        let [a, b] = self.f_range;
        let f = if b > a { r.random_range(a..b) } else { a };
        (f, r.random_range(0..self.read_noise.len()))
    }
}

impl NoiseModel for OursModel {
    fn kind(&self) -> NoiseModelKind {
        NoiseModelKind::Ours
    }

    fn synthesize(&self, clean: &[f32], width: usize, out: &mut [f32], seed: u64) {
        check_frame(clean, width, out);
        let (f, map) = self.frame_draws(seed);
        let k = self.slope / (f * f);
        let f_eff = if self.ablation.multiplicative { f } else { 1.0 };
        let rn = &self.read_noise[map];
        assert_eq!(
            rn.len(),
            clean.len(),
            "read-noise map and frame differ in size"
        );
        let (readout, quant, q) = (self.ablation.readout, self.ablation.quantization, self.q);
        out.par_chunks_mut(width)
            .zip(clean.par_chunks(width))
            .enumerate()
            .for_each(|(y, (o, c))| {
                let mut rng = stream(seed, y as u64, 1);
                let sig = &rn[y * width..(y + 1) * width];
                for ((o, &s), &sd) in o.iter_mut().zip(c).zip(sig) {
                    let i = (s.max(0.0) as f64) / k;
                    let n = poisson(&mut rng, i);
                    let mut v = k * (i + f_eff * (n - i));
                    if readout {
                        v += sd as f64 * normal(&mut rng);
                    }
                    if quant {
                        v += q * (rng.random::<f64>() - 0.5);
                    }
                    *o = v as f32;
                }
            });
    }

    fn moments(&self, signal_dn: f64, pixel: usize) -> Moments {
        let [a, b] = self.f_range;
        let s = self.slope;
        let sig = signal_dn.max(0.0);
        let (var_shot, third) = if self.ablation.multiplicative {
            (s * sig, s * s * sig * inv_moment(a, b, 1))
        } else {
            (
                s * sig * inv_moment(a, b, 2),
                s * s * sig * inv_moment(a, b, 4),
            )
        };
        let read = if self.ablation.readout {
            let m = &self.read_noise;
            m.iter().map(|map| (map[pixel] as f64).powi(2)).sum::<f64>() / m.len() as f64
        } else {
            0.0
        };
        let quant = if self.ablation.quantization {
            self.q * self.q / 12.0
        } else {
            0.0
        };
        Moments {
            mean: sig,
            var: var_shot + read + quant,
            third,
        }
    }
}

/// ELD (Wei et al. 2021), built for CMOS sensors: `K·Poisson(S/K)` + Tukey-lambda read noise +
/// a Gaussian offset per row + uniform quantization.
#[derive(Clone, Debug)]
pub struct EldModel {
    k: f64,
    lambda: f64,
    scale: f64,
    row_sigma: f64,
    q: f64,
}

/// Variance of the standard Tukey-lambda distribution (finite for λ > −1/2).
pub fn tukey_variance(lambda: f64) -> f64 {
    if lambda.abs() < 1e-9 {
        std::f64::consts::PI.powi(2) / 3.0
    } else {
        let g = libm::tgamma;
        2.0 / (lambda * lambda)
            * (1.0 / (1.0 + 2.0 * lambda) - g(lambda + 1.0).powi(2) / g(2.0 * lambda + 2.0))
    }
}

impl EldModel {
    /// Builds the model; λ must exceed −1/2 for the variance to exist.
    pub fn new(
        k_dn: f64,
        tukey_lambda: f64,
        tukey_scale_dn: f64,
        row_sigma_dn: f64,
        q: f64,
    ) -> Result<EldModel, Error> {
        if !(k_dn > 0.0
            && tukey_lambda > -0.5
            && tukey_scale_dn >= 0.0
            && row_sigma_dn >= 0.0
            && q >= 0.0)
        {
            return Err(Error::Parameter(format!(
                "eld: need K > 0, λ > −1/2 and non-negative scales (K={k_dn}, λ={tukey_lambda})"
            )));
        }
        Ok(EldModel {
            k: k_dn,
            lambda: tukey_lambda,
            scale: tukey_scale_dn,
            row_sigma: row_sigma_dn,
            q,
        })
    }

    /// Builds the model from a profile's `[eld]` section.
    pub fn from_profile(p: &CameraProfile) -> Result<EldModel, Error> {
        let e = p
            .eld
            .as_ref()
            .ok_or_else(|| Error::Parameter("the profile has no [eld] parameters".into()))?;
        EldModel::new(
            e.k_dn,
            e.tukey_lambda,
            e.tukey_scale_dn,
            e.row_sigma_dn,
            p.quantization_dn,
        )
    }

    #[inline]
    fn tukey<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        // Quantile function at u ∈ (0, 1).
        let u: f64 = rng.random_range(f64::EPSILON..1.0);
        if self.lambda.abs() < 1e-9 {
            (u / (1.0 - u)).ln()
        } else {
            (u.powf(self.lambda) - (1.0 - u).powf(self.lambda)) / self.lambda
        }
    }
}

impl NoiseModel for EldModel {
    fn kind(&self) -> NoiseModelKind {
        NoiseModelKind::Eld
    }

    fn synthesize(&self, clean: &[f32], width: usize, out: &mut [f32], seed: u64) {
        check_frame(clean, width, out);
        out.par_chunks_mut(width)
            .zip(clean.par_chunks(width))
            .enumerate()
            .for_each(|(y, (o, c))| {
                let mut rng = stream(seed, y as u64, 2);
                let row = self.row_sigma * normal(&mut rng);
                for (o, &s) in o.iter_mut().zip(c) {
                    let shot = self.k * poisson(&mut rng, s.max(0.0) as f64 / self.k);
                    let read = self.scale * self.tukey(&mut rng);
                    let quant = self.q * (rng.random::<f64>() - 0.5);
                    *o = (shot + read + row + quant) as f32;
                }
            });
    }

    fn moments(&self, signal_dn: f64, _pixel: usize) -> Moments {
        let s = signal_dn.max(0.0);
        Moments {
            mean: s,
            var: self.k * s
                + self.scale * self.scale * tukey_variance(self.lambda)
                + self.row_sigma * self.row_sigma
                + self.q * self.q / 12.0,
            third: self.k * self.k * s,
        }
    }
}

/// The theoretical EMCCD chain (Ryan et al. 2021): electrons `n ~ Poisson(S·c/G + dark·t + CIC)`,
/// EM output `m ~ Gamma(n, G)`, then `m/c + N(0, σ²)`; the mean dark and CIC level is removed
/// (as FPN subtraction does on real frames) and quantization is uniform on ±q/2.
#[derive(Clone, Debug)]
pub struct PgnModel {
    g: f64,
    c: f64,
    cic: f64,
    dark: f64,
    exposure_s: f64,
    sigma: f64,
    q: f64,
    /// Per-pixel read-noise std (DN), replacing `sigma` where given.
    read_map: Option<Arc<Vec<f32>>>,
}

impl PgnModel {
    /// Builds the model at a given exposure (for the dark-current term).
    pub fn new(
        em_gain: f64,
        e_per_dn: f64,
        cic_e: f64,
        dark_e_per_s: f64,
        exposure_s: f64,
        read_sigma_dn: f64,
        q: f64,
    ) -> Result<PgnModel, Error> {
        if !(em_gain >= 1.0
            && e_per_dn > 0.0
            && cic_e >= 0.0
            && dark_e_per_s >= 0.0
            && exposure_s >= 0.0
            && read_sigma_dn >= 0.0
            && q >= 0.0)
        {
            return Err(Error::Parameter(format!(
                "pgn: need G ≥ 1, e/DN > 0 and non-negative rates (G={em_gain}, c={e_per_dn})"
            )));
        }
        Ok(PgnModel {
            g: em_gain,
            c: e_per_dn,
            cic: cic_e,
            dark: dark_e_per_s,
            exposure_s,
            sigma: read_sigma_dn,
            q,
            read_map: None,
        })
    }

    /// The same camera with a per-pixel read-noise std map (DN, row-major, the frame's size)
    /// instead of one σ: real registers read out through pixel-dependent noise, and training
    /// sees the same map the network's noise-level channel is built from.
    pub fn with_read_noise_map(mut self, map: Vec<f32>) -> PgnModel {
        self.read_map = Some(Arc::new(map));
        self
    }

    fn sigma_at(&self, pixel: usize) -> f64 {
        self.read_map
            .as_ref()
            .and_then(|m| m.get(pixel))
            .map_or(self.sigma, |&v| v as f64)
    }

    /// Builds the model from a profile's `[pgn]` section.
    pub fn from_profile(p: &CameraProfile, exposure_s: f64) -> Result<PgnModel, Error> {
        let m = p
            .pgn
            .as_ref()
            .ok_or_else(|| Error::Parameter("the profile has no [pgn] parameters".into()))?;
        PgnModel::new(
            m.em_gain,
            m.e_per_dn,
            m.cic_e,
            m.dark_e_per_s,
            exposure_s,
            m.read_sigma_dn,
            p.quantization_dn,
        )
    }

    fn background_e(&self) -> f64 {
        self.dark * self.exposure_s + self.cic
    }
}

/// One EM-register output for `n` input electrons: Gamma(n, G), 0 for n = 0.
#[inline]
pub fn em_register<R: Rng + ?Sized>(rng: &mut R, n: f64, gain: f64) -> f64 {
    if n <= 0.0 {
        0.0
    } else {
        Gamma::new(n, gain).map(|d| d.sample(rng)).unwrap_or(0.0)
    }
}

impl NoiseModel for PgnModel {
    fn kind(&self) -> NoiseModelKind {
        NoiseModelKind::Pgn
    }

    fn synthesize(&self, clean: &[f32], width: usize, out: &mut [f32], seed: u64) {
        check_frame(clean, width, out);
        let bg = self.background_e();
        let offset = self.g * bg / self.c;
        if let Some(m) = &self.read_map {
            assert_eq!(m.len(), clean.len(), "read-noise map size");
        }
        out.par_chunks_mut(width)
            .zip(clean.par_chunks(width))
            .enumerate()
            .for_each(|(y, (o, c))| {
                let mut rng = stream(seed, y as u64, 3);
                for (x, (o, &s)) in o.iter_mut().zip(c).enumerate() {
                    let lambda = s.max(0.0) as f64 * self.c / self.g + bg;
                    let n = poisson(&mut rng, lambda);
                    let m = em_register(&mut rng, n, self.g);
                    let sigma = self.sigma_at(y * width + x);
                    let v = m / self.c + sigma * normal(&mut rng) - offset
                        + self.q * (rng.random::<f64>() - 0.5);
                    *o = v as f32;
                }
            });
    }

    fn moments(&self, signal_dn: f64, pixel: usize) -> Moments {
        // Compound Poisson of Exp(G) summands: cumulants κ_r = λ·E[X^r] = λ·r!·G^r.
        let lambda = signal_dn.max(0.0) * self.c / self.g + self.background_e();
        let (g, c) = (self.g, self.c);
        Moments {
            mean: signal_dn.max(0.0),
            var: 2.0 * g * g * lambda / (c * c)
                + self.sigma_at(pixel).powi(2)
                + self.q * self.q / 12.0,
            third: 6.0 * g.powi(3) * lambda / c.powi(3),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_noise_writes_seeded_frames_and_refuses_bad_settings() {
        let noise = SceneNoise {
            kind: NoiseModelKind::Pgn,
            signal_dn: 200.0,
            exposure_s: 0.01,
            ablate: Ablation::default(),
            frames: 2,
            seed: 7,
        };
        let profile = emccd_profile::default_profile();
        let scene = emccd_io::Image {
            width: 24,
            height: 16,
            data: (0..24 * 16).map(|i| (i % 24) as f32 / 24.0).collect(),
        };
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("n.tif");
        noise.write(&profile, &scene, &out).unwrap();
        let mut r = emccd_io::open(&out).unwrap();
        let info = r.info().clone();
        assert_eq!((info.width, info.height, info.frames), (24, 16, 2));
        let mut frames = vec![vec![0f32; 24 * 16]; 2];
        for f in &mut frames {
            assert!(r.read_frame(f).unwrap());
        }
        // Frame k is the model's frame with seed + k, on the profile's top-left corner.
        let p = profile.top_left(24, 16).unwrap();
        let model = NoiseModelKind::Pgn
            .build(&p, Ablation::default(), 0.01)
            .unwrap();
        let clean: Vec<f32> = scene
            .data
            .iter()
            .map(|&v| (v as f64 * 200.0) as f32)
            .collect();
        let mut want = vec![0f32; 24 * 16];
        model.synthesize(&clean, 24, &mut want, 8);
        assert_eq!(frames[1], want);
        // Each bad setting is named as its flag, and nothing is written.
        for (bad, name) in [
            (
                SceneNoise {
                    signal_dn: 1e30,
                    ..noise
                },
                "signal-dn",
            ),
            (
                SceneNoise {
                    exposure_s: -1.0,
                    ..noise
                },
                "exposure-s",
            ),
            (SceneNoise { frames: 0, ..noise }, "frames"),
            (
                SceneNoise {
                    ablate: "fpn".parse().unwrap(),
                    ..noise
                },
                "ablate",
            ),
        ] {
            let e = bad
                .write(&profile, &scene, &dir.path().join("bad.tif"))
                .unwrap_err();
            assert!(e.to_string().starts_with(name), "{e}");
        }
        assert!(!dir.path().join("bad.tif").exists());
    }

    #[test]
    fn ablations_parse_from_names_and_lists() {
        let a: Ablation = "readout, fpn".parse().unwrap();
        assert!(!a.readout && !a.fpn && a.multiplicative && a.quantization && a.blooming);
        assert_eq!("".parse::<Ablation>().unwrap(), Ablation::default());
        let a: Ablation = "blooming, readout".parse().unwrap();
        assert_eq!(a.off(), ["readout", "blooming"]);
        assert_eq!(a.to_string().parse::<Ablation>().unwrap(), a);
        let json = serde_json::to_string(&a).unwrap();
        assert_eq!(json, r#"["readout","blooming"]"#);
        assert_eq!(serde_json::from_str::<Ablation>(&json).unwrap(), a);
        assert!(serde_json::from_str::<Ablation>(r#"["gain"]"#).is_err());
        assert!(Ablation::default().is_full() && !a.is_full());
        assert_eq!(
            Ablation::from_names(&Ablation::COMPONENTS).unwrap(),
            Ablation {
                multiplicative: false,
                readout: false,
                quantization: false,
                fpn: false,
                blooming: false
            }
        );
        let e = Ablation::from_names(&["gain"]).unwrap_err();
        assert!(
            e.contains("\"gain\"") && e.contains("multiplicative, readout"),
            "{e}"
        );
    }
}

/// Noisy frames of one clean scene under a noise model: what `emccd synthesize` writes (the
/// noise of training pairs, to look at or to feed another tool). With the `clap` feature, its
/// flags.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SceneNoise {
    /// The noise model.
    #[cfg_attr(feature = "clap", arg(long = "model", value_name = "MODEL", value_enum, default_value_t = SceneNoise::default().kind))]
    pub kind: NoiseModelKind,
    /// The clean signal at the image's full scale (its 1.0), DN above bias; at most 10⁶.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SceneNoise::default().signal_dn))]
    pub signal_dn: f64,
    /// Exposure, s (the fixed pattern and dark signal the models add depend on it).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SceneNoise::default().exposure_s))]
    pub exposure_s: f64,
    /// Components to switch off (comma-separated): multiplicative, readout, quantization; only
    /// synthesis components (not the fpn and blooming corrections of a network's
    /// preprocessing).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SceneNoise::default().ablate))]
    pub ablate: Ablation,
    /// Noisy frames, each with its own noise (seeded from the seed, the seed + 1, …).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SceneNoise::default().frames))]
    pub frames: usize,
    /// Seed of the first frame.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SceneNoise::default().seed))]
    pub seed: u64,
}

impl Default for SceneNoise {
    /// One frame of the paper's model (`ours`) at 200 DN full scale, 10 ms.
    fn default() -> SceneNoise {
        SceneNoise {
            kind: NoiseModelKind::Ours,
            signal_dn: 200.0,
            exposure_s: 0.01,
            ablate: Ablation::default(),
            frames: 1,
            seed: 1,
        }
    }
}

impl SceneNoise {
    /// An error naming the setting as a flag would (`signal-dn`, `exposure-s`, `frames`,
    /// `ablate`) unless every setting is usable.
    pub fn check(&self) -> Result<(), Error> {
        // A signal past 10⁶ DN is beyond any 16- to 20-bit ADC, and at 10³⁰ the f32 arithmetic
        // wraps into garbage that looks like data.
        if !(self.signal_dn > 0.0 && self.signal_dn <= 1e6) {
            return Err(Error::Parameter(format!(
                "signal-dn {}: the signal must be a positive number of DN, at most 10⁶",
                self.signal_dn
            )));
        }
        emccd_profile::check_exposure(self.exposure_s)
            .map_err(|e| Error::Parameter(format!("exposure-s: {e}")))?;
        if self.frames == 0 {
            return Err(Error::Parameter("frames must be at least 1".into()));
        }
        if !(self.ablate.fpn && self.ablate.blooming) {
            return Err(Error::Parameter("ablate: fpn and blooming are corrections of a network's preprocessing (`train --ablate`), not parts of the synthesized noise".into()));
        }
        Ok(())
    }

    /// Writes [`SceneNoise::frames`] noisy frames of `scene` (values in [0, 1]) as a float32
    /// stack at `out` (TIFF or FITS by its extension, atomically), under the noise of the
    /// top-left region of `profile` the scene's size.
    pub fn write(
        &self,
        profile: &CameraProfile,
        scene: &emccd_io::Image,
        out: &std::path::Path,
    ) -> Result<(), Error> {
        self.check()?;
        let (w, h) = (scene.width, scene.height);
        let prof = profile
            .top_left(w, h)
            .map_err(|e| Error::Parameter(format!("a {w}×{h} scene: {e}")))?;
        let model = self.kind.build(&prof, self.ablate, self.exposure_s)?;
        let clean: Vec<f32> = scene
            .data
            .iter()
            .map(|&v| (v as f64 * self.signal_dn) as f32)
            .collect();
        let mut wr = emccd_io::StackWriter::create(
            out,
            w,
            h,
            emccd_io::SampleFormat::F32,
            Some(self.frames),
        )?;
        wr.set_metadata(&emccd_io::Metadata {
            exposure_s: Some(self.exposure_s),
            em_gain: Some(prof.em_gain),
            ..Default::default()
        });
        let mut frame = vec![0f32; w * h];
        for k in 0..self.frames {
            model.synthesize(&clean, w, &mut frame, self.seed.wrapping_add(k as u64));
            wr.write_frame(&frame)?;
        }
        wr.finish()?;
        Ok(())
    }
}
