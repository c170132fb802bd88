//! The calibration in a few lines of text: what `emccd calibrate` prints and the Python
//! package returns.

use std::fmt::Write as _;

use crate::Calibration;

impl Calibration {
    /// A plain-text summary of the calibrated numbers, one item per line: the photon-transfer
    /// slope, bias and read noise, the fixed-pattern fit and the form chosen on a held-out
    /// exposure, blooming, the gain series, and what could not be calibrated.
    pub fn summary(&self) -> String {
        let c = self;
        // Writing to a String cannot fail: the results of `writeln!` are ignored.
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{} at EM gain {} ({}×{} px)",
            c.camera, c.em_gain, c.width, c.height
        );
        if let Some(p) = &c.ptc {
            let used = p
                .levels
                .iter()
                .filter(|l| l.status == crate::ptc::LevelStatus::Included)
                .count();
            let _ = writeln!(
                out,
                "  PTC slope s = K·f²   {:.4} ± {:.4} DN   (r² = {:.5}, {used} of {} levels)",
                p.fit.slope,
                p.fit.slope_se,
                p.fit.r2,
                p.levels.len()
            );
        }
        if let Some(b) = c.bias.first() {
            let _ = writeln!(
                out,
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
            let _ = writeln!(out, "  read noise           {:.3} DN median std, {rms:.3} DN rms (over pixels and {} exposures)", emccd_profile::median(rn).unwrap_or(0.0), c.bias.len());
            // What few frames cost: each pixel's std as measured and as the profile holds it.
            if let Some((raw, shrunk)) = crate::read_noise::pixel_error(&b.std, b.frames) {
                let map = crate::read_noise::shrunk(&b.std, b.frames);
                let held = if shrunk < 0.1 * raw {
                    "the pixels' own spread is below what the frames resolve: the map holds the frame's".to_string()
                } else {
                    format!("± {:.1} % shrunk towards the frame's", 100.0 * shrunk)
                };
                let _ = writeln!(
                    out,
                    "  read-noise map       {:.3} DN median at {} s ({} frames: each pixel ± {:.1} % as measured, {held}; the FPN map ± {:.2} DN a pixel)",
                    emccd_profile::median(map.iter().copied()).unwrap_or(0.0),
                    b.exposure_s,
                    b.frames,
                    100.0 * raw,
                    b.read_noise_rms_dn / (b.frames as f64).sqrt()
                );
            }
        }
        if let Some(f) = &c.spurious {
            let dark = if f.dark_se.is_finite() {
                format!("{} ± {}", short(f.dark_e_per_s), short(f.dark_se))
            } else {
                format!(
                    "{} (one exposure: not separated from CIC)",
                    short(f.dark_e_per_s)
                )
            };
            let _ = writeln!(
                out,
                "  spurious charge      CIC {} ± {} e⁻ per pixel per frame, dark {dark} e⁻/s; the read noise beneath them {:.3} DN",
                short(f.cic_e),
                short(f.cic_se),
                f.read_sigma_dn
            );
        }
        if let Some(f) = &c.fpn {
            let mid: Vec<&crate::fpn::FpnError> = f
                .errors
                .iter()
                .filter(|e| e.exposure_s >= 0.006 && e.exposure_s <= 0.1)
                .collect();
            let avg = |g: fn(&crate::fpn::FpnError) -> f64| {
                mid.iter().map(|e| g(e)).sum::<f64>() / mid.len().max(1) as f64
            };
            if f.chosen == emccd_profile::FpnForm::Constant {
                let _ = writeln!(out,
                    "  FPN fit              shared θ not used: the bias does not change with exposure"
                );
            } else {
                let th = |i: usize| crate::fpn::theta_text(f.shared_theta[i], f.shared_se[i]);
                let _ = writeln!(out,
                    "  FPN fit              shared θ1 {}, θ2 {}, θ3 {};  mean |error| 6–100 ms: shared {:.3} DN, per-pixel {:.3} DN",
                    th(1),
                    th(2),
                    th(3),
                    avg(|e| e.shared_mae_dn),
                    avg(|e| e.per_pixel_mae_dn),
                );
            }
            let [hc, hs, hp] = f.heldout_mean_dn;
            let dn = crate::fpn::error_text;
            let _ = writeln!(out,
                "  FPN form             {:?}: mean |error| on a held-out exposure constant {}, shared {}, per-pixel {} DN",
                f.chosen,
                dn(hc),
                dn(hs),
                dn(hp)
            );
        }
        if let Some(b) = &c.blooming {
            let _ = writeln!(
                out,
                "  blooming x(t)        {:.4e} · t^{:.4} (± {:.4}), r² = {:.4}",
                b.a, b.b, b.loglog.slope_se, b.loglog.r2
            );
        }
        if let Some(g) = &c.gain_series {
            let r = g
                .reference_e_per_dn
                .map_or(String::new(), |r| format!("  (reference {r:.3})"));
            let _ = writeln!(
                out,
                "  gain series          {:.4} ± {:.4} e⁻/DN{r}",
                g.e_per_dn, g.e_per_dn_se
            );
            for s in &g.settings {
                let _ = writeln!(
                    out,
                    "    {:>6}× → G = {:.3} ± {:.3}{}",
                    s.nominal,
                    s.gain,
                    s.gain_se,
                    if s.fixed { " (anchor)" } else { "" }
                );
            }
        }
        for m in &c.missing {
            let _ = writeln!(out, "  not calibrated: {m}");
        }
        out
    }
}

/// A small rate for a person: four significant digits.
fn short(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        format!("{v}")
    } else {
        let digits = (3 - v.abs().log10().floor() as i32).max(0) as usize;
        format!("{v:.digits$}")
    }
}
