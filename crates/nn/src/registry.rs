//! Models by name and what a denoising request runs: the bundled models, the denoising methods,
//! the method and model a request resolves to, and [`FrameDenoiser`], which turns one raw frame
//! into the output. The CLI, the Python package and library users share this, so `emccd
//! denoise` and `emccd.denoise` give the same frames for the same request.

use std::path::{Path, PathBuf};

use emccd_profile::CameraProfile;

use crate::pipeline::{classical_estimate, preprocess, Pipeline};
use crate::tile::Tiling;
use crate::{Base, Denoiser, Error, Inputs, Result};

/// A model that ships with emccd, by the name `--model` (and `model=`) accepts.
#[derive(Clone, Copy, Debug)]
pub struct Bundled {
    /// The name.
    pub name: &'static str,
    /// Its file in `models/`.
    pub file: &'static str,
}

/// The bundled models: `hybrid` (BM3D-refining), `default` (natural images, the default
/// profile), `microscopy` (the default fine-tuned on fluorescence microscopy) and `lowlight`
/// (the low-light run of README "Low light": 0.3–30 mean photoelectrons per pixel, many
/// cameras' read noise and CIC, Charbonnier loss).
pub const BUNDLED: [Bundled; 4] = [
    Bundled {
        name: "hybrid",
        file: "hybrid-unet.safetensors",
    },
    Bundled {
        name: "default",
        file: "default-unet.safetensors",
    },
    Bundled {
        name: "microscopy",
        file: "microscopy-unet.safetensors",
    },
    Bundled {
        name: "lowlight",
        file: "lowlight-unet.safetensors",
    },
];

/// The bundled model of this name, if it is one.
pub fn bundled(name: &str) -> Option<&'static Bundled> {
    BUNDLED.iter().find(|b| b.name == name)
}

/// Where the bundled model files are: `$EMCCD_MODELS` when set, else `models/` of the source
/// tree this library was built from.
pub fn models_dir() -> PathBuf {
    match std::env::var_os("EMCCD_MODELS") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models"),
    }
}

/// The file of a model argument: a bundled model's by name, else the argument as a path; an
/// error if it does not exist.
pub fn model_path(arg: &str) -> Result<PathBuf> {
    let b = bundled(arg);
    let path = match b {
        Some(b) => models_dir().join(b.file),
        None => PathBuf::from(arg),
    };
    if !path.is_file() {
        return Err(Error::Model(format!(
            "{}: model not found{}",
            path.display(),
            if b.is_some() {
                " (bundled models ship in models/; train one with `emccd train`)"
            } else {
                ""
            }
        )));
    }
    Ok(path)
}

/// Loads a model file, or a bundled model by name, onto [`crate::device`].
pub fn load(arg: &str) -> Result<Denoiser> {
    Denoiser::load(&model_path(arg)?, &crate::device())
}

/// A denoising method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Method {
    /// A classical estimate refined by a network (bundled model `hybrid`): the network sees the
    /// frame, its noise level and the estimate its model file names (one BM3D + GAT pass, or
    /// iterative BM3D), and corrects it; it starts from that estimate's quality and learns to
    /// improve on it (still in training: the README gives its figures). The estimate's time
    /// plus the network's.
    Hybrid,
    /// Iterative BM3D (`ivst`) and a network (bundled model `lowlight`), averaged pixel by
    /// pixel: their errors are partly independent, so the average is better than either at
    /// every light level of the low-light suite (README, "Low light"). Their two times.
    Blend,
    /// The network alone (bundled models `default`, `microscopy`, `lowlight`): the fastest.
    #[cfg_attr(feature = "clap", value(alias = "network"))]
    Net,
    /// BM3D after the generalized Anscombe transform (gain = the profile's slope, Gaussian σ =
    /// its read noise), with the exact unbiased inverse.
    Bm3d,
    /// BM3D with iterative variance stabilization (Azzari & Foi 2016): up to four BM3D passes,
    /// each on the data mixed with the previous estimate and, below a few photoelectrons per
    /// pixel, summed over 2×2–4×4 bins; the passes are chosen from the frame's light level.
    /// Better than `bm3d` below about 8 e⁻ per pixel (4 counts), the same above; up to about
    /// 2.3× its time.
    Ivst,
    /// No denoising: blooming and the fixed pattern removed and the units converted, as every
    /// method does first (the preprocessed photo-signal, for one's own analysis).
    None,
}

