//! The denoising benchmark of `emccd bench --denoise`: networks beside the input and BM3D + GAT
//! on virtual-camera test pairs (each scene at 20 and 200 photons at its peak, 10 ms), with
//! seconds per frame. Each method's time includes the preprocessing it runs first.

use std::path::PathBuf;
use std::time::Instant;

use emccd_camera::VirtualCamera;
use emccd_profile::CameraProfile;

use crate::registry::{load, Estimator};
use crate::{Error, Result};

/// Photons at a scene's peak of the benchmark's two pairs per scene.
pub const PHOTONS: [f64; 2] = [20.0, 200.0];

/// One test pair's PSNRs.
#[derive(Clone, Debug)]
pub struct Row {
    /// The scene's file name.
    pub scene: String,
    /// Photons at the scene's peak.
    pub photons: f64,
    /// The preprocessed input's PSNR, dB.
    pub input_db: f64,
    /// BM3D + GAT's, dB.
    pub bm3d_db: f64,
    /// Each model's, in the order given.
    pub model_db: Vec<f64>,
}

/// Means over every pair.
#[derive(Clone, Debug, Default)]
pub struct Totals {
    /// Pairs scored.
    pub pairs: usize,
    /// Mean input PSNR, dB.
    pub input_db: f64,
    /// Mean BM3D + GAT PSNR, dB.
    pub bm3d_db: f64,
    /// BM3D's mean seconds per frame.
    pub bm3d_s: f64,
    /// Each model's mean PSNR, dB.
    pub model_db: Vec<f64>,
    /// Each model's mean seconds per frame over the timed frames.
    pub model_s: Vec<f64>,
}

/// The models to benchmark: each argument a model file or bundled name (`MODEL@8` for the
/// self-ensemble); anything that runs no network (`bm3d`, `ivst`, …) is refused.
pub fn models(args: &[String]) -> Result<Vec<Estimator>> {
    args.iter()
        .map(|m| {
            let est = Estimator::parse(m, load)?;
            if est.model().is_none() {
                return Err(Error::Model(format!(
                    "--denoise {m}: not a model (a file, or `default`, `microscopy`, `lowlight`; `MODEL@8` for the self-ensemble)"
                )));
            }
            Ok(est)
        })
        .collect()
}

/// Runs the benchmark: the virtual camera of `profile` (also used to denoise) records each of
/// `scenes` (the camera's size; others are passed to `skipped` and left out) at [`PHOTONS`];
/// `on_row` gets each pair's PSNRs as they come. Models are timed on their first
/// `timed_frames` frames (at least one).
pub fn denoise(
    profile: &CameraProfile,
    scenes: &[PathBuf],
    models: &[Estimator],
    timed_frames: usize,
    on_row: &mut dyn FnMut(&Row),
    skipped: &mut dyn FnMut(String),
) -> Result<Totals> {
    let bm3d = Estimator::parse("bm3d", load)?;
    let cam = VirtualCamera::new(profile.clone(), Default::default())?;
    let e = cam.exposure(0.01);
    let k = models.len();
    let mut t = Totals {
        model_db: vec![0.0; k],
        model_s: vec![0.0; k],
        ..Totals::default()
    };
    let mut timed = vec![0usize; k];
    for (si, sc) in scenes.iter().enumerate() {
        let emccd_io::Image {
            width: w,
            height: h,
            data: img,
        } = emccd_io::Image::read_scene(sc)?;
        if (w, h) != (cam.width(), cam.height()) {
            skipped(format!(
                "skipping {}: {w}×{h}, the camera is {}×{}",
                sc.display(),
                cam.width(),
                cam.height()
            ));
            continue;
        }
        for (li, &level) in PHOTONS.iter().enumerate() {
            let phot: Vec<f32> = img.iter().map(|&v| (v as f64 * level) as f32).collect();
            let truth = e.ground_truth(&phot);
            let mut raw = vec![0f32; w * h];
            e.frame(&phot, 1000 + (si * 2 + li) as u64, &mut raw);
            let peak = emccd_eval::scores::truth_peak(&truth);
            let pre = crate::pipeline::preprocess(profile, &raw, 0.01)?;
            let clock = Instant::now();
            let bm = bm3d.run(profile, &raw, 0.01)?;
            t.bm3d_s += clock.elapsed().as_secs_f64();
            let mut row = Row {
                scene: sc
                    .file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned(),
                photons: level,
                input_db: emccd_eval::psnr(&pre, &truth, peak),
                bm3d_db: emccd_eval::psnr(&bm, &truth, peak),
                model_db: Vec::with_capacity(k),
            };
            for (mi, est) in models.iter().enumerate() {
                let clock = Instant::now();
                let den = est.run(profile, &raw, 0.01)?;
                if timed[mi] < timed_frames.max(1) {
                    t.model_s[mi] += clock.elapsed().as_secs_f64();
                    timed[mi] += 1;
                }
                let db = emccd_eval::psnr(&den, &truth, peak);
                t.model_db[mi] += db;
                row.model_db.push(db);
            }
            on_row(&row);
            t.input_db += row.input_db;
            t.bm3d_db += row.bm3d_db;
            t.pairs += 1;
        }
    }
    let n = t.pairs.max(1) as f64;
    t.input_db /= n;
    t.bm3d_db /= n;
    t.bm3d_s /= n;
    for (mi, db) in t.model_db.iter_mut().enumerate() {
        *db /= n;
        t.model_s[mi] /= timed[mi].max(1) as f64;
    }
    Ok(t)
}
