//! `emccd adapt`: fine-tune a model on the user's own recording, with no clean data.

use std::path::PathBuf;

use anyhow::{Context, Result};
use emccd_nn::Adaptation;
use emccd_train::adapt::{adapt, AdaptConfig, AdaptData, AdaptRun, Recorded, Start};
use emccd_train::RunPaths;

use crate::common::{progress, step_progress, RecordingArgs};

/// Adapt a denoising network to your own recording, with no clean images: the frames are
/// preprocessed as `denoise` does (blooming, fixed pattern), averaged (the scene must be static
/// over the frames given), the average is denoised with iterative BM3D at its own, N times
/// lower, noise, and the model is fine-tuned on pairs synthesized from that scene estimate with
/// the profile's exact noise chain at the recording's light level (the calibrated profile, or without
/// --profile the camera characterized from the recordings). The output is an
/// ordinary model file (`emccd denoise --model OUT`) that records what it was adapted on and
/// from which model. A checkpoint is kept in OUT.ckpt/; --resume continues an interrupted run.
/// The more frames, the better the scene estimate: 20–50 is a good range. An existing OUT is
/// replaced only with --force.
///
/// --method noise2noise and --method neighbors train on the recorded frames themselves instead
/// (self-supervised; up to 256 MiB of frames are kept); `--from-scratch --method neighbors` is
/// the self-supervised baseline, a new network trained on the recordings alone (which may then
/// show different scenes and exposures).
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Recordings of one static scene (TIFF/BigTIFF, SIF, FITS stacks; read frame by frame);
    /// with --method neighbors any recordings of the camera.
    #[arg(required = true, num_args = 1..)]
    pub inputs: Vec<PathBuf>,
    #[command(flatten)]
    pub recording: RecordingArgs,
    /// The model to start from: a bundled one (`lowlight`, `default`, `microscopy`) or a model
    /// file. `lowlight` is the best network at a few photoelectrons per pixel.
    #[arg(long, default_value = "lowlight")]
    pub init: String,
    /// Start from a new network of --init's architecture (its weights are not used),
    /// initialized from --seed.
    #[arg(long)]
    pub from_scratch: bool,
    #[command(flatten)]
    pub cfg: AdaptConfig,
    /// Peak learning rate [default: 5e-4 fine-tuning, 1e-3 from scratch].
    #[arg(long)]
    pub lr: Option<f64>,
    /// Continue the run whose checkpoint is in OUT.ckpt/.
    #[arg(long)]
    pub resume: bool,
    /// Output model file (.safetensors).
    #[arg(short, long)]
    pub out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let scratch = a.from_scratch;
    let cfg = AdaptConfig {
        lr: a.lr.unwrap_or(AdaptConfig::default_lr(scratch)),
        ..a.cfg
    };
    cfg.check()?;
    let init = emccd_denoise::bundled::source(&a.init)?;
    for input in &a.inputs {
        emccd_io::refuse_overwrite(&a.out, input, "an input")?;
    }
    if let Some(file) = init.file() {
        emccd_io::refuse_overwrite(&a.out, file, "the --init model")?;
    }
    // Before anything is read or trained: where the model goes.
    check_out(&a.out, a.recording.force)?;
    let init_meta = init.read_meta()?;
    let mut chosen = a.recording.choose_profile(&a.inputs, true)?;
    let profile = chosen.profile.clone();
    profile
        .require_complete()
        .with_context(|| format!("profile {}: it cannot preprocess frames", chosen.name))?;
    let mut rec = Recorded::new(
        cfg.method,
        &profile,
        init_meta.ablate,
        Recorded::MEMORY_BUDGET,
    );
    for input in &a.inputs {
        a.recording.open(input, &profile)?;
    }
    a.recording.check_fit(&mut chosen, &a.inputs, false)?;
    for input in &a.inputs {
        let recording = a.recording.reopen(input, &profile)?;
        let pb = progress(recording.info.frames as u64, "reading");
        rec.add_recording(&profile, recording, &mut || pb.inc(1))?;
        pb.finish_and_clear();
    }
    if let Some(w) = rec.warning() {
        eprintln!("warning: {w}");
    }
    let frames = rec.frames();
    let data = rec.finish(&profile)?;
    let level = data.mean_electrons(&profile)?;
    if level < MIN_LEVEL {
        anyhow::bail!(
            "the recordings hold {level:.3} mean photoelectrons per pixel, what bias frames leave: no scene to adapt to (bias or dark frames?); adapt on a recording of the scene, at {MIN_LEVEL} or more"
        );
    }
    match &data {
        AdaptData::Scene(_) => eprintln!(
            "scene estimate from {frames} frames at {level:.3} mean photoelectrons per pixel"
        ),
        AdaptData::Frames(_) => eprintln!(
            "{} of {frames} frames kept, at {level:.3} mean photoelectrons per pixel",
            data.frames()
        ),
    }
    let provenance = Adaptation::new(
        cfg.method.name(),
        &a.init,
        scratch,
        &a.inputs,
        data.frames(),
        level,
    );
    let paths = RunPaths::beside(&a.out);
    let (pb, mut report) = step_progress(cfg.steps, cfg.checkpoint_every);
    let start = if scratch {
        Start::Scratch(init_meta)
    } else {
        Start::Model(&init)
    };
    let model = adapt(
        data,
        AdaptRun {
            profile: &profile,
            start,
            cfg: &cfg,
            provenance,
            paths: &paths,
            resume: a.resume,
            device: crate::common::device(),
        },
        &mut report,
    )?;
    pb.finish();
    eprintln!(
        "adapted model written to {} ({} steps in all); denoise with `emccd denoise --model {}`",
        a.out.display(),
        model.meta.steps,
        a.out.display()
    );
    Ok(())
}

/// The least light a recording is adapted on, mean photoelectrons per pixel per frame: below it
/// the frames are a bias (a calibrated profile takes its spurious charge out with the fixed
/// pattern; 0.007 is left on the virtual camera), not a scene.
const MIN_LEVEL: f64 = 0.02;

/// The model's path must name a file in an existing folder, and an existing file (an earlier
/// model, or anything else) is replaced only with `--force`: a run that fails on it after
/// minutes of training would leave its checkpoint behind.
fn check_out(out: &std::path::Path, force: bool) -> Result<()> {
    if out.is_dir() {
        anyhow::bail!(
            "{}: is a folder; -o takes the model's file name (e.g. {})",
            out.display(),
            out.join("adapted.safetensors").display()
        );
    }
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty());
    if let Some(dir) = parent.filter(|d| !d.is_dir()) {
        anyhow::bail!(
            "{}: the folder {} does not exist",
            out.display(),
            dir.display()
        );
    }
    if out.exists() && !force {
        anyhow::bail!(
            "{}: exists; pass --force to replace it (an adapted model is written there)",
            out.display()
        );
    }
    Ok(())
}
