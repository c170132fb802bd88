//! Adaptation of a model to a user's own recording, without clean data.
//!
//! The default method ("resynthesis") uses what this project has and generic self-supervised
//! tools do not: the calibrated camera. The recording's frames are preprocessed and averaged (a
//! static scene: the mean of N frames has 1/N of a frame's noise variance), the average is
//! denoised with iterative BM3D at *its* noise level (gain α/N, read noise σ/√N), and that scene
//! estimate becomes the clean image of ordinary training: pairs synthesized from it with the
//! profile's exact noise chain at the recording's own light level, the model fine-tuned on them.
//! The network thus learns the sample's structures at the noise it will actually see.
//!
//! Two self-supervised methods train on the recorded frames themselves ([`AdaptMethod`]):
//! Noise2Noise between frames of the static scene, and spatial-redundancy sampling of single
//! frames (SRDTrans, Neighbor2Neighbor); the latter, from a new network, is the paper's
//! self-supervised baseline.

use emccd_camera::{Ablation, NoiseModelKind};
use emccd_profile::CameraProfile;

use crate::recorded::{AdaptMethod, FrameMean, FrameSet, RecordedPairs};
use crate::train::{train_from, Image, Run, RunPaths, Source, StepReport};
use emccd_nn::norm::Scale;
use emccd_nn::{Adaptation, Error, Loss, Model, ModelMeta, ModelSource, Result, TrainConfig};

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
    let q = emccd_classical::frame::vst_params(profile, exposure_s)?.of_mean(n);
    let est = emccd_classical::vst::bm3d_adaptive(&m, mean.width, mean.height, q);
    let finite_mean = m
        .iter()
        .filter(|v| v.is_finite())
        .map(|&v| v as f64)
        .sum::<f64>()
        / m.len() as f64;
    let mean_electrons = finite_mean / profile.dn_per_electron()?;
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

/// How an adaptation runs (with the `clap` feature, `emccd adapt`'s recipe flags; the
/// learning rate's default depends on the start, [`AdaptConfig::default_lr`]).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct AdaptConfig {
    /// Where the training pairs come from.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = AdaptConfig::default().method))]
    pub method: AdaptMethod,
    /// Fine-tuning steps (about 1 s each for 4 × 128² crops on 2 cores; the default takes
    /// about 8 minutes).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = AdaptConfig::default().steps))]
    pub steps: u64,
    /// Peak learning rate (a fine-tune: lower than training from scratch).
    #[cfg_attr(feature = "clap", arg(skip = AdaptConfig::default().lr))]
    pub lr: f64,
    /// Crops per step.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = AdaptConfig::default().batch))]
    pub batch: usize,
    /// Largest training crop side, px (smaller frames use their own size, rounded to the
    /// network's multiple; half of it with --method neighbors).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = AdaptConfig::default().crop))]
    pub crop: usize,
    /// Resynthesized pairs span the recording's mean light level divided and multiplied by
    /// this factor (1: exactly its level).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = AdaptConfig::default().spread))]
    pub spread: f64,
    /// Each crop in one of the 8 flips/transposes, drawn at random; off (the default), every
    /// crop in the recording's own orientation. A network adapted to one scene should learn it
    /// as the held-out frames show it: with flips, seven of eight crops are views those frames
    /// never have, and a camera need not be isotropic (blooming runs along columns).
    #[cfg_attr(feature = "clap", arg(long, action = clap::ArgAction::SetTrue, help = "Train on crops in any of the 8 flips/transposes of the recording (by default every crop keeps the recording's own orientation, which adapts about twice as much)"))]
    pub augment: bool,
    /// Noise model of the synthesized pairs (`ours`: the profile's exact EMCCD chain).
    #[cfg_attr(feature = "clap", arg(long = "noise-model", value_name = "NOISE_MODEL", value_enum, default_value_t = AdaptConfig::default().noise))]
    pub noise: NoiseModelKind,
    /// Seed.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = AdaptConfig::default().seed))]
    pub seed: u64,
    /// Checkpoint every this many steps.
    #[cfg_attr(feature = "clap", arg(skip = AdaptConfig::default().checkpoint_every))]
    pub checkpoint_every: u64,
}

