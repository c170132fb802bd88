//! The calibration report: one self-contained `index.html` (inline SVG plots, images as
//! embedded PNG) with the plots a person checks against the paper's figures, a table of every
//! fitted number with its uncertainty, and `results.json` with the same numbers for scripts.

use std::fmt::Write as _;
use std::path::Path;

use base64::Engine as _;
use plotters::prelude::*;

use emccd_profile::CameraProfile;

use crate::ptc::LevelStatus;
use crate::{Calibration, Error, Result};

impl Calibration {
    /// Writes the outputs of `emccd calibrate` (and of Python's `calibrate`): the HTML report
    /// into `report` where asked, then the profile folder `out`; returns the profile. A report
    /// folder this call made is removed again if the profile cannot be written (the profile
    /// leaves nothing behind itself): a failed run leaves nothing it created. Without `replace`,
    /// a profile found in `out` as it is placed is an error ([`CameraProfile::save_new`]).
    pub fn save(&self, out: &Path, report: Option<&Path>, replace: bool) -> Result<CameraProfile> {
        let profile = self.profile()?;
        save_with_report(&profile, out, report, replace, |dir| write(self, dir))?;
        Ok(profile)
    }
}

/// Writes `profile` into `out` and, where asked, a report (`write_report` into a folder) into
/// `report`. The report is written in full beside its folder, the profile saved, and only then
/// the report moved into place: a run that fails or is stopped leaves neither a report of a
/// profile that was never written nor a folder of its own.
pub(crate) fn save_with_report(
    profile: &CameraProfile,
    out: &Path,
    report: Option<&Path>,
    replace: bool,
    write_report: impl FnOnce(&Path) -> std::io::Result<()>,
) -> Result<()> {
    let staged = report
        .map(
            |dir| -> std::result::Result<_, Box<dyn std::error::Error + Send + Sync>> {
                let stage = emccd_io::StagedDir::beside(dir)?;
                write_report(stage.path())?;
                Ok(stage)
            },
        )
        .transpose()
        .map_err(|source| Error::Write {
            what: format!("the report to {}", report.unwrap_or(out).display()),
            source,
        })?;
    if replace {
        profile.save(out)
    } else {
        profile.save_new(out)
    }
    .map_err(|e| Error::Write {
        what: format!("the profile to {}", out.display()),
        source: Box::new(e),
    })?;
    if let (Some(stage), Some(dir)) = (staged, report) {
        stage.place().map_err(|e| Error::Write {
            what: format!("the report to {}", dir.display()),
            source: Box::new(e),
        })?;
    }
    Ok(())
}

pub(crate) type Draw<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;
pub(crate) type PlotResult = std::result::Result<(), Box<dyn std::error::Error>>;

/// Renders one SVG chart into a string.
pub(crate) fn svg(w: u32, h: u32, f: impl FnOnce(&Draw<'_>) -> PlotResult) -> String {
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (w, h)).into_drawing_area();
        let _ = root.fill(&WHITE);
        if let Err(e) = f(&root) {
            let _ = root.draw(&Text::new(
                format!("plot failed: {e}"),
                (10, 20),
                ("sans-serif", 14),
            ));
        }
        let _ = root.present();
    }
    s
}

pub(crate) fn range(v: impl Iterator<Item = f64> + Clone, log: bool) -> (f64, f64) {
    let ok = |x: &f64| x.is_finite() && (!log || *x > 0.0);
    let lo = v.clone().filter(ok).fold(f64::INFINITY, f64::min);
    let hi = v.filter(ok).fold(f64::NEG_INFINITY, f64::max);
    if !(lo.is_finite() && hi.is_finite()) {
        return (1.0, 10.0);
    }
    if log {
        (lo / 1.5, hi * 1.5)
    } else {
        let pad = ((hi - lo) * 0.08).max(1e-9 * hi.abs().max(1.0));
        (lo - pad, hi + pad)
    }
}

