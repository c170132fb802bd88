//! Adaptation of a model to a user's own recording, without clean data.
//!
//! The method ("resynthesis") uses what this project has and generic self-supervised tools do
//! not: the calibrated camera. The recording's frames are preprocessed and averaged (a static
//! scene: the mean of N frames has 1/N of a frame's noise variance), the average is denoised
//! with iterative BM3D at *its* noise level (gain α/N, read noise σ/√N), and that scene estimate
//! becomes the clean image of ordinary training: pairs synthesized from it with the profile's
//! exact noise chain at the recording's own light level, the model fine-tuned on them. The
//! network thus learns the sample's structures at the noise it will actually see.

use std::path::Path;

use emccd_camera::NoiseModelKind;
use emccd_profile::CameraProfile;
use serde::{Deserialize, Serialize};

use crate::train::{train, Image, Loss, RunPaths, StepReport, TrainConfig};
use crate::{Denoiser, Error, ModelMeta, Result};

/// What an adapted model file records about its adaptation ([`ModelMeta::adapted`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adaptation {
    /// How it was adapted (`resynthesis`: see the module documentation).
    pub method: String,
    /// The model it started from (a bundled name or a file).
    pub from: String,
    /// The recordings it was adapted on (file names).
    pub files: Vec<String>,
    /// Frames averaged into the scene estimate.
    pub frames: usize,
    /// The recording's mean photoelectrons per pixel, as the profile converts it.
    pub mean_electrons: f64,
}

/// Running mean of preprocessed frames (DN above bias), in bounded memory.
#[derive(Clone, Debug)]
pub struct FrameMean {
    width: usize,
    height: usize,
    sum: Vec<f64>,
    frames: usize,
}

impl FrameMean {
    /// An empty mean of `width × height` frames.
    pub fn new(width: usize, height: usize) -> FrameMean {
        FrameMean {
            width,
            height,
            sum: vec![0.0; width * height],
            frames: 0,
        }
    }

    /// Adds one frame; an error if its size differs.
    pub fn add(&mut self, frame: &[f32]) -> Result<()> {
        if frame.len() != self.sum.len() {
            return Err(Error::Data(format!(
                "a frame of {} pixels where the recording's frames have {}×{}",
                frame.len(),
                self.width,
                self.height
            )));
        }
        for (s, &v) in self.sum.iter_mut().zip(frame) {
            *s += v as f64;
        }
        self.frames += 1;
        Ok(())
    }

    /// Frames added.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The mean frame.
    pub fn mean(&self) -> Vec<f32> {
        let n = self.frames.max(1) as f64;
        self.sum.iter().map(|&s| (s / n) as f32).collect()
    }
}

/// A recording's scene, estimated from its frames alone.
#[derive(Clone, Debug)]
pub struct SceneEstimate {
    /// The scene scaled to [0, 1] (by its maximum): a clean training image.
    pub image: Image,
    /// DN above bias of the image's 1.0.
    pub dn_peak: f32,
    /// The recording's mean photoelectrons per pixel.
    pub mean_electrons: f64,
    /// Frames averaged.
    pub frames: usize,
}

/// The scene estimate of a recording from the mean of its preprocessed frames: the mean
/// denoised with iterative BM3D at the mean's own noise (gain α/N, read noise σ/√N).
pub fn scene_estimate(
    mean: &FrameMean,
    profile: &CameraProfile,
    exposure_s: f64,
) -> Result<SceneEstimate> {
    if mean.frames == 0 {
        return Err(Error::Data("the recording has no frames".into()));
    }
    if (mean.width, mean.height) != (profile.width, profile.height) {
        return Err(Error::Data(format!(
            "frames are {}×{}, the profile's sensor is {}×{}",
            mean.width, mean.height, profile.width, profile.height
        )));
    }
    let m = mean.mean();
    let n = mean.frames as f64;
    let p = crate::pipeline::vst_params(profile, exposure_s)?;
    let q = emccd_eval::vst::PoissonGaussian {
        alpha: p.alpha / n,
        sigma: p.sigma / n.sqrt(),
        mu: p.mu,
    };
    let est = emccd_eval::vst::bm3d_adaptive(&m, mean.width, mean.height, q);
    let finite_mean = m
        .iter()
        .filter(|v| v.is_finite())
        .map(|&v| v as f64)
        .sum::<f64>()
        / m.len() as f64;
    // An EM register's output has 2× the variance of the photoelectrons' Poisson noise
    // (excess noise factor √2), so the photon-transfer slope is 2 DN per photoelectron's DN.
    let mean_electrons = finite_mean / (p.alpha / 2.0);
    let peak = est
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0f32, f32::max);
    if !(mean_electrons > 0.0 && peak > 0.0) {
        return Err(Error::Data(format!(
            "the recording has no signal above bias (mean {finite_mean:.3} DN): nothing to adapt to"
        )));
    }
    Ok(SceneEstimate {
        image: Image {
            width: mean.width,
            height: mean.height,
            data: est
                .iter()
                .map(|&v| {
                    if v.is_finite() {
                        (v / peak).clamp(0.0, 1.0)
                    } else {
                        0.0
                    }
                })
                .collect(),
        },
        dn_peak: peak,
        mean_electrons,
        frames: mean.frames,
    })
}

