//! Training on pairs synthesized on the fly: random crops of clean images, 8-way flips and
//! rotations, a random photon level, noise from a camera model; AdamW with linear warm-up and
//! cosine decay, Charbonnier or L2 loss; validation PSNR on held-out images; checkpoints that
//! resume. A hybrid (BM3D-refining) network gets each crop's BM3D + GAT estimate, computed as
//! the pair is synthesized.
//!
//! Every batch is a pure function of (seed, step), so a resumed run sees the same data as an
//! uninterrupted one. Pairs can be reused a few times from a sliding pool (`reuse`), which
//! makes a hybrid step several times cheaper. Batches are synthesized on a second thread while
//! the step runs.

use std::path::{Path, PathBuf};
use std::sync::mpsc;

use burn::optim::{AdamWConfig, GradientsParams};
use burn::prelude::*;
use emccd_camera::{Ablation, EldModel, NoiseModel, NoiseModelKind, OursModel, PgnModel};
use emccd_profile::CameraProfile;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::crops::{draw_orientation, orient, sub_image};
use crate::motion::Motion;
use crate::recorded::RecordedPairs;
use emccd_nn::norm::{prepare_hybrid, prepare_movie_scaled, prepare_scaled, signal_scale};
use emccd_nn::{
    Classical, Error, Inputs, Loss, Model, ModelMeta, ModelSource, Net, Result, Scale, TrainConfig,
    MOVIE_WINDOW,
};

/// A clean training image, values in [0, 1].
pub use emccd_io::Image;

/// Light levels of the validation set.
pub const VAL_LEVELS: usize = 4;

/// The validation light levels: the training range's log-uniform quantiles (k + ½)/VAL_LEVELS
/// (for mean 0.3–30 e⁻: 0.53, 1.7, 5.3 and 17 e⁻, close to the low-light suite's 0.5/1/4/16).
pub fn val_levels(cfg: &TrainConfig) -> Vec<f64> {
    let range = cfg.mean_electrons.unwrap_or(cfg.electrons);
    (0..VAL_LEVELS)
        .map(|k| log_uniform((k as f64 + 0.5) / VAL_LEVELS as f64, range))
        .collect()
}

/// The value at `u` ∈ [0, 1) of a log-uniform draw from `[lo, hi]`.
fn log_uniform(u: f64, [lo, hi]: [f64; 2]) -> f64 {
    (lo.ln() + u * (hi.ln() - lo.ln())).exp()
}

/// Clean images for a run: what it trains on and what it validates on.
#[derive(Clone, Debug)]
pub struct TrainImages {
    /// Pairs are synthesized from these.
    pub train: Vec<Image>,
    /// Held out: validation PSNR, never trained on.
    pub val: Vec<Image>,
}

impl TrainImages {
    /// Reads the clean scenes of `clean` and `val` (files, or folders of PNG, TIFF and FITS
    /// files); with no `val`, every tenth image of `clean` is held out for validation instead.
    pub fn read(clean: &[std::path::PathBuf], val: &[std::path::PathBuf]) -> Result<TrainImages> {
        let read = |paths: &[std::path::PathBuf]| -> Result<Vec<Image>> {
            emccd_io::image_files(paths)
                .map_err(|e| Error::Data(e.to_string()))?
                .iter()
                .map(|p| {
                    Image::read_scene(p).map_err(|e| {
                        // The reader's errors mostly name the file already.
                        let (e, name) = (e.to_string(), p.display().to_string());
                        Error::Data(if e.contains(&name) {
                            e
                        } else {
                            format!("{name}: {e}")
                        })
                    })
                })
                .collect()
        };
        let all = read(clean)?;
        if !val.is_empty() {
            return Ok(TrainImages {
                train: all,
                val: read(val)?,
            });
        }
        let (train, val): (Vec<_>, Vec<_>) =
            all.into_iter().enumerate().partition(|(i, _)| i % 10 != 9);
        Ok(TrainImages {
            train: train.into_iter().map(|x| x.1).collect(),
            val: val.into_iter().map(|x| x.1).collect(),
        })
    }
}

/// One batch: network inputs [B, 2, c, c] and targets [B, 1, c, c] in the same units, plus the
/// noisy channel's PSNR reference data for validation.
struct Batch {
    input: Vec<f32>,
    target: Vec<f32>,
}

