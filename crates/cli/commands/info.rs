//! `emccd info FILE`: what a file holds.

use std::path::PathBuf;

use anyhow::Result;

/// Print what an image file holds.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A TIFF/BigTIFF stack, Andor SIF, FITS or PNG file, or a Zarr store (folder).
    pub file: PathBuf,
    /// Print JSON (keys: width, height, frames, pixel_type, format, exposure_s, em_gain,
    /// temperature_c, camera_model, binning, warnings; null where unknown).
    #[arg(long)]
    pub json: bool,
    /// Also measure the light level through this camera profile (a directory, or `default`):
    /// photo-electrons per pixel per frame over the first 20 frames, and whether the stack is
    /// in the photon-counting regime (`emccd count`).
    #[arg(long)]
    pub profile: Option<String>,
    /// The exposure in seconds for --profile, where the header does not record it.
    #[arg(long)]
    pub exposure_s: Option<f64>,
}

pub fn run(a: Args) -> Result<()> {
    let r = emccd_io::open(&a.file)?;
    let i = r.info();
    let level = match &a.profile {
        Some(p) => {
            let profile = crate::common::load_profile(p)?;
            let mut rec = crate::common::open_recording(&a.file, &profile, a.exposure_s, true)?;
            Some(emccd_count::light_level(&profile, &mut rec, 20)?)
        }
        None => None,
    };
    if a.json {
        let mut v = i.summary_json(&a.file);
        if let Some(l) = level {
            v["photo_electrons_per_pixel_per_frame"] = l.into();
            v["counting_regime"] = (l < crate::common::COUNTING_LEVEL).into();
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print!("{}", i.summary_text(&a.file));
        if let Some(l) = level {
            println!("  light level  {l:.4} photo-electrons per pixel per frame (first 20 frames)");
            if let Some(n) = crate::common::counting_note(l) {
                println!("  note         {n}");
            }
        }
    }
    Ok(())
}