/// The method run with neither a method nor a model: the most accurate one shipped on the
/// low-light suite (README, "Low light"): `blend` (iterative BM3D and the `lowlight` network,
/// averaged) is above `ivst`, the network alone and plain BM3D at every light level there (its
/// weight, ½, was chosen on the separate validation camera).
pub const DEFAULT_METHOD: Method = Method::Blend;

impl Method {
    /// Every method.
    pub const ALL: [Method; 6] = [
        Method::Hybrid,
        Method::Blend,
        Method::Net,
        Method::Bm3d,
        Method::Ivst,
        Method::None,
    ];

    /// The classical estimate this method runs without a network, if it is one.
    pub fn classical(self) -> Option<Base> {
        match self {
            Method::Bm3d => Some(Base::Bm3d),
            Method::Ivst => Some(Base::Ivst),
            Method::Hybrid | Method::Blend | Method::Net | Method::None => None,
        }
    }

    /// The name `--method` takes.
    pub fn name(self) -> &'static str {
        match self {
            Method::Hybrid => "hybrid",
            Method::Blend => "blend",
            Method::Net => "net",
            Method::Bm3d => "bm3d",
            Method::Ivst => "ivst",
            Method::None => "none",
        }
    }

    /// Whether the method runs a network (and so takes a model).
    pub fn uses_model(self) -> bool {
        matches!(self, Method::Hybrid | Method::Blend | Method::Net)
    }
}

impl std::str::FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Method> {
        let s = if s == "network" { "net" } else { s };
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                Error::Model(format!(
                    "method {s:?}: the methods are {}",
                    Method::ALL.map(Method::name).join(", ")
                ))
            })
    }
}

/// The units denoised frames are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Units {
    /// DN above bias (the photo-signal, blooming and fixed pattern removed).
    #[default]
    Dn,
    /// Photo-electrons: DN / K with K = s/2 (the EM register's f² = 2).
    Electrons,
}

impl Units {
    /// The name `--units` takes.
    pub fn name(self) -> &'static str {
        match self {
            Units::Dn => "dn",
            Units::Electrons => "electrons",
        }
    }

    /// What the values are, in words (for provenance and reports).
    pub fn describe(self) -> &'static str {
        match self {
            Units::Dn => "DN above bias",
            Units::Electrons => "photoelectrons",
        }
    }

    /// The factor from DN above bias to these units through `profile`.
    pub fn factor(self, profile: &CameraProfile) -> Result<f32> {
        Ok(match self {
            Units::Dn => 1.0,
            Units::Electrons => (1.0 / profile.dn_per_electron()?) as f32,
        })
    }
}

impl std::str::FromStr for Units {
    type Err = Error;
    fn from_str(s: &str) -> Result<Units> {
        [Units::Dn, Units::Electrons]
            .into_iter()
            .find(|u| u.name() == s)
            .ok_or_else(|| {
                Error::Data(format!(
                    "units {s:?}: the units are \"dn\" (DN above bias) or \"electrons\""
                ))
            })
    }
}

/// What a request runs ([`resolve`]).
pub struct Resolved {
    /// The method.
    pub method: Method,
    /// The network, for the methods that run one.
    pub model: Option<Denoiser>,
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

    /// What runs this method and model on frames of `profile`'s camera; an error when the
    /// profile lacks what denoising needs (a gain-series calibration has no slope or bias maps).
    pub fn denoiser<'a>(
        &'a self,
        profile: &'a CameraProfile,
        tiling: Tiling,
        ensemble: usize,
        units: Units,
    ) -> Result<FrameDenoiser<'a>> {
        crate::pipeline::can_denoise(profile)?;
        Ok(FrameDenoiser {
            profile,
            method: self.method,
            model: self.model.as_ref(),
            tiling,
            ensemble,
            units,
        })
    }
}

