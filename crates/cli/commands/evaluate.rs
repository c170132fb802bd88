//! `emccd evaluate`: PSNR and SSIM of denoisers on noisy/clean pairs from the virtual camera.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use emccd_eval::PairsManifest;
use emccd_nn::pipeline::Pipeline;
use serde::Serialize;

use crate::common::{load_profile, progress};

/// Evaluate denoisers on the pairs `emccd simulate pairs` (or tools/unseen_camera.py) writes:
/// raw noisy frames, ground truth in DN above bias, pairs.toml. Prints a Markdown table of PSNR,
/// SSIM and seconds per 512² frame per method, overall and per light level — the mean
/// photoelectrons per pixel where pairs.toml gives them, else photons at the scene's peak — and,
/// for several pair directories (cameras), per camera too (JSON with --json); --out also gets
/// results.csv and PNG panels (input | each method | ground truth). PSNR uses the ground truth's
/// peak as data range; the paper's convention (images / 65535, range 1) is reported beside it.
/// LPIPS is not computed: its network weights cannot be obtained here. The input is never
/// aligned or rescaled with the ground truth's help.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Directories with pairs.toml (one per camera).
    #[arg(required = true, num_args = 1..)]
    pub pairs: Vec<PathBuf>,
    /// Camera profile used for preprocessing and BM3D's noise parameters. Default: the
    /// `profile` that pairs.toml names (`default`, or a directory relative to pairs.toml),
    /// else the bundled default.
    #[arg(long)]
    pub profile: Option<String>,
    /// Methods: `input`, `bm3d` (one BM3D + GAT pass), `ivst` (iterative BM3D, the default of
    /// `denoise`), `ivst:λ/b,λ/b,…` (iterative BM3D with these passes: the data's weight and the
    /// bin side, e.g. `ivst:1/3,0.7/2,0.4/1`), `hybrid` (the bundled BM3D-refining network), or
    /// a model file (`default`, `microscopy` = the bundled networks; a hybrid model file runs as
    /// the hybrid method); repeatable. `MODEL@8` averages the model over 8 flips/transposes
    /// (self-ensemble; 2, 4, 8).
    #[arg(long = "method", required = true, num_args = 1..)]
    pub methods: Vec<String>,
    /// Print JSON instead of Markdown.
    #[arg(long)]
    pub json: bool,
    /// Write results.csv, results.json and PNG panels here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// One method on one pair.
#[derive(Serialize, Clone)]
struct Score {
    method: String,
    camera: String,
    scene: String,
    photons: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_electrons: Option<f64>,
    psnr_db: f64,
    psnr_paper_db: f64,
    ssim: f64,
    /// Seconds the method took on this frame (preprocessing included).
    seconds: f64,
    pixels: usize,
}

