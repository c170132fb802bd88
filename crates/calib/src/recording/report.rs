//! The report of `emccd calibrate --from-recording`: one self-contained `index.html` with the
//! plots a person checks (the dark pixels' values with the fitted zero-electron peak and EM
//! tail, their differences with the read noise and the register's gain, the movie's
//! mean–variance line), the estimates with their errors, and `results.json`.

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;

use super::em::{self, Form, Histogram};
use super::Characterization;
use crate::report::{esc, range, row, svg, STYLE};

/// A histogram (log counts) with the fit's expected counts over it.
fn histogram_plot(
    title: &str,
    x_desc: &str,
    hist: &Histogram,
    form: Form,
    fit: &em::Fit,
) -> String {
    let expected = em::expected(form, hist, &fit.params);
    let pts: Vec<(f64, f64)> = hist
        .counts
        .iter()
        .enumerate()
        .filter(|(_, &c)| c > 0.0)
        .map(|(i, &c)| ((hist.origin + i as i64) as f64, c))
        .collect();
    svg(560, 400, |root| {
        let (x0, x1) = range(pts.iter().map(|p| p.0), false);
        let y1 = pts.iter().map(|p| p.1).fold(1.0, f64::max) * 2.0;
        let mut ch = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1, (0.5..y1).log_scale())?;
        ch.configure_mesh()
            .x_desc(x_desc)
            .y_desc("values per DN")
            .draw()?;
        ch.draw_series(pts.iter().map(|&p| Circle::new(p, 1, BLUE.filled())))?
            .label("recording")
            .legend(|(x, y)| Circle::new((x + 10, y), 3, BLUE.filled()));
        let line: Vec<(f64, f64)> = expected
            .iter()
            .enumerate()
            .map(|(i, &e)| ((hist.origin + i as i64) as f64, e))
            .filter(|p| p.1 >= 0.5)
            .collect();
        let p = fit.params;
        ch.draw_series(LineSeries::new(line, RED.stroke_width(2)))?
            .label(format!(
                "fit: σ {:.2} DN, {:.3} e⁻, {:.1} DN/e⁻",
                p.sigma, p.electrons, p.gain
            ))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        ch.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .position(SeriesLabelPosition::UpperRight)
            .draw()?;
        Ok(())
    })
}

/// The movie's blocks: half the variance of their frame differences against their level.
fn ptc_plot(c: &Characterization) -> String {
    let Some(curve) = &c.curve else {
        return String::new();
    };
    svg(560, 400, |root| {
        let (x0, x1) = range(curve.points.iter().map(|p| p.level), false);
        let (y0, y1) = range(curve.points.iter().map(|p| p.variance), false);
        let mut ch = ChartBuilder::on(root)
            .caption(
                "Temporal variance vs level (8×8 blocks, frame pairs)",
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1, y0.max(0.0)..y1)?;
        ch.configure_mesh()
            .x_desc("level above the bias map, from the neighbouring frames (DN)")
            .y_desc("½ variance of the difference (DN²)")
            .draw()?;
        ch.draw_series(
            curve
                .points
                .iter()
                .map(|p| Circle::new((p.level, p.variance), 1, BLUE.mix(0.5).filled())),
        )?;
        let line = [x0, x1].map(|x| (x, curve.slope * x + curve.intercept));
        ch.draw_series(LineSeries::new(line, RED.stroke_width(2)))?
            .label(format!(
                "Var = {:.3}·level {:+.1}",
                curve.slope, curve.intercept
            ))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        ch.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
        Ok(())
    })
}