/// The method and model a request runs: `method` and `model` as given (either may be absent),
/// with `load` turning a model argument into a model ([`load`], or a loader that also knows
/// models embedded in a program). The model a method takes by default is `hybrid` for
/// [`Method::Hybrid`], `lowlight` for [`Method::Blend`], `default` for [`Method::Net`]; a model alone picks the method it was
/// trained for. An error where a model does not fit the method.
pub fn resolve(
    method: Option<Method>,
    model: Option<&str>,
    load: impl Fn(&str) -> Result<Denoiser>,
) -> Result<Resolved> {
    let hybrid = |m: &Denoiser| m.meta.inputs == Inputs::Hybrid;
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
                Method::Blend => "lowlight",
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
pub fn profile_mismatch(model: &Denoiser, profile: &CameraProfile) -> Option<String> {
    let profile_fp = profile.fingerprint_hex();
    (model.meta.profile_fingerprint != profile_fp).then(|| {
        format!(
            "the model was trained for profile {} and is applied through profile {profile_fp}; the network input is camera-independent, but fine-tuning on this camera (`emccd train --init`) may gain a little",
            model.meta.profile_fingerprint
        )
    })
}

/// What turns one raw frame into the output: the method, model and profile, fixed for a run.
pub struct FrameDenoiser<'a> {
    /// The camera profile the frames are corrected and described with.
    pub profile: &'a CameraProfile,
    /// The method.
    pub method: Method,
    /// The network, for the methods that run one.
    pub model: Option<&'a Denoiser>,
    /// Tiling of large frames.
    pub tiling: Tiling,
    /// Orientations the network is averaged over (1, 2, 4 or 8).
    pub ensemble: usize,
    /// The output's units.
    pub units: Units,
}

impl FrameDenoiser<'_> {
    /// Denoises one raw frame (DN, the profile's size) taken with `exposure_s`; a frame with a
    /// non-finite value is an error naming the pixel.
    pub fn run(&self, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        let width = self.profile.width.max(1);
        if let Some(i) = raw.iter().position(|v| !v.is_finite()) {
            return Err(Error::Data(format!(
                "a non-finite value at pixel ({}, {})",
                i % width,
                i / width
            )));
        }
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
        let mut d = match (self.model, self.method.classical()) {
            (Some(m), _) => {
                let pipe = Pipeline {
                    model: m,
                    profile: self.profile,
                    tiling: self.tiling,
                    ensemble: self.ensemble,
                    device: crate::device(),
                };
                let pre = pipe.preprocess(raw, exposure_s)?;
                let net = pipe.denoise_preprocessed(&pre, exposure_s)?;
                if self.method == Method::Blend {
                    let iv = classical_estimate(self.profile, &pre, exposure_s, Base::Ivst)?;
                    net.iter().zip(&iv).map(|(a, b)| 0.5 * (a + b)).collect()
                } else {
                    net
                }
            }
            (None, Some(base)) => {
                let pre = preprocess(self.profile, raw, exposure_s)?;
                classical_estimate(self.profile, &pre, exposure_s, base)?
            }
            (None, None) => preprocess(self.profile, raw, exposure_s)?,
        };
        let to_units = self.units.factor(self.profile)?;
        if to_units != 1.0 {
            d.iter_mut().for_each(|v| *v *= to_units);
        }
        Ok(d)
    }
}

/// The self-ensemble sizes allowed: up to the eight flips and transposes of a frame.
const ENSEMBLES: [usize; 4] = [1, 2, 4, 8];

/// A self-ensemble size (orientations a network is averaged over) as a flag gives it: 1, 2, 4
/// or 8.
pub fn ensemble_size(k: &str) -> Result<usize> {
    check_ensemble(k.parse::<usize>().unwrap_or(0))
}

/// `k` if it is a self-ensemble size (1, 2, 4 or 8 orientations).
pub fn check_ensemble(k: usize) -> Result<usize> {
    if ENSEMBLES.contains(&k) {
        Ok(k)
    } else {
        Err(Error::Model(
            "the self-ensemble is 1, 2, 4 or 8 orientations".into(),
        ))
    }
}

