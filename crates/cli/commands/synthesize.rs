//! `emccd synthesize`: add a noise model's noise to clean images (training-pair synthesis).

use std::path::PathBuf;

use anyhow::{Context, Result};
use emccd_camera::{Ablation, NoiseModelKind, SceneNoise};

use crate::common::load_profile;

/// Add noise from one of the noise models to a clean image, in the preprocessed domain (DN
/// above bias; blooming and FPN are what preprocessing removes, so they are not added).
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Clean image (PNG/TIFF/FITS), scaled so its full-scale value becomes `--signal-dn`.
    pub input: PathBuf,
    /// Output: float32 TIFF (or .fits) stack of noisy frames.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Camera profile directory or `default`.
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// Noise model.
    #[arg(long, value_enum, default_value = "ours")]
    pub model: NoiseModelKind,
    /// Clean signal at the image's full-scale value, DN above bias.
    #[arg(long, default_value_t = 200.0)]
    pub signal_dn: f64,
    /// Exposure (s), for the PGN model's dark current.
    #[arg(long, default_value_t = 0.01)]
    pub exposure_s: f64,
    /// Components of `ours` to switch off (comma-separated): multiplicative, readout, quantization.
    #[arg(long, default_value = "")]
    pub ablate: Ablation,
    /// Number of noisy frames (each with its own seed).
    #[arg(long, default_value_t = 1)]
    pub frames: usize,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(a: Args) -> Result<()> {
    let noise = SceneNoise {
        kind: a.model,
        signal_dn: a.signal_dn,
        exposure_s: a.exposure_s,
        ablate: a.ablate,
        frames: a.frames,
        seed: a.seed,
    };
    noise.check().map_err(|e| anyhow::anyhow!("--{e}"))?;
    let profile = load_profile(&a.profile)?;
    emccd_io::refuse_overwrite(&a.out, &a.input, "the input image")?;
    let scene = emccd_io::Image::read_scene(&a.input)
        .with_context(|| format!("reading {}", a.input.display()))?;
    noise
        .write(&profile, &scene, &a.out)
        .with_context(|| format!("synthesizing noise on {}", a.input.display()))?;
    eprintln!(
        "wrote {} {:?}-model frame(s) of {}×{} to {}",
        a.frames,
        a.model,
        scene.width,
        scene.height,
        a.out.display()
    );
    Ok(())
}