/// Writes `index.html` and `results.json` for `c`, made from `source`, into `dir`.
pub fn write(c: &Characterization, source: &str, dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut t = String::new();
    let pm = |e: super::Estimate, unit: &str| format!("{:.4} ± {:.4}{unit}", e.value, e.se);
    row(
        &mut t,
        "photon-transfer slope s = K·f²",
        pm(c.slope_dn, " DN"),
        match c.slope_from {
            super::SlopeFrom::TemporalPtc => "the movie's temporal mean–variance line",
            super::SlopeFrom::EmTail => "2 × the register's gain (f² = 2 assumed)",
        },
    );
    row(
        &mut t,
        "DN per photoelectron (s/2, as the profile converts)",
        format!("{:.4}", c.dn_per_electron()),
        "",
    );
    match c.gain_dn {
        Some(g) => row(
            &mut t,
            "register gain K (mean DN per electron)",
            pm(g, " DN"),
            "the dark pixels' differences: their exponential tails",
        ),
        None => row(
            &mut t,
            "register gain K",
            "not measured".into(),
            "too few electrons in the dark pixels",
        ),
    }
    if let Some(f2) = c.excess_f2 {
        row(&mut t, "excess noise f² = s/K", pm(f2, ""), "2 in theory");
    }
    row(
        &mut t,
        "bias",
        pm(c.bias_dn, " DN"),
        "the zero-electron peak of the dark pixels' values",
    );
    row(
        &mut t,
        "read noise",
        pm(c.read_noise_dn, " DN"),
        if c.frames > 1 {
            "the Gaussian core of frame differences (the fixed pattern cancelled)"
        } else {
            "the Gaussian core of neighbouring pixels' differences (holds the fixed pattern)"
        },
    );
    if let Some(p) = c.pattern_dn {
        row(
            &mut t,
            "bias pattern (pixel to pixel)",
            format!("{p:.3} DN"),
            "peak width beyond the read noise",
        );
    }
    row(
        &mut t,
        "electrons per frame in the dark pixels",
        pm(c.dark_electrons, ""),
        "light, dark current and clock-induced charge together",
    );
    row(
        &mut t,
        "mean light level",
        format!("{:.3} e⁻ per pixel per frame", c.mean_electrons),
        super::regime(c.mean_electrons),
    );
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=utf-8><title>emccd characterization — {src}</title><style>{STYLE}</style></head><body>\
<h1>Camera characterized from {src}</h1><p>{w}×{hh} px · {f} frame(s) · no calibration acquisition: every number below comes from the recording itself</p>",
        src = esc(source),
        w = c.width,
        hh = c.height,
        f = c.frames
    );
    for n in &c.notes {
        let _ = write!(h, "<p class=missing>{}</p>", esc(n));
    }
    let _ = write!(h, "<h2>Estimates</h2><table><tr><th>quantity</th><th>value ± standard error</th><th>from</th></tr>{t}</table>");
    let _ = write!(
        h,
        "<h2>The dark pixels</h2><p>{} values of the darkest pixels (chosen by their neighbours' mean, not their own values).</p><div class=row>{}{}</div>",
        c.values.total(),
        histogram_plot(
            "Values: the zero-electron peak and the EM tail",
            "value (DN)",
            &c.values,
            Form::Values,
            &c.values_fit
        ),
        histogram_plot(
            if c.frames > 1 {
                "Differences of frame pairs"
            } else {
                "Differences of neighbouring pixels"
            },
            "difference (DN)",
            &c.differences,
            Form::Differences,
            &c.differences_fit
        )
    );
    if let Some(curve) = &c.curve {
        let _ = write!(
            h,
            "<h2>Photon transfer</h2><p>{} block pairs kept, {} left out as moving or saturated.</p>{}",
            curve.kept,
            curve.left_out,
            ptc_plot(c)
        );
    }
    h.push_str("<p style=\"color:#777;font-size:12px\">Written by emccd calibrate --from-recording.</p></body></html>");
    emccd_io::write_atomic(dir.join("index.html"), h.as_bytes()).map_err(std::io::Error::other)?;
    let json = serde_json::to_string_pretty(c).map_err(std::io::Error::other)?;
    emccd_io::write_atomic(dir.join("results.json"), json.as_bytes())
        .map_err(std::io::Error::other)?;
    Ok(())
}
