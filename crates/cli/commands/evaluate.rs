//! `emccd evaluate`: PSNR and SSIM of denoisers on noisy/clean pairs from the virtual camera.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use emccd_eval::{PairFrames, PairsManifest, Score};
use emccd_nn::registry::Estimator;

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
    /// Methods: `input`, `bm3d` (one BM3D + GAT pass), `ivst` (iterative BM3D), `blend` (`ivst`
    /// and the `lowlight` network averaged, the default of `denoise`), `ivst:λ/b,λ/b,…` (iterative BM3D with these passes: the data's weight and the
    /// bin side, e.g. `ivst:1/3,0.7/2,0.4/1`), `hybrid` (the bundled BM3D-refining network), or
    /// a model file (`default`, `microscopy`, `lowlight` = the bundled networks; a hybrid model file runs as
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

struct Camera {
    dir: PathBuf,
    name: String,
    file: PairsManifest,
    profile: emccd_profile::CameraProfile,
}

/// A folder of pairs with the profile to denoise them with: `--profile`, else the one
/// pairs.toml names, else the bundled default.
fn load_camera(dir: &Path, profile: Option<&str>) -> Result<Camera> {
    let file = PairsManifest::load(dir).map_err(anyhow::Error::msg)?;
    let profile = match (profile, file.profile_arg(dir)) {
        (Some(p), _) => load_profile(p)?,
        (None, Some(p)) => load_profile(&p).with_context(|| {
            format!(
                "the profile {} names",
                dir.join(PairsManifest::FILE).display()
            )
        })?,
        (None, None) => load_profile("default")?,
    };
    Ok(Camera {
        dir: dir.to_path_buf(),
        name: file.camera_name(dir),
        file,
        profile,
    })
}

pub fn run(a: Args) -> Result<()> {
    let cameras = a
        .pairs
        .iter()
        .map(|d| load_camera(d, a.profile.as_deref()))
        .collect::<Result<Vec<_>>>()?;
    let estimators = a
        .methods
        .iter()
        .map(|m| Estimator::parse(m, emccd_nn::registry::load))
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(o) = &a.out {
        std::fs::create_dir_all(o).with_context(|| format!("creating {}", o.display()))?;
    }
    let total: usize = cameras.iter().map(|c| c.file.pair.len()).sum();
    let pb = progress((total * a.methods.len()) as u64, "evaluations");
    let mut scores = Vec::new();
    for cam in &cameras {
        for p in &cam.file.pair {
            let frames = p.read(&cam.dir).map_err(anyhow::Error::msg)?;
            let PairFrames {
                width: w,
                height: h,
                noisy: raw,
                clean: truth,
            } = &frames;
            let (w, h) = (*w, *h);
            let prof = if (w, h) == (cam.profile.width, cam.profile.height) {
                cam.profile.clone()
            } else {
                cam.profile.crop(0, 0, w, h)?
            };
            let peak = emccd_eval::scores::truth_peak(truth);
            let mut outputs: Vec<(String, Vec<f32>)> = Vec::new();
            for est in &estimators {
                let m = est.name();
                let t = std::time::Instant::now();
                let out = est.run(&prof, raw, p.exposure_s)?;
                let seconds = t.elapsed().as_secs_f64();
                scores.push(Score::measure(m, &cam.name, p, &frames, &out, seconds));
                outputs.push((m.to_string(), out));
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
                write_panel(o, &stem, p, w, h, &outputs, truth, peak)?;
            }
        }
    }
    pb.finish_and_clear();
    let camera_names: Vec<String> = cameras.iter().map(|c| c.name.clone()).collect();
    let table = emccd_eval::scores::summarize(&scores, &a.methods, &camera_names);
    let v = serde_json::json!({
        "psnr_data_range": "ground-truth peak per pair; psnr_paper_db: images / 65535, range 1 (the paper's convention)",
        "lpips": "not computed: its network weights cannot be obtained offline",
        "level_unit": table.unit.describe(),
        "summary": table.rows,
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
        print!("{}", table.markdown());
    }
    if let Some(o) = &a.out {
        emccd_io::write_atomic(
            o.join("results.csv"),
            emccd_eval::scores::csv(&scores).as_bytes(),
        )?;
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
    let panels: Vec<&[f32]> = outs
        .iter()
        .map(|o| o.1.as_slice())
        .chain(std::iter::once(truth))
        .collect();
    let n = panels.len();
    let img = emccd_eval::scores::side_by_side(&panels, w, ((w - c) / 2, (h - c) / 2), (c, c));
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
