//! `emccd train`: train or fine-tune a denoising network on pairs synthesized on the fly.

use std::path::PathBuf;

use anyhow::Result;
use emccd_camera::{Ablation, NoiseModelKind};
use emccd_nn::train::{train, Loss, Run, RunPaths, TrainConfig, TrainImages};
use emccd_nn::{Arch, Base, Inputs, ModelMeta, Scale, UNetConfig};

use crate::common::load_profile;

/// Train a denoising network on noisy/clean pairs synthesized on the fly from clean images and a
/// camera profile (random crops, 8-way flips/rotations, random photon level), with AdamW,
/// warm-up + cosine decay and the Charbonnier (or L2) loss. A checkpoint (model, optimizer
/// state, step) is written to OUT.ckpt/ every --checkpoint-every steps; --resume continues from
/// it. `--inputs hybrid` trains the BM3D-refining network of `emccd denoise --method hybrid`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Camera profile (`default` = the bundled iXon 897 model).
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// Clean images: PNG/TIFF/FITS files or directories (repeatable).
    #[arg(long, required = true, num_args = 1..)]
    pub clean: Vec<PathBuf>,
    /// Held-out validation images; default: every 10th clean image is held out.
    #[arg(long, num_args = 1..)]
    pub val: Vec<PathBuf>,
    /// Architecture: `unet` (the CPU default, ≈ 2.5 M parameters), or the paper's Uformer in its
    /// three sizes `uformer-t` (5.3 M), `uformer-s` (20.7 M), `uformer-b` (50.9 M; crops must be
    /// multiples of 128 px). With --init the initial model's architecture is kept.
    #[arg(long, default_value = "unet", value_parser = clap::builder::PossibleValuesParser::new(emccd_nn::model::ARCHS))]
    pub arch: String,
    /// U-Net channels at full resolution.
    #[arg(long, default_value_t = 16)]
    pub base: usize,
    /// U-Net levels.
    #[arg(long, default_value_t = 4)]
    pub levels: usize,
    /// U-Net denoiser: output the clean frame directly instead of a correction added to the
    /// noisy frame (which, at a few photoelectrons, has to cancel every EM spike exactly).
    #[arg(long)]
    pub direct: bool,
    /// U-Net: fold each N×N pixel block into channels before the first layer and unfold the
    /// output (FFDNet's down-sampling; 2 costs about a quarter of the operations per pixel, so
    /// about 3× the crops per CPU-hour, for a receptive field one level deeper). 1: none.
    #[arg(long, default_value_t = 1, value_name = "1|2|4")]
    pub unshuffle: usize,
    /// How a denoiser's input is scaled per frame: `percentile` (the noisy frame's 99.5th
    /// percentile, what the bundled networks use) or `binned` (the same of 4×4 block means,
    /// which follows the scene rather than the noise). Recorded in the model. Default: the
    /// --init model's, else percentile.
    #[arg(long, value_enum)]
    pub scale: Option<Scale>,
    /// What the network is given: `noisy` (the frame and its noise level: a denoiser), or
    /// `hybrid` (also the BM3D + GAT estimate, which the network corrects; its output layer
    /// starts at zero, so training starts at BM3D's quality; U-Net only).
    #[arg(long, value_enum, default_value = "noisy")]
    pub inputs: Inputs,
    /// --inputs hybrid: the estimate the network corrects: `bm3d` (BM3D + GAT, one pass) or
    /// `ivst` (BM3D with iterative variance stabilization and binning, better below a few
    /// photoelectrons per pixel; `emccd denoise --method ivst`). Default: the --init model's
    /// base, else bm3d. Another base than the --init model's restarts its output layer at zero.
    #[arg(long, value_enum)]
    pub hybrid_base: Option<Base>,
    /// Noise model of the synthesized pairs.
    #[arg(long, value_enum, default_value = "ours")]
    pub noise_model: NoiseModelKind,
    /// Components to switch off: multiplicative, readout, quantization (synthesis); fpn, blooming
    /// (recorded in the model: its denoising pipeline then skips that correction).
    #[arg(long, default_value = "")]
    pub ablate: Ablation,
    /// Optimizer steps.
    #[arg(long, default_value_t = 20000)]
    pub steps: u64,
    /// Crops per step.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Crop side, px.
    #[arg(long, default_value_t = 128)]
    pub crop: usize,
    /// Use each synthesized pair about this many times (in different batches, re-oriented):
    /// synthesis then costs batch/reuse pairs per step. Worth it for --inputs hybrid, where every
    /// pair needs a BM3D run (≈ 0.4 s per 128² crop on one core).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub reuse: u32,
    /// Multiply the profile's read noise by a factor drawn log-uniformly from LO,HI for every
    /// pair (noise model `ours`), so the model learns many read-noise-to-gain ratios and serves
    /// other cameras too. 1,1: the profile's own read noise only.
    #[arg(long, default_value = "1,1", value_parser = lo_hi, value_name = "LO,HI")]
    pub read_noise_scale: [f64; 2],
    /// Photo-electrons at a scene's brightest pixel, drawn log-uniformly from LO,HI.
    #[arg(long, default_value = "3,3000", value_parser = lo_hi, value_name = "LO,HI")]
    pub electrons: [f64; 2],
    /// Instead of --electrons: the scene's mean photo-electrons per pixel, drawn log-uniformly
    /// from LO,HI (e.g. 0.2,100 for the photon-starved range EMCCDs are used in).
    #[arg(long, value_parser = lo_hi, value_name = "LO,HI")]
    pub mean_electrons: Option<[f64; 2]>,
    /// Noise model pgn: clock-induced charge per pixel and frame (e⁻), drawn uniformly from
    /// LO,HI; default: the profile's.
    #[arg(long, value_parser = lo_hi, value_name = "LO,HI")]
    pub cic: Option<[f64; 2]>,
    /// Training loss.
    #[arg(long, value_enum, default_value = "charbonnier")]
    pub loss: Loss,
    /// Peak learning rate.
    #[arg(long, default_value_t = 2e-4)]
    pub lr: f64,
    /// Warm-up steps.
    #[arg(long, default_value_t = 500)]
    pub warmup: u64,
    /// Validate (and checkpoint) every this many steps.
    #[arg(long, default_value_t = 250)]
    pub checkpoint_every: u64,
    /// Seed.
    #[arg(long, default_value_t = 897)]
    pub seed: u64,
    /// Fine-tune from this model (a file, or a bundled model: `default`, `microscopy`, `lowlight`).
    #[arg(long)]
    pub init: Option<String>,
    /// Continue the run whose checkpoint is in OUT.ckpt/.
    #[arg(long)]
    pub resume: bool,
    /// Output model file (.safetensors).
    #[arg(short, long)]
    pub out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let shape = UNetConfig {
        base: a.base,
        levels: a.levels,
        direct: a.direct,
        unshuffle: a.unshuffle,
        ..UNetConfig::DEFAULT
    };
    let arch = Arch::for_training(&a.arch, a.inputs, shape)?;
    // Before any image is read: the model a run starts from is never its output.
    let init = a
        .init
        .as_deref()
        .map(emccd_nn::registry::model_path)
        .transpose()?;
    if let Some(i) = &init {
        emccd_io::refuse_overwrite(&a.out, i, "the --init model")?;
    }
    let init_meta = init
        .as_deref()
        .map(emccd_nn::Denoiser::read_meta)
        .transpose()?;
    let base = Base::for_run(a.hybrid_base, a.inputs, init_meta.as_ref())?;
    let scale = Scale::for_run(a.scale, init_meta.as_ref());
    let profile = load_profile(&a.profile)?;
    let images = TrainImages::read(&a.clean, &a.val)?;
    let cfg = TrainConfig {
        base,
        steps: a.steps,
        batch: a.batch,
        crop: a.crop,
        reuse: a.reuse,
        lr: a.lr,
        warmup: a.warmup,
        noise: a.noise_model,
        ablate: a.ablate,
        read_noise_scale: a.read_noise_scale,
        electrons: a.electrons,
        mean_electrons: a.mean_electrons,
        cic_e: a.cic,
        loss: a.loss,
        scale,
        seed: a.seed,
        val_every: a.checkpoint_every,
        checkpoint_every: a.checkpoint_every,
        ..TrainConfig::default()
    };
    let meta = ModelMeta::for_run(arch, a.inputs, &cfg, &profile, &images);
    let paths = RunPaths::beside(&a.out);
    let (pb, mut report) = crate::common::step_progress(a.steps, a.checkpoint_every);
    let model = train(
        images,
        Run::new(&profile, cfg, meta, &paths)
            .with_init(init.as_deref())
            .resuming(a.resume),
        &mut report,
    )?;
    pb.finish();
    eprintln!(
        "model written to {} ({} steps, {} parameters)",
        a.out.display(),
        model.meta.steps,
        model.num_params()
    );
    Ok(())
}

/// `LO,HI`: two comma-separated numbers (a range to draw from).
fn lo_hi(s: &str) -> std::result::Result<[f64; 2], String> {
    let v: Vec<&str> = s.split(',').map(str::trim).collect();
    match v[..] {
        [lo, hi] => match (lo.parse(), hi.parse()) {
            (Ok(lo), Ok(hi)) => Ok([lo, hi]),
            _ => Err(format!("{s:?}: two numbers, LO,HI")),
        },
        _ => Err(format!("{s:?}: two comma-separated numbers, LO,HI")),
    }
}
