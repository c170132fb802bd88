//! Denoisers scored on test pairs, and the tables `emccd evaluate` prints and writes: averages
//! per method, light level and camera, Markdown, CSV, and side-by-side panels.

use std::fmt::Write as _;

use serde::Serialize;

use crate::pairs::{Pair, PairFrames};

/// One method on one pair.
#[derive(Clone, Debug, Serialize)]
pub struct Score {
    /// The method's name as the user gave it.
    pub method: String,
    /// The camera (pairs folder) the pair belongs to.
    pub camera: String,
    /// The clean scene.
    pub scene: String,
    /// Photons at the scene's peak.
    pub photons: f64,
    /// Exposure ratio of the pair, where it was made so (not written: the level says it).
    #[serde(skip)]
    pub exposure_ratio: Option<f64>,
    /// Mean photoelectrons per pixel, where the pair records it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_electrons: Option<f64>,
    /// PSNR with the ground truth's peak as data range, dB.
    pub psnr_db: f64,
    /// PSNR in the paper's convention (images / 65535, range 1), dB.
    pub psnr_paper_db: f64,
    /// SSIM (Gaussian window, the truth's peak as data range).
    pub ssim: f64,
    /// The estimate's mean over the frames scored over the truth's: photometry (1 = unbiased).
    pub mean_ratio: f64,
    /// Seconds the method took on the pair's frames (preprocessing included).
    pub seconds: f64,
    /// Pixels in the frames scored.
    pub pixels: usize,
}

impl Score {
    /// Scores `out`, `method`'s estimate of the frames scored of `pair` of `camera` (one after
    /// another), against their ground truth in `frames` (photo-signal in DN above bias);
    /// `seconds` is what the method took.
    pub fn measure(
        method: &str,
        camera: &str,
        pair: &Pair,
        frames: &PairFrames,
        out: &[f32],
        seconds: f64,
    ) -> Score {
        let (truth, w, h) = (&frames.clean, frames.width, frames.height);
        let peak = truth_peak(truth);
        let n = w * h;
        // A movie's SSIM is its frames' mean; PSNR pools every pixel of every frame.
        let ssim = (0..frames.frames)
            .map(|k| {
                let f = k * n..(k + 1) * n;
                crate::ssim(&out[f.clone()], &truth[f], w, h, peak, Default::default())
            })
            .sum::<f64>()
            / frames.frames.max(1) as f64;
        Score {
            method: method.into(),
            camera: camera.into(),
            scene: pair.scene.clone(),
            photons: pair.photons,
            exposure_ratio: pair.exposure_ratio,
            mean_electrons: pair.mean_electrons,
            psnr_db: crate::psnr(out, truth, peak),
            psnr_paper_db: crate::psnr(out, truth, 65535.0),
            ssim,
            mean_ratio: mean(out.iter().map(|&v| v as f64)) / mean(truth.iter().map(|&v| v as f64)),
            seconds,
            pixels: n * frames.frames,
        }
    }
}

/// The data range PSNR and SSIM use: the ground truth's peak (floored, so an all-dark truth
/// still gives a finite number).
pub fn truth_peak(truth: &[f32]) -> f64 {
    truth.iter().copied().fold(0f32, f32::max).max(1e-6) as f64
}

/// What pairs are grouped by: mean photoelectrons per pixel where every pair records them,
/// else photons at the scene's brightest pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LevelUnit {
    /// Mean photoelectrons per pixel.
    MeanElectrons,
    /// Photons at the scene's brightest pixel.
    PeakPhotons,
}

impl LevelUnit {
    /// The unit `scores` can all be grouped by.
    pub fn for_scores(scores: &[Score]) -> LevelUnit {
        if scores.iter().all(|s| s.mean_electrons.is_some()) {
            LevelUnit::MeanElectrons
        } else {
            LevelUnit::PeakPhotons
        }
    }

    /// A score's level in this unit.
    pub fn level(self, s: &Score) -> f64 {
        match self {
            LevelUnit::MeanElectrons => s.mean_electrons.unwrap_or(s.photons),
            LevelUnit::PeakPhotons => s.photons,
        }
    }

    /// The unit in words.
    pub fn describe(self) -> &'static str {
        match self {
            LevelUnit::MeanElectrons => "mean photoelectrons per pixel",
            LevelUnit::PeakPhotons => "photons at the scene's brightest pixel",
        }
    }

    /// The table's column heading.
    pub fn column(self) -> &'static str {
        match self {
            LevelUnit::MeanElectrons => "mean e⁻/px",
            LevelUnit::PeakPhotons => "photons",
        }
    }
}

