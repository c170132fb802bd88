//! `emccd profile show|init-default|crop|export`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use emccd_profile::Roi;

use crate::common::{load_profile, refuse_replacing};

/// Show or create camera profiles.
#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// Print a profile's calibrated numbers.
    Show {
        /// A profile directory (profile.toml + maps.safetensors), or `default` for the bundled one.
        #[arg(default_value = "default")]
        profile: String,
        /// Print JSON (keys include ptc_slope_dn, bias_dn, read_noise_dn, width, height, exposures_s).
        #[arg(long)]
        json: bool,
    },
    /// Write the bundled default profile (iXon Ultra 897 model) into a directory; with
    /// --em-gain or --read-noise-scale, a variant of it (a second camera for experiments).
    InitDefault {
        /// Output directory.
        dir: PathBuf,
        /// Replace a profile already in the directory.
        #[arg(long)]
        force: bool,
        /// EM gain of the variant (the default runs at 300): the photon-transfer slope scales with it.
        #[arg(long)]
        em_gain: Option<f64>,
        /// Multiply the read-noise maps by this factor.
        #[arg(long, default_value_t = 1.0)]
        read_noise_scale: f64,
    },
    /// Write the profile of a region of interest of a profile's sensor: for recordings made
    /// with sub-array readout (a cropped sensor), whose frames are that region of the full
    /// calibration.
    Crop {
        /// The full-sensor profile (a directory, or `default`).
        profile: String,
        /// Output directory.
        out: PathBuf,
        /// The region: X,Y,WxH — its top-left pixel (from 0) and its size, e.g. `128,128,256x256`
        /// (WxH alone: at the top-left corner).
        #[arg(long)]
        roi: Roi,
        /// Replace a profile already in the output directory.
        #[arg(long)]
        force: bool,
    },
    /// Write a profile's camera numbers (baseline, electrons per A/D count before EM gain, EM
    /// gain, read noise, spurious charge) in the form a localization tool takes: a camera entry
    /// for Picasso's config.yaml, DECODE's `Camera:` block, ThunderSTORM's `Camera setup` macro
    /// line, or SMAP's Camera Manager values; units in comments. To stdout, or -o FILE.
    Export {
        /// A profile directory, or `default`.
        profile: String,
        /// The tool: picasso, thunderstorm, decode or smap.
        #[arg(long)]
        to: emccd_profile::export::Tool,
        /// The EM gain setting, where the profile does not record it.
        #[arg(long)]
        em_gain: Option<f64>,
        /// Pixel size in the sample, nm (the tools need it; a profile does not hold it).
        #[arg(long)]
        pixel_size_nm: Option<f64>,
        /// Write here instead of stdout.
        #[arg(short, long)]
        out: Option<PathBuf>,
        /// Replace an existing output file.
        #[arg(long)]
        force: bool,
    },
}

pub fn run(c: Cmd) -> Result<()> {
    match c {
        Cmd::Export {
            profile,
            to,
            em_gain,
            pixel_size_nm,
            out,
            force,
        } => {
            for (what, v) in [("--em-gain", em_gain), ("--pixel-size-nm", pixel_size_nm)] {
                if let Some(v) = v.filter(|v| !(v.is_finite() && *v > 0.0)) {
                    anyhow::bail!("{what} {v}: a positive number");
                }
            }
            let p = load_profile(&profile)?;
            let extra = emccd_profile::export::Extra {
                em_gain,
                pixel_size_nm,
            };
            let text = emccd_profile::export::export(&p, to, &extra)
                .with_context(|| format!("profile {profile}"))?;
            match out {
                None => print!("{text}"),
                Some(path) => {
                    if path.exists() && !force {
                        anyhow::bail!("{}: exists; pass --force to replace it", path.display());
                    }
                    emccd_io::write_atomic(&path, text.as_bytes())?;
                    eprintln!("wrote {to:?} camera settings to {}", path.display());
                }
            }
            Ok(())
        }
        Cmd::Show { profile, json } => {
            let p = load_profile(&profile)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&p.summary())?);
            } else {
                print!("{}", p.summary_text());
            }
            Ok(())
        }
        Cmd::Crop {
            profile,
            out,
            roi,
            force,
        } => {
            refuse_replacing(&out, "profile.toml", "a camera profile", force)?;
            let p = load_profile(&profile)?;
            // `default` is the bundled profile, never a folder here.
            if profile != "default" {
                emccd_io::refuse_overwrite(
                    &out,
                    std::path::Path::new(&profile),
                    "the input profile",
                )?;
            }
            let c = p.crop(roi).with_context(|| format!("profile {profile}"))?;
            c.save(&out)
                .with_context(|| format!("writing {}", out.display()))?;
            eprintln!(
                "wrote the {}×{} region at ({}, {}) of {} to {} (fingerprint {})",
                roi.width,
                roi.height,
                roi.x,
                roi.y,
                p.camera,
                out.display(),
                c.fingerprint_hex()
            );
            Ok(())
        }
        Cmd::InitDefault {
            dir,
            force,
            em_gain,
            read_noise_scale,
        } => {
            refuse_replacing(&dir, "profile.toml", "a camera profile", force)?;
            let mut p = emccd_profile::default_profile();
            if em_gain.is_some() || read_noise_scale != 1.0 {
                p = p.variant(em_gain.unwrap_or(p.em_gain), read_noise_scale)?;
            }
            p.save(&dir)
                .with_context(|| format!("writing {}", dir.display()))?;
            eprintln!(
                "wrote {} to {} (fingerprint {})",
                p.camera,
                dir.display(),
                p.fingerprint_hex()
            );
            Ok(())
        }
    }
}
