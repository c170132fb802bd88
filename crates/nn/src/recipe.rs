//! What a model file records about how it was made: the training recipe ([`TrainConfig`], also
//! `emccd train`'s flags with the `clap` feature) and an adaptation ([`Adaptation`]). These are
//! records, read back by `--init` and `--resume`; the training itself is `emccd-train`'s.

use std::path::Path;

use emccd_camera::{Ablation, NoiseModelKind};
use emccd_classical::Classical;
use serde::{Deserialize, Serialize};

use crate::norm::Scale;

/// The training loss on network-unit outputs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Loss {
    /// `√(d² + 10⁻⁶)`: L1-like, robust.
    #[default]
    Charbonnier,
    /// Mean squared error: what PSNR scores (the posterior mean minimizes it).
    L2,
}

/// The recipe (recorded in the model file it produces, [`crate::ModelMeta::train`]). With the
/// `clap` feature it is also `emccd train`'s flags (their defaults are [`TrainConfig::default`]'s,
/// tested); what a run resolves from its `--init` model (`scale`, `base`) is set by the caller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct TrainConfig {
    /// Optimizer steps.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().steps))]
    pub steps: u64,
    /// Crops per step.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().batch))]
    pub batch: usize,
    /// Crop side, px.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().crop))]
    pub crop: usize,
    /// Peak learning rate.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().lr))]
    pub lr: f64,
    /// AdamW weight decay.
    #[cfg_attr(feature = "clap", arg(skip = TrainConfig::default().weight_decay))]
    pub weight_decay: f64,
    /// Linear warm-up steps (at most a fifth of the run).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().warmup))]
    pub warmup: u64,
    /// Photo-electrons at a scene's brightest pixel, drawn log-uniformly from LO,HI.
    #[cfg_attr(feature = "clap", arg(long, default_value = "3,3000", value_parser = parse_range, value_name = "LO,HI"))]
    pub electrons: [f64; 2],
    /// Instead of the brightest pixel's: the scene's mean photo-electrons per pixel, drawn
    /// log-uniformly from LO,HI (how EMCCD light levels are quoted; e.g. 0.2,100 for the
    /// photon-starved range EMCCDs are used in, what the low-light suite measures).
    #[serde(default)]
    #[cfg_attr(feature = "clap", arg(long, value_parser = parse_range, value_name = "LO,HI"))]
    pub mean_electrons: Option<[f64; 2]>,
    /// Noise model pgn: clock-induced charge per pixel and frame (e⁻), drawn uniformly from
    /// LO,HI; default: the profile's.
    #[serde(default)]
    #[cfg_attr(feature = "clap", arg(long = "cic", value_parser = parse_range, value_name = "LO,HI"))]
    pub cic_e: Option<[f64; 2]>,
    /// Training loss.
    #[serde(default)]
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = TrainConfig::default().loss))]
    pub loss: Loss,
    /// How a denoiser's input is scaled per frame (recorded in the model it trains).
    #[serde(default, skip_serializing_if = "Scale::is_default")]
    #[cfg_attr(feature = "clap", arg(skip = TrainConfig::default().scale))]
    pub scale: Scale,
    /// Multiply the profile's read noise by a factor drawn log-uniformly from LO,HI for every
    /// pair (noise model ours), so the model learns many read-noise-to-gain ratios and serves
    /// cameras other than the training profile. 1,1: the profile's own read noise only.
    #[serde(default = "unit_range")]
    #[cfg_attr(feature = "clap", arg(long, default_value = "1,1", value_parser = parse_range, value_name = "LO,HI"))]
    pub read_noise_scale: [f64; 2],
    /// Use each synthesized pair about this many times (in different batches, with fresh flips
    /// and rotations) before it leaves the pool, so that synthesis costs batch/reuse pairs per
    /// step. Worth it for a refinement network (hybrid inputs), where every pair needs a
    /// BM3D run (about 0.4 s per 128² crop on one core). 1: every pair is fresh.
    #[serde(default = "one")]
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().reuse, value_parser = clap::value_parser!(u32).range(1..=64)))]
    pub reuse: u32,
    /// On (the default), each crop in one of the 8 flips/transposes, drawn at random (more
    /// views of few images); off (`--no-augment`), every crop keeps its image's orientation.
    #[serde(default = "yes", skip_serializing_if = "is_yes")]
    #[cfg_attr(feature = "clap", arg(long = "no-augment", action = clap::ArgAction::SetFalse, help = "Keep every crop in its image's orientation (by default each is in one of the 8 flips/transposes, drawn at random)"))]
    pub augment: bool,
    /// The estimate a refinement network is trained to correct.
    #[serde(default)]
    #[cfg_attr(feature = "clap", arg(skip = TrainConfig::default().base))]
    pub base: Classical,
    /// Noise model of the synthesized pairs.
    #[cfg_attr(feature = "clap", arg(long = "noise-model", value_name = "NOISE_MODEL", value_enum, default_value_t = TrainConfig::default().noise))]
    pub noise: NoiseModelKind,
    /// Components to switch off: multiplicative, readout, quantization (synthesis); fpn,
    /// blooming (recorded in the model: its denoising pipeline then skips that correction).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().ablate))]
    pub ablate: Ablation,
    /// Seed of everything random.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().seed))]
    pub seed: u64,
    /// Validate every this many steps.
    #[cfg_attr(feature = "clap", arg(skip = TrainConfig::default().val_every))]
    pub val_every: u64,
    /// Checkpoint every this many steps (`emccd train` also validates at this interval).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = TrainConfig::default().checkpoint_every))]
    pub checkpoint_every: u64,
}

