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
}

pub fn run(a: Args) -> Result<()> {
    let r = emccd_io::open(&a.file)?;
    let i = r.info();
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&i.summary_json(&a.file))?
        );
    } else {
        print!("{}", i.summary_text(&a.file));
    }
    Ok(())
}