/// Perceptual colour map (viridis anchors, linear between them).
fn viridis(t: f64) -> [u8; 3] {
    const A: [[f64; 3]; 6] = [
        [68., 1., 84.],
        [65., 68., 135.],
        [42., 120., 142.],
        [34., 168., 132.],
        [122., 209., 81.],
        [253., 231., 37.],
    ];
    let t = t.clamp(0.0, 1.0) * 5.0;
    let i = (t.floor() as usize).min(4);
    let f = t - i as f64;
    [0, 1, 2].map(|k| (A[i][k] + f * (A[i + 1][k] - A[i][k])).round() as u8)
}

/// A heat map as an embedded PNG with a colour bar; scaled between the 1st and 99th percentiles.
fn heat_map(map: &[f32], w: usize, h: usize, unit: &str) -> String {
    let range = |q| emccd_profile::percentile(map.iter().copied(), q);
    let (Some(lo), Some(hi)) = (range(0.01), range(0.99)) else {
        return String::new();
    };
    let span = (hi - lo).max(1e-9);
    let mut rgb = Vec::with_capacity(w * h * 3);
    for &x in map {
        rgb.extend_from_slice(&viridis((x as f64 - lo) / span));
    }
    let mut png_bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png_bytes, w as u32, h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        if let Ok(mut wr) = enc.write_header() {
            let _ = wr.write_image_data(&rgb);
        }
    }
    let b64 = base64::engine::general_purpose::STANDARD.encode(&png_bytes);
    let stops: String = (0..=5)
        .map(|i| {
            let c = viridis(i as f64 / 5.0);
            format!("rgb({},{},{}) {}%", c[0], c[1], c[2], i * 20)
        })
        .collect::<Vec<_>>()
        .join(",");
    let disp = (w.max(h) as f64).clamp(256.0, 420.0);
    let (dw, dh) = (
        disp * w as f64 / w.max(h) as f64,
        disp * h as f64 / w.max(h) as f64,
    );
    format!(
        "<div class=heat><img style=\"width:{dw:.0}px;height:{dh:.0}px;image-rendering:pixelated\" src=\"data:image/png;base64,{b64}\">\
         <div class=bar><span>{hi:.2} {unit}</span><div style=\"background:linear-gradient(to top,{stops})\"></div><span>{lo:.2} {unit}</span></div></div>"
    )
}

pub(crate) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn ptc_plot(c: &Calibration) -> String {
    let Some(p) = &c.ptc else {
        return String::new();
    };
    svg(560, 400, |root| {
        let (x0, x1) = range(p.levels.iter().map(|l| l.median_dn), true);
        let (y0, y1) = range(p.levels.iter().map(|l| l.variance_dn2), true);
        let mut ch = ChartBuilder::on(root)
            .caption("Variance vs median (flat fields)", ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())?;
        ch.configure_mesh()
            .x_desc("median signal (DN)")
            .y_desc("temporal variance (DN²)")
            .draw()?;
        let f = p.fit;
        let line: Vec<(f64, f64)> = (0..=100)
            .map(|i| x0 * (x1 / x0).powf(i as f64 / 100.0))
            .map(|x| (x, f.slope * x + f.intercept))
            .filter(|p| p.1 > 0.0)
            .collect();
        ch.draw_series(LineSeries::new(line, RED.stroke_width(2)))?
            .label(format!("Var = {:.3}·Median + {:.1}", f.slope, f.intercept))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        ch.draw_series(
            p.levels
                .iter()
                .filter(|l| l.status == LevelStatus::Included)
                .map(|l| Circle::new((l.median_dn, l.variance_dn2), 5, BLUE.filled())),
        )?
        .label("included")
        .legend(|(x, y)| Circle::new((x + 10, y), 4, BLUE.filled()));
        ch.draw_series(
            p.levels
                .iter()
                .filter(|l| l.status != LevelStatus::Included)
                .map(|l| Cross::new((l.median_dn, l.variance_dn2), 6, BLACK.stroke_width(2))),
        )?;
        ch.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
        Ok(())
    })
}