/// Synthesizes one training pair from `img` (a crop, augmented) in the network's units.
///
/// The noise is synthesized over the whole image and the crop cut from it afterwards, so that
/// the normalizing scale is the whole frame's, as it is when a recorded frame is denoised: a
/// crop of dark background is then scaled like the background of a frame with bright
/// structure elsewhere, not blown up to its own 99.5th percentile.
///
/// A hybrid sample also gets the BM3D + GAT estimate of the noisy crop (with the VST parameters
/// a calibrated profile of this synthetic camera would give), and is scaled by the clean frame's
/// 99.5th percentile, which the estimate's stands in for at inference.
fn synth_sample(
    img: &Image,
    other: &Image,
    profile: &CameraProfile,
    cfg: &TrainConfig,
    inputs: Inputs,
    abl: Ablation,
    seed: u64,
) -> Result<(Vec<f32>, Vec<f32>)> {
    let c = cfg.crop;
    let mut rng = Pcg64::seed_from_u64(seed);
    let (w, h) = (img.width, img.height);
    let x0 = rng.random_range(0..=w - c);
    let y0 = rng.random_range(0..=h - c);
    let mode = draw_orientation(&mut rng, cfg.augment);
    let slope = profile.slope()?;
    let k_mean = profile.dn_per_electron()?;
    // A movie's motion has its own random sequence, so single-frame runs keep theirs.
    let motion = (inputs == Inputs::Movie).then(|| {
        Motion::draw(
            &mut Pcg64::seed_from_u64(seed ^ 0x4D4F_5649_45),
            MOVIE_WINDOW,
            c,
        )
    });
    let dim = motion.as_ref().map_or(1.0, |m| m.background() as f64);
    // Electrons per unit of the clean image (whose values lie in [0, 1]).
    let per_unit = match cfg.mean_electrons {
        Some(range) => {
            let mean =
                img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len().max(1) as f64;
            log_uniform(rng.random(), range) / (dim * mean).max(1e-3)
        }
        None => log_uniform(rng.random(), cfg.electrons),
    };
    let to_dn = |v: f32| (v as f64 * per_unit * k_mean) as f32;
    let mut clean: Vec<f32> = img.data.iter().map(|&v| to_dn(v * dim as f32)).collect();
    if let Some(m) = &motion {
        // The centre frame's spots, on the whole frame it is synthesized as.
        for (i, s) in m.spots(0, c).into_iter().enumerate() {
            clean[(y0 + i / c) * w + x0 + i % c] += to_dn(s);
        }
    }
    // A random read-noise map of the profile at a random offset, repeated to the image's size.
    let m = &profile.maps.read_noise[rng.random_range(0..profile.maps.read_noise.len())];
    let (pw, ph) = (profile.width, profile.height);
    let (mx, my) = (rng.random_range(0..pw), rng.random_range(0..ph));
    let [rlo, rhi] = cfg.read_noise_scale;
    // A fixed factor draws nothing, so runs without randomization keep their random sequence.
    let rs = if rhi > rlo {
        log_uniform(rng.random(), [rlo, rhi]) as f32
    } else {
        rlo as f32
    };
    let rn: Vec<f32> = (0..w * h)
        .map(|i| rs * m[((my + i / w) % ph) * pw + (mx + i % w) % pw])
        .collect();
    let mut noisy = vec![0f32; w * h];
    let noise_seed = rng.random::<u64>();
    // The neighbours' camera is this one over the crop (its clock-induced charge is drawn the
    // same way from the same state).
    let mut crop_rng = rng.clone();
    pair_camera(cfg, profile, abl, &rn, &mut rng)?.synthesize(&clean, w, &mut noisy, noise_seed);
    let scale = match inputs {
        Inputs::Noisy | Inputs::Movie => cfg.scale.of(
            &noisy.iter().map(|v| v / slope as f32).collect::<Vec<f32>>(),
            w,
        ),
        Inputs::Hybrid => {
            signal_scale(&clean.iter().map(|v| v / slope as f32).collect::<Vec<f32>>())
        }
    };
    // The crop, in its drawn orientation (8-way augmentation unless switched off): optional
    // transpose, then optional flips.
    let cut = |src: &[f32]| orient(&sub_image(src, w, x0, y0, c, c), c, mode);
    let (noisy_c, rn_c) = (cut(&noisy), cut(&rn));
    let p = match (inputs, &motion) {
        (Inputs::Movie, Some(m)) => {
            // The neighbours, synthesized over the crop alone, unoriented; frames beyond a
            // movie's end are their mirror's noisy frame.
            let raw_rn = sub_image(&rn, w, x0, y0, c, c);
            let cam = pair_camera(cfg, profile, abl, &raw_rn, &mut crop_rng)?;
            let k = MOVIE_WINDOW as isize;
            let mut made: Vec<(isize, Vec<f32>)> = vec![(0, noisy_c.clone())];
            for d in (-k..=k).filter(|&d| d != 0 && m.shown(d) == d) {
                let frame: Vec<f32> = m
                    .frame(img, other, [x0, y0], c, d)
                    .into_iter()
                    .map(to_dn)
                    .collect();
                let mut n = vec![0f32; c * c];
                cam.synthesize(
                    &frame,
                    c,
                    &mut n,
                    noise_seed ^ (d as u64).wrapping_mul(0x9E37),
                );
                made.push((d, orient(&n, c, mode)));
            }
            let frames: Vec<&[f32]> = (-k..=k)
                .map(|d| {
                    let shown = m.shown(d);
                    made.iter()
                        .find(|(e, _)| *e == shown)
                        .map(|(_, f)| f.as_slice())
                })
                .collect::<Option<_>>()
                .ok_or_else(|| Error::Data("a mirrored frame beyond both ends".into()))?;
            prepare_movie_scaled(&frames, MOVIE_WINDOW, slope, &rn_c, scale)
        }
        (Inputs::Noisy | Inputs::Movie, _) => prepare_scaled(&noisy_c, slope, &rn_c, scale),
        (Inputs::Hybrid, _) => {
            // The base estimate is made on a window reaching CONTEXT px beyond the crop (where
            // the image allows) and then cut: run on the crop alone, BM3D would see few similar
            // blocks near its edges and leave errors there that a whole frame never shows, and
            // the network would learn to fix those instead of what inference needs.
            const CONTEXT: usize = 32;
            let (wx0, wy0) = (x0.saturating_sub(CONTEXT), y0.saturating_sub(CONTEXT));
            let (wx1, wy1) = ((x0 + c + CONTEXT).min(w), (y0 + c + CONTEXT).min(h));
            let (ww, wh) = (wx1 - wx0, wy1 - wy0);
            let window = sub_image(&noisy, w, wx0, wy0, ww, wh);
            let rn_w = sub_image(&rn, w, wx0, wy0, ww, wh);
            let vst = emccd_profile::PoissonGaussian::from_read_noise(
                slope,
                &rn_w,
                profile.quantization_dn,
            );
            let est_w = cfg.base.estimate(&window, ww, wh, vst);
            let est = sub_image(&est_w, ww, x0 - wx0, y0 - wy0, c, c);
            prepare_hybrid(&noisy_c, &orient(&est, c, mode), slope, &rn_c, scale)
        }
    };
    let target = cut(&clean).iter().map(|v| v / p.to_dn).collect();
    Ok((p.input, target))
}

