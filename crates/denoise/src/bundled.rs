//! The models that ship with emccd, by name, and model arguments (a bundled name or a file)
//! turned into model sources and loaded models. The bundled models are built into the library
//! (about 10 MB each), so a binary or a Python wheel works wherever it is copied; a directory
//! in `EMCCD_MODELS` replaces them (a GPU run's own copies, a newer training).

use std::path::PathBuf;

use burn::prelude::Device;
use emccd_nn::{Error, Model, ModelSource, Result};

/// A model that ships with emccd, by the name `--model` (and `model=`) accepts.
#[derive(Clone, Copy, Debug)]
pub struct Bundled {
    /// The name.
    pub name: &'static str,
    /// Its file name (in the repository's `models/`, and in an `EMCCD_MODELS` directory).
    pub file: &'static str,
    /// The file's bytes, built in.
    pub bytes: &'static [u8],
}

macro_rules! bundled_model {
    ($name:literal, $file:literal) => {
        Bundled {
            name: $name,
            file: $file,
            bytes: include_bytes!(concat!("../../../models/", $file)),
        }
    };
}

/// The bundled models: `hybrid` (BM3D-refining), `default` (natural images, the default
/// profile), `microscopy` (the default fine-tuned on fluorescence microscopy) and `lowlight`
/// (the low-light run: 0.3–30 mean photoelectrons per pixel, many cameras' read noise and CIC,
/// Charbonnier loss; the best of them, which `--method net` runs), and `movie` (`lowlight`
/// widened to five frames and trained on synthesized movies: `--method temporal-net`). Their
/// cards are in `models/README.md`.
pub const BUNDLED: [Bundled; 5] = [
    bundled_model!("hybrid", "hybrid-unet.safetensors"),
    bundled_model!("default", "default-unet.safetensors"),
    bundled_model!("microscopy", "microscopy-unet.safetensors"),
    bundled_model!("lowlight", "lowlight-unet.safetensors"),
    bundled_model!("movie", "movie-unet.safetensors"),
];

/// The bundled model of this name, if it is one.
pub fn bundled(name: &str) -> Option<&'static Bundled> {
    BUNDLED.iter().find(|b| b.name == name)
}

/// The directory `EMCCD_MODELS` names, if set: bundled names are read from files there.
fn models_override() -> Option<PathBuf> {
    std::env::var_os("EMCCD_MODELS")
        .filter(|d| !d.is_empty())
        .map(PathBuf::from)
}

/// The model a model argument stands for: a bundled model by name (built in, or its file in
/// `EMCCD_MODELS` when that is set), else the argument as a file, which must exist.
pub fn source(arg: &str) -> Result<ModelSource> {
    let source = match (bundled(arg), models_override()) {
        (Some(b), None) => {
            return Ok(ModelSource::Embedded {
                name: b.name,
                bytes: b.bytes,
            })
        }
        (Some(b), Some(dir)) => dir.join(b.file),
        (None, _) => PathBuf::from(arg),
    };
    if let Some(kind) = emccd_io::not_a_file(&source) {
        return Err(Error::Model(format!(
            "{}: not a model file ({kind}; a model is a .safetensors file)",
            source.display()
        )));
    }
    if !source.is_file() {
        return Err(Error::Model(format!(
            "{}: model not found{}",
            source.display(),
            if bundled(arg).is_some() {
                " (EMCCD_MODELS names a directory without this bundled model's file; unset it \
                 to use the built-in one)"
            } else {
                " (a bundled name — hybrid, default, microscopy, lowlight, movie — or a model file)"
            }
        )));
    }
    Ok(ModelSource::File(source))
}

/// Loads a model file, or a bundled model by name, onto `device`.
pub fn load(arg: &str, device: &Device) -> Result<Model> {
    source(arg)?.load(device)
}