fn fpn_curve_plot(c: &Calibration) -> String {
    let Some(f) = &c.fpn else {
        return String::new();
    };
    let ex = &f.example;
    svg(560, 400, |root| {
        let (x0, x1) = range(f.exposures_s.iter().copied(), true);
        let (y0, y1) = range(ex.measured_dn.iter().copied(), false);
        let mut ch = ChartBuilder::on(root)
            .caption(
                format!("FPN of pixel ({}, {}) vs exposure", ex.x, ex.y),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((x0..x1).log_scale(), y0..y1)?;
        ch.configure_mesh()
            .x_desc("exposure (s)")
            .y_desc("FPN (DN)")
            .draw()?;
        let ts: Vec<f64> = (0..=120)
            .map(|i| x0 * (x1 / x0).powf(i as f64 / 120.0))
            .collect();
        // The curves as the profile evaluates them (one evaluator: emccd_profile::logistic).
        let sig = emccd_profile::logistic;
        let u0 = f.exposures_s[0].ln();
        let shared: Vec<(f64, f64)> = ts
            .iter()
            .map(|&t| {
                (
                    t,
                    ex.base_dn * (sig(t.ln(), f.shared_theta) - sig(u0, f.shared_theta)).exp(),
                )
            })
            .collect();
        ch.draw_series(LineSeries::new(shared, BLUE.stroke_width(2)))?
            .label("shared θ × base map")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
        if f.per_pixel {
            let own: Vec<(f64, f64)> = ts
                .iter()
                .map(|&t| (t, sig(t.ln(), ex.theta).exp()))
                .collect();
            ch.draw_series(LineSeries::new(own, RED.stroke_width(2)))?
                .label("per-pixel θ")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        }
        ch.draw_series(
            f.exposures_s
                .iter()
                .zip(&ex.measured_dn)
                .map(|(&t, &v)| Circle::new((t, v), 4, BLACK.filled())),
        )?
        .label("measured")
        .legend(|(x, y)| Circle::new((x + 10, y), 4, BLACK.filled()));
        ch.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
        Ok(())
    })
}

fn qq_plot(c: &Calibration) -> String {
    if c.normality.is_empty() {
        return String::new();
    }
    svg(460, 400, |root| {
        let lim = c
            .normality
            .iter()
            .flat_map(|n| n.points.iter().map(|p| p.0.abs().max(p.1.abs())))
            .fold(3.0, f64::max);
        let mut ch = ChartBuilder::on(root)
            .caption("Normal probability plot (bias values)", ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(-lim..lim, -lim..lim)?;
        ch.configure_mesh()
            .x_desc("normal quantile")
            .y_desc("standardized value")
            .draw()?;
        ch.draw_series(LineSeries::new(vec![(-lim, -lim), (lim, lim)], BLACK))?;
        for (k, n) in c.normality.iter().enumerate() {
            let col = Palette99::pick(k).to_rgba();
            ch.draw_series(
                n.points
                    .iter()
                    .map(|&(q, z)| Circle::new((q, z), 2, col.filled())),
            )?
            .label(format!("({}, {}) r²={:.4}", n.x, n.y, n.r2))
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, col.filled()));
        }
        ch.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
        Ok(())
    })
}

fn blooming_plot(c: &Calibration) -> String {
    let Some(b) = &c.blooming else {
        return String::new();
    };
    svg(560, 400, |root| {
        let (x0, x1) = range(b.levels.iter().map(|l| l.exposure_s), true);
        let (y0, y1) = range(b.levels.iter().map(|l| l.x), true);
        let mut ch = ChartBuilder::on(root)
            .caption("Blooming factor vs exposure", ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())?;
        ch.configure_mesh()
            .x_desc("exposure (s)")
            .y_desc("blooming factor x")
            .draw()?;
        let line: Vec<(f64, f64)> = (0..=50)
            .map(|i| x0 * (x1 / x0).powf(i as f64 / 50.0))
            .map(|t| (t, b.a * t.powf(b.b)))
            .collect();
        ch.draw_series(LineSeries::new(line, RED.stroke_width(2)))?
            .label(format!(
                "x = {:.3e}·t^{:.4} (r² {:.4})",
                b.a, b.b, b.loglog.r2
            ))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        ch.draw_series(
            b.levels
                .iter()
                .filter(|l| l.x > 0.0)
                .map(|l| Circle::new((l.exposure_s, l.x), 5, BLUE.filled())),
        )?;
        ch.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .position(SeriesLabelPosition::UpperRight)
            .draw()?;
        Ok(())
    })
}

