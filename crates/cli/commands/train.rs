//! `emccd train`: train or fine-tune a denoising network on pairs synthesized on the fly.

use std::path::PathBuf;

use anyhow::Result;
use emccd_nn::{Arch, Classical, Inputs, Scale, TrainConfig, UNetConfig};
use emccd_train::train::{classical_for_run, scale_for_run};
use emccd_train::{meta_for_run, train, Run, RunPaths, TrainImages};

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
    #[command(flatten)]
    pub shape: UNetConfig,
    /// How a denoiser's input is scaled per frame: `percentile` (the noisy frame's 99.5th
    /// percentile, what the bundled networks use) or `binned` (the same of 4×4 block means,
    /// which follows the scene rather than the noise). Recorded in the model. Default: the
    /// --init model's, else percentile.
    #[arg(long, value_enum)]
    pub scale: Option<Scale>,
    /// What the network is given: `noisy` (the frame and its noise level: a denoiser),
    /// `hybrid` (also the BM3D + GAT estimate, which the network corrects; its output layer
    /// starts at zero, so training starts at BM3D's quality; U-Net only), or `movie` (the frame,
    /// the 2 frames before and after it and its noise level: a temporal network, trained on
    /// movies synthesized with every kind of motion; U-Net only).
    #[arg(long, value_enum, default_value = "noisy")]
    pub inputs: Inputs,
    /// --inputs hybrid: the estimate the network corrects: `bm3d` (BM3D + GAT, one pass) or
    /// `ivst` (BM3D with iterative variance stabilization and binning, better below a few
    /// photoelectrons per pixel; `emccd denoise --method ivst`). Default: the --init model's
    /// base, else bm3d. Another base than the --init model's restarts its output layer at zero.
    #[arg(long, value_enum)]
    pub hybrid_base: Option<Classical>,
    #[command(flatten)]
    pub cfg: TrainConfig,
    /// Fine-tune from this model (a file, or a bundled model: `default`, `microscopy`, `lowlight`,
    /// `movie`). With --inputs movie, a single-frame U-Net denoiser (e.g. `lowlight`) is widened
    /// to the five frames, starting as exactly the network it was.
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
    let arch = Arch::for_training(&a.arch, a.inputs, a.shape)?;
    // Before any image is read: the model a run starts from is never its output.
    let init = a
        .init
        .as_deref()
        .map(emccd_denoise::bundled::source)
        .transpose()?;
    if let Some(i) = init.as_ref().and_then(|i| i.file()) {
        emccd_io::refuse_overwrite(&a.out, i, "the --init model")?;
    }
    let init_meta = init.as_ref().map(|i| i.read_meta()).transpose()?;
    let cfg = TrainConfig {
        base: classical_for_run(a.hybrid_base, a.inputs, init_meta.as_ref())?,
        scale: scale_for_run(a.scale, init_meta.as_ref()),
        val_every: a.cfg.checkpoint_every,
        ..a.cfg
    };
    let profile = load_profile(&a.profile)?;
    let images = TrainImages::read(&a.clean, &a.val)?;
    let meta = meta_for_run(arch, a.inputs, &cfg, &profile, &images);
    let paths = RunPaths::beside(&a.out);
    let (pb, mut report) = crate::common::step_progress(cfg.steps, cfg.checkpoint_every);
    let model = train(
        images,
        Run::new(&profile, cfg, meta, &paths, &crate::common::device())
            .with_init(init.as_ref())
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
