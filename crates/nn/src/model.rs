//! A denoising model on disk: safetensors weights plus metadata (architecture and its
//! configuration, noise model, the profile it was trained for, the recipe and step count).
//! Loading reads tensors and strings only; nothing in a model file is executed.

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use burn::prelude::*;
use burn_store::{ModuleSnapshot, SafetensorsStore};
use serde::{Deserialize, Serialize};

use emccd_camera::{Ablation, NoiseModelKind};

use crate::norm::Scale;
use crate::recipe::{Adaptation, TrainConfig};
use crate::uformer::{Uformer, UformerConfig};
use crate::unet::{UNet, UNetConfig};
use crate::{Error, Result};
pub use emccd_classical::Classical;

/// Architectures this build knows, by the names flags and model files use.
pub const ARCHS: [&str; 4] = ["unet", "uformer-t", "uformer-s", "uformer-b"];

/// A network's architecture and size. On disk (as model files have always said it): the `arch`
/// name beside a `unet` or `uformer` table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Arch {
    /// The U-Net.
    UNet(UNetConfig),
    /// A Uformer (`uformer-t`, `-s` and `-b` are its presets).
    Uformer(UformerConfig),
}

impl Arch {
    /// The name flags and files use: `unet`, a Uformer preset's name, or `uformer` for a
    /// Uformer of another size.
    pub fn name(&self) -> &'static str {
        match self {
            Arch::UNet(_) => "unet",
            Arch::Uformer(c) => ["uformer-t", "uformer-s", "uformer-b"]
                .into_iter()
                .find(|n| {
                    UformerConfig::by_name(n).is_some_and(|p| {
                        UformerConfig {
                            in_channels: c.in_channels,
                            ..p
                        } == *c
                    })
                })
                .unwrap_or("uformer"),
        }
    }

    /// The architecture named `name` (one of [`ARCHS`]) for a new network taking `inputs`: a
    /// Uformer preset, or a U-Net of `unet`'s size (`base`, `levels`, `direct`, `unshuffle`; its
    /// channels and residual follow `inputs`). Refuses what this build has not: an unknown
    /// name, a refinement or temporal network (hybrid or movie inputs), a direct output or an
    /// unshuffled input on anything but a U-Net, a direct refinement network, an unshuffle
    /// other than 1, 2 or 4.
    pub fn for_training(name: &str, inputs: Inputs, unet: UNetConfig) -> Result<Arch> {
        let uformer = UformerConfig::by_name(name);
        if uformer.is_none() && name != "unet" {
            return Err(Error::Model(format!(
                "architecture {name:?}: this build has {}",
                ARCHS.join(", ")
            )));
        }
        if unet.direct && (inputs == Inputs::Hybrid || name != "unet") {
            return Err(Error::Model(
                "a direct output: only a U-Net denoiser (arch unet, noisy or movie inputs) has one"
                    .into(),
            ));
        }
        if unet.unshuffle != 1 && (name != "unet" || ![2, 4].contains(&unet.unshuffle)) {
            return Err(Error::Model(format!(
                "unshuffle {}: a U-Net folds 2×2 or 4×4 blocks into channels (1: none); other architectures take no unshuffle",
                unet.unshuffle
            )));
        }
        if inputs != Inputs::Noisy && name != "unet" {
            return Err(Error::Model(format!(
                "{} inputs: that network is a U-Net in this build (arch unet)",
                inputs.name()
            )));
        }
        Ok(match uformer {
            Some(c) => Arch::Uformer(c),
            None => Arch::UNet(UNetConfig {
                in_channels: inputs.channels(),
                residual: inputs.residual(),
                ..unet
            }),
        })
    }

    /// Input channels of the network.
    pub fn in_channels(&self) -> usize {
        match self {
            Arch::UNet(c) => c.in_channels,
            Arch::Uformer(c) => c.in_channels,
        }
    }

    /// Frame sides the network accepts are multiples of this (frames are padded to it).
    pub fn multiple(&self) -> usize {
        match self {
            Arch::UNet(c) => c.multiple(),
            Arch::Uformer(c) => c.multiple(),
        }
    }
}

/// The on-disk keys of [`Arch`].
#[derive(Serialize, Deserialize)]
struct ArchKeys {
    arch: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    unet: Option<UNetConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    uformer: Option<UformerConfig>,
}