fn gain_plots(c: &Calibration) -> (String, String) {
    let Some(g) = &c.gain_series else {
        return (String::new(), String::new());
    };
    let e = &g.example;
    let hist = svg(560, 400, |root| {
        let x1 = e.x0 + e.bin * e.counts.len() as f64;
        let ymax = e
            .counts
            .iter()
            .chain(&e.model)
            .fold(1.0, |a: f64, &b| a.max(b))
            * 1.1;
        let s = &g.settings[e.setting];
        let mut ch = ChartBuilder::on(root)
            .caption(
                format!(
                    "{}× setting, pixel {:?}: data and fitted density",
                    s.nominal, g.pixels[e.pixel]
                ),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(e.x0..x1, 0.0..ymax)?;
        ch.configure_mesh()
            .x_desc("DN")
            .y_desc(format!("frames per {} DN", e.bin))
            .draw()?;
        ch.draw_series(e.counts.iter().enumerate().map(|(i, &c)| {
            let x = e.x0 + i as f64 * e.bin;
            Rectangle::new([(x, 0.0), (x + e.bin, c)], RGBColor(150, 170, 220).filled())
        }))?;
        ch.draw_series(LineSeries::new(
            e.model
                .iter()
                .enumerate()
                .map(|(i, &m)| (e.x0 + (i as f64 + 0.5) * e.bin, m)),
            RED.stroke_width(2),
        ))?
        .label("Poisson–Gamma ⊛ Normal fit")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        ch.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .position(SeriesLabelPosition::UpperRight)
            .draw()?;
        Ok(())
    });
    let gains = svg(460, 400, |root| {
        let (lo, hi) = range(g.settings.iter().flat_map(|s| [s.nominal, s.gain]), true);
        let mut ch = ChartBuilder::on(root)
            .caption("Fitted EM gain vs setting", ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((lo..hi).log_scale(), (lo..hi).log_scale())?;
        ch.configure_mesh()
            .x_desc("nominal EM gain")
            .y_desc("fitted G")
            .draw()?;
        ch.draw_series(LineSeries::new(vec![(lo, lo), (hi, hi)], BLACK))?;
        ch.draw_series(g.settings.iter().flat_map(|s| {
            s.gain_per_pixel
                .iter()
                .map(move |&v| Circle::new((s.nominal, v), 4, BLUE.filled()))
        }))?;
        Ok(())
    });
    (hist, gains)
}

pub(crate) fn row(out: &mut String, name: &str, value: String, note: &str) {
    let _ = writeln!(
        out,
        "<tr><td>{}</td><td>{}</td><td>{}</td></tr>",
        esc(name),
        value,
        esc(note)
    );
}

/// The rows of the fitted-numbers table.
fn fitted_rows(c: &Calibration, t: &mut String) {
    if let Some(p) = &c.ptc {
        row(
            t,
            "photon-transfer slope s = K·f²",
            format!("{:.4} ± {:.4} DN", p.fit.slope, p.fit.slope_se),
            "median–variance, weighted by 1/Var²",
        );
        row(
            t,
            "PTC intercept",
            format!("{:.2} ± {:.2} DN²", p.fit.intercept, p.fit.intercept_se),
            "read noise² + quantization + other signal-independent noise",
        );
        row(t, "PTC r²", format!("{:.6}", p.fit.r2), "");
        row(
            t,
            "K range (f ∈ [1.3, √2])",
            format!("{:.3} – {:.3} DN/e⁻", p.fit.slope / 2.0, p.fit.slope / 1.69),
            "K = s/f²",
        );
    }
    if let Some(b) = c.bias.first() {
        row(
            t,
            "bias level (median FPN)",
            format!("{:.2} DN at {} s", b.median_dn, b.exposure_s),
            "",
        );
        let rn: Vec<f32> = c.bias.iter().flat_map(|b| b.std.iter().copied()).collect();
        row(
            t,
            "read noise (median std)",
            format!("{:.3} DN", emccd_profile::median(rn).unwrap_or(0.0)),
            &format!("over pixels and {} exposures", c.bias.len()),
        );
    }
    if let Some(f) = &c.fpn {
        if f.chosen == emccd_profile::FpnForm::Constant {
            row(
                t,
                "FPN shared θ",
                "not used".into(),
                "the bias does not change with exposure: the constant form was chosen",
            );
        } else {
            let th = |i: usize| crate::fpn::theta_text(f.shared_theta[i], f.shared_se[i]);
            row(t, "FPN shared θ1", th(1), "");
            row(t, "FPN shared θ2", th(2), "");
            row(
                t,
                "FPN shared θ3",
                format!("{} (t = {:.3} s)", th(3), f.shared_theta[3].exp()),
                "",
            );
        }
        row(
            t,
            "FPN outlier pixels",
            format!("{}", f.outliers),
            "excluded from the shared fit",
        );
        let [hc, hs, hp] = f.heldout_mean_dn;
        row(
            t,
            "FPN form used",
            format!("{:?}", f.chosen),
            &format!(
                "lowest mean error on a held-out exposure: constant {}, shared {}, per-pixel {} DN",
                crate::fpn::error_text(hc),
                crate::fpn::error_text(hs),
                crate::fpn::error_text(hp)
            ),
        );
    }
    if let Some(b) = &c.blooming {
        row(
            t,
            "blooming a",
            format!("{:.4e}", b.a),
            &format!(
                "ln a = {:.4} ± {:.4}",
                b.loglog.intercept, b.loglog.intercept_se
            ),
        );
        row(
            t,
            "blooming b",
            format!("{:.4} ± {:.4}", b.b, b.loglog.slope_se),
            &format!("r² = {:.5}", b.loglog.r2),
        );
    }
    if let Some(g) = &c.gain_series {
        let r = g.reference_e_per_dn.map_or("–".to_string(), |r| {
            format!(
                "reference {r:.4} ({:+.2} %)",
                100.0 * (g.e_per_dn / r - 1.0)
            )
        });
        row(
            t,
            "e⁻ per DN (gain series MLE)",
            format!("{:.4} ± {:.4}", g.e_per_dn, g.e_per_dn_se),
            &r,
        );
        row(
            t,
            "e⁻ per DN from moments",
            format!("{:.4}", g.moments_e_per_dn),
            "the fit's starting point",
        );
        for s in &g.settings {
            row(
                t,
                &format!("EM gain at {}× setting", s.nominal),
                if s.fixed {
                    format!("{} (anchor)", s.nominal)
                } else {
                    format!("{:.3} ± {:.3}", s.gain, s.gain_se)
                },
                &format!("{} frames, {} pixels", s.frames, s.gain_per_pixel.len()),
            );
        }
    }
}

/// The style both reports' pages share.
pub(crate) const STYLE: &str = "body{font-family:sans-serif;max-width:1200px;margin:20px auto;color:#222} h2{border-bottom:1px solid #ccc;margin-top:32px}\
table{border-collapse:collapse;font-size:14px} td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}\
.row{display:flex;flex-wrap:wrap;gap:16px;align-items:flex-start} .heat{display:flex;gap:6px;align-items:stretch}\
.bar{display:flex;flex-direction:column;justify-content:space-between;font-size:12px} .bar div{flex:1;width:16px;margin:2px 0}\
.missing{background:#fff4e0;padding:6px 10px} .warn{background:#fde8e8;padding:6px 10px}";

/// The page up to the fitted-numbers table: title, style, what was not calibrated, warnings.
fn page_head(c: &Calibration, h: &mut String) {
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=utf-8><title>emccd calibration — {cam}</title><style>{STYLE}</style></head><body>\
<h1>Calibration of {cam}</h1><p>EM gain {g} · {w}×{hh} px · manifest <code>{man}</code></p>",
        cam = esc(&c.camera),
        g = c.em_gain,
        w = c.width,
        hh = c.height,
        man = esc(&c.manifest.display().to_string())
    );
    for m in &c.missing {
        let _ = write!(h, "<p class=missing>Not calibrated: {}</p>", esc(m));
    }
    for w in &c.warnings {
        let _ = write!(h, "<p class=warn>Warning: {}</p>", esc(w));
    }
}

/// Photon transfer: the curve and its levels.
fn ptc_section(c: &Calibration, h: &mut String) {
    if let Some(p) = &c.ptc {
        let _ = write!(h, "<h2>Photon transfer (paper Fig. 10)</h2><p>Central crop {}×{} at ({}, {}); FPN {} · blooming {} before the median.</p><div class=row>{}<table><tr><th>file</th><th>median DN</th><th>variance DN²</th><th>frames</th><th>status</th></tr>",
            p.crop[2], p.crop[3], p.crop[0], p.crop[1],
            if p.fpn_subtracted { "subtracted" } else { "not subtracted (no bias)" },
            if p.blooming_removed { "removed" } else { "not removed" },
            ptc_plot(c));
        for l in &p.levels {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{:.2}</td><td>{:.2} ± {:.2}</td><td>{}</td><td>{:?}</td></tr>",
                esc(&l.file.file_name().unwrap_or_default().to_string_lossy()),
                l.median_dn,
                l.variance_dn2,
                l.variance_se_dn2,
                l.frames,
                l.status
            );
        }
        h.push_str("</table></div>");
    }
}