/// `LO,HI`: two comma-separated numbers (a range to draw from).
pub fn parse_range(s: &str) -> std::result::Result<[f64; 2], String> {
    let v: Vec<&str> = s.split(',').map(str::trim).collect();
    match v[..] {
        [lo, hi] => match (lo.parse(), hi.parse()) {
            (Ok(lo), Ok(hi)) => Ok([lo, hi]),
            _ => Err(format!("{s:?}: two numbers, LO,HI")),
        },
        _ => Err(format!("{s:?}: two comma-separated numbers, LO,HI")),
    }
}

impl Default for TrainConfig {
    fn default() -> TrainConfig {
        TrainConfig {
            steps: 20_000,
            batch: 4,
            crop: 128,
            lr: 2e-4,
            weight_decay: 0.02,
            warmup: 500,
            electrons: [3.0, 3000.0],
            mean_electrons: None,
            cic_e: None,
            loss: Loss::Charbonnier,
            scale: Scale::Percentile,
            read_noise_scale: [1.0, 1.0],
            reuse: 1,
            augment: true,
            base: Classical::Bm3d,
            noise: NoiseModelKind::Ours,
            ablate: Ablation::default(),
            seed: 897,
            val_every: 250,
            checkpoint_every: 250,
        }
    }
}

fn unit_range() -> [f64; 2] {
    [1.0, 1.0]
}

fn one() -> u32 {
    1
}

fn yes() -> bool {
    true
}

fn is_yes(v: &bool) -> bool {
    *v
}

impl TrainConfig {
    /// A one-line description of the run on `train_images` scenes (validated on `val_images`), for the model file's `recipe`.
    pub fn recipe(&self, train_images: usize, val_images: usize) -> String {
        format!(
            "{} train / {} val images; batch {} × {}², each pair used ≈{}×; AdamW lr {} wd {} warm-up {} + cosine; {:?} loss; {}; read noise ×{:?}; CIC {:?}; seed {}",
            train_images,
            val_images,
            self.batch,
            self.crop,
            self.reuse,
            self.lr,
            self.weight_decay,
            self.warmup_steps(),
            self.loss,
            match self.mean_electrons {
                Some(r) => format!("mean electrons {r:?}"),
                None => format!("peak electrons {:?}", self.electrons),
            },
            self.read_noise_scale,
            self.cic_e,
            self.seed
        )
    }

    /// The warm-up a run takes: `warmup`, but at most a fifth of the steps (a short run, a
    /// test or a quick fine-tune, still spends most of its steps at the peak rate), at least 1.
    pub fn warmup_steps(&self) -> u64 {
        self.warmup.min(self.steps / 5).max(1)
    }

    /// Learning rate at `step`: linear warm-up ([`TrainConfig::warmup_steps`]), then cosine
    /// decay to 1 % of the peak.
    pub fn lr_at(&self, step: u64) -> f64 {
        let w = self.warmup_steps();
        if step < w {
            return self.lr * (step + 1) as f64 / w as f64;
        }
        let p = (step - w) as f64 / (self.steps.saturating_sub(w).max(1)) as f64;
        self.lr * (0.01 + 0.99 * 0.5 * (1.0 + (std::f64::consts::PI * p.min(1.0)).cos()))
    }
}

/// What an adapted model file records about its adaptation ([`crate::ModelMeta::adapted`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adaptation {
    /// How it was adapted (`resynthesis`, `noise2noise`, …).
    pub method: String,
    /// The model it started from (a bundled name or a file).
    pub from: String,
    /// The recordings it was adapted on (file names).
    pub files: Vec<String>,
    /// Frames it trained on (averaged into the scene estimate, or kept for self-supervision).
    pub frames: usize,
    /// The recording's mean photoelectrons per pixel, as the profile converts it.
    pub mean_electrons: f64,
}

impl Adaptation {
    /// The record of adapting `from` (a bundled name or a file; `scratch`: only its
    /// architecture was kept) by `method` on the recordings `files` (their file names are
    /// kept), `frames` of them at `mean_electrons` photoelectrons per pixel.
    pub fn new(
        method: &str,
        from: &str,
        scratch: bool,
        files: &[impl AsRef<Path>],
        frames: usize,
        mean_electrons: f64,
    ) -> Adaptation {
        Adaptation {
            method: method.into(),
            from: if scratch {
                format!("scratch ({from}'s architecture)")
            } else {
                from.to_string()
            },
            files: files
                .iter()
                .map(|p| {
                    let p = p.as_ref();
                    p.file_name()
                        .map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into())
                })
                .collect(),
            frames,
            mean_electrons,
        }
    }
}