impl AdaptConfig {
    /// The training run this adaptation is: crops of `side` px around `level` mean
    /// photoelectrons per pixel, from a model described by `start`.
    fn train_config(&self, side: usize, level: f64, start: &ModelMeta) -> TrainConfig {
        TrainConfig {
            steps: self.steps,
            batch: self.batch,
            crop: side,
            lr: self.lr,
            warmup: (self.steps / 10).min(50),
            mean_electrons: Some([level / self.spread, level * self.spread]),
            // Recorded targets are noisy: only an L2 loss has the scene (their mean) as its
            // minimizer; a Charbonnier loss would pull towards the skewed EM noise's median.
            loss: match self.method {
                AdaptMethod::Resynthesis => Loss::Charbonnier,
                _ => Loss::L2,
            },
            read_noise_scale: [1.0, 1.0],
            augment: self.augment,
            noise: self.noise,
            ablate: start.ablate,
            // The network keeps the input scaling it was trained with.
            scale: start.scale,
            seed: self.seed,
            val_every: self.checkpoint_every,
            checkpoint_every: self.checkpoint_every,
            ..TrainConfig::default()
        }
    }

    /// The peak learning rate of a network trained from scratch on the recording (the
    /// self-supervised baseline): a new network needs the rate a training run starts with, not
    /// a fine-tune's.
    pub const SCRATCH_LR: f64 = 1e-3;

    /// An error unless the recipe is usable (checked before any frame is read, and again by
    /// [`adapt`]).
    pub fn check(&self) -> Result<()> {
        if !(self.spread >= 1.0 && self.spread.is_finite()) {
            return Err(Error::Data(format!(
                "--spread {}: must be at least 1",
                self.spread
            )));
        }
        if self.batch == 0 || self.steps == 0 {
            return Err(Error::Data(format!(
                "{} steps of {} crops: both must be at least 1",
                self.steps, self.batch
            )));
        }
        Ok(())
    }

    /// The default peak rate of a run that starts from a model (`scratch` false) or from its
    /// architecture alone.
    pub fn default_lr(scratch: bool) -> f64 {
        if scratch {
            Self::SCRATCH_LR
        } else {
            AdaptConfig::default().lr
        }
    }
}

impl Default for AdaptConfig {
    /// 400 steps at a peak rate of 5·10⁻⁴, crops in the recording's own orientation: on
    /// held-out frames of emccd-detect's cameras A and B (never used to choose it) +0.53–1.21 dB
    /// over the bundled `lowlight` per stack, where the same steps with flips and transposes
    /// gave +0.39–0.71 (docs/results.md).
    fn default() -> AdaptConfig {
        AdaptConfig {
            method: AdaptMethod::Resynthesis,
            steps: 400,
            lr: 5e-4,
            batch: 4,
            crop: 128,
            spread: 1.5,
            augment: false,
            noise: NoiseModelKind::Ours,
            seed: 2411,
            checkpoint_every: 50,
        }
    }
}

/// The network an adaptation starts from.
#[derive(Clone, Debug)]
pub enum Start<'a> {
    /// A model, fine-tuned.
    Model(&'a ModelSource),
    /// A new network of this architecture, initialized from the seed: the self-supervised
    /// baseline trained on the recording alone.
    Scratch(ModelMeta),
}

/// One adaptation: the camera, the network it starts from, the recipe, what the model file
/// will record about it, and where it is saved.
#[derive(Clone, Debug)]
pub struct AdaptRun<'a> {
    /// The recording's camera.
    pub profile: &'a CameraProfile,
    /// The network it starts from.
    pub start: Start<'a>,
    /// The recipe.
    pub cfg: &'a AdaptConfig,
    /// What the adapted model file records ([`ModelMeta::adapted`]).
    pub provenance: Adaptation,
    /// The output and the checkpoint directory.
    pub paths: &'a RunPaths,
    /// Continue from the checkpoint in `paths.checkpoint`.
    pub resume: bool,
    /// Where the network trains (the caller's choice: `emccd_nn::device`).
    pub device: burn::prelude::Device,
}

/// What an adaptation trains on.
#[derive(Clone, Debug)]
pub enum AdaptData {
    /// A recording's scene estimate ([`AdaptMethod::Resynthesis`]).
    Scene(SceneEstimate),
    /// Recorded frames (the self-supervised methods), handed over: training keeps them.
    Frames(FrameSet),
}

impl AdaptData {
    /// The recording's mean photoelectrons per pixel, as `profile` converts DN.
    pub fn mean_electrons(&self, profile: &CameraProfile) -> Result<f64> {
        match self {
            AdaptData::Scene(s) => Ok(s.mean_electrons),
            AdaptData::Frames(set) => set.mean_electrons(profile),
        }
    }

    /// Frames it stands for: averaged into the scene estimate, or kept.
    pub fn frames(&self) -> usize {
        match self {
            AdaptData::Scene(s) => s.frames,
            AdaptData::Frames(set) => set.len(),
        }
    }
}

