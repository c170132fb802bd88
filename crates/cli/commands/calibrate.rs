//! `emccd calibrate`: a camera's acquisitions → a camera profile and a report.

use std::path::PathBuf;

use anyhow::{Context, Result};
use emccd_calib::{Manifest, Options, Progress};

use crate::common::progress;

/// Calibrate a camera from its bias, flat-field, blooming and gain-series stacks.
///
/// MANIFEST is a TOML file naming the stacks (paths relative to it), in the form
/// `emccd simulate calibration` writes:
///
///   camera = "iXon Ultra 897"
///   em_gain = 300
///   [[bias]]      file = "bias_10ms.tif", exposure_s = 0.01   (one per exposure)
///   [[flat]]      file = "flat_01.tif",   exposure_s = 0.01   (one per light level)
///   [[blooming]]  file = "bloom_1ms.tif", exposure_s = 0.001  (bright source in one quadrant)
///   [gain_series] with [[gain_series.settings]] em_gain, file, offset_map + sigma_map or no_signal
///
/// exposure_s may be left out where the file's header records it (SIF). Any subset works:
/// flats alone give the photon-transfer slope, bias alone the FPN and read noise; what is missing
/// is reported and left out of the profile. Nothing is written unless every input is good.
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The calibration manifest (TOML).
    pub manifest: PathBuf,
    /// Output profile directory (profile.toml + maps.safetensors).
    #[arg(short, long)]
    pub out: PathBuf,
    /// Also write an HTML report (index.html, self-contained) and results.json here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Side of the central crop for the median–variance regression, px.
    #[arg(long, default_value_t = 256)]
    pub crop: usize,
    /// Side of the sliding window of the blooming search, px.
    #[arg(long, default_value_t = 32)]
    pub window: usize,
    /// Most pixels (a central block) fitted in a gain series.
    #[arg(long, default_value_t = 16)]
    pub gain_pixels: usize,
}

struct Bar(indicatif::ProgressBar);
impl Progress for Bar {
    fn advance(&self, frames: u64) {
        self.0.inc(frames);
    }
}

pub fn run(a: Args) -> Result<()> {
    let m = Manifest::load(&a.manifest)?;
    let opts = Options {
        crop: a.crop.max(2),
        window: a.window.max(2),
        gain_pixels: a.gain_pixels.max(1),
    };
    let bar = Bar(progress(emccd_calib::total_frames(&m), "frames"));
    let cal = emccd_calib::calibrate(&m, &opts, &bar);
    bar.0.finish_and_clear();
    let cal = cal?;
    for w in &cal.warnings {
        eprintln!("warning: {w}");
    }
    let profile = cal.profile()?;
    if let Some(dir) = &a.report {
        emccd_calib::report::write(&cal, dir)
            .with_context(|| format!("writing the report to {}", dir.display()))?;
    }
    profile
        .save(&a.out)
        .with_context(|| format!("writing the profile to {}", a.out.display()))?;
    print_summary(&cal);
    eprintln!("profile written to {}", a.out.display());
    if let Some(dir) = &a.report {
        eprintln!("report written to {}", dir.join("index.html").display());
    }
    Ok(())
}

fn print_summary(c: &emccd_calib::Calibration) {
    println!(
        "{} at EM gain {} ({}×{} px)",
        c.camera, c.em_gain, c.width, c.height
    );
    if let Some(p) = &c.ptc {
        let used = p
            .levels
            .iter()
            .filter(|l| l.status == emccd_calib::ptc::LevelStatus::Included)
            .count();
        println!(
            "  PTC slope s = K·f²   {:.4} ± {:.4} DN   (r² = {:.5}, {used} of {} levels)",
            p.fit.slope,
            p.fit.slope_se,
            p.fit.r2,
            p.levels.len()
        );
    }
    if let Some(b) = c.bias.first() {
        println!(
            "  bias (FPN median)    {:.2} DN at {} s",
            b.median_dn, b.exposure_s
        );
        let rn: Vec<f32> = c.bias.iter().flat_map(|b| b.std.iter().copied()).collect();
        let rms = (c
            .bias
            .iter()
            .map(|b| b.read_noise_rms_dn.powi(2))
            .sum::<f64>()
            / c.bias.len() as f64)
            .sqrt();
        println!("  read noise           {:.3} DN median std, {rms:.3} DN rms (over pixels and {} exposures)", emccd_profile::median(rn).unwrap_or(0.0), c.bias.len());
    }
    if let Some(f) = &c.fpn {
        let mid: Vec<&emccd_calib::fpn::FpnError> = f
            .errors
            .iter()
            .filter(|e| e.exposure_s >= 0.006 && e.exposure_s <= 0.1)
            .collect();
        let avg = |g: fn(&emccd_calib::fpn::FpnError) -> f64| {
            mid.iter().map(|e| g(e)).sum::<f64>() / mid.len().max(1) as f64
        };
        if f.chosen == emccd_profile::FpnForm::Constant {
            println!(
                "  FPN fit              shared θ not used: the bias does not change with exposure"
            );
        } else {
            let th = |i: usize| emccd_calib::fpn::theta_text(f.shared_theta[i], f.shared_se[i]);
            println!(
                "  FPN fit              shared θ1 {}, θ2 {}, θ3 {};  mean |error| 6–100 ms: shared {:.3} DN, per-pixel {:.3} DN",
                th(1),
                th(2),
                th(3),
                avg(|e| e.shared_mae_dn),
                avg(|e| e.per_pixel_mae_dn),
            );
        }
        let [hc, hs, hp] = f.heldout_mean_dn;
        let dn = emccd_calib::fpn::error_text;
        println!(
            "  FPN form             {:?}: mean |error| on a held-out exposure constant {}, shared {}, per-pixel {} DN",
            f.chosen,
            dn(hc),
            dn(hs),
            dn(hp)
        );
    }
    if let Some(b) = &c.blooming {
        println!(
            "  blooming x(t)        {:.4e} · t^{:.4} (± {:.4}), r² = {:.4}",
            b.a, b.b, b.loglog.slope_se, b.loglog.r2
        );
    }
    if let Some(g) = &c.gain_series {
        let r = g
            .reference_e_per_dn
            .map_or(String::new(), |r| format!("  (reference {r:.3})"));
        println!(
            "  gain series          {:.4} ± {:.4} e⁻/DN{r}",
            g.e_per_dn, g.e_per_dn_se
        );
        for s in &g.settings {
            println!(
                "    {:>6}× → G = {:.3} ± {:.3}{}",
                s.nominal,
                s.gain,
                s.gain_se,
                if s.fixed { " (anchor)" } else { "" }
            );
        }
    }
    for m in &c.missing {
        println!("  not calibrated: {m}");
    }
}