impl Serialize for Arch {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let (unet, uformer) = match *self {
            Arch::UNet(c) => (Some(c), None),
            Arch::Uformer(c) => (None, Some(c)),
        };
        ArchKeys {
            arch: self.name().into(),
            unet,
            uformer,
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for Arch {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Arch, D::Error> {
        use serde::de::Error as _;
        let k = ArchKeys::deserialize(d)?;
        match (k.arch.as_str(), k.unet, k.uformer) {
            ("unet", Some(c), _) => Ok(Arch::UNet(c)),
            (a, _, Some(c)) if a.starts_with("uformer") => Ok(Arch::Uformer(c)),
            (a, _, _) if ARCHS.contains(&a) || a == "uformer" => Err(D::Error::custom(format!(
                "model metadata names architecture {a:?} but not its configuration"
            ))),
            (a, _, _) => Err(D::Error::custom(format!(
                "unknown architecture {a:?} (this build has: {})",
                ARCHS.join(", ")
            ))),
        }
    }
}

/// A network of any architecture this build has. Model files name tensors without the
/// variant (`enc.0.c1.weight`, not `UNet.enc.0.c1.weight`): the metadata says which it is.
#[derive(Module, Debug)]
pub enum Net {
    /// The convolutional U-Net.
    UNet(UNet),
    /// The paper's transformer.
    Uformer(Uformer),
}

impl Net {
    /// `x`: [N, C, H, W] ([`Inputs::channels`]: normalized frame, noise level, and for a
    /// refinement network the estimate it refines; for a temporal one the window's frames,
    /// then the noise level), H and W multiples of
    /// [`ModelMeta::multiple`]; returns the denoised [N, 1, H, W].
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        match self {
            Net::UNet(n) => n.forward(x),
            Net::Uformer(n) => n.forward(x),
        }
    }
}

/// What a network is given, which also fixes how the frame is normalized.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Inputs {
    /// A denoiser: the frame and its noise level, scaled by the noisy frame's 99.5th percentile
    /// ([`crate::norm::prepare`]).
    #[default]
    #[cfg_attr(
        feature = "clap",
        value(help = "a denoiser: the frame and its noise level")
    )]
    Noisy,
    /// A refinement network: the frame, its noise level and the BM3D + GAT estimate, scaled by
    /// the estimate's 99.5th percentile ([`crate::norm::prepare_hybrid`]); the output is the
    /// estimate plus a learned correction.
    #[cfg_attr(
        feature = "clap",
        value(help = "a refinement network: also the BM3D estimate, which it corrects")
    )]
    Hybrid,
    /// A temporal denoiser: the frame with [`MOVIE_WINDOW`] frames of its movie on each side,
    /// then the frame's noise level, all scaled by the frame's own rule
    /// ([`crate::norm::prepare_movie`]); the output is a correction to the frame.
    #[cfg_attr(
        feature = "clap",
        value(help = "a temporal denoiser: the frame, 2 frames each side and its noise level")
    )]
    Movie,
}

/// Frames each side of the one it denoises that a temporal network ([`Inputs::Movie`]) sees.
pub const MOVIE_WINDOW: usize = 2;

impl Inputs {
    /// Input channels the network takes.
    pub fn channels(self) -> usize {
        match self {
            Inputs::Noisy => 2,
            Inputs::Hybrid => 3,
            Inputs::Movie => 2 * MOVIE_WINDOW + 2,
        }
    }

    /// Frames of a movie the network sees at once (1 for a single-frame network).
    pub fn frames(self) -> usize {
        match self {
            Inputs::Movie => 2 * MOVIE_WINDOW + 1,
            Inputs::Noisy | Inputs::Hybrid => 1,
        }
    }

    /// The input channel the network's output is a correction to: the noisy frame, the
    /// estimate a hybrid refines, or a temporal network's centre frame.
    pub fn residual(self) -> usize {
        match self {
            Inputs::Noisy => 0,
            Inputs::Hybrid => 2,
            Inputs::Movie => MOVIE_WINDOW,
        }
    }

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Inputs::Noisy => "noisy",
            Inputs::Hybrid => "hybrid",
            Inputs::Movie => "movie",
        }
    }
}