/// How an adaptation runs.
#[derive(Clone, Debug, PartialEq)]
pub struct AdaptConfig {
    /// Optimizer steps.
    pub steps: u64,
    /// Peak learning rate (a fine-tune: lower than training from scratch).
    pub lr: f64,
    /// Crops per step.
    pub batch: usize,
    /// Largest crop side (smaller frames use their own size, rounded to the network's multiple).
    pub crop: usize,
    /// Training pairs span the recording's mean light level ÷ and × this factor.
    pub spread: f64,
    /// Noise model of the synthesized pairs (`ours`: the calibrated exact chain).
    pub noise: NoiseModelKind,
    /// Seed.
    pub seed: u64,
    /// Checkpoint every this many steps.
    pub checkpoint_every: u64,
}

impl Default for AdaptConfig {
    fn default() -> AdaptConfig {
        AdaptConfig {
            steps: 300,
            lr: 2e-4,
            batch: 4,
            crop: 128,
            spread: 1.5,
            noise: NoiseModelKind::Ours,
            seed: 2411,
            checkpoint_every: 50,
        }
    }
}

/// Fine-tunes the model at `init` on `scene` (see the module documentation) and writes it to
/// `paths.out`, recording `provenance`. `report` is called after every step (return `false` to
/// stop: the checkpoint stays and `--resume` continues).
#[allow(clippy::too_many_arguments)]
pub fn adapt(
    scene: &SceneEstimate,
    profile: &CameraProfile,
    init: &Path,
    cfg: &AdaptConfig,
    provenance: Adaptation,
    paths: &RunPaths,
    resume: bool,
    report: &mut dyn FnMut(&StepReport) -> bool,
) -> Result<Denoiser> {
    if !(cfg.spread >= 1.0 && cfg.spread.is_finite()) {
        return Err(Error::Data(format!(
            "spread {}: must be at least 1",
            cfg.spread
        )));
    }
    let start = Denoiser::load(init, &crate::device())?;
    let multiple = start.meta.multiple();
    let side = cfg.crop.min(scene.image.width).min(scene.image.height) / multiple * multiple;
    if side == 0 {
        return Err(Error::Data(format!(
            "frames of {}×{} are smaller than the {multiple}-px unit of {}",
            scene.image.width,
            scene.image.height,
            start.meta.arch.name()
        )));
    }
    let m = scene.mean_electrons;
    let tc = TrainConfig {
        steps: cfg.steps,
        batch: cfg.batch,
        crop: side,
        lr: cfg.lr,
        warmup: (cfg.steps / 10).min(50),
        mean_electrons: Some([m / cfg.spread, m * cfg.spread]),
        loss: Loss::Charbonnier,
        read_noise_scale: [1.0, 1.0],
        noise: cfg.noise,
        ablate: start.meta.ablate,
        seed: cfg.seed,
        val_every: cfg.checkpoint_every,
        checkpoint_every: cfg.checkpoint_every,
        ..TrainConfig::default()
    };
    let meta = ModelMeta {
        noise_model: cfg.noise,
        profile_fingerprint: format!("{:016x}", profile.fingerprint()),
        recipe: format!(
            "adapted ({}) from {} on {} frames of {} at {:.3} mean e⁻/pixel: {} steps, batch {} × {side}², lr {}, seed {}",
            provenance.method,
            provenance.from,
            provenance.frames,
            provenance.files.join(", "),
            m,
            cfg.steps,
            cfg.batch,
            cfg.lr,
            cfg.seed
        ),
        adapted: Some(provenance),
        ..start.meta.clone()
    };
    drop(start);
    train(
        vec![scene.image.clone()],
        Vec::new(),
        profile,
        tc,
        meta,
        Some(init),
        resume,
        paths,
        report,
    )
}