/// The fixed pattern: the map, the curves and the forms' prediction errors (the map alone without a fit).
fn fpn_section(c: &Calibration, h: &mut String) {
    if let (Some(f), false) = (&c.fpn, c.bias.is_empty()) {
        let i = (0..c.bias.len())
            .min_by(|&a, &b| {
                (c.bias[a].exposure_s.ln() - 0.01f64.ln())
                    .abs()
                    .total_cmp(&(c.bias[b].exposure_s.ln() - 0.01f64.ln()).abs())
            })
            .unwrap_or(0);
        let _ = write!(h, "<h2>Fixed pattern (paper Fig. 3)</h2><div class=row><div><p>FPN at {} s</p>{}</div>{}</div>", c.bias[i].exposure_s, heat_map(&c.bias[i].mean, c.width, c.height, "DN"), fpn_curve_plot(c));
        let _ = write!(h, "<p>Mean absolute prediction error per pixel. <b>Held out</b> (what chose the form, {:?}): each form fitted to the other exposures predicts this one, on {} regularly spaced pixels (the shortest and longest exposures are not left out: that would score extrapolation); the constant form is the other exposures' pooled map. <b>Fitted</b>: the forms fitted to every exposure, scored on the same ones (all pixels) — below the noise floor means the form fits the maps' noise. The noise floor is what a perfect prediction would still show, from the finite number of bias frames.</p><table><tr><th rowspan=2>exposure s</th><th colspan=3>held out DN</th><th colspan=3>fitted DN</th><th rowspan=2>noise floor DN</th></tr><tr><th>constant</th><th>shared</th><th>per-pixel</th><th>shared</th><th>shared, inliers</th><th>per-pixel</th></tr>", f.chosen, f.heldout_pixels);
        let dn = crate::fpn::error_text;
        for e in &f.errors {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                e.exposure_s,
                dn(e.constant_heldout_dn),
                dn(e.shared_heldout_dn),
                dn(e.per_pixel_heldout_dn),
                dn(e.shared_mae_dn),
                dn(e.shared_mae_inliers_dn),
                dn(e.per_pixel_mae_dn),
                dn(e.noise_floor_dn)
            );
        }
        h.push_str("</table>");
    } else if let Some(b) = c.bias.first() {
        let _ = write!(
            h,
            "<h2>Fixed pattern</h2><p>FPN at {} s</p>{}",
            b.exposure_s,
            heat_map(&b.mean, c.width, c.height, "DN")
        );
    }
}

