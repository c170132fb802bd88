//! `emccd evaluate`: PSNR and SSIM of denoisers on noisy/clean pairs from the virtual camera.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use emccd_nn::pipeline::Pipeline;
use serde::{Deserialize, Serialize};

use crate::common::{load_profile, progress};

/// Evaluate denoisers on the pairs `emccd simulate pairs` writes (raw noisy frames, ground truth
/// in DN above bias, pairs.toml). Prints a Markdown table of PSNR and SSIM per method, overall
/// and per photon level (JSON with --json); --out also gets results.csv and PNG panels
/// (input | each method | ground truth). PSNR uses the ground truth's peak as data range; the
/// paper's convention (images / 65535, range 1) is reported beside it. LPIPS is not computed:
/// its network weights cannot be obtained here. The input is never aligned or rescaled with the
/// ground truth's help.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Directory with pairs.toml.
    pub pairs: PathBuf,
    /// Camera profile used for preprocessing and BM3D's noise parameters.
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// Methods: `input`, `bm3d`, or a model file (`default`, `microscopy` = the bundled models);
    /// repeatable. `MODEL@8` averages the model over 8 flips/transposes (self-ensemble; 2, 4, 8).
    #[arg(long = "method", required = true, num_args = 1..)]
    pub methods: Vec<String>,
    /// Print JSON instead of Markdown.
    #[arg(long)]
    pub json: bool,
    /// Write results.csv, results.json and PNG panels here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

#[derive(Deserialize)]
struct PairsFile {
    pair: Vec<PairEntry>,
}

#[derive(Deserialize)]
struct PairEntry {
    scene: String,
    noisy: String,
    clean: String,
    exposure_s: f64,
    photons: f64,
    #[serde(default)]
    exposure_ratio: Option<f64>,
}

/// One method on one pair.
#[derive(Serialize, Clone)]
struct Score {
    method: String,
    scene: String,
    photons: f64,
    psnr_db: f64,
    psnr_paper_db: f64,
    ssim: f64,
}

/// Averages per method (and photon level).
#[derive(Serialize)]
struct Summary {
    method: String,
    photons: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    exposure_ratio: Option<f64>,
    pairs: usize,
    psnr_db: f64,
    psnr_paper_db: f64,
    ssim: f64,
}

fn read_first(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let (info, buf) = emccd_io::read_first(path)?;
    Ok((info.width, info.height, buf))
}

