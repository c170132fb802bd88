//! `emccd profile show|init-default|crop`.

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::common::load_profile;

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
        /// The region: X,Y,WxH — its top-left pixel (from 0) and its size, e.g. `128,128,256x256`.
        #[arg(long, value_parser = parse_roi)]
        roi: (usize, usize, usize, usize),
    },
}

fn parse_roi(s: &str) -> std::result::Result<(usize, usize, usize, usize), String> {
    let bad = || {
        format!("'{s}': a region is X,Y,WxH (top-left pixel from 0, then the size), e.g. 128,128,256x256")
    };
    let mut it = s.splitn(3, ',');
    let (x, y, size) = (it.next(), it.next(), it.next());
    let (Some(x), Some(y), Some(size)) = (x, y, size) else {
        return Err(bad());
    };
    let (w, h) = crate::common::parse_size(size.trim()).map_err(|_| bad())?;
    match (x.trim().parse(), y.trim().parse()) {
        (Ok(x), Ok(y)) => Ok((x, y, w, h)),
        _ => Err(bad()),
    }
}

pub fn run(c: Cmd) -> Result<()> {
    match c {
        Cmd::Show { profile, json } => {
            let p = load_profile(&profile)?;
            let s = p.summary();
            if json {
                println!("{}", serde_json::to_string_pretty(&s)?);
                return Ok(());
            }
            println!("{}  ({})", s.camera, s.provenance.source);
            println!(
                "  sensor            {} × {} px, EM gain {}",
                s.width, s.height, s.em_gain
            );
            const NONE: &str = "not calibrated";
            match (s.ptc_slope_dn, s.k_range_dn) {
                (Some(slope), Some(k)) => {
                    println!("  PTC slope s=K·f²  {slope:.3} DN");
                    println!(
                        "  noise factor f    {:.3} – {:.3}  (K = {:.3} – {:.3} DN/e⁻)",
                        s.f_range[0], s.f_range[1], k[0], k[1]
                    );
                }
                _ => println!("  PTC slope s=K·f²  {NONE} (no flat fields)"),
            }
            println!("  quantization q    {} DN", s.quantization_dn);
            match (s.bias_dn, s.read_noise_dn) {
                (Some(b), Some(r)) => {
                    println!(
                        "  bias (FPN median) {b:.2} DN at {} s",
                        p.fpn.base_exposure_s
                    );
                    println!("  read noise        {r:.3} DN (median over pixels and exposures)");
                    println!(
                        "  FPN form          {:?}, shared θ = {:?}",
                        s.fpn_form, s.fpn_shared_theta
                    );
                }
                _ => println!("  bias, read noise  {NONE} (no bias frames)"),
            }
            match (s.blooming_a, s.blooming_b) {
                (Some(a), Some(b)) => println!(
                    "  blooming x(t)     {a:.4e} · t^{b:.4}   (x(10 ms) = {:.4})",
                    p.blooming_factor(0.01)
                ),
                _ => println!(
                    "  blooming x(t)     {NONE} (no blooming frames; preprocessing removes none)"
                ),
            }
            let e = &s.exposures_s;
            println!(
                "  exposures         {} read-noise maps, {} s – {} s",
                e.len(),
                e.first().unwrap_or(&0.0),
                e.last().unwrap_or(&0.0)
            );
            if let Some(eld) = &s.eld {
                println!(
                    "  ELD               K={} DN/e⁻, Tukey λ={} scale={} DN, row σ={} DN",
                    eld.k_dn, eld.tukey_lambda, eld.tukey_scale_dn, eld.row_sigma_dn
                );
            }
            if let Some(pgn) = &s.pgn {
                println!(
                    "  PGN               G={}, {:.3} e⁻/DN, CIC={} e⁻, dark={} e⁻/s, read σ={} DN",
                    pgn.em_gain, pgn.e_per_dn, pgn.cic_e, pgn.dark_e_per_s, pgn.read_sigma_dn
                );
            }
            println!("  fingerprint       {}", s.fingerprint);
            if !s.provenance.notes.is_empty() {
                println!("  notes             {}", s.provenance.notes);
            }
            Ok(())
        }
        Cmd::Crop {
            profile,
            out,
            roi: (x, y, w, h),
        } => {
            let p = load_profile(&profile)?;
            // `default` is the bundled profile, never a folder here.
            if profile != "default" {
                emccd_io::refuse_overwrite(
                    &out,
                    std::path::Path::new(&profile),
                    "the input profile",
                )?;
            }
            let c = p
                .crop(x, y, w, h)
                .with_context(|| format!("profile {profile}"))?;
            c.save(&out)
                .with_context(|| format!("writing {}", out.display()))?;
            eprintln!(
                "wrote the {w}×{h} region at ({x}, {y}) of {} to {} (fingerprint {:016x})",
                p.camera,
                out.display(),
                c.fingerprint()
            );
            Ok(())
        }
        Cmd::InitDefault {
            dir,
            em_gain,
            read_noise_scale,
        } => {
            let mut p = emccd_profile::default_profile();
            if em_gain.is_some() || read_noise_scale != 1.0 {
                p = p.variant(em_gain.unwrap_or(p.em_gain), read_noise_scale)?;
            }
            p.save(&dir)
                .with_context(|| format!("writing {}", dir.display()))?;
            eprintln!(
                "wrote {} to {} (fingerprint {:016x})",
                p.camera,
                dir.display(),
                p.fingerprint()
            );
            Ok(())
        }
    }
}
