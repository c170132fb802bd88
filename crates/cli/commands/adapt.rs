//! `emccd adapt`: fine-tune a model on the user's own recording, with no clean data.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use emccd_camera::NoiseModelKind;
use emccd_nn::adapt::{adapt, scene_estimate, AdaptConfig, Adaptation, FrameMean};
use emccd_nn::train::RunPaths;

use crate::common::{load_profile, open_recording, progress, step_progress, Recording};

/// Adapt a denoising network to your own recording, with no clean images: the frames are
/// preprocessed as `denoise` does (blooming, fixed pattern), averaged (the scene must be static
/// over the frames given), the average is denoised with iterative BM3D at its own, N times
/// lower, noise, and the model is fine-tuned on pairs synthesized from that scene estimate with
/// the calibrated profile's exact noise chain at the recording's light level. The output is an
/// ordinary model file (`emccd denoise --model OUT`) that records what it was adapted on and
/// from which model. A checkpoint is kept in OUT.ckpt/; --resume continues an interrupted run.
/// The more frames, the better the scene estimate: 20–50 is a good range.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Recordings of one static scene (TIFF/BigTIFF, SIF, FITS stacks; read frame by frame).
    #[arg(required = true, num_args = 1..)]
    pub inputs: Vec<PathBuf>,
    /// The camera's profile (`emccd calibrate`), or `default`.
    #[arg(long)]
    pub profile: String,
    /// Exposure time (s); default: from each file's header.
    #[arg(long)]
    pub exposure_s: Option<f64>,
    /// Allow an exposure outside the profile's calibrated dark-current range.
    #[arg(long)]
    pub extrapolate: bool,
    /// The model to start from: a bundled one (`lowlight`, `default`, `microscopy`) or a model
    /// file. `lowlight` is the best network at a few photoelectrons per pixel.
    #[arg(long, default_value = "lowlight")]
    pub init: String,
    /// Fine-tuning steps (about 1 s each for 4 × 128² crops on 2 cores).
    #[arg(long, default_value_t = AdaptConfig::default().steps)]
    pub steps: u64,
    /// Peak learning rate.
    #[arg(long, default_value_t = AdaptConfig::default().lr)]
    pub lr: f64,
    /// Noise model of the synthesized pairs (`ours`: the profile's exact EMCCD chain).
    #[arg(long, value_enum, default_value = "ours")]
    pub noise_model: NoiseModelKind,
    /// Seed.
    #[arg(long, default_value_t = AdaptConfig::default().seed)]
    pub seed: u64,
    /// Continue the run whose checkpoint is in OUT.ckpt/.
    #[arg(long)]
    pub resume: bool,
    /// Output model file (.safetensors).
    #[arg(short, long)]
    pub out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let profile = load_profile(&a.profile)?;
    profile
        .require_complete()
        .with_context(|| format!("profile {}: it cannot preprocess frames", a.profile))?;
    let init = emccd_nn::registry::model_path(&a.init)?;
    for input in &a.inputs {
        if input.canonicalize().ok() == a.out.canonicalize().ok() || *input == a.out {
            bail!(
                "{}: the output is an input; choose another -o, inputs are never overwritten",
                a.out.display()
            );
        }
    }
    if init.canonicalize().ok() == a.out.canonicalize().ok() {
        bail!(
            "{}: the output is the --init model; choose another -o, inputs are never overwritten",
            a.out.display()
        );
    }
    let mut mean = FrameMean::new(profile.width, profile.height);
    let mut exposure = None;
    for input in &a.inputs {
        let Recording {
            mut reader,
            info,
            exposure: t,
            ..
        } = open_recording(input, &profile, a.exposure_s, a.extrapolate)?;
        match exposure {
            Some(e) if e != t => bail!(
                "{}: exposure {t} s, the first recording's is {e} s: adapt on one exposure",
                input.display()
            ),
            _ => exposure = Some(t),
        }
        let pb = progress(info.frames as u64, "averaging");
        let mut buf = vec![0f32; info.frame_len()];
        while reader
            .read_frame(&mut buf)
            .with_context(|| input.display().to_string())?
        {
            let dn = emccd_nn::pipeline::preprocess(&profile, &buf, t)
                .with_context(|| format!("{}: frame {}", input.display(), mean.frames() + 1))?;
            mean.add(&dn)?;
            pb.inc(1);
        }
        pb.finish_and_clear();
    }
    let exposure = exposure.context("no recordings")?;
    if mean.frames() < 8 {
        eprintln!(
            "warning: {} frame(s): the scene estimate keeps much of their noise, and the model \
             learns it as structure; 20–50 frames of the static scene are better",
            mean.frames()
        );
    }
    let scene = scene_estimate(&mean, &profile, exposure)?;
    eprintln!(
        "scene estimate from {} frames at {:.3} mean photoelectrons per pixel",
        scene.frames, scene.mean_electrons
    );
    let cfg = AdaptConfig {
        steps: a.steps,
        lr: a.lr,
        noise: a.noise_model,
        seed: a.seed,
        ..AdaptConfig::default()
    };
    let provenance = Adaptation {
        method: "resynthesis".into(),
        from: a.init.clone(),
        files: a
            .inputs
            .iter()
            .map(|p| {
                p.file_name()
                    .map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into())
            })
            .collect(),
        frames: scene.frames,
        mean_electrons: scene.mean_electrons,
    };
    let paths = RunPaths {
        out: a.out.clone(),
        checkpoint: PathBuf::from(format!("{}.ckpt", a.out.display())),
    };
    let (pb, mut report) = step_progress(a.steps, cfg.checkpoint_every);
    let model = adapt(
        &scene,
        &profile,
        &init,
        &cfg,
        provenance,
        &paths,
        a.resume,
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