/// Averages per method (and light level, and camera).
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// The method.
    pub method: String,
    /// The camera; None: all cameras.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
    /// The level in the table's [`LevelUnit`]; None: all levels.
    pub photons: Option<f64>,
    /// The level's exposure ratio, where the pairs were made by ratio.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exposure_ratio: Option<f64>,
    /// Pairs averaged.
    pub pairs: usize,
    /// Mean PSNR, dB.
    pub psnr_db: f64,
    /// Mean PSNR in the paper's convention, dB.
    pub psnr_paper_db: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Seconds per 512×512 frame, from the time per pixel on these frames.
    pub s_per_512: f64,
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n.max(1) as f64
}

/// The rows of an evaluation table and the unit of their light levels.
#[derive(Clone, Debug)]
pub struct Summaries {
    /// What the rows' levels are.
    pub unit: LevelUnit,
    /// Per method (and camera): overall, then per level.
    pub rows: Vec<Summary>,
}

/// Averages of `scores` per method (in `methods` order): over everything, then per level;
/// with several `cameras`, the same again per camera.
pub fn summarize(scores: &[Score], methods: &[String], cameras: &[String]) -> Summaries {
    let unit = LevelUnit::for_scores(scores);
    let mut levels: Vec<f64> = scores.iter().map(|s| unit.level(s)).collect();
    levels.sort_by(f64::total_cmp);
    levels.dedup();
    let ratio_of = |l: f64| {
        scores
            .iter()
            .find(|s| unit == LevelUnit::PeakPhotons && s.photons == l)
            .and_then(|s| s.exposure_ratio)
    };
    let groups: Vec<Option<&str>> = std::iter::once(None)
        .chain(
            cameras
                .iter()
                .map(|c| Some(c.as_str()))
                .filter(|_| cameras.len() > 1),
        )
        .collect();
    let mut out = Vec::new();
    for cam in &groups {
        for m in methods {
            for lvl in std::iter::once(None).chain(levels.iter().map(|&l| Some(l))) {
                let s: Vec<&Score> = scores
                    .iter()
                    .filter(|s| {
                        &s.method == m
                            && cam.is_none_or(|c| s.camera == c)
                            && lvl.is_none_or(|l| unit.level(s) == l)
                    })
                    .collect();
                if s.is_empty() {
                    continue;
                }
                let pixels: usize = s.iter().map(|x| x.pixels).sum();
                out.push(Summary {
                    method: m.clone(),
                    camera: cam.map(str::to_string),
                    photons: lvl,
                    exposure_ratio: lvl.and_then(ratio_of),
                    pairs: s.len(),
                    psnr_db: mean(s.iter().map(|x| x.psnr_db)),
                    psnr_paper_db: mean(s.iter().map(|x| x.psnr_paper_db)),
                    ssim: mean(s.iter().map(|x| x.ssim)),
                    s_per_512: s.iter().map(|x| x.seconds).sum::<f64>() * (512.0 * 512.0)
                        / pixels.max(1) as f64,
                });
            }
        }
    }
    Summaries { unit, rows: out }
}

impl Summaries {
    /// The Markdown table `emccd evaluate` prints, with its two lines of conventions above.
    pub fn markdown(&self) -> String {
        markdown(self.unit, &self.rows)
    }
}

fn markdown(unit: LevelUnit, summaries: &[Summary]) -> String {
    let mut t = String::new();
    let _ = writeln!(t, "PSNR data range: the ground truth's peak; \"paper\": images / 65535 with range 1. LPIPS: not computed (no weights offline).");
    let _ = writeln!(
        t,
        "Level: {}. Time: seconds per 512×512 frame on this machine, from the time per pixel.\n",
        unit.describe()
    );
    let _ = writeln!(
        t,
        "| camera | method | {} | pairs | PSNR (dB) | PSNR paper conv. (dB) | SSIM | s / 512² |",
        unit.column()
    );
    let _ = writeln!(t, "|---|---|---:|---:|---:|---:|---:|---:|");
    for s in summaries {
        let l = match (s.photons, s.exposure_ratio) {
            (None, _) => "all".to_string(),
            (Some(p), Some(r)) => format!("{p:.4} (ratio {r})"),
            (Some(p), None) => format!("{p}"),
        };
        let c = s.camera.as_deref().unwrap_or("all");
        let _ = writeln!(
            t,
            "| {c} | {} | {l} | {} | {:.2} | {:.2} | {:.4} | {:.2} |",
            s.method, s.pairs, s.psnr_db, s.psnr_paper_db, s.ssim, s.s_per_512
        );
    }
    t
}