/// Read noise: the map, the normal Q–Q plot and the table per exposure, with the spurious
/// charge and the read noise beneath it where they were fitted.
fn read_noise_section(c: &Calibration, h: &mut String) {
    if let Some(b) = c.bias.first() {
        let _ = write!(h, "<h2>Read noise (paper Fig. 4)</h2><div class=row><div><p>read-noise std at {} s</p>{}</div>{}</div><table><tr><th>exposure s</th><th>frames</th><th>FPN median DN</th><th>read-noise median DN</th><th>read-noise rms DN</th><th>profile's map median DN</th><th>per pixel ± % (measured / shrunk)</th><th>FPN per pixel ± DN</th><th>spurious e⁻ per frame</th><th>read noise beneath DN</th></tr>", b.exposure_s, heat_map(&b.std, c.width, c.height, "DN"), qq_plot(c));
        for l in &c.bias {
            let fit = c
                .spurious
                .as_ref()
                .and_then(|s| s.levels.iter().find(|f| f.exposure_s == l.exposure_s));
            let (e, r) = fit.map_or(("–".to_string(), "–".to_string()), |f| {
                (
                    format!("{:.5} ± {:.5}", f.electrons, f.electrons_se),
                    format!("{:.3}", f.read_sigma_dn),
                )
            });
            // What the stack's frame count costs: the profile's (shrunk) map and each pixel's
            // error in it and in the fixed pattern.
            let map = crate::read_noise::shrunk(&l.std, l.frames);
            let (raw, shrunk) =
                crate::read_noise::pixel_error(&l.std, l.frames).unwrap_or((f64::NAN, f64::NAN));
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{:.2}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.1} / {:.1}</td><td>{:.2}</td><td>{e}</td><td>{r}</td></tr>",
                l.exposure_s,
                l.frames,
                l.median_dn,
                l.read_noise_median_dn,
                l.read_noise_rms_dn,
                emccd_profile::median(map.iter().copied()).unwrap_or(f64::NAN),
                100.0 * raw,
                100.0 * shrunk,
                l.read_noise_rms_dn / (l.frames as f64).sqrt()
            );
        }
        h.push_str("</table>");
        if let Some(s) = &c.spurious {
            let _ = write!(
                h,
                "<p>Spurious charge from paired-frame differences (CIC + dark·t): CIC {:.5} ± {:.5} e⁻ per pixel per frame, dark current {:.5} e⁻/s; the read noise beneath it {:.3} DN. The std maps hold both.</p>",
                s.cic_e, s.cic_se, s.dark_e_per_s, s.read_sigma_dn
            );
        }
    }
}

