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

use std::path::Path;

use emccd_camera::{Ablation, NoiseModelKind};
use emccd_profile::CameraProfile;
use serde::{Deserialize, Serialize};

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::norm::{prepare_scaled, Scale};
use crate::train::{
    orient, sub_image, train_from, Image, Loss, Run, RunPaths, Source, StepReport, TrainConfig,
};
use crate::{Denoiser, Error, ModelMeta, Result};

/// What an adapted model file records about its adaptation ([`ModelMeta::adapted`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adaptation {
    /// How it was adapted ([`AdaptMethod::name`]).
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
        method: AdaptMethod,
        from: &str,
        scratch: bool,
        files: &[impl AsRef<Path>],
        frames: usize,
        mean_electrons: f64,
    ) -> Adaptation {
        Adaptation {
            method: method.name().into(),
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

/// An error unless `frame` has the recording's `width × height` pixels.
fn check_size(frame: &[f32], width: usize, height: usize) -> Result<()> {
    if frame.len() == width * height {
        return Ok(());
    }
    Err(Error::Data(format!(
        "a frame of {} pixels where the recording's frames have {width}×{height}",
        frame.len()
    )))
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
        check_size(frame, self.width, self.height)?;
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

/// Preprocessed frames (DN above bias) kept in memory with their exposures, up to a capacity:
/// what the self-supervised methods train on. For neighbor sampling the frames may show
/// different scenes and exposures; Noise2Noise needs one exposure of a static scene.
#[derive(Clone, Debug)]
pub struct FrameSet {
    width: usize,
    height: usize,
    capacity: usize,
    frames: Vec<Vec<f32>>,
    exposures: Vec<f64>,
}

impl FrameSet {
    /// An empty set of `width × height` frames that keeps the first `capacity` added.
    pub fn new(width: usize, height: usize, capacity: usize) -> FrameSet {
        FrameSet {
            width,
            height,
            capacity,
            frames: Vec::new(),
            exposures: Vec::new(),
        }
    }

    /// Adds a frame taken with `exposure_s` (ignored once the set is full); an error if its
    /// size differs or a pixel is not a finite number (it would end training as a diverged run).
    pub fn add(&mut self, frame: &[f32], exposure_s: f64) -> Result<()> {
        check_size(frame, self.width, self.height)?;
        if let Some(k) = frame.iter().position(|v| !v.is_finite()) {
            return Err(Error::Data(format!(
                "pixel ({}, {}) is {}: frames to train on must be finite",
                k % self.width,
                k / self.width,
                frame[k]
            )));
        }
        if self.frames.len() < self.capacity {
            self.frames.push(frame.to_vec());
            self.exposures.push(exposure_s);
        }
        Ok(())
    }

    /// Frames kept.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame is kept.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// The frames' mean photoelectrons per pixel, as `profile` converts DN.
    pub fn mean_electrons(&self, profile: &CameraProfile) -> Result<f64> {
        let k = profile.dn_per_electron()?;
        // Every kept pixel is finite: `add` refuses others.
        let n = self.frames.len() * self.width * self.height;
        let sum: f64 = self.frames.iter().flatten().map(|&v| v as f64).sum();
        let m = sum / n.max(1) as f64 / k;
        if !(m > 0.0) {
            return Err(Error::Data(
                "the recording has no signal above bias: nothing to adapt to".into(),
            ));
        }
        Ok(m)
    }
}

/// Where an adaptation's training pairs come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum AdaptMethod {
    /// Pairs synthesized with the profile's exact noise chain from the scene estimate (the
    /// frames' mean denoised by iterative BM3D at its own noise).
    #[default]
    Resynthesis,
    /// Noise2Noise on frames of the static scene: a crop of one frame is the input, the same
    /// crop of another frame the target. Their noises are independent and the target's mean is
    /// the scene, so an L2 loss learns the clean image without ever seeing it.
    Noise2noise,
    /// Spatial-redundancy sampling (SRDTrans; Neighbor2Neighbor's sub-sampler, without its
    /// regularizer): in every 2×2 cell of a frame one pixel goes to the input and an adjacent
    /// one to the target, two half-size images of one frame with independent noise. Needs a
    /// single frame, but trains on half-resolution images.
    Neighbors,
}

impl AdaptMethod {
    /// The name in the CLI and in a model file's provenance.
    pub fn name(self) -> &'static str {
        match self {
            AdaptMethod::Resynthesis => "resynthesis",
            AdaptMethod::Noise2noise => "noise2noise",
            AdaptMethod::Neighbors => "neighbors",
        }
    }

    /// Frames the method needs at least.
    pub fn min_frames(self) -> usize {
        match self {
            AdaptMethod::Noise2noise => 2,
            _ => 1,
        }
    }
}

/// Training pairs cut from recorded frames alone, in the network's units (as [`prepare`]
/// would give for the input's whole frame), for the self-supervised methods.
///
/// [`prepare`]: crate::norm::prepare
pub(crate) struct RecordedPairs {
    frames: Vec<Vec<f32>>,
    width: usize,
    height: usize,
    /// Each frame's normalizing scale (slope units), from the whole frame as at inference.
    scales: Vec<f32>,
    slope: f64,
    /// Read-noise maps, one per exposure, and each frame's.
    read_noise: Vec<Vec<f32>>,
    map_of: Vec<usize>,
    method: AdaptMethod,
}

impl RecordedPairs {
    /// Pairs of `method` (not resynthesis) from `set`, whose frames it takes.
    pub(crate) fn new(
        set: FrameSet,
        profile: &CameraProfile,
        method: AdaptMethod,
        rule: Scale,
    ) -> Result<RecordedPairs> {
        if method == AdaptMethod::Resynthesis || set.len() < method.min_frames() {
            return Err(Error::Data(format!(
                "{} needs {} frame(s) of the recording, {} given",
                method.name(),
                method.min_frames(),
                set.len()
            )));
        }
        if (set.width, set.height) != (profile.width, profile.height) {
            return Err(Error::Data(format!(
                "frames are {}×{}, the profile's sensor is {}×{}",
                set.width, set.height, profile.width, profile.height
            )));
        }
        if method == AdaptMethod::Noise2noise
            && set.exposures.iter().any(|&t| t != set.exposures[0])
        {
            return Err(Error::Data(
                "noise2noise pairs frames of one static scene: the frames' exposures differ".into(),
            ));
        }
        let slope = profile.slope()?;
        let s = slope as f32;
        let scales = set
            .frames
            .iter()
            .map(|f| rule.of(&f.iter().map(|v| v / s).collect::<Vec<f32>>(), set.width))
            .collect();
        let mut exposures: Vec<f64> = Vec::new();
        let mut map_of = Vec::with_capacity(set.len());
        for &t in &set.exposures {
            emccd_profile::check_exposure(t)?;
            map_of.push(match exposures.iter().position(|&e| e == t) {
                Some(k) => k,
                None => {
                    exposures.push(t);
                    exposures.len() - 1
                }
            });
        }
        Ok(RecordedPairs {
            frames: set.frames,
            width: set.width,
            height: set.height,
            scales,
            slope,
            read_noise: exposures
                .iter()
                .map(|&t| profile.read_noise_near(t).to_vec())
                .collect(),
            map_of,
            method,
        })
    }

    /// The largest crop side, at most `crop`, a multiple of `multiple`, that the frames give
    /// (the neighbor sampler halves a window twice the crop's side).
    pub(crate) fn side(&self, crop: usize, multiple: usize) -> usize {
        let k = if self.method == AdaptMethod::Neighbors {
            2
        } else {
            1
        };
        crop.min(self.width / k).min(self.height / k) / multiple * multiple
    }

    /// Pair number `seed`: input [2, c, c] and target [c, c], 8-way augmented if `augment`.
    pub(crate) fn sample(&self, c: usize, augment: bool, seed: u64) -> (Vec<f32>, Vec<f32>) {
        let mut rng = Pcg64::seed_from_u64(seed);
        let (w, h) = (self.width, self.height);
        let i = rng.random_range(0..self.frames.len());
        let (inp, rn, tgt) = match self.method {
            AdaptMethod::Neighbors => {
                let (x0, y0) = (
                    rng.random_range(0..=w - 2 * c),
                    rng.random_range(0..=h - 2 * c),
                );
                let f = &self.frames[i];
                let (mut a, mut r, mut b) =
                    (vec![0f32; c * c], vec![0f32; c * c], vec![0f32; c * c]);
                // One pixel of the cell, then one of its two neighbors in the cell.
                const CELL: [(usize, usize); 4] = [(0, 0), (1, 0), (1, 1), (0, 1)];
                for k in 0..c * c {
                    let (cx, cy) = (x0 + 2 * (k % c), y0 + 2 * (k / c));
                    let p = rng.random_range(0..4usize);
                    let q = (p + if rng.random::<bool>() { 1 } else { 3 }) % 4;
                    let at = |j: usize| (cy + CELL[j].1) * w + cx + CELL[j].0;
                    a[k] = f[at(p)];
                    r[k] = self.read_noise[self.map_of[i]][at(p)];
                    b[k] = f[at(q)];
                }
                (a, r, b)
            }
            _ => {
                let mut j = rng.random_range(0..self.frames.len() - 1);
                if j >= i {
                    j += 1;
                }
                let (x0, y0) = (rng.random_range(0..=w - c), rng.random_range(0..=h - c));
                (
                    sub_image(&self.frames[i], w, x0, y0, c, c),
                    sub_image(&self.read_noise[self.map_of[i]], w, x0, y0, c, c),
                    sub_image(&self.frames[j], w, x0, y0, c, c),
                )
            }
        };
        let mode = crate::train::draw_orientation(&mut rng, augment);
        let p = prepare_scaled(
            &orient(&inp, c, mode),
            self.slope,
            &orient(&rn, c, mode),
            self.scales[i],
        );
        let target = orient(&tgt, c, mode).iter().map(|v| v / p.to_dn).collect();
        (p.input, target)
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
    let q = crate::pipeline::vst_params(profile, exposure_s)?.of_mean(n);
    let est = emccd_eval::vst::bm3d_adaptive(&m, mean.width, mean.height, q);
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
    /// gave +0.39–0.71 (README, "Adaptation to a recording").
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
    /// A model file, fine-tuned.
    Model(&'a Path),
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
        let dn = crate::pipeline::preprocess_ablated(profile, raw, t, self.ablate)?;
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
) -> Result<Denoiser> {
    let AdaptRun {
        profile,
        start,
        cfg,
        provenance,
        paths,
        resume,
    } = run;
    cfg.check()?;
    let (init, start_meta) = match start {
        Start::Model(p) => (Some(p), Denoiser::read_meta(p)?),
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
        Run::new(profile, tc, meta, paths)
            .with_init(init)
            .resuming(resume),
        report,
    )
}