/// Everything a model file says about itself: what running it needs (architecture, inputs,
/// base, scale, ablation: the contract the denoising pipeline reads; a file without the
/// `inputs`, `base` or `scale` key has that field's default) and how it came to be (noise
/// model, profile, steps, recipe, the last run's `train` configuration, `adapted`). `train` is
/// a record of the last run, not a second contract: its base, scale, noise model and ablation
/// are the fields above (`train_from` sets both from the run), and files written
/// before runs were recorded have only the fields above, so those are what readers use.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelMeta {
    /// Architecture and size.
    #[serde(flatten)]
    pub arch: Arch,
    /// What the network is given (files without the key are denoisers).
    #[serde(default)]
    pub inputs: Inputs,
    /// The estimate a refinement network corrects (files without the key: one BM3D pass).
    #[serde(default)]
    pub base: Classical,
    /// Noise model the training pairs were synthesized with.
    pub noise_model: NoiseModelKind,
    /// Ablated components (on disk: their names, `[]` for the full model).
    pub ablate: Ablation,
    /// How the network's input is scaled per frame (files without the key: the percentile).
    #[serde(default, skip_serializing_if = "Scale::is_default")]
    pub scale: Scale,
    /// Fingerprint (hex) of the profile used in training.
    pub profile_fingerprint: String,
    /// Optimizer steps taken.
    pub steps: u64,
    /// Free text: data, batch, crop, learning-rate schedule, seed.
    pub recipe: String,
    /// The configuration of the training run that wrote the file (the last one, for a
    /// fine-tuned model; files written before it was recorded have none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train: Option<TrainConfig>,
    /// For a model adapted to a recording (`emccd adapt`): on what, and from which model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adapted: Option<Adaptation>,
}

impl ModelMeta {
    /// Frame sides the network accepts are multiples of this (frames are padded to it).
    pub fn multiple(&self) -> usize {
        self.arch.multiple()
    }
}

const META_KEY: &str = "emccd_model";

/// A network with its metadata, on the device it runs on (chosen by whoever loads it).
#[derive(Debug)]
pub struct Model {
    /// The network.
    pub net: Net,
    /// Its description.
    pub meta: ModelMeta,
    device: Device,
}

impl Model {
    /// The device its network lives on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// This model for inference after training: its network without the autodiff graph, on
    /// `device` (the device it trained on, without autodiff).
    pub fn valid(self, device: &Device) -> Model {
        Model {
            net: self.net.valid(),
            meta: self.meta,
            device: device.clone(),
        }
    }

    /// The network's trainable parameters.
    pub fn num_params(&self) -> usize {
        burn::module::Module::num_params(&self.net)
    }

    /// A freshly initialized model.
    pub fn new(meta: ModelMeta, device: &Device) -> Result<Model> {
        check_size(&meta).map_err(|e| Error::Model(format!("model configuration: {e}")))?;
        let channels = meta.arch.in_channels();
        if channels != meta.inputs.channels() {
            return Err(Error::Model(format!(
                "model metadata: a {} network takes {} input channels, its configuration says {channels}",
                meta.inputs.name(),
                meta.inputs.channels(),
            )));
        }
        let net = match meta.arch {
            // The residual is what the output corrects: the input's frame, or the estimate a
            // hybrid refines.
            Arch::UNet(c) if !c.direct && c.residual != meta.inputs.residual() => {
                return Err(Error::Model(format!(
                    "model metadata: a {} network corrects input channel {}, its configuration says {}",
                    meta.inputs.name(),
                    meta.inputs.residual(),
                    c.residual
                )));
            }
            Arch::UNet(c) => Net::UNet(c.init(device)),
            Arch::Uformer(_) if meta.inputs != Inputs::Noisy => {
                return Err(Error::Model(format!(
                    "a {} network is a U-Net in this build, not {}",
                    meta.inputs.name(),
                    meta.arch.name()
                )));
            }
            Arch::Uformer(c) => Net::Uformer(c.init(device)),
        };
        Ok(Model {
            net,
            meta,
            device: device.clone(),
        })
    }

