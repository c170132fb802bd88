//! `emccd synthesize`: add a noise model's noise to clean images (training-pair synthesis).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use emccd_camera::{Ablation, NoiseModelKind};
use emccd_io::{Metadata, SampleFormat, StackWriter};

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
    // A signal past 10⁶ DN is beyond any 16- to 20-bit ADC, and at 10³⁰ the f32 arithmetic
    // wraps into garbage that looks like data.
    if !(a.signal_dn > 0.0 && a.signal_dn <= 1e6) {
        bail!(
            "--signal-dn {}: the signal must be a positive number of DN, at most 10⁶",
            a.signal_dn
        );
    }
    emccd_profile::check_exposure(a.exposure_s)
        .map_err(|e| anyhow::anyhow!("--exposure-s: {e}"))?;
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    let p = load_profile(&a.profile)?;
    let ab = a.ablate;
    if !(ab.fpn && ab.blooming) {
        bail!("--ablate: fpn and blooming are corrections of a network's preprocessing (`train --ablate`), not parts of the synthesized noise");
    }
    emccd_io::refuse_overwrite(&a.out, &a.input, "the input image")?;
    let emccd_io::Image {
        width: w,
        height: h,
        data: img,
    } = emccd_io::Image::read_scene(&a.input)
        .with_context(|| format!("reading {}", a.input.display()))?;
    let prof = p
        .top_left(w, h)
        .with_context(|| format!("{}: a {w}×{h} scene", a.input.display()))?;
    let kind = a.model;
    let model = kind.build(&prof, ab, a.exposure_s)?;
    let clean: Vec<f32> = img
        .iter()
        .map(|&v| (v as f64 * a.signal_dn) as f32)
        .collect();
    let mut wr = StackWriter::create(&a.out, w, h, SampleFormat::F32, Some(a.frames))?;
    wr.set_metadata(&Metadata {
        exposure_s: Some(a.exposure_s),
        em_gain: Some(prof.em_gain),
        ..Default::default()
    });
    let mut out = vec![0f32; w * h];
    for k in 0..a.frames {
        model.synthesize(&clean, w, &mut out, a.seed.wrapping_add(k as u64));
        wr.write_frame(&out)?;
    }
    wr.finish()?;
    eprintln!(
        "wrote {} {:?}-model frame(s) of {}×{} to {}",
        a.frames,
        kind,
        w,
        h,
        a.out.display()
    );
    Ok(())
}