/// A CSV field, quoted where it holds a comma, quote or line break (RFC 4180): method names
/// such as `ivst:1/2,0.5/1` and camera names have commas.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// One row per score (`results.csv`).
pub fn csv(scores: &[Score]) -> String {
    let mut csv = String::from(
        "method,camera,scene,photons,mean_electrons,psnr_db,psnr_paper_db,ssim,mean_ratio,seconds\n",
    );
    for s in scores {
        let me = s.mean_electrons.map_or(String::new(), |m| m.to_string());
        let _ = writeln!(
            csv,
            "{},{},{},{},{me},{:.4},{:.4},{:.6},{:.5},{:.4}",
            csv_field(&s.method),
            csv_field(&s.camera),
            csv_field(&s.scene),
            s.photons,
            s.psnr_db,
            s.psnr_paper_db,
            s.ssim,
            s.mean_ratio,
            s.seconds
        );
    }
    csv
}

/// The same `side`×`side` window (at `x0`, `y0`) of equally sized `w`-wide frames, placed side
/// by side: a `panels.len()·side` × `side` image.
pub fn side_by_side(
    panels: &[&[f32]],
    w: usize,
    (x0, y0): (usize, usize),
    (cw, ch): (usize, usize),
) -> Vec<f32> {
    let n = panels.len();
    let mut img = vec![0f32; n * cw * ch];
    for (k, src) in panels.iter().enumerate() {
        for y in 0..ch {
            img[y * n * cw + k * cw..y * n * cw + (k + 1) * cw]
                .copy_from_slice(&src[(y0 + y) * w + x0..(y0 + y) * w + x0 + cw]);
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    fn score(method: &str, camera: &str, level: f64, psnr: f64) -> Score {
        Score {
            method: method.into(),
            camera: camera.into(),
            scene: "s".into(),
            photons: level * 3.0,
            exposure_ratio: None,
            mean_electrons: Some(level),
            psnr_db: psnr,
            psnr_paper_db: psnr + 40.0,
            ssim: 0.5,
            mean_ratio: 1.0,
            seconds: 1.0,
            pixels: 256 * 256,
        }
    }

    #[test]
    fn summaries_per_level_and_camera() {
        let scores = vec![
            score("bm3d", "a", 1.0, 20.0),
            score("bm3d", "b", 1.0, 22.0),
            score("bm3d", "a", 4.0, 26.0),
            score("net", "a", 1.0, 19.0),
        ];
        let table = summarize(
            &scores,
            &["bm3d".into(), "net".into()],
            &["a".into(), "b".into()],
        );
        let (unit, s) = (table.unit, &table.rows);
        assert_eq!(unit, LevelUnit::MeanElectrons);
        let all = &s[0];
        assert_eq!(
            (
                all.method.as_str(),
                all.camera.as_deref(),
                all.photons,
                all.pairs
            ),
            ("bm3d", None, None, 3)
        );
        assert!((all.psnr_db - 68.0 / 3.0).abs() < 1e-12);
        // 1 s per 256² frame is 4 s per 512² frame
        assert!((all.s_per_512 - 4.0).abs() < 1e-12);
        let at1 = s
            .iter()
            .find(|x| x.method == "bm3d" && x.camera.is_none() && x.photons == Some(1.0))
            .unwrap();
        assert_eq!(at1.pairs, 2);
        let b = s
            .iter()
            .filter(|x| x.camera.as_deref() == Some("b"))
            .count();
        assert_eq!(
            b, 2,
            "camera b: bm3d overall and at 1 e⁻ (no net scores there)"
        );
        let md = table.markdown();
        assert!(md.contains("| all | bm3d | all | 3 | 22.67 |"), "{md}");
        assert!(csv(&scores)
            .lines()
            .nth(1)
            .unwrap()
            .starts_with("bm3d,a,s,3,1,20.0000"));
        assert_eq!(csv_field("ivst:1/2,0.5/1"), "\"ivst:1/2,0.5/1\"");
    }

    #[test]
    fn panels_side_by_side() {
        let a: Vec<f32> = (0..16).map(|v| v as f32).collect();
        let b: Vec<f32> = (0..16).map(|v| -(v as f32)).collect();
        // the 2×2 window at (1, 1) of two 4×4 frames
        let img = side_by_side(&[&a, &b], 4, (1, 1), (2, 2));
        assert_eq!(img, vec![5.0, 6.0, -5.0, -6.0, 9.0, 10.0, -9.0, -10.0]);
    }
}