    /// Writes the model atomically (temporary file, then rename).
    pub fn save(&self, path: &Path) -> Result<()> {
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).map_err(|e| Error::io(path, e))?;
        let tmp = emccd_io::temp_beside(path).map_err(|e| Error::io(path, e))?;
        let meta = serde_json::to_string(&self.meta).map_err(|e| Error::Model(e.to_string()))?;
        let mut store = SafetensorsStore::from_file(tmp.path())
            .metadata(META_KEY, meta)
            .overwrite(true)
            .skip_enum_variants(true);
        self.net
            .save_into(&mut store)
            .map_err(|e| Error::Model(format!("{}: {e}", path.display())))?;
        // The same model is the same bytes (safetensors writes its metadata in hash order).
        let bytes = std::fs::read(tmp.path()).map_err(|e| Error::io(path, e))?;
        std::fs::write(tmp.path(), emccd_io::safetensors_sorted(bytes))
            .map_err(|e| Error::io(path, e))?;
        emccd_io::persist(tmp, path).map_err(|e| Error::Model(e.to_string()))
    }

    /// Reads only the metadata of a model file.
    pub fn read_meta(path: &Path) -> Result<ModelMeta> {
        let bytes = emccd_io::read_regular(path).map_err(|e| Error::io(path, e))?;
        meta_of(&bytes, path)
    }

    /// Loads a model onto `device`.
    pub fn load(path: &Path, device: &Device) -> Result<Model> {
        let bytes = emccd_io::read_regular(path).map_err(|e| Error::io(path, e))?;
        Model::from_bytes(bytes, path, device)
    }

    /// Loads a model from the bytes of a model file (`path` names it in messages): for models
    /// a program carries inside it ([`ModelSource::Embedded`]).
    pub fn from_bytes(bytes: Vec<u8>, path: &Path, device: &Device) -> Result<Model> {
        let meta = meta_of(&bytes, path)?;
        let mut d = Model::new(meta, device)?;
        let mut store = SafetensorsStore::from_bytes(Some(bytes)).skip_enum_variants(true);
        let r = d
            .net
            .load_from(&mut store)
            .map_err(|e| import_error(path, e))?;
        if !r.missing.is_empty() {
            return Err(Error::Model(format!(
                "{}: weights missing for {:?}",
                path.display(),
                r.missing
            )));
        }
        Ok(d)
    }
}

/// Where a model's bytes come from: a file, or bytes the program carries inside it (the
/// bundled models, so that a binary copied anywhere has them).
#[derive(Clone, Debug, PartialEq)]
pub enum ModelSource {
    /// A model file.
    File(PathBuf),
    /// A model built into the program, by its name.
    Embedded {
        /// The name it is asked for by (`lowlight`, …).
        name: &'static str,
        /// The model file's bytes.
        bytes: &'static [u8],
    },
}

impl ModelSource {
    /// The model file's bytes.
    pub fn bytes(&self) -> Result<Cow<'static, [u8]>> {
        match self {
            ModelSource::File(p) => Ok(Cow::Owned(
                emccd_io::read_regular(p).map_err(|e| Error::io(p, e))?,
            )),
            ModelSource::Embedded { bytes, .. } => Ok(Cow::Borrowed(bytes)),
        }
    }

    /// The file, for a model read from one.
    pub fn file(&self) -> Option<&Path> {
        match self {
            ModelSource::File(p) => Some(p),
            ModelSource::Embedded { .. } => None,
        }
    }

    /// How messages name it: the file's path, or `bundled model NAME`.
    pub fn label(&self) -> PathBuf {
        match self {
            ModelSource::File(p) => p.clone(),
            ModelSource::Embedded { name, .. } => PathBuf::from(format!("bundled model {name}")),
        }
    }

    /// Reads only the model's metadata.
    pub fn read_meta(&self) -> Result<ModelMeta> {
        meta_of(&self.bytes()?, &self.label())
    }

    /// Loads the model onto `device`.
    pub fn load(&self, device: &Device) -> Result<Model> {
        Model::from_bytes(self.bytes()?.into_owned(), &self.label(), device)
    }
}

impl std::fmt::Display for ModelSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.label().display())
    }
}

