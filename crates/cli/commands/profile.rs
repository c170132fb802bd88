//! `emccd profile show|init-default`.

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
    /// Write the bundled default profile (iXon Ultra 897 model) into a directory.
    InitDefault {
        /// Output directory.
        dir: PathBuf,
    },
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
            println!("  sensor            {} × {} px, EM gain {}", s.width, s.height, s.em_gain);
            println!("  PTC slope s=K·f²  {:.3} DN", s.ptc_slope_dn);
            println!("  noise factor f    {:.3} – {:.3}  (K = {:.3} – {:.3} DN/e⁻)", s.f_range[0], s.f_range[1], s.k_range_dn[0], s.k_range_dn[1]);
            println!("  quantization q    {} DN", s.quantization_dn);
            println!("  bias (FPN median) {:.2} DN at {} s", s.bias_dn, p.fpn.base_exposure_s);
            println!("  read noise        {:.3} DN (median over pixels and exposures)", s.read_noise_dn);
            println!("  FPN form          {:?}, shared θ = {:?}", s.fpn_form, s.fpn_shared_theta);
            println!("  blooming x(t)     {:.4e} · t^{:.4}   (x(10 ms) = {:.4})", s.blooming_a, s.blooming_b, p.blooming_factor(0.01));
            let e = &s.exposures_s;
            println!("  exposures         {} read-noise maps, {} s – {} s", e.len(), e.first().unwrap_or(&0.0), e.last().unwrap_or(&0.0));
            if let Some(eld) = &s.eld {
                println!("  ELD               K={} DN/e⁻, Tukey λ={} scale={} DN, row σ={} DN", eld.k_dn, eld.tukey_lambda, eld.tukey_scale_dn, eld.row_sigma_dn);
            }
            if let Some(pgn) = &s.pgn {
                println!("  PGN               G={}, {:.3} e⁻/DN, CIC={} e⁻, dark={} e⁻/s, read σ={} DN", pgn.em_gain, pgn.e_per_dn, pgn.cic_e, pgn.dark_e_per_s, pgn.read_sigma_dn);
            }
            println!("  fingerprint       {}", s.fingerprint);
            if !s.provenance.notes.is_empty() {
                println!("  notes             {}", s.provenance.notes);
            }
            Ok(())
        }
        Cmd::InitDefault { dir } => {
            let p = emccd_profile::default_profile();
            p.save(&dir).with_context(|| format!("writing {}", dir.display()))?;
            eprintln!("wrote the default profile to {} (fingerprint {:016x})", dir.display(), p.fingerprint());
            Ok(())
        }
    }
}