/// A model argument with an optional self-ensemble suffix: `microscopy@8` is the bundled
/// `microscopy` model averaged over 8 orientations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelSpec<'a> {
    /// The model: a bundled name or a file.
    pub model: &'a str,
    /// Orientations averaged (1 without a suffix).
    pub ensemble: usize,
}

impl<'a> ModelSpec<'a> {
    /// Splits `MODEL[@K]`.
    pub fn parse(arg: &'a str) -> Result<ModelSpec<'a>> {
        match arg.rsplit_once('@') {
            Some((model, k)) => Ok(ModelSpec {
                model,
                ensemble: ensemble_size(k)
                    .map_err(|e| Error::Model(format!("{arg}: after `@`, {e}")))?,
            }),
            None => Ok(ModelSpec {
                model: arg,
                ensemble: 1,
            }),
        }
    }
}

/// A method under comparison, by the name `emccd evaluate --method` takes: `input` (the
/// preprocessed frame, no denoising), `bm3d`, `ivst`, `ivst:λ/b,…` (iterative BM3D with these
/// passes, for comparing schedules), `blend` (`blend@K` with the network's K-orientation
/// self-ensemble, `blend:MODEL[@K]` with another network), or a model (a bundled name or a file, `@K` for a
/// K-orientation self-ensemble; a hybrid model runs as [`Method::Hybrid`]). Models are loaded
/// once, when the name is parsed; every run goes through the same code as `emccd denoise`.
pub struct Estimator {
    name: String,
    kind: Kind,
}

enum Kind {
    /// Iterative BM3D with the passes given.
    Passes(emccd_eval::vst::Schedule),
    /// What `emccd denoise` runs for this method and model.
    Denoise {
        method: Method,
        model: Option<Denoiser>,
        ensemble: usize,
    },
}

impl Estimator {
    /// The estimator `name` stands for, with its model loaded by `load` ([`load`], or a
    /// loader that also knows models embedded in a program).
    pub fn parse(name: &str, load: impl Fn(&str) -> Result<Denoiser>) -> Result<Estimator> {
        let classical = match name {
            "input" => Some(Method::None),
            "bm3d" => Some(Method::Bm3d),
            "ivst" => Some(Method::Ivst),
            _ => None,
        };
        let kind = if let Some(method) = classical {
            Kind::Denoise {
                method,
                model: None,
                ensemble: 1,
            }
        } else if let Some(passes) = name.strip_prefix("ivst:") {
            Kind::Passes(
                passes
                    .parse()
                    .map_err(|e: String| Error::Model(format!("--method {name}: {e}")))?,
            )
        } else if let Some(rest) = name
            .strip_prefix("blend")
            .filter(|r| r.is_empty() || r.starts_with([':', '@']))
        {
            // `blend`, `blend@K` (the network's K-orientation self-ensemble) or
            // `blend:MODEL[@K]` (another network averaged with ivst).
            let (model_name, ensemble) = match rest.strip_prefix(':') {
                Some(m) => {
                    let spec = ModelSpec::parse(m)?;
                    (spec.model, spec.ensemble)
                }
                // `blend[@K]` splits as a model spec would; its network is `lowlight`.
                None => ("lowlight", ModelSpec::parse(name)?.ensemble),
            };
            let model = load(model_name)?;
            if model.meta.inputs == Inputs::Hybrid {
                return Err(Error::Model(format!(
                    "--method {name}: {model_name} is a refinement network; blend averages ivst with a denoiser"
                )));
            }
            Kind::Denoise {
                method: Method::Blend,
                model: Some(model),
                ensemble,
            }
        } else {
            let spec = ModelSpec::parse(name)?;
            let model = load(spec.model)?;
            Kind::Denoise {
                method: if model.meta.inputs == Inputs::Hybrid {
                    Method::Hybrid
                } else {
                    Method::Net
                },
                model: Some(model),
                ensemble: spec.ensemble,
            }
        };
        Ok(Estimator {
            name: name.to_string(),
            kind,
        })
    }

    /// The name it was parsed from.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The network it runs, if any.
    pub fn model(&self) -> Option<&Denoiser> {
        match &self.kind {
            Kind::Denoise { model, .. } => model.as_ref(),
            Kind::Passes(_) => None,
        }
    }