/// Fewer frames than this make a scene estimate that keeps much of their noise.
const FEW_SCENE_FRAMES: usize = 8;

/// Recordings gathered for adaptation, frame by frame in bounded memory: every raw frame is
/// preprocessed as `emccd denoise` will preprocess it for the model (its ablations included),
/// then averaged ([`AdaptMethod::Resynthesis`]) or kept, up to a byte budget (the
/// self-supervised methods).
pub struct Recorded {
    method: AdaptMethod,
    ablate: Ablation,
    kept: Kept,
    exposure: Option<f64>,
    frames: usize,
}

/// What gathering keeps of the frames: their mean (resynthesis) or the frames themselves.
enum Kept {
    Mean(FrameMean),
    Frames(FrameSet),
}

impl Recorded {
    /// The frames the self-supervised methods keep in memory by default: 256 MiB of them
    /// (1024 frames of 256², 256 of 512²).
    pub const MEMORY_BUDGET: usize = 256 << 20;

    /// An empty gathering for `method` and a model made with `ablate`, keeping at most
    /// `max_bytes` of frames for the self-supervised methods.
    pub fn new(
        method: AdaptMethod,
        profile: &CameraProfile,
        ablate: Ablation,
        max_bytes: usize,
    ) -> Recorded {
        let (w, h) = (profile.width, profile.height);
        let kept = if method == AdaptMethod::Resynthesis {
            Kept::Mean(FrameMean::new(w, h))
        } else {
            Kept::Frames(FrameSet::new(w, h, max_bytes / (4 * profile.len()).max(1)))
        };
        Recorded {
            method,
            ablate,
            kept,
            exposure: None,
            frames: 0,
        }
    }

    /// Starts the next recording, taken with `exposure_s`. Neighbor sampling uses each frame
    /// alone, so its recordings may differ in exposure; the other methods adapt on one
    /// exposure of one static scene, and a different one is an error.
    pub fn start_recording(&mut self, exposure_s: f64) -> Result<()> {
        match self.exposure {
            Some(e) if e != exposure_s && self.method != AdaptMethod::Neighbors => {
                Err(Error::Data(format!(
                    "exposure {exposure_s} s, the first recording's is {e} s: --method {} adapts \
                     on one exposure of one static scene",
                    self.method.name()
                )))
            }
            _ => {
                self.exposure = Some(exposure_s);
                Ok(())
            }
        }
    }

    /// Adds one raw frame (DN, the profile's size) of the current recording; an error names
    /// what is wrong with it ([`Recorded::frames`] counts it).
    pub fn add_raw(&mut self, profile: &CameraProfile, raw: &[f32]) -> Result<()> {
        let t = self
            .exposure
            .ok_or_else(|| Error::Data("a frame before its recording was started".into()))?;
        self.frames += 1;
        let dn = emccd_classical::frame::preprocess_ablated(profile, raw, t, self.ablate)?;
        match &mut self.kept {
            Kept::Mean(mean) => mean.add(&dn),
            Kept::Frames(set) => set.add(&dn, t),
        }
    }

    /// Adds every frame of `recording` (opened and checked against `profile`), streamed;
    /// `on_frame` is called after each. Errors name the file and the frame (from 1).
    pub fn add_recording(
        &mut self,
        profile: &CameraProfile,
        mut recording: emccd_profile::Recording,
        on_frame: &mut dyn FnMut(),
    ) -> Result<()> {
        let name = recording.path.display().to_string();
        self.start_recording(recording.exposure)
            .map_err(|e| e.at(&name))?;
        let mut buf = vec![0f32; recording.info.frame_len()];
        for k in 1.. {
            let read = recording
                .reader
                .read_frame(&mut buf)
                .map_err(|source| Error::Frame {
                    at: format!("{name}: frame {k}"),
                    source,
                })?;
            if !read {
                break;
            }
            self.add_raw(profile, &buf)
                .map_err(|e| e.at(format!("{name}: frame {k}")))?;
            on_frame();
        }
        Ok(())
    }

    /// Frames added so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The warning a user deserves about these recordings, if any: too few frames for a
    /// clean scene estimate.
    pub fn warning(&self) -> Option<String> {
        (self.method == AdaptMethod::Resynthesis && (1..FEW_SCENE_FRAMES).contains(&self.frames))
            .then(|| {
                format!(
                "{} frame(s): the scene estimate keeps much of their noise, and the model learns \
                 it as structure; 20–50 frames of the static scene are better",
                self.frames
            )
            })
    }

