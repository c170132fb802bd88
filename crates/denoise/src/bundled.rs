//! The models that ship with emccd, by name, and model arguments (a bundled name or a file)
//! turned into files and loaded models.

use std::path::{Path, PathBuf};

use burn::prelude::Device;
use emccd_nn::{Error, Model, Result};

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

/// Loads a model file, or a bundled model by name, onto `device`.
pub fn load(arg: &str, device: &Device) -> Result<Model> {
    Model::load(&model_path(arg)?, device)
}