/// The camera one training pair is synthesized with: the noise model `cfg.noise` with the
/// profile's parameters and this pair's draws, the read-noise map `rn` (a scaled, shifted tile
/// of one of the profile's; ELD has none) and, for PGN, clock-induced charge drawn from
/// `cfg.cic_e` (with `rng`, after the pair's other draws).
fn pair_camera(
    cfg: &TrainConfig,
    profile: &CameraProfile,
    abl: Ablation,
    rn: &[f32],
    rng: &mut Pcg64,
) -> Result<Box<dyn NoiseModel>> {
    let (slope, k_mean) = (profile.slope()?, profile.dn_per_electron()?);
    Ok(match cfg.noise {
        NoiseModelKind::Ours => Box::new(OursModel::new(
            slope,
            profile.f_range,
            profile.quantization_dn,
            vec![rn.to_vec()],
            abl,
        )?),
        NoiseModelKind::Eld => Box::new(EldModel::from_profile(profile)?),
        NoiseModelKind::Pgn => {
            let pgn = profile
                .pgn
                .as_ref()
                .ok_or_else(|| Error::Data("the profile has no [pgn] parameters".into()))?;
            let cic = match cfg.cic_e {
                Some([lo, hi]) => lo + (hi - lo) * rng.random::<f64>(),
                None => pgn.cic_e,
            };
            // The EM gain and e⁻/DN set the DN per electron; the slope they imply is the profile's.
            Box::new(
                PgnModel::new(
                    pgn.em_gain,
                    pgn.em_gain / k_mean,
                    cic,
                    pgn.dark_e_per_s,
                    0.01,
                    pgn.read_sigma_dn,
                    profile.quantization_dn,
                )?
                .with_read_noise_map(rn.to_vec()),
            )
        }
    })
}

/// The training pair with sample seed `s`: the image (chosen by `s`) and its synthesized crop.
fn sample(
    images: &[Image],
    profile: &CameraProfile,
    cfg: &TrainConfig,
    inputs: Inputs,
    abl: Ablation,
    s: u64,
) -> Result<(Vec<f32>, Vec<f32>)> {
    let pick = |salt: u64| {
        &images[(Pcg64::seed_from_u64(s ^ salt).random::<u64>() % images.len() as u64) as usize]
    };
    // `other`: the unrelated scene a training movie may cut to.
    synth_sample(pick(0xA5A5), pick(0x0C07), profile, cfg, inputs, abl, s)
}

/// The sample seed of pair number `k` of a pooled run with seed `seed`.
fn pair_seed(seed: u64, k: u64) -> u64 {
    (seed ^ 0x5EED_9001)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(k.wrapping_mul(0xD1B5_4A32_D192_ED03))
}

/// Pairs synthesized once and drawn about `reuse` times: a sliding window over the sequence of
/// pairs 0, 1, 2, …. At step t the window holds pairs [n − W, n), with W = batch·reuse and
/// n = W + ⌈t·batch / reuse⌉, so `batch / reuse` pairs enter per step and each stays for about
/// reuse² steps, drawn with probability 1/reuse per step. A batch is a pure function of (seed,
/// step): a resumed run rebuilds the window and sees what an uninterrupted one would.
struct Pool {
    pairs: std::collections::BTreeMap<u64, (Vec<f32>, Vec<f32>)>,
}

impl Pool {
    fn batch(
        &mut self,
        images: &[Image],
        profile: &CameraProfile,
        cfg: &TrainConfig,
        inputs: Inputs,
        abl: Ablation,
        step: u64,
    ) -> Result<Batch> {
        let (b, r) = (cfg.batch as u64, cfg.reuse.max(1) as u64);
        let w = b * r;
        let n = w + (step * b).div_ceil(r);
        let lo = n - w;
        self.pairs = self.pairs.split_off(&lo);
        let missing: Vec<u64> = (lo..n).filter(|k| !self.pairs.contains_key(k)).collect();
        let fresh: Vec<(u64, (Vec<f32>, Vec<f32>))> = missing
            .into_par_iter()
            .map(|k| {
                sample(images, profile, cfg, inputs, abl, pair_seed(cfg.seed, k)).map(|p| (k, p))
            })
            .collect::<Result<_>>()?;
        self.pairs.extend(fresh);
        let c = cfg.crop;
        let ch = inputs.channels();
        let mut rng = Pcg64::seed_from_u64(cfg.seed.wrapping_add(step.wrapping_mul(7919)) ^ 0xD7A3);
        let mut input = Vec::with_capacity(cfg.batch * ch * c * c);
        let mut target = Vec::with_capacity(cfg.batch * c * c);
        for _ in 0..cfg.batch {
            let (i, t) = &self.pairs[&(lo + rng.random_range(0..w))];
            let mode = draw_orientation(&mut rng, cfg.augment);
            for plane in i.chunks_exact(c * c) {
                input.extend(orient(plane, c, mode));
            }
            target.extend(orient(t, c, mode));
        }
        Ok(Batch { input, target })
    }
}

fn make_batch(
    images: &[Image],
    profile: &CameraProfile,
    cfg: &TrainConfig,
    inputs: Inputs,
    abl: Ablation,
    seed: u64,
) -> Result<Batch> {
    let c = cfg.crop;
    let samples: Vec<(Vec<f32>, Vec<f32>)> = (0..cfg.batch)
        .into_par_iter()
        .map(|b| {
            let s = seed
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(b as u64 + 1);
            sample(images, profile, cfg, inputs, abl, s)
        })
        .collect::<Result<_>>()?;
    let mut input = Vec::with_capacity(cfg.batch * inputs.channels() * c * c);
    let mut target = Vec::with_capacity(cfg.batch * c * c);
    for (i, t) in samples {
        input.extend(i);
        target.extend(t);
    }
    Ok(Batch { input, target })
}

/// Progress of a run, reported after every step.
#[derive(Clone, Debug)]
pub struct StepReport {
    /// Steps done.
    pub step: u64,
    /// Of.
    pub steps: u64,
    /// Smoothed training loss.
    pub loss: f64,
    /// Latest validation PSNR.
    pub val_psnr: Option<ValPsnr>,
}

/// Validation PSNR on the held-out crops, dB.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValPsnr {
    /// Of the network's output.
    pub denoised_db: f64,
    /// Of its noisy input (the same for every step: the crops are fixed).
    pub noisy_db: f64,
}

/// Where and how a run is saved.
#[derive(Clone, Debug)]
pub struct RunPaths {
    /// Final model file.
    pub out: PathBuf,
    /// Checkpoint directory (model, optimizer state, progress).
    pub checkpoint: PathBuf,
}

impl RunPaths {
    /// The model file `out` with its checkpoint beside it, `OUT.ckpt/` (where `--resume` of
    /// `emccd train` and `emccd adapt` looks).
    pub fn beside(out: &Path) -> RunPaths {
        RunPaths {
            out: out.to_path_buf(),
            checkpoint: PathBuf::from(format!("{}.ckpt", out.display())),
        }
    }
}