    /// What the method trains on: the scene estimate (resynthesis) or the kept frames; an
    /// error with no recording or fewer frames than the method needs.
    pub fn finish(self, profile: &CameraProfile) -> Result<AdaptData> {
        let exposure = self
            .exposure
            .ok_or_else(|| Error::Data("no recordings".into()))?;
        if self.frames < self.method.min_frames() {
            return Err(Error::Data(format!(
                "{} frame(s) in all: --method {} needs {} or more frames",
                self.frames,
                self.method.name(),
                self.method.min_frames()
            )));
        }
        Ok(match self.kept {
            Kept::Mean(mean) => AdaptData::Scene(scene_estimate(&mean, profile, exposure)?),
            Kept::Frames(set) => AdaptData::Frames(set),
        })
    }
}

/// What a run trains on, with the light level it is made for and the frame size.
struct Material {
    source: Source,
    mean_electrons: f64,
    size: (usize, usize),
}

/// The training material `method` makes of `data` (a scene estimate for resynthesis, recorded
/// frames otherwise; recorded pairs scaled as the network's input is, `scale`).
fn material(
    method: AdaptMethod,
    data: AdaptData,
    profile: &CameraProfile,
    scale: Scale,
) -> Result<Material> {
    Ok(match (method, data) {
        (AdaptMethod::Resynthesis, AdaptData::Scene(scene)) => {
            let size = (scene.image.width, scene.image.height);
            Material {
                source: Source::Synthetic(vec![scene.image]),
                mean_electrons: scene.mean_electrons,
                size,
            }
        }
        (AdaptMethod::Resynthesis, AdaptData::Frames(_)) => {
            return Err(Error::Data(
                "resynthesis trains on a scene estimate, not on frames".into(),
            ))
        }
        (m, AdaptData::Frames(set)) => {
            let (level, size) = (set.mean_electrons(profile)?, (set.width, set.height));
            Material {
                source: Source::Recorded(RecordedPairs::new(set, profile, m, scale)?),
                mean_electrons: level,
                size,
            }
        }
        (m, AdaptData::Scene(_)) => {
            return Err(Error::Data(format!(
                "{} trains on recorded frames, not on a scene estimate",
                m.name()
            )))
        }
    })
}

/// Adapts a network to a recording (see the module documentation and [`AdaptMethod`]) and
/// writes it to `paths.out`, recording `provenance`. `report` is called after every step
/// (return `false` to stop: the checkpoint stays and `--resume` continues).
pub fn adapt(
    data: AdaptData,
    run: AdaptRun,
    report: &mut dyn FnMut(&StepReport) -> bool,
) -> Result<Model> {
    let AdaptRun {
        profile,
        start,
        cfg,
        provenance,
        paths,
        resume,
        device,
    } = run;
    cfg.check()?;
    let (init, start_meta) = match start {
        Start::Model(p) => (Some(p), p.read_meta()?),
        Start::Scratch(m) => (None, ModelMeta { steps: 0, ..m }),
    };
    let multiple = start_meta.multiple();
    if cfg.crop < multiple {
        return Err(Error::Data(format!(
            "a crop of {} px: {} works on multiples of {multiple} px",
            cfg.crop,
            start_meta.arch.name()
        )));
    }
    let Material {
        source,
        mean_electrons: level,
        size: (w, h),
    } = material(cfg.method, data, profile, start_meta.scale)?;
    let side = match &source {
        Source::Recorded(pairs) => pairs.side(cfg.crop, multiple),
        Source::Synthetic(_) => cfg.crop.min(w).min(h) / multiple * multiple,
    };
    if side == 0 {
        return Err(Error::Data(format!(
            "frames of {w}×{h} are too small for the {multiple}-px unit of {}{}",
            start_meta.arch.name(),
            if cfg.method == AdaptMethod::Neighbors {
                " at half resolution"
            } else {
                ""
            }
        )));
    }
    let tc = cfg.train_config(side, level, &start_meta);
    let meta = ModelMeta {
        profile_fingerprint: profile.fingerprint_hex(),
        recipe: format!(
            "adapted ({}) from {} on {} frames of {} at {:.3} mean e⁻/pixel: {} steps, batch {} × {side}², lr {}, seed {}",
            provenance.method,
            provenance.from,
            provenance.frames,
            provenance.files.join(", "),
            level,
            cfg.steps,
            cfg.batch,
            cfg.lr,
            cfg.seed
        ),
        adapted: Some(provenance),
        ..start_meta
    };
    train_from(
        source,
        Vec::new(),
        Run::new(profile, tc, meta, paths, &device)
            .with_init(init)
            .resuming(resume),
        report,
    )
}