/// Averages per method (and light level, and camera).
#[derive(Serialize)]
struct Summary {
    method: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    camera: Option<String>,
    /// The level: photons at the scene's peak, or mean photoelectrons per pixel (`level_unit`).
    photons: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    exposure_ratio: Option<f64>,
    pairs: usize,
    psnr_db: f64,
    psnr_paper_db: f64,
    ssim: f64,
    /// Seconds per 512×512 frame, from the time per pixel on these frames.
    s_per_512: f64,
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

fn read_first(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let (info, buf) = emccd_io::read_first(path)?;
    Ok((info.width, info.height, buf))
}

struct Camera {
    dir: PathBuf,
    name: String,
    file: PairsManifest,
    profile: emccd_profile::CameraProfile,
}

fn load_camera(dir: &Path, profile: Option<&str>) -> Result<Camera> {
    let mpath = dir.join(PairsManifest::FILE);
    let file = PairsManifest::load(dir).map_err(anyhow::Error::msg)?;
    let profile = match (profile, &file.profile) {
        (Some(p), _) => load_profile(p)?,
        // `default`, a directory relative to pairs.toml, or (as `simulate pairs` records it) as given.
        (None, Some(p)) => {
            let rel = dir.join(p);
            let p = if p != "default" && rel.is_dir() {
                rel.to_string_lossy().into_owned()
            } else {
                p.clone()
            };
            load_profile(&p).with_context(|| format!("the profile {} names", mpath.display()))?
        }
        (None, None) => load_profile("default")?,
    };
    let name = file
        .camera
        .clone()
        .unwrap_or_else(|| dir.display().to_string());
    Ok(Camera {
        dir: dir.to_path_buf(),
        name,
        file,
        profile,
    })
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n.max(1) as f64
}

fn summarize(
    method: &str,
    camera: Option<&str>,
    level: Option<f64>,
    ratio: Option<f64>,
    scores: &[&Score],
) -> Summary {
    let pixels: usize = scores.iter().map(|x| x.pixels).sum();
    Summary {
        method: method.to_string(),
        camera: camera.map(str::to_string),
        photons: level,
        exposure_ratio: ratio,
        pairs: scores.len(),
        psnr_db: mean(scores.iter().map(|x| x.psnr_db)),
        psnr_paper_db: mean(scores.iter().map(|x| x.psnr_paper_db)),
        ssim: mean(scores.iter().map(|x| x.ssim)),
        s_per_512: scores.iter().map(|x| x.seconds).sum::<f64>() * (512.0 * 512.0)
            / pixels.max(1) as f64,
    }
}

pub fn run(a: Args) -> Result<()> {
    let cameras = a
        .pairs
        .iter()
        .map(|d| load_camera(d, a.profile.as_deref()))
        .collect::<Result<Vec<_>>>()?;
    let mut models = BTreeMap::new();
    let mut schedules = BTreeMap::new();
    for m in &a.methods {
        if let Some(spec) = m.strip_prefix("ivst:") {
            let s: emccd_eval::vst::Schedule = spec
                .parse()
                .map_err(|e: String| anyhow::anyhow!("--method {m}: {e}"))?;
            schedules.insert(m.clone(), s);
        } else if !["input", "bm3d", "ivst"].contains(&m.as_str()) {
            let (name, k) = crate::commands::denoise::model_spec(m)?;
            models.insert(m.clone(), (crate::commands::denoise::load_model(name)?, k));
        }
    }
    if let Some(o) = &a.out {
        std::fs::create_dir_all(o).with_context(|| format!("creating {}", o.display()))?;
    }
    let total: usize = cameras.iter().map(|c| c.file.pair.len()).sum();
    let pb = progress((total * a.methods.len()) as u64, "evaluations");
    let mut scores = Vec::new();
    for cam in &cameras {
        for p in &cam.file.pair {
            let (w, h, raw) = read_first(&cam.dir.join(&p.noisy))?;
            let (cw, ch, truth) = read_first(&cam.dir.join(&p.clean))?;
            if (w, h) != (cw, ch) {
                bail!("{}: noisy {w}×{h} and clean {cw}×{ch} differ", p.noisy);
            }
            let prof = if (w, h) == (cam.profile.width, cam.profile.height) {
                cam.profile.clone()
            } else {
                cam.profile.crop(0, 0, w, h)?
            };
            let peak = truth.iter().copied().fold(0f32, f32::max).max(1e-6) as f64;
            let mut outputs: Vec<(String, Vec<f32>)> = Vec::new();
            for m in &a.methods {
                let t = std::time::Instant::now();
                let out = match m.as_str() {
                    "input" => emccd_nn::pipeline::preprocess(&prof, &raw, p.exposure_s)?,
                    "bm3d" | "ivst" => crate::commands::denoise::classical_frame(
                        &prof,
                        &raw,
                        p.exposure_s,
                        m.parse().map_err(|e: String| anyhow::anyhow!(e))?,
                    )?,
                    spec if schedules.contains_key(spec) => {
                        let pre = emccd_nn::pipeline::preprocess(&prof, &raw, p.exposure_s)?;
                        emccd_nn::pipeline::bm3d_passes(
                            &prof,
                            &pre,
                            p.exposure_s,
                            &schedules[spec].0,
                        )?
                    }
                    other => Pipeline {
                        model: &models[other].0,
                        profile: &prof,
                        tiling: Default::default(),
                        ensemble: models[other].1,
                        device: emccd_nn::device(),
                    }
                    .denoise_raw(&raw, p.exposure_s)?,
                };
                scores.push(Score {
                    method: m.clone(),
                    camera: cam.name.clone(),
                    scene: p.scene.clone(),
                    photons: p.photons,
                    mean_electrons: p.mean_electrons,
                    psnr_db: emccd_eval::psnr(&out, &truth, peak),
                    psnr_paper_db: emccd_eval::psnr(&out, &truth, 65535.0),
                    ssim: emccd_eval::ssim(&out, &truth, w, h, peak, Default::default()),
                    seconds: t.elapsed().as_secs_f64(),
                    pixels: w * h,
                });
                outputs.push((m.clone(), out));
                pb.inc(1);
            }
            if let Some(o) = &a.out {
                let stem = if cameras.len() > 1 {
                    format!(
                        "{}-",
                        cam.dir
                            .parent()
                            .and_then(|d| d.file_name())
                            .or(cam.dir.file_name())
                            .map(|s| s.to_string_lossy().into_owned())
                            .unwrap_or_default()
                    )
                } else {
                    String::new()
                };
                write_panel(o, &stem, p, w, h, &outputs, &truth, peak)?;
            }
        }
    }
    pb.finish_and_clear();
    let all_pairs: Vec<&emccd_eval::Pair> = cameras.iter().flat_map(|c| &c.file.pair).collect();
    let by_mean = all_pairs.iter().all(|p| p.mean_electrons.is_some());
    // The level pairs are grouped by: mean photoelectrons where every pair records them.
    let level = |mean_electrons: Option<f64>, photons: f64| {
        if by_mean {
            mean_electrons.unwrap_or(photons)
        } else {
            photons
        }
    };
    let level_of = |s: &Score| level(s.mean_electrons, s.photons);
    let levels: Vec<f64> = {
        let mut v: Vec<f64> = all_pairs
            .iter()
            .map(|p| level(p.mean_electrons, p.photons))
            .collect();
        v.sort_by(f64::total_cmp);
        v.dedup();
        v
    };
    let ratio_of = |l: f64| {
        all_pairs
            .iter()
            .find(|p| p.photons == l && !by_mean)
            .and_then(|p| p.exposure_ratio)
    };
    let mut summaries = Vec::new();
    let camera_groups: Vec<Option<&str>> = std::iter::once(None)
        .chain(
            cameras
                .iter()
                .map(|c| Some(c.name.as_str()))
                .filter(|_| cameras.len() > 1),
        )
        .collect();
    for cam in &camera_groups {
        for m in &a.methods {
            for lvl in std::iter::once(None).chain(levels.iter().map(|&l| Some(l))) {
                let s: Vec<&Score> = scores
                    .iter()
                    .filter(|s| {
                        &s.method == m
                            && cam.is_none_or(|c| s.camera == c)
                            && lvl.is_none_or(|l| level_of(s) == l)
                    })
                    .collect();
                if !s.is_empty() {
                    summaries.push(summarize(m, *cam, lvl, lvl.and_then(ratio_of), &s));
                }
            }
        }
    }
    let unit = if by_mean {
        "mean photoelectrons per pixel"
    } else {
        "photons at the scene's brightest pixel"
    };
    let v = serde_json::json!({
        "psnr_data_range": "ground-truth peak per pair; psnr_paper_db: images / 65535, range 1 (the paper's convention)",
        "lpips": "not computed: its network weights cannot be obtained offline",
        "level_unit": unit,
        "summary": summaries,
        "pairs": scores,
    });
    if let Some(o) = &a.out {
        emccd_io::write_atomic(
            o.join("results.json"),
            serde_json::to_string_pretty(&v)?.as_bytes(),
        )?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("PSNR data range: the ground truth's peak; \"paper\": images / 65535 with range 1. LPIPS: not computed (no weights offline).");
        println!("Level: {unit}. Time: seconds per 512×512 frame on this machine, from the time per pixel.\n");
        let col = if by_mean { "mean e⁻/px" } else { "photons" };
        println!("| camera | method | {col} | pairs | PSNR (dB) | PSNR paper conv. (dB) | SSIM | s / 512² |");
        println!("|---|---|---:|---:|---:|---:|---:|---:|");
        for s in &summaries {
            let l = match (s.photons, s.exposure_ratio) {
                (None, _) => "all".to_string(),
                (Some(p), Some(r)) => format!("{p:.4} (ratio {r})"),
                (Some(p), None) => format!("{p}"),
            };
            let c = s.camera.as_deref().unwrap_or("all");
            println!(
                "| {c} | {} | {l} | {} | {:.2} | {:.2} | {:.4} | {:.2} |",
                s.method, s.pairs, s.psnr_db, s.psnr_paper_db, s.ssim, s.s_per_512
            );
        }
    }
    if let Some(o) = &a.out {
        let mut csv = String::from(
            "method,camera,scene,photons,mean_electrons,psnr_db,psnr_paper_db,ssim,seconds\n",
        );
        for s in &scores {
            let me = s.mean_electrons.map_or(String::new(), |m| m.to_string());
            let _ = writeln!(
                csv,
                "{},{},{},{},{me},{:.4},{:.4},{:.6},{:.4}",
                csv_field(&s.method),
                csv_field(&s.camera),
                csv_field(&s.scene),
                s.photons,
                s.psnr_db,
                s.psnr_paper_db,
                s.ssim,
                s.seconds
            );
        }
        emccd_io::write_atomic(o.join("results.csv"), csv.as_bytes())?;
    }
    Ok(())
}

/// A 256² crop (the frame's centre) of input | each method | ground truth, side by side.
#[allow(clippy::too_many_arguments)]
fn write_panel(
    dir: &Path,
    prefix: &str,
    p: &emccd_eval::Pair,
    w: usize,
    h: usize,
    outs: &[(String, Vec<f32>)],
    truth: &[f32],
    peak: f64,
) -> Result<()> {
    let c = 256.min(w).min(h);
    let (x0, y0) = ((w - c) / 2, (h - c) / 2);
    let panels: Vec<&[f32]> = outs
        .iter()
        .map(|o| o.1.as_slice())
        .chain(std::iter::once(truth))
        .collect();
    let n = panels.len();
    let mut img = vec![0f32; n * c * c];
    for (k, src) in panels.iter().enumerate() {
        for y in 0..c {
            for x in 0..c {
                img[y * n * c + k * c + x] = src[(y0 + y) * w + x0 + x];
            }
        }
    }
    let stem = Path::new(&p.noisy)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    emccd_io::write_png_preview(
        dir.join(format!("{prefix}{stem}.png")),
        n * c,
        c,
        &img,
        0.0,
        peak as f32,
    )?;
    Ok(())
}