/// The classical estimate of a training run's refinement network: `chosen` (only a refinement
/// network has one), else the `init` model's, else one BM3D pass.
pub fn classical_for_run(
    chosen: Option<Classical>,
    inputs: Inputs,
    init: Option<&ModelMeta>,
) -> Result<Classical> {
    match (chosen, init) {
        (Some(_), _) if inputs != Inputs::Hybrid => Err(Error::Model(
            "--hybrid-base: only a refinement network (--inputs hybrid) has a base estimate".into(),
        )),
        (Some(b), _) => Ok(b),
        (None, Some(init)) => Ok(init.base),
        (None, None) => Ok(Classical::Bm3d),
    }
}

/// The input scaling rule of a training run: the one asked for, else the rule of the model it
/// starts from (a fine-tune keeps the input its weights were trained on), else the default.
pub fn scale_for_run(given: Option<Scale>, init: Option<&ModelMeta>) -> Scale {
    given.or(init.map(|m| m.scale)).unwrap_or_default()
}

/// The metadata of a new training run's model: `arch` taking `inputs` (a refinement network
/// refines `cfg.base`), trained with `cfg` on `images` through `profile`. The run records its
/// steps and `cfg`.
pub fn meta_for_run(
    arch: emccd_nn::Arch,
    inputs: emccd_nn::Inputs,
    cfg: &TrainConfig,
    profile: &CameraProfile,
    images: &TrainImages,
) -> ModelMeta {
    ModelMeta {
        arch,
        inputs,
        base: cfg.base,
        noise_model: cfg.noise,
        ablate: cfg.ablate,
        scale: cfg.scale,
        profile_fingerprint: profile.fingerprint_hex(),
        steps: 0,
        train: None,
        adapted: None,
        recipe: cfg.recipe(images.train.len(), images.val.len()),
    }
}

#[derive(Serialize, Deserialize)]
struct CkptState {
    step: u64,
    config: TrainConfig,
    loss: f64,
    meta: ModelMeta,
}

/// The optimizer's state is keyed by parameter identity, which safetensors does not carry; the
/// checkpoint's weights are therefore also kept as burnpack, which does.
fn save_net_with_ids(model: &Model, path: &Path) -> Result<()> {
    use burn_store::{BurnpackStore, ModuleSnapshot};
    let tmp = emccd_io::temp_beside(path).map_err(|e| Error::io(path, e))?;
    let mut store = BurnpackStore::from_file(tmp.path()).overwrite(true);
    model
        .net
        .save_into(&mut store)
        .map_err(|e| Error::Model(format!("{}: {e}", path.display())))?;
    emccd_io::persist(tmp, path).map_err(|e| Error::Model(e.to_string()))
}

fn load_net_with_ids(meta: ModelMeta, path: &Path, device: &Device) -> Result<Model> {
    use burn_store::{BurnpackStore, ModuleSnapshot};
    let mut d = Model::new(meta, device)?;
    let mut store = BurnpackStore::from_file(path);
    d.net
        .load_from(&mut store)
        .map_err(|e| Error::Model(format!("{}: {e}", path.display())))?;
    Ok(d)
}

/// Validation PSNR (dB, peak = clean maximum) of the network output and of its residual
/// channel (the noisy input; for a hybrid network, the BM3D estimate it refines), averaged over
/// the fixed validation batch.
fn validate(model: &Model, val: &Batch, n: usize, c: usize, device: &Device) -> ValPsnr {
    let net = model.net.valid();
    let ch = model.meta.inputs.channels();
    let base = model.meta.inputs.residual();
    // In chunks: the validation set is several training batches, and one forward pass over all
    // of it would need that many times a step's activation memory (a GPU's limit).
    const CHUNK: usize = 16;
    let mut out: Vec<f32> = Vec::with_capacity(n * c * c);
    for b0 in (0..n).step_by(CHUNK) {
        let k = CHUNK.min(n - b0);
        let x = Tensor::<4>::from_data(
            TensorData::new(
                val.input[b0 * ch * c * c..(b0 + k) * ch * c * c].to_vec(),
                [k, ch, c, c],
            ),
            device,
        );
        out.extend(
            net.forward(x)
                .into_data()
                .convert::<f32>()
                .try_into_vec::<f32>()
                .unwrap_or_default(),
        );
    }
    let mut po = 0.0;
    let mut pi = 0.0;
    for b in 0..n {
        let t = &val.target[b * c * c..(b + 1) * c * c];
        let o = &out[b * c * c..(b + 1) * c * c];
        let i = &val.input[(b * ch + base) * c * c..(b * ch + base + 1) * c * c];
        let peak = emccd_eval::scores::truth_peak(t);
        po += emccd_eval::psnr(o, t, peak);
        pi += emccd_eval::psnr(i, t, peak);
    }
    ValPsnr {
        denoised_db: po / n as f64,
        noisy_db: pi / n as f64,
    }
}

/// One training run: the camera whose noise the pairs are synthesized with, the recipe, the
/// model's metadata (its `steps` and `train` are filled in by the run) and where it is saved;
/// a new network unless [`Run::with_init`] names a model file to fine-tune, and continued from
/// its checkpoint with [`Run::resuming`].
#[derive(Clone, Debug)]
pub struct Run<'a> {
    /// The camera.
    pub profile: &'a CameraProfile,
    /// The recipe.
    pub cfg: TrainConfig,
    /// The model's architecture, inputs and description.
    pub meta: ModelMeta,
    /// The output and the checkpoint directory.
    pub paths: &'a RunPaths,
    /// A model file to fine-tune, else a new network from the seed.
    pub init: Option<&'a ModelSource>,
    /// Continue from the checkpoint in `paths.checkpoint`.
    pub resume: bool,
    /// Where the network trains (the caller's choice: `emccd_nn::device`).
    pub device: Device,
}