pub fn run(a: Args) -> Result<()> {
    let mpath = a.pairs.join("pairs.toml");
    let text = std::fs::read_to_string(&mpath).with_context(|| format!("reading {}", mpath.display()))?;
    let pf: PairsFile = toml::from_str(&text).with_context(|| format!("parsing {}", mpath.display()))?;
    let profile = load_profile(&a.profile)?;
    let mut models = BTreeMap::new();
    for m in &a.methods {
        if m != "input" && m != "bm3d" {
            let (name, k) = crate::commands::denoise::model_spec(m)?;
            models.insert(m.clone(), (crate::commands::denoise::load_model(name)?, k));
        }
    }
    if let Some(o) = &a.out {
        std::fs::create_dir_all(o).with_context(|| format!("creating {}", o.display()))?;
    }
    let pb = progress((pf.pair.len() * a.methods.len()) as u64, "evaluations");
    let mut scores = Vec::new();
    for p in &pf.pair {
        let (w, h, raw) = read_first(&a.pairs.join(&p.noisy))?;
        let (cw, ch, truth) = read_first(&a.pairs.join(&p.clean))?;
        if (w, h) != (cw, ch) {
            bail!("{}: noisy {w}×{h} and clean {cw}×{ch} differ", p.noisy);
        }
        let prof = if (w, h) == (profile.width, profile.height) { profile.clone() } else { profile.crop(0, 0, w, h)? };
        let peak = truth.iter().copied().fold(0f32, f32::max).max(1e-6) as f64;
        let mut outputs: Vec<(String, Vec<f32>)> = Vec::new();
        for m in &a.methods {
            let out = match m.as_str() {
                "input" => emccd_nn::pipeline::preprocess(&prof, &raw, p.exposure_s)?,
                "bm3d" => crate::commands::denoise::bm3d_frame(&prof, &raw, p.exposure_s)?,
                other => Pipeline { model: &models[other].0, profile: &prof, tiling: Default::default(), ensemble: models[other].1, device: emccd_nn::device() }
                    .denoise_raw(&raw, p.exposure_s)?,
            };
            scores.push(Score {
                method: m.clone(),
                scene: p.scene.clone(),
                photons: p.photons,
                psnr_db: emccd_eval::psnr(&out, &truth, peak),
                psnr_paper_db: emccd_eval::psnr(&out, &truth, 65535.0),
                ssim: emccd_eval::ssim(&out, &truth, w, h, peak, Default::default()),
            });
            outputs.push((m.clone(), out));
            pb.inc(1);
        }
        if let Some(o) = &a.out {
            write_panel(o, p, w, h, &outputs, &truth, peak)?;
        }
    }
    pb.finish_and_clear();
    let mut summaries = Vec::new();
    let levels: Vec<f64> = {
        let mut v: Vec<f64> = pf.pair.iter().map(|p| p.photons).collect();
        v.sort_by(f64::total_cmp);
        v.dedup();
        v
    };
    for m in &a.methods {
        for lvl in std::iter::once(None).chain(levels.iter().map(|&l| Some(l))) {
            let s: Vec<&Score> = scores.iter().filter(|s| &s.method == m && lvl.is_none_or(|l| s.photons == l)).collect();
            let n = s.len().max(1) as f64;
            let ratio = lvl.and_then(|l| pf.pair.iter().find(|p| p.photons == l).and_then(|p| p.exposure_ratio));
            summaries.push(Summary {
                method: m.clone(),
                photons: lvl,
                exposure_ratio: ratio,
                pairs: s.len(),
                psnr_db: s.iter().map(|x| x.psnr_db).sum::<f64>() / n,
                psnr_paper_db: s.iter().map(|x| x.psnr_paper_db).sum::<f64>() / n,
                ssim: s.iter().map(|x| x.ssim).sum::<f64>() / n,
            });
        }
    }
    let v = serde_json::json!({
        "psnr_data_range": "ground-truth peak per pair; psnr_paper_db: images / 65535, range 1 (the paper's convention)",
        "lpips": "not computed: its network weights cannot be obtained offline",
        "summary": summaries,
        "pairs": scores,
    });
    if let Some(o) = &a.out {
        emccd_io::write_atomic(o.join("results.json"), serde_json::to_string_pretty(&v)?.as_bytes())?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("PSNR data range: the ground truth's peak; \"paper\": images / 65535 with range 1. LPIPS: not computed (no weights offline).\n");
        println!("| method | photons | pairs | PSNR (dB) | PSNR paper conv. (dB) | SSIM |");
        println!("|---|---:|---:|---:|---:|---:|");
        for s in &summaries {
            let l = match (s.photons, s.exposure_ratio) {
                (None, _) => "all".to_string(),
                (Some(p), Some(r)) => format!("{p:.4} (ratio {r})"),
                (Some(p), None) => format!("{p}"),
            };
            println!("| {} | {l} | {} | {:.2} | {:.2} | {:.4} |", s.method, s.pairs, s.psnr_db, s.psnr_paper_db, s.ssim);
        }
    }
    if let Some(o) = &a.out {
        let mut csv = String::from("method,scene,photons,psnr_db,psnr_paper_db,ssim\n");
        for s in &scores {
            let _ = writeln!(csv, "{},{},{},{:.4},{:.4},{:.6}", s.method, s.scene, s.photons, s.psnr_db, s.psnr_paper_db, s.ssim);
        }
        emccd_io::write_atomic(o.join("results.csv"), csv.as_bytes())?;
    }
    Ok(())
}

/// A 256² crop (the frame's centre) of input | each method | ground truth, side by side.
fn write_panel(dir: &Path, p: &PairEntry, w: usize, h: usize, outs: &[(String, Vec<f32>)], truth: &[f32], peak: f64) -> Result<()> {
    let c = 256.min(w).min(h);
    let (x0, y0) = ((w - c) / 2, (h - c) / 2);
    let panels: Vec<&[f32]> = outs.iter().map(|o| o.1.as_slice()).chain(std::iter::once(truth)).collect();
    let n = panels.len();
    let mut img = vec![0f32; n * c * c];
    for (k, src) in panels.iter().enumerate() {
        for y in 0..c {
            for x in 0..c {
                img[y * n * c + k * c + x] = src[(y0 + y) * w + x0 + x];
            }
        }
    }
    let stem = Path::new(&p.noisy).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    emccd_io::write_png_preview(dir.join(format!("{stem}.png")), n * c, c, &img, 0.0, peak as f32)?;
    Ok(())
}
