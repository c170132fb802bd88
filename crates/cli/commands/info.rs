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
    let m = &i.metadata;
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&i.summary_json(&a.file))?
        );
        return Ok(());
    }
    let opt = |v: Option<f64>, unit: &str| {
        v.map(|x| format!("{x}{unit}"))
            .unwrap_or_else(|| "unknown".into())
    };
    println!("{}", a.file.display());
    println!("  format       {:?}", i.format);
    println!("  size         {} × {} pixels", i.width, i.height);
    println!("  frames       {}", i.frames);
    println!("  pixel type   {:?}", i.pixel_type);
    // A header's exposure is shown as recorded; one that `denoise` would refuse is marked.
    let bad = m.exposure_s.is_some_and(|t| !(t.is_finite() && t > 0.0));
    println!(
        "  exposure     {}{}",
        opt(m.exposure_s, " s"),
        if bad {
            "  (not a positive number of seconds: give --exposure-s to denoise)"
        } else {
            ""
        }
    );
    let gain = match m.em_gain {
        Some(g) if g == 0.0 => "0 (EM register off)".to_string(),
        g => opt(g, ""),
    };
    println!("  EM gain      {gain}");
    println!("  temperature  {}", opt(m.temperature_c, " °C"));
    println!(
        "  camera       {}",
        m.camera_model.as_deref().unwrap_or("unknown")
    );
    if let Some((bx, by)) = m.binning {
        println!("  binning      {bx} × {by}");
    }
    if let Some(acc) = m.accumulations {
        println!("  accumulations {acc}");
    }
    for w in &m.warnings {
        println!("  warning: {w}");
    }
    Ok(())
}