impl<'a> Run<'a> {
    /// A run of a new network on `device`.
    pub fn new(
        profile: &'a CameraProfile,
        cfg: TrainConfig,
        meta: ModelMeta,
        paths: &'a RunPaths,
        device: &Device,
    ) -> Run<'a> {
        Run {
            profile,
            cfg,
            meta,
            paths,
            init: None,
            resume: false,
            device: device.clone(),
        }
    }

    /// Fine-tunes the model `init` (if given) instead.
    pub fn with_init(mut self, init: Option<&'a ModelSource>) -> Run<'a> {
        self.init = init;
        self
    }

    /// Continues the run from its checkpoint where `resume` is true.
    pub fn resuming(mut self, resume: bool) -> Run<'a> {
        self.resume = resume;
        self
    }
}

/// Trains (or fine-tunes, or resumes: see [`Run`]) on pairs synthesized from `images.train`,
/// validating on `images.val`, and writes the model to `run.paths.out`. `report` is called
/// after every step; returning `false` stops the run there (as an interruption would: the last
/// checkpoint stays, no final model is written).
pub fn train(
    images: TrainImages,
    run: Run,
    report: &mut dyn FnMut(&StepReport) -> bool,
) -> Result<Model> {
    if images.train.is_empty() {
        return Err(Error::Data("no training images".into()));
    }
    train_from(Source::Synthetic(images.train), images.val, run, report)
}

/// What a run trains on.
pub(crate) enum Source {
    /// Clean images: pairs synthesized from them with the camera model.
    Synthetic(Vec<Image>),
    /// Pairs cut from a recording alone (self-supervised adaptation).
    Recorded(RecordedPairs),
}

/// A batch of pairs cut from a recording, a pure function of `seed`.
fn recorded_batch(pairs: &RecordedPairs, cfg: &TrainConfig, seed: u64) -> Batch {
    let samples: Vec<(Vec<f32>, Vec<f32>)> = (0..cfg.batch as u64)
        .into_par_iter()
        .map(|b| pairs.sample(cfg.crop, cfg.augment, pair_seed(seed, b)))
        .collect();
    let (input, target): (Vec<Vec<f32>>, Vec<Vec<f32>>) = samples.into_iter().unzip();
    Batch {
        input: input.concat(),
        target: target.concat(),
    }
}

/// Refuses a run that cannot train: images smaller than the crop, empty or reversed ranges.
fn check_run(source: &Source, val_images: &[Image], cfg: &TrainConfig) -> Result<()> {
    let c = cfg.crop;
    let synthetic: &[Image] = match source {
        Source::Synthetic(images) => images,
        Source::Recorded(_) => &[],
    };
    for im in synthetic.iter().chain(val_images) {
        if im.width < c || im.height < c {
            return Err(Error::Data(format!(
                "a {}×{} image is smaller than the {c}-px crop",
                im.width, im.height
            )));
        }
    }
    let mut ranges = vec![
        ("electrons", cfg.electrons),
        ("read-noise scale", cfg.read_noise_scale),
    ];
    ranges.extend(cfg.mean_electrons.map(|r| ("mean electrons", r)));
    for (name, [lo, hi]) in ranges {
        if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
            return Err(Error::Data(format!(
                "{name} range {lo}–{hi}: must be positive and increasing"
            )));
        }
    }
    if let Some([lo, hi]) = cfg.cic_e {
        if !(lo >= 0.0 && hi >= lo && hi.is_finite()) {
            return Err(Error::Data(format!(
                "CIC range {lo}–{hi}: must be non-negative and increasing"
            )));
        }
    }
    Ok(())
}

/// Where a run starts: its network, optimizer, first step and smoothed loss.
struct Start {
    model: Model,
    optim: burn::optim::ModuleOptimizer,
    step: u64,
    loss_ema: f64,
}

/// An error where the run a checkpoint holds was made through another profile or adapted on
/// other recordings than the run asked to continue it: continued, the model would be trained
/// on both and record only the first.
fn resumable(was: &ModelMeta, now: &ModelMeta, checkpoint: &Path) -> Result<()> {
    let start_again = "start a new run (without --resume, or with another -o), or resume with the first run's inputs";
    if was.profile_fingerprint != now.profile_fingerprint {
        return Err(Error::Data(format!(
            "{}: the run there went through profile {}, this one through {}: {start_again}",
            checkpoint.display(),
            was.profile_fingerprint,
            now.profile_fingerprint
        )));
    }
    if let (Some(a), Some(b)) = (&was.adapted, &now.adapted) {
        let what = |x: &emccd_nn::Adaptation| {
            format!(
                "{} from {} on {} ({} frames at {:.3} e⁻)",
                x.method,
                x.from,
                x.files.join(", "),
                x.frames,
                x.mean_electrons
            )
        };
        if a != b {
            return Err(Error::Data(format!(
                "{}: the run there adapts {}, this one {}: {start_again}",
                checkpoint.display(),
                what(a),
                what(b)
            )));
        }
    }
    Ok(())
}

