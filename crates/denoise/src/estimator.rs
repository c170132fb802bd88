//! The methods `emccd evaluate` and `emccd bench` compare, by name ([`Estimator`]): every one
//! runs through the same [`Denoiser`] as `emccd denoise`.

use emccd_nn::tile::Tiling;
use emccd_nn::{Error, Inputs, Model, Result};
use emccd_profile::CameraProfile;

use crate::denoiser::Denoiser;
use crate::method::{Method, ModelSpec, Units};

/// A method under comparison, by the name `emccd evaluate --method` takes: `input` (the
/// preprocessed frame, no denoising), `bm3d`, `ivst`, `ivst:λ/b,…` (iterative BM3D with these
/// passes, for comparing schedules), `blend` (`blend@K` with the network's K-orientation
/// self-ensemble, `blend:MODEL[@K]` with another network), `temporal[:K]` (K frames each side),
/// `temporal-net` (the bundled temporal network), or a model (a bundled name or a file, `@K`
/// for a K-orientation self-ensemble; a hybrid model runs as [`Method::Hybrid`], a temporal one
/// as [`Method::TemporalNet`]). Models are loaded
/// once, when the name is parsed; every run goes through the same code as `emccd denoise`.
pub struct Estimator {
    name: String,
    kind: Kind,
}

enum Kind {
    /// Iterative BM3D with the passes given.
    Passes(emccd_classical::vst::Schedule),
    /// What `emccd denoise` runs for this method and model.
    Denoise {
        method: Method,
        model: Option<Model>,
        ensemble: usize,
        /// Frames each side, for a temporal method.
        window: usize,
    },
}

impl Estimator {
    /// The estimator `name` stands for, with its model loaded by `load` ([`crate::bundled::load`], or a
    /// loader that also knows models embedded in a program).
    pub fn parse(name: &str, load: impl Fn(&str) -> Result<Model>) -> Result<Estimator> {
        let classical = match name {
            "input" => Some(Method::None),
            "bm3d" => Some(Method::Bm3d),
            "ivst" => Some(Method::Ivst),
            _ => None,
        };
        // `temporal[:K]`: K frames each side.
        let (stem, window) = match name.split_once(':') {
            Some((m @ "temporal", k)) => (
                m,
                k.parse::<usize>()
                    .ok()
                    .filter(|k| *k <= crate::MAX_WINDOW)
                    .ok_or_else(|| {
                        Error::Model(format!(
                            "--method {name}: after `:`, the frames each side (0 to {})",
                            crate::MAX_WINDOW
                        ))
                    })?,
            ),
            _ => (name, crate::DEFAULT_WINDOW),
        };
        let kind = if stem == "temporal" {
            Kind::Denoise {
                method: Method::Temporal,
                model: None,
                ensemble: 1,
                window,
            }
        } else if let Some(method) = classical {
            Kind::Denoise {
                method,
                model: None,
                ensemble: 1,
                window: 0,
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
            if model.meta.inputs != Inputs::Noisy {
                return Err(Error::Model(format!(
                    "--method {name}: {model_name} is a {} network; blend averages ivst with a single-frame denoiser",
                    model.meta.inputs.name()
                )));
            }
            Kind::Denoise {
                method: Method::Blend,
                model: Some(model),
                ensemble,
                window: 0,
            }
        } else {
            // A model (bundled or a file) runs the method it was trained for; `temporal-net`
            // is the bundled temporal network.
            let spec = ModelSpec::parse(name)?;
            let model = load(match spec.model {
                "temporal-net" => Method::TemporalNet.default_model(),
                m => m,
            })?;
            let (method, window) = match model.meta.inputs {
                Inputs::Hybrid => (Method::Hybrid, 0),
                Inputs::Movie => (Method::TemporalNet, emccd_nn::MOVIE_WINDOW),
                Inputs::Noisy => (Method::Net, 0),
            };
            Kind::Denoise {
                method,
                model: Some(model),
                ensemble: spec.ensemble,
                window,
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
    pub fn model(&self) -> Option<&Model> {
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
                self.run_frames(p, raw, t)
                    .map_err(|e| emccd_io::error_lines(&e).join(": ").into())
            }),
            whole_stack: false,
        }
    }

    /// Its estimate of one raw frame (DN, the profile's size) taken with `exposure_s`, in DN
    /// above bias.
    pub fn run(&self, profile: &CameraProfile, raw: &[f32], exposure_s: f64) -> Result<Vec<f32>> {
        self.run_frames(profile, raw, exposure_s)
    }

    /// Its estimate of a movie's raw frames (each the profile's size, one after another), as
    /// `emccd denoise` gives it: a temporal method from each frame's neighbours, the others
    /// frame by frame.
    pub fn run_frames(
        &self,
        profile: &CameraProfile,
        raw: &[f32],
        exposure_s: f64,
    ) -> Result<Vec<f32>> {
        crate::movie::frame_count(profile, raw.len())?;
        let mut out = Vec::with_capacity(raw.len());
        match &self.kind {
            Kind::Passes(s) => {
                for f in raw.chunks(profile.len()) {
                    let pre = emccd_classical::frame::preprocess(profile, f, exposure_s)?;
                    out.extend(emccd_classical::frame::bm3d_passes(
                        profile, &pre, exposure_s, &s.0,
                    )?);
                }
                Ok(out)
            }
            Kind::Denoise {
                method,
                model,
                ensemble,
                window,
            } => {
                let fd = Denoiser {
                    profile,
                    method: *method,
                    model: model.as_ref(),
                    tiling: Tiling::default(),
                    ensemble: *ensemble,
                    units: Units::Dn,
                    window: *window,
                };
                crate::movie::denoise_slice(&fd, exposure_s, raw, &mut |_, f| {
                    out.extend(f);
                    Ok(())
                })?;
                Ok(out)
            }
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
            let e = Estimator::parse(name, |m: &str| -> Result<Model> {
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
            let fd = Denoiser {
                profile: &p,
                method,
                model: None,
                tiling: Tiling::default(),
                ensemble: 1,
                units: Units::Dn,
                window: 0,
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