fn meta_of(bytes: &[u8], path: &Path) -> Result<ModelMeta> {
    let (_, header) = safetensors::SafeTensors::read_metadata(bytes).map_err(|e| {
        Error::Model(format!(
            "{}: not a safetensors model file ({e})",
            path.display()
        ))
    })?;
    let map: HashMap<String, String> = header.metadata().clone().unwrap_or_default();
    let text = map.get(META_KEY).ok_or_else(|| {
        Error::Model(format!(
            "{}: safetensors file without emccd model metadata",
            path.display()
        ))
    })?;
    let meta: ModelMeta = serde_json::from_str(text)
        .map_err(|e| Error::Model(format!("{}: model metadata: {e}", path.display())))?;
    check_size(&meta)
        .map_err(|e| Error::Model(format!("{}: model metadata: {e}", path.display())))?;
    Ok(meta)
}

/// Refuses network sizes no emccd model has, before anything is built from them: a damaged or
/// hostile file could otherwise ask for a million channels, or 70 levels whose channel count
/// doubles past the integer range.
fn check_size(meta: &ModelMeta) -> std::result::Result<(), String> {
    if let Arch::UNet(c) = meta.arch {
        // Channels double at every level: bound the deepest level's width, not only the first.
        if !(1..=512).contains(&c.channels)
            || !(1..=8).contains(&c.levels)
            || c.channels << c.levels > 4096
            || ![1, 2, 4].contains(&c.unshuffle)
        {
            return Err(format!(
                "a U-Net of {} channels, {} levels and unshuffle {} is outside what emccd builds (1–512 channels, 1–8 levels, at most 4096 channels at the deepest level, unshuffle 1, 2 or 4)",
                c.channels, c.levels, c.unshuffle
            ));
        }
    }
    if let Arch::Uformer(c) = meta.arch {
        if !(1..=128).contains(&c.embed)
            || c.depths.iter().sum::<usize>() > 64
            || !(1..=64).contains(&c.win)
        {
            return Err(format!(
                "a Uformer with embedding {}, depths {:?} and windows of {} px is outside what emccd builds",
                c.embed, c.depths, c.win
            ));
        }
    }
    Ok(())
}

/// burn's import error, shortened: a file whose weights disagree with its metadata lists every
/// tensor (kilobytes of text); say how many and show the first.
fn import_error(path: &Path, e: impl std::fmt::Display) -> Error {
    let text = e.to_string();
    let n = text.matches("ShapeMismatch").count();
    if n == 0 {
        return Error::Model(format!("{}: {text}", path.display()));
    }
    let first: String = text
        .split("ShapeMismatch")
        .nth(1)
        .unwrap_or("")
        .chars()
        .take(160)
        .collect();
    Error::Model(format!(
        "{}: {n} weights have other shapes than the metadata's network (the file's metadata and weights disagree); the first:{first}…",
        path.display()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sized(channels: usize, levels: usize, direct: bool, unshuffle: usize) -> UNetConfig {
        UNetConfig {
            channels,
            levels,
            direct,
            unshuffle,
            ..UNetConfig::DEFAULT
        }
    }

    #[test]
    fn architectures_for_training_are_the_builds_and_their_combinations() {
        let unet = Arch::for_training("unet", Inputs::Hybrid, sized(16, 3, false, 1)).unwrap();
        assert_eq!(unet.name(), "unet");
        assert_eq!(unet.in_channels(), Inputs::Hybrid.channels());
        assert_eq!(unet.multiple(), 8);
        let folded = Arch::for_training("unet", Inputs::Noisy, sized(16, 3, false, 2)).unwrap();
        assert_eq!(folded.multiple(), 16);
        let t = Arch::for_training("uformer-t", Inputs::Noisy, sized(16, 3, false, 1)).unwrap();
        assert_eq!(t.name(), "uformer-t");
        for (name, inputs, direct, unshuffle, says) in [
            ("resnet", Inputs::Noisy, false, 1, "this build has"),
            ("uformer-s", Inputs::Noisy, true, 1, "direct output"),
            ("unet", Inputs::Hybrid, true, 1, "direct output"),
            ("uformer-b", Inputs::Hybrid, false, 1, "hybrid inputs"),
            ("uformer-t", Inputs::Movie, false, 1, "movie inputs"),
            ("uformer-t", Inputs::Noisy, false, 2, "unshuffle 2"),
            ("unet", Inputs::Noisy, false, 3, "unshuffle 3"),
        ] {
            let e = Arch::for_training(name, inputs, sized(16, 3, direct, unshuffle))
                .unwrap_err()
                .to_string();
            assert!(e.contains(says), "{name}: {e}");
        }
    }
}