/// The checkpoint in `checkpoint` when resuming (and one was written), else the `init` model
/// (with this run's metadata) or a new network seeded from the config, with a new optimizer.
fn start_model(
    checkpoint: &Path,
    resume: bool,
    init: Option<&ModelSource>,
    meta: &ModelMeta,
    cfg: &TrainConfig,
    device: &Device,
) -> Result<Start> {
    let adamw = || AdamWConfig::new().with_weight_decay(cfg.weight_decay as f32);
    let state_path = checkpoint.join("state.json");
    if resume && state_path.is_file() {
        let st: CkptState = serde_json::from_str(
            &std::fs::read_to_string(&state_path).map_err(|e| Error::io(&state_path, e))?,
        )
        .map_err(|e| Error::Model(format!("{}: {e}", state_path.display())))?;
        resumable(&st.meta, meta, checkpoint)?;
        let model = load_net_with_ids(st.meta.clone(), &checkpoint.join("net.bpk"), device)?;
        let optim = adamw()
            .init()
            .load(checkpoint.join("optim.bin"))
            .map_err(|e| Error::Model(format!("optimizer state: {e:?}")))?;
        return Ok(Start {
            model,
            optim,
            step: st.step,
            loss_ema: st.loss,
        });
    }
    let model = match init {
        Some(p) => {
            let mut m = p.load(device)?;
            // A refinement network moved onto another base estimate would apply its
            // corrections for the old base's errors: it restarts as the identity on the new
            // base (its output layer zeroed), keeping what its other layers learned.
            if m.meta.inputs == Inputs::Hybrid && m.meta.base != meta.base {
                m.net = match m.net {
                    Net::UNet(u) => Net::UNet(u.with_zero_output()),
                    other => other,
                };
            }
            // A single-frame denoiser starting a temporal network is widened to the window,
            // as exactly the network it was: it learns what the neighbours add.
            if meta.inputs == Inputs::Movie && m.meta.inputs == Inputs::Noisy {
                let widened = match (m.net, m.meta.arch) {
                    (Net::UNet(u), emccd_nn::Arch::UNet(c)) => {
                        u.widened_for_movie(Inputs::Movie.frames()).map(|u| (u, c))
                    }
                    _ => None,
                };
                let (u, c) = widened.ok_or_else(|| {
                    Error::Model(
                        "a temporal network starts from a U-Net denoiser with a residual output \
                         on the frame (like the bundled lowlight), or from scratch"
                            .into(),
                    )
                })?;
                m.net = Net::UNet(u);
                m.meta.arch = emccd_nn::Arch::UNet(emccd_nn::UNetConfig {
                    in_channels: Inputs::Movie.channels(),
                    residual: Inputs::Movie.residual(),
                    ..c
                });
                m.meta.inputs = Inputs::Movie;
            }
            // The architecture is the initial model's; the rest describes this run.
            m.meta = ModelMeta {
                steps: m.meta.steps,
                arch: m.meta.arch,
                inputs: m.meta.inputs,
                ..meta.clone()
            };
            m
        }
        None => {
            // Seeded initialization: the same seed gives the same network.
            device.seed(cfg.seed);
            Model::new(meta.clone(), device)?
        }
    };
    Ok(Start {
        model,
        optim: adamw().init(),
        step: 0,
        loss_ema: f64::NAN,
    })
}

/// The fixed validation set: at each of VAL_LEVELS light levels spread over the training range,
/// 2 crops per validation image (at most 16 per level; images drawn at random). Eight random
/// crops — what this was before — made a noisy and level-skewed score: a hybrid's +0.48 dB
/// there was +0.0–0.2 dB on whole frames.
fn validation_set(
    val_images: &[Image],
    profile: &CameraProfile,
    cfg: &TrainConfig,
    inputs: Inputs,
) -> Result<Option<Batch>> {
    if val_images.is_empty() {
        return Ok(None);
    }
    let per_level = (2 * val_images.len()).min(16);
    let mut input = Vec::new();
    let mut target = Vec::new();
    for (k, level) in val_levels(cfg).into_iter().enumerate() {
        let mut vcfg = TrainConfig {
            batch: per_level,
            ..cfg.clone()
        };
        match &mut vcfg.mean_electrons {
            Some(r) => *r = [level, level],
            None => vcfg.electrons = [level, level],
        }
        let b = make_batch(
            val_images,
            profile,
            &vcfg,
            inputs,
            cfg.ablate,
            (cfg.seed ^ 0x7A11D).wrapping_add(k as u64),
        )?;
        input.extend(b.input);
        target.extend(b.target);
    }
    Ok(Some(Batch { input, target }))
}

/// Writes a checkpoint into `dir`: the weights (safetensors, and burnpack with the parameter
/// identities the optimizer's state is keyed by), the optimizer state, and last the state file,
/// which is what makes the checkpoint count.
fn save_checkpoint(
    dir: &Path,
    model: &Model,
    optim: &burn::optim::ModuleOptimizer,
    cfg: &TrainConfig,
    step: u64,
    loss: f64,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    model.save(&dir.join("model.safetensors"))?;
    save_net_with_ids(model, &dir.join("net.bpk"))?;
    let opath = dir.join("optim.bin");
    let tmp = emccd_io::temp_beside(&opath).map_err(|e| Error::io(&opath, e))?;
    optim
        .save(tmp.path())
        .map_err(|e| Error::Model(format!("saving optimizer state: {e:?}")))?;
    emccd_io::persist(tmp, &opath).map_err(|e| Error::Model(e.to_string()))?;
    let st = serde_json::to_string_pretty(&CkptState {
        step,
        config: cfg.clone(),
        loss,
        meta: model.meta.clone(),
    })
    .map_err(|e| Error::Model(e.to_string()))?;
    emccd_io::write_atomic(dir.join("state.json"), st.as_bytes())
        .map_err(|e| Error::Model(e.to_string()))?;
    Ok(())
}