/// Blooming: the fit and its levels.
fn blooming_section(c: &Calibration, h: &mut String) {
    if let Some(b) = &c.blooming {
        let _ = write!(h, "<h2>Blooming (paper Fig. 11)</h2><div class=row>{}<table><tr><th>exposure s</th><th>v1</th><th>v2</th><th>v3</th><th>c1</th><th>x</th></tr>", blooming_plot(c));
        for l in &b.levels {
            let _ = write!(h, "<tr><td>{}</td><td>{:.2}</td><td>{:.3}</td><td>{:.3}</td><td>{:.2}</td><td>{:.5} ± {:.5}</td></tr>", l.exposure_s, l.v1.mean, l.v2.mean, l.v3.mean, l.c1, l.x, l.x_se);
        }
        h.push_str("</table></div>");
    }
}

/// The gain series: histogram with the fitted density, and the gains.
fn gain_section(c: &Calibration, h: &mut String) {
    if c.gain_series.is_some() {
        let (hist, gains) = gain_plots(c);
        let _ = write!(
            h,
            "<h2>Gain series (Ryan et al. 2021)</h2><div class=row>{hist}{gains}</div>"
        );
    }
}

/// Writes `dir/index.html` and `dir/results.json` (each atomically).
pub fn write(c: &Calibration, dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut t = String::new();
    fitted_rows(c, &mut t);
    let mut h = String::new();
    page_head(c, &mut h);
    let _ = write!(h, "<h2>Fitted numbers</h2><table><tr><th>quantity</th><th>value ± standard error</th><th>note</th></tr>{t}</table>");
    for section in [
        ptc_section,
        fpn_section,
        read_noise_section,
        blooming_section,
        gain_section,
    ] {
        section(c, &mut h);
    }
    h.push_str(
        "<p style=\"color:#777;font-size:12px\">Written by emccd calibrate.</p></body></html>",
    );
    emccd_io::write_atomic(dir.join("index.html"), h.as_bytes()).map_err(std::io::Error::other)?;
    let json = serde_json::to_string_pretty(c).map_err(std::io::Error::other)?;
    emccd_io::write_atomic(dir.join("results.json"), json.as_bytes())
        .map_err(std::io::Error::other)?;
    Ok(())
}