    /// It as a contender of [`emccd_eval::evaluation::evaluate`] (also the denoiser that
    /// `emccd_eval::virtual_pairs::write_pairs` takes): the one adapter from this crate's
    /// estimators to the evaluation's denoisers, with an error as the text of its causes.
    pub fn contender(&self) -> emccd_eval::evaluation::Contender<'_> {
        emccd_eval::evaluation::Contender {
            name: self.name(),
            run: Box::new(move |p: &CameraProfile, raw: &[f32], t: f64| {
                self.run(p, raw, t)
                    .map_err(|e| emccd_io::error_lines(&e).join(": ").into())
            }),
        }
    }

    /// Its estimate of one raw frame (DN, the profile's size) taken with `exposure_s`, in DN
    /// above bias.
    pub fn run(&self, profile: &CameraProfile, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        match &self.kind {
            Kind::Passes(s) => {
                let pre = preprocess(profile, raw, exposure_s)?;
                crate::pipeline::bm3d_passes(profile, &pre, exposure_s, &s.0)
            }
            Kind::Denoise {
                method,
                model,
                ensemble,
            } => FrameDenoiser {
                profile,
                method: *method,
                model: model.as_ref(),
                tiling: Tiling::default(),
                ensemble: *ensemble,
                units: Units::Dn,
            }
            .run(raw, exposure_s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_specs_split_the_self_ensemble() {
        assert_eq!(
            ModelSpec::parse("microscopy@8").unwrap(),
            ModelSpec {
                model: "microscopy",
                ensemble: 8
            }
        );
        assert_eq!(
            ModelSpec::parse("out/m.safetensors").unwrap(),
            ModelSpec {
                model: "out/m.safetensors",
                ensemble: 1
            }
        );
        let e = ModelSpec::parse("default@3").unwrap_err().to_string();
        assert!(e.contains("default@3") && e.contains("1, 2, 4 or 8"), "{e}");
    }

    #[test]
    fn blend_takes_a_self_ensemble_and_another_network() {
        // The loader says which model each spelling asks for.
        let asks = |name: &str| -> String {
            let e = Estimator::parse(name, |m: &str| -> Result<Denoiser> {
                Err(Error::Model(format!("asked for {m}")))
            });
            e.err().map(|e| e.to_string()).unwrap_or_default()
        };
        assert_eq!(asks("blend"), "asked for lowlight");
        assert_eq!(asks("blend@8"), "asked for lowlight");
        assert_eq!(
            asks("blend:out/m.safetensors@4"),
            "asked for out/m.safetensors"
        );
        assert!(
            asks("blend@3").contains("1, 2, 4 or 8"),
            "{}",
            asks("blend@3")
        );
        // Not a blend: a model file whose name starts with "blend".
        assert_eq!(asks("blended.safetensors"), "asked for blended.safetensors");
    }

    #[test]
    fn classical_estimators_need_no_model_and_match_denoise() {
        let p = emccd_profile::default_profile()
            .crop(emccd_profile::Roi::corner(32, 32))
            .unwrap();
        let no_model = |m: &str| Err(Error::Model(format!("{m}: no models in this test")));
        let raw: Vec<f32> = (0..32 * 32)
            .map(|i| 120.0 + (i % 7) as f32 * 30.0)
            .collect();
        for (name, method) in [
            ("bm3d", Method::Bm3d),
            ("ivst", Method::Ivst),
            ("input", Method::None),
        ] {
            let est = Estimator::parse(name, no_model).unwrap();
            assert_eq!(est.name(), name);
            let fd = FrameDenoiser {
                profile: &p,
                method,
                model: None,
                tiling: Tiling::default(),
                ensemble: 1,
                units: Units::Dn,
            };
            assert_eq!(
                est.run(&p, &raw, 0.01).unwrap(),
                fd.run(&raw, 0.01).unwrap(),
                "{name}"
            );
        }
        assert!(Estimator::parse("ivst:1/3,0.5/1", no_model).is_ok());
        let e = Estimator::parse("ivst:x", no_model)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("ivst:x"), "{e}");
        let e = Estimator::parse("blend", no_model)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("lowlight"), "{e}");
    }
}