/// [`train`] on any [`Source`].
pub(crate) fn train_from(
    source: Source,
    val_images: Vec<Image>,
    run: Run,
    report: &mut dyn FnMut(&StepReport) -> bool,
) -> Result<Model> {
    let Run {
        profile,
        cfg,
        meta,
        paths,
        init,
        resume,
        device,
    } = run;
    profile.require_complete()?;
    check_run(&source, &val_images, &cfg)?;
    let c = cfg.crop;
    let abl = cfg.ablate;
    let inference = device.clone();
    let device = device.autodiff();
    let Start {
        mut model,
        mut optim,
        step: start,
        mut loss_ema,
    } = start_model(&paths.checkpoint, resume, init, &meta, &cfg, &device)?;
    if matches!(source, Source::Recorded(_)) && model.meta.inputs != Inputs::Noisy {
        return Err(Error::Data(match model.meta.inputs {
            Inputs::Movie => "a temporal network trains on synthesized movies only; recorded \
                              pairs train networks of noisy frames"
                .into(),
            other => format!(
                "a {} network needs a base estimate of every training crop; recorded pairs \
                 train networks of noisy frames only",
                other.name()
            ),
        }));
    }
    if c % model.meta.multiple() != 0 {
        return Err(Error::Data(format!(
            "the crop ({c} px) must be a multiple of {} px for {}",
            model.meta.multiple(),
            model.meta.arch.name()
        )));
    }
    // The base estimate is the model's (a resumed run's checkpoint records it), whatever the
    // command line said: a refinement network is only ever trained on the base it is saved with.
    let cfg = TrainConfig {
        base: model.meta.base,
        ..cfg
    };
    // ...and the model records what it is trained with: the record below then repeats its
    // contract (ModelMeta) instead of contradicting it when a caller's metadata said otherwise.
    model.meta.scale = cfg.scale;
    model.meta.ablate = cfg.ablate;
    model.meta.noise_model = cfg.noise;
    model.meta.train = Some(cfg.clone());
    let base_steps = model.meta.steps.saturating_sub(start);
    let inputs = model.meta.inputs;
    let ch = inputs.channels();
    let val = validation_set(&val_images, profile, &cfg, inputs)?;
    let nval = val.as_ref().map_or(0, |v| v.target.len() / (c * c));
    let mut val_psnr = None;

    // Producer: batches for steps start.. on another thread.
    let (tx, rx) = mpsc::sync_channel::<Result<Batch>>(2);
    let (prof, pcfg) = (profile.clone(), cfg.clone());
    let producer = std::thread::spawn(move || {
        let mut pool = Pool {
            pairs: Default::default(),
        };
        for step in start..pcfg.steps {
            let seed = pcfg.seed.wrapping_add(step.wrapping_mul(7919));
            let b = match &source {
                Source::Recorded(pairs) => Ok(recorded_batch(pairs, &pcfg, seed)),
                Source::Synthetic(imgs) if pcfg.reuse > 1 => {
                    pool.batch(imgs, &prof, &pcfg, inputs, abl, step)
                }
                Source::Synthetic(imgs) => make_batch(imgs, &prof, &pcfg, inputs, abl, seed),
            };
            if tx.send(b).is_err() {
                break;
            }
        }
    });
    for step in start..cfg.steps {
        let batch = rx
            .recv()
            .map_err(|_| Error::Data("the pair synthesizer stopped".into()))??;
        let x =
            Tensor::<4>::from_data(TensorData::new(batch.input, [cfg.batch, ch, c, c]), &device);
        let y =
            Tensor::<4>::from_data(TensorData::new(batch.target, [cfg.batch, 1, c, c]), &device);
        let d = model.net.forward(x) - y;
        let loss = match cfg.loss {
            Loss::Charbonnier => (d.clone() * d + 1e-6).sqrt().mean(),
            Loss::L2 => (d.clone() * d).mean(),
        };
        let lv = loss
            .clone()
            .into_data()
            .convert::<f64>()
            .try_into_vec::<f64>()
            .map(|v| v[0])
            .unwrap_or(f64::NAN);
        if !lv.is_finite() {
            return Err(Error::Data(format!(
                "training diverged at step {step} (loss {lv})"
            )));
        }
        loss_ema = if loss_ema.is_nan() {
            lv
        } else {
            0.98 * loss_ema + 0.02 * lv
        };
        let grads = GradientsParams::from_grads(loss.backward(), &model.net);
        model.net = optim.step(cfg.lr_at(step), model.net, grads);
        let done = step + 1;
        model.meta.steps = base_steps + done;
        if let Some(v) = &val {
            if done % cfg.val_every.max(1) == 0 || done == cfg.steps {
                val_psnr = Some(validate(&model, v, nval, c, &device));
            }
        }
        if done % cfg.checkpoint_every.max(1) == 0 || done == cfg.steps {
            save_checkpoint(&paths.checkpoint, &model, &optim, &cfg, done, loss_ema)?;
        }
        if !report(&StepReport {
            step: done,
            steps: cfg.steps,
            loss: loss_ema,
            val_psnr,
        }) {
            drop(rx);
            let _ = producer.join();
            return Ok(model.valid(&inference));
        }
    }
    drop(rx);
    let _ = producer.join();
    model.save(&paths.out)?;
    Ok(model.valid(&inference))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warm_up_is_at_most_a_fifth_of_the_run() {
        let cfg = |warmup, steps| TrainConfig {
            warmup,
            steps,
            ..TrainConfig::default()
        };
        assert_eq!(cfg(500, 20000).warmup_steps(), 500);
        assert_eq!(cfg(500, 100).warmup_steps(), 20);
        assert_eq!(cfg(0, 3).warmup_steps(), 1);
        // The peak rate is reached at the end of the warm-up, and the run ends at 1 % of it.
        let c = cfg(500, 100);
        assert!((c.lr_at(19) - c.lr).abs() < 1e-15);
        assert!(c.lr_at(0) < c.lr / 10.0);
        assert!((c.lr_at(100) - 0.01 * c.lr).abs() < 1e-12);
    }

    #[test]
    fn every_tenth_image_is_held_out_unless_validation_images_are_given() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, v: f32| {
            let path = dir.path().join(name);
            let mut w =
                emccd_io::StackWriter::create(&path, 2, 2, emccd_io::SampleFormat::F32, Some(1))
                    .unwrap();
            w.write_frame(&[v, 12.0, 12.0, 24.0]).unwrap();
            w.finish().unwrap();
            path
        };
        for k in 0..12 {
            write(&format!("s{k:02}.tif"), (k + 1) as f32);
        }
        let all = [dir.path().to_path_buf()];
        let imgs = TrainImages::read(&all, &[]).unwrap();
        assert_eq!((imgs.train.len(), imgs.val.len()), (11, 1));
        // float scenes are scaled by their maximum (24 for s11): the tenth, s09, is held out
        let first = |imgs: &[Image]| imgs.iter().map(|i| i.data[0]).collect::<Vec<f32>>();
        assert_eq!(first(&imgs.val), vec![10.0 / 24.0]);
        assert!(!first(&imgs.train).contains(&(10.0 / 24.0)));
        let val_dir = tempfile::tempdir().unwrap();
        let val = val_dir.path().join("v.tif");
        std::fs::rename(write("v.tif", 3.0), &val).unwrap();
        let imgs = TrainImages::read(&all, &[val]).unwrap();
        assert_eq!((imgs.train.len(), imgs.val.len()), (12, 1));
        let e = TrainImages::read(&[dir.path().join("none")], &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("none") && e.contains("no such file"), "{e}");
    }

    fn setup() -> (Vec<Image>, CameraProfile, TrainConfig) {
        let (w, h) = (48, 40);
        let data = (0..w * h)
            .map(|i| ((i % w) as f32 / w as f32 + (i / w) as f32 / h as f32) / 2.0)
            .collect();
        let cfg = TrainConfig {
            batch: 3,
            crop: 16,
            reuse: 4,
            mean_electrons: Some([0.5, 16.0]),
            ..TrainConfig::default()
        };
        (
            vec![Image {
                width: w,
                height: h,
                data,
            }],
            emccd_profile::default_profile(),
            cfg,
        )
    }

    #[test]
    fn validation_levels_span_the_training_range() {
        let cfg = TrainConfig {
            mean_electrons: Some([0.3, 30.0]),
            ..TrainConfig::default()
        };
        let l = val_levels(&cfg);
        // Log-uniform quantiles 1/8, 3/8, 5/8, 7/8 of 0.3–30: 0.3·100^q.
        for (got, q) in l.iter().zip([0.125, 0.375, 0.625, 0.875]) {
            let want = 0.3 * 100f64.powf(q);
            assert!((got / want - 1.0).abs() < 1e-12, "{got} vs {want}");
        }
        // Without a mean range, the full-scale range is used.
        let l = val_levels(&TrainConfig::default());
        assert!(l[0] > 3.0 && l[3] < 3000.0 && l.windows(2).all(|w| w[0] < w[1]));
    }

    /// A resumed run rebuilds the pool from scratch: its batch at a step must be the one the
    /// uninterrupted run drew there.
    #[test]
    fn pool_batches_depend_only_on_seed_and_step() {
        let (imgs, prof, cfg) = setup();
        let abl = Ablation::default();
        let mut running = Pool {
            pairs: Default::default(),
        };
        let mut seen = Vec::new();
        for step in 0..9 {
            seen.push(
                running
                    .batch(&imgs, &prof, &cfg, Inputs::Noisy, abl, step)
                    .unwrap(),
            );
        }
        for step in [0u64, 4, 8] {
            let fresh = Pool {
                pairs: Default::default(),
            }
            .batch(&imgs, &prof, &cfg, Inputs::Noisy, abl, step)
            .unwrap();
            assert_eq!(fresh.input, seen[step as usize].input, "step {step}");
            assert_eq!(fresh.target, seen[step as usize].target, "step {step}");
        }
        // The window slides: it holds batch·reuse pairs, batch/reuse of them new per step.
        assert_eq!(running.pairs.len(), 12);
        assert_eq!(
            *running.pairs.keys().next().unwrap(),
            (8 * 3u64).div_ceil(4)
        );
    }

    /// Reuse draws each pair several times, re-oriented: a batch's crops are orientations of
    /// pairs in the window, never something else.
    #[test]
    fn pool_draws_orientations_of_window_pairs() {
        let (imgs, prof, cfg) = setup();
        let abl = Ablation::default();
        let mut pool = Pool {
            pairs: Default::default(),
        };
        let b = pool
            .batch(&imgs, &prof, &cfg, Inputs::Noisy, abl, 5)
            .unwrap();
        let c = cfg.crop;
        for t in b.target.chunks_exact(c * c) {
            let found = pool
                .pairs
                .values()
                .any(|(_, pt)| (0..8u8).any(|m| orient(pt, c, m) == t));
            assert!(found, "a drawn target is no orientation of a window pair");
        }
    }

    /// Without augmentation every crop keeps the image's orientation (the test image grows to
    /// the right and downwards), and the pairs drawn are the same ones: only the orientation
    /// differs from an augmented run.
    #[test]
    fn without_augmentation_crops_keep_their_orientation() {
        let (imgs, prof, cfg) = setup();
        let abl = Ablation::default();
        let c = cfg.crop;
        let grows = |t: &[f32]| {
            (0..c).all(|y| (1..c).all(|x| t[y * c + x] >= t[y * c + x - 1]))
                && (1..c).all(|y| (0..c).all(|x| t[y * c + x] >= t[(y - 1) * c + x]))
        };
        let run = |augment: bool| {
            let cfg = TrainConfig {
                augment,
                ..cfg.clone()
            };
            let mut pool = Pool {
                pairs: Default::default(),
            };
            let targets: Vec<Vec<f32>> = (1..4)
                .flat_map(|step| {
                    let b = pool
                        .batch(&imgs, &prof, &cfg, Inputs::Noisy, abl, step)
                        .unwrap();
                    b.target
                        .chunks_exact(c * c)
                        .map(<[f32]>::to_vec)
                        .collect::<Vec<_>>()
                })
                .collect();
            (targets, pool.pairs.keys().copied().collect::<Vec<u64>>())
        };
        let (plain, keys_plain) = run(false);
        assert!(plain.iter().all(|t| grows(t)));
        let (augmented, keys_augmented) = run(true);
        assert!(
            augmented.iter().any(|t| !grows(t)),
            "no crop was flipped or transposed"
        );
        assert_eq!(keys_plain, keys_augmented);
        for (p, a) in plain.iter().zip(&augmented) {
            assert!((0..8u8).any(|m| orient(p, c, m) == *a));
        }
    }

    #[test]
    fn a_run_s_base_is_chosen_or_inherited_and_only_a_refinement_network_has_one() {
        assert_eq!(
            classical_for_run(None, Inputs::Noisy, None).unwrap(),
            Classical::Bm3d
        );
        assert_eq!(
            classical_for_run(Some(Classical::Ivst), Inputs::Hybrid, None).unwrap(),
            Classical::Ivst
        );
        let e = classical_for_run(Some(Classical::Ivst), Inputs::Noisy, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--inputs hybrid"), "{e}");
        // The bundled hybrid network refines one BM3D pass: a run from it inherits that.
        let hybrid = Model::read_meta(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../models/hybrid-unet.safetensors"),
        )
        .unwrap();
        assert_eq!(
            classical_for_run(None, Inputs::Hybrid, Some(&hybrid)).unwrap(),
            hybrid.base
        );
    }

    #[test]
    fn a_run_keeps_its_initial_models_scale_unless_told() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/lowlight-unet.safetensors");
        let mut meta = Model::read_meta(&path).unwrap();
        assert_eq!(scale_for_run(None, Some(&meta)), meta.scale);
        meta.scale = Scale::Binned;
        assert_eq!(scale_for_run(None, Some(&meta)), Scale::Binned);
        assert_eq!(
            scale_for_run(Some(Scale::Percentile), Some(&meta)),
            Scale::Percentile
        );
        assert_eq!(scale_for_run(None, None), Scale::Percentile);
    }
}
