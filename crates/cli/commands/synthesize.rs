//! `emccd synthesize`: add a noise model's noise to clean images (training-pair synthesis).

use std::path::PathBuf;

use anyhow::{Context, Result};
use emccd_camera::SceneNoise;

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
    #[command(flatten)]
    pub noise: SceneNoise,
}

pub fn run(a: Args) -> Result<()> {
    let noise = a.noise;
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
        noise.frames,
        noise.kind,
        scene.width,
        scene.height,
        a.out.display()
    );
    Ok(())
}
