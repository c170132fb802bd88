//! `emccd simulate calibration|pairs`: the virtual camera.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use emccd_calib::manifest::{Entry, Manifest as CalibrationManifest};
use emccd_camera::acquisition::{
    frame_seed, pair_seed, CalibrationPlan, PairLevel, PlannedStack, Role,
};
use emccd_camera::{PhysicalParams, VirtualCamera};
use emccd_eval::{Pair, PairsManifest};
use emccd_io::{Metadata, SampleFormat, StackWriter};
use emccd_profile::preprocess;

use crate::common::{load_profile, parse_size, progress};

/// Options shared by both simulations: the camera's truth.
#[derive(clap::Args, Debug, Clone)]
pub struct CameraOpts {
    /// Truth profile: a profile directory or `default` (the bundled iXon Ultra 897 model).
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// Simulate only the top-left WIDTHxHEIGHT region of the sensor (e.g. 128x128).
    #[arg(long, value_parser = parse_size)]
    pub crop: Option<(usize, usize)>,
    /// Quantum efficiency.
    #[arg(long, default_value_t = 0.9)]
    pub qe: f64,
    /// Clock-induced charge, e⁻ per pixel per frame.
    #[arg(long, default_value_t = 0.005)]
    pub cic: f64,
    /// Dark current, e⁻ per pixel per second.
    #[arg(long, default_value_t = 0.001)]
    pub dark: f64,
    /// Fraction of hot pixels (dark current `--hot-dark`).
    #[arg(long, default_value_t = 2e-4)]
    pub hot_fraction: f64,
    /// Dark current of hot pixels, e⁻ per pixel per second.
    #[arg(long, default_value_t = 50.0)]
    pub hot_dark: f64,
    /// Random seed (same seed, same files).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

impl CameraOpts {
    /// The truth profile (`--profile`, cut to `--crop`), loaded once per run.
    fn profile(&self) -> Result<emccd_profile::CameraProfile> {
        let p = load_profile(&self.profile)?;
        Ok(match self.crop {
            Some((w, h)) => p.crop(0, 0, w.min(p.width), h.min(p.height))?,
            None => p,
        })
    }

    /// A camera over `profile` (or its top-left `roi`) with the physics flags.
    fn camera(
        &self,
        profile: &emccd_profile::CameraProfile,
        roi: Option<(usize, usize)>,
    ) -> Result<VirtualCamera> {
        let p = match roi {
            Some((w, h)) => profile.crop(0, 0, w, h)?,
            None => profile.clone(),
        };
        let phys = PhysicalParams {
            qe: self.qe,
            dark_e_per_s: self.dark,
            cic_e: self.cic,
            hot_fraction: self.hot_fraction,
            hot_dark_e_per_s: self.hot_dark,
            seed: self.seed ^ 0x5eed,
        };
        Ok(VirtualCamera::new(p, phys)?)
    }
}

/// Run the virtual camera.
#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// Write a calibration acquisition (bias, flat and blooming stacks), its manifest
    /// `calibration.toml`, and the truth (`truth.toml` plus the truth profile in `truth/`).
    Calibration {
        /// Output directory.
        #[arg(short, long)]
        out: PathBuf,
        /// Frames per stack.
        #[arg(long, default_value_t = CalibrationPlan::default().frames)]
        frames: usize,
        /// Bias exposures in seconds (comma-separated).
        #[arg(long, value_delimiter = ',', default_values_t = CalibrationPlan::default().bias_exposures_s)]
        bias_exposures: Vec<f64>,
        /// Flat-field signal levels in DN above bias (comma-separated), at 10 ms.
        #[arg(long, value_delimiter = ',', default_values_t = CalibrationPlan::default().flat_levels_dn)]
        flat_levels: Vec<f64>,
        /// Blooming-frame exposures in seconds (comma-separated).
        #[arg(long, value_delimiter = ',', default_values_t = CalibrationPlan::default().blooming_exposures_s)]
        blooming_exposures: Vec<f64>,
        #[command(flatten)]
        camera: CameraOpts,
    },
    /// Write noisy raw frames of clean scenes with their ground truth (photo-signal in DN above
    /// bias), a `pairs.toml` manifest, and side-by-side previews (preprocessed noisy | truth).
    Pairs {
        /// Clean scenes: PNG/TIFF/FITS files or directories of them.
        #[arg(long, required = true, num_args = 1..)]
        clean: Vec<PathBuf>,
        /// Photon level: expected photons at the scene's brightest value (repeatable).
        #[arg(long, default_values_t = vec![20.0])]
        photons: Vec<f64>,
        /// Exposure time of the noisy frames, seconds.
        #[arg(long, default_value_t = 0.01)]
        exposure_s: f64,
        /// Instead of --photons/--exposure-s: short exposures at these ratios to a long reference
        /// exposure (the paper's 30–1600), each with the reference's photons divided by the ratio.
        #[arg(long, value_delimiter = ',', conflicts_with = "photons")]
        exposure_ratio: Vec<f64>,
        /// With --exposure-ratio: the reference exposure, seconds.
        #[arg(long, default_value_t = 1.6)]
        reference_exposure_s: f64,
        /// With --exposure-ratio: photons at the scene's brightest value in the reference exposure.
        #[arg(long, default_value_t = 16000.0)]
        reference_photons: f64,
        /// Noisy frames per pair (written as one stack).
        #[arg(long, default_value_t = 1)]
        frames: usize,
        /// Also denoise each pair's first frame with this model (a file, or the bundled `default` or `microscopy`):
        /// writes denoised/*.tif, a noisy | denoised | truth preview and the PSNR after.
        #[arg(long, value_name = "MODEL")]
        denoise: Option<String>,
        /// Output directory.
        #[arg(short, long)]
        out: PathBuf,
        #[command(flatten)]
        camera: CameraOpts,
    },
}

pub fn run(c: Cmd) -> Result<()> {
    match c {
        Cmd::Calibration {
            out,
            frames,
            bias_exposures,
            flat_levels,
            blooming_exposures,
            camera,
        } => calibration(
            &out,
            &CalibrationPlan {
                frames,
                bias_exposures_s: bias_exposures,
                flat_levels_dn: flat_levels,
                blooming_exposures_s: blooming_exposures,
                ..CalibrationPlan::default()
            },
            &camera,
        ),
        Cmd::Pairs {
            clean,
            photons,
            exposure_s,
            exposure_ratio,
            reference_exposure_s,
            reference_photons,
            frames,
            denoise,
            out,
            camera,
        } => {
            check_positive("photons", &photons)?;
            check_positive("exposure-s", &[exposure_s])?;
            check_positive("exposure-ratio", &exposure_ratio)?;
            check_positive("reference-exposure-s", &[reference_exposure_s])?;
            check_positive("reference-photons", &[reference_photons])?;
            let levels: Vec<PairLevel> = if exposure_ratio.is_empty() {
                photons
                    .iter()
                    .map(|&p| PairLevel {
                        exposure_s,
                        photons: p,
                        ratio: None,
                    })
                    .collect()
            } else {
                exposure_ratio
                    .iter()
                    .map(|&r| PairLevel::from_ratio(reference_exposure_s, reference_photons, r))
                    .collect()
            };
            pairs(&clean, &levels, frames, denoise.as_deref(), &out, &camera)
        }
    }
}

fn check_positive(name: &str, v: &[f64]) -> Result<()> {
    if let Some(x) = v.iter().find(|x| !(x.is_finite() && **x > 0.0)) {
        bail!("--{name}: every value must be a positive number, got {x}");
    }
    Ok(())
}

/// Writes one planned stack as 16-bit TIFF, frame by frame.
fn write_stack(
    out: &Path,
    cam: &VirtualCamera,
    stack: &PlannedStack,
    frames: usize,
    pb: &indicatif::ProgressBar,
) -> Result<()> {
    let path = out.join(&stack.file);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let e = cam.exposure(stack.exposure_s);
    let mut w = StackWriter::create(
        &path,
        cam.width(),
        cam.height(),
        SampleFormat::U16,
        Some(frames),
    )?;
    w.set_metadata(&Metadata {
        exposure_s: Some(stack.exposure_s),
        em_gain: Some(cam.em_gain),
        camera_model: Some("virtual-897".into()),
        ..Default::default()
    });
    let mut buf = vec![0f32; cam.profile.len()];
    for k in 0..frames {
        e.frame(&stack.photons, frame_seed(stack.seed, k), &mut buf);
        w.write_frame(&buf)?;
        pb.inc(1);
    }
    w.finish()?;
    Ok(())
}

fn calibration(out: &Path, plan: &CalibrationPlan, opts: &CameraOpts) -> Result<()> {
    // The plan's own check, which names each setting as its flag does.
    plan.check().map_err(|e| anyhow::anyhow!("--{e}"))?;
    let cam = opts.camera(&opts.profile()?, None)?;
    let stacks = plan.stacks(&cam, opts.seed)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let pb = progress(plan.total_frames(), "frames");
    let mut manifest = CalibrationManifest {
        camera: "virtual-897".into(),
        em_gain: cam.em_gain,
        ..Default::default()
    };
    for stack in &stacks {
        write_stack(out, &cam, stack, plan.frames, &pb)?;
        let entry = Entry {
            file: stack.file.clone().into(),
            exposure_s: Some(stack.exposure_s),
        };
        match stack.role {
            Role::Bias => manifest.bias.push(entry),
            Role::Flat => manifest.flat.push(entry),
            Role::Blooming => manifest.blooming.push(entry),
        }
    }
    pb.finish_and_clear();
    emccd_io::write_atomic(
        out.join("calibration.toml"),
        manifest.to_toml("`emccd simulate calibration`").as_bytes(),
    )?;
    cam.profile
        .save(out.join("truth"))
        .context("writing the truth profile")?;
    emccd_io::write_atomic(out.join("truth.toml"), plan.truth_toml(&cam)?.as_bytes())?;
    eprintln!(
        "wrote {} bias, {} flat and {} blooming stacks of {} frames ({}×{}) to {}",
        plan.bias_exposures_s.len(),
        plan.flat_levels_dn.len(),
        plan.blooming_exposures_s.len(),
        plan.frames,
        cam.width(),
        cam.height(),
        out.display()
    );
    Ok(())
}

fn pairs(
    clean: &[PathBuf],
    levels: &[PairLevel],
    frames: usize,
    denoise: Option<&str>,
    out: &Path,
    opts: &CameraOpts,
) -> Result<()> {
    let model = denoise.map(emccd_nn::registry::load).transpose()?;
    if frames == 0 {
        bail!("--frames must be at least 1");
    }
    let scenes = emccd_io::image_files(clean)?;
    let dirs: &[&str] = if model.is_some() {
        &["noisy", "clean", "preview", "denoised"]
    } else {
        &["noisy", "clean", "preview"]
    };
    check_outputs(&scenes, levels, dirs, out)?;
    // Folders this run creates hold only what it writes: on failure they are removed again, so
    // a failed run leaves nothing behind (folders that existed before are left alone).
    let mut created: Vec<PathBuf> = Vec::new();
    for dir in std::iter::once(out.to_path_buf()).chain(dirs.iter().map(|d| out.join(d))) {
        if !dir.exists() {
            created.push(dir.clone());
        }
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    // Stopped by Ctrl-C, the run's own folders go too if nothing was finished in them.
    for d in &created {
        emccd_io::track_new_dir(d);
    }
    let r = write_pairs(&scenes, levels, frames, model.as_ref(), out, opts);
    emccd_io::untrack_new_dirs();
    if r.is_err() {
        // `out` first if this run made it: everything under it is then this run's.
        for d in &created {
            let _ = std::fs::remove_dir_all(d);
        }
    }
    r
}

/// The stem of scene `si`'s output names.
fn scene_stem(si: usize, scene: &Path) -> String {
    scene
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| format!("scene{si}"))
}

/// Refuses, before anything is written, a run that would overwrite its own outputs (two scenes
/// with one file stem, from different folders) or an input scene (one that lies where an
/// output goes, which would be replaced before it is read).
fn check_outputs(
    scenes: &[PathBuf],
    levels: &[PairLevel],
    dirs: &[&str],
    out: &Path,
) -> Result<()> {
    let stems: Vec<String> = scenes
        .iter()
        .enumerate()
        .map(|(i, s)| scene_stem(i, s))
        .collect();
    let mut by_stem: std::collections::HashMap<&str, &Path> = Default::default();
    for (stem, scene) in stems.iter().zip(scenes) {
        if let Some(other) = by_stem.insert(stem, scene) {
            bail!(
                "scenes {} and {} have the same name, so their pairs would overwrite each other; rename one",
                other.display(),
                scene.display()
            );
        }
    }
    let inputs: std::collections::HashSet<emccd_io::FileId> =
        scenes.iter().map(|p| emccd_io::FileId::of(p)).collect();
    for stem in &stems {
        for lv in levels {
            let name = lv.pair_name(stem);
            for d in dirs {
                let ext = if *d == "preview" { "png" } else { "tif" };
                let o = out.join(d).join(format!("{name}.{ext}"));
                if inputs.contains(&emccd_io::FileId::of(&o)) {
                    bail!(
                        "{}: an output of this run is an input scene; choose another -o, inputs are never overwritten",
                        o.display()
                    );
                }
            }
        }
    }
    Ok(())
}

fn write_pairs(
    scenes: &[PathBuf],
    levels: &[PairLevel],
    frames: usize,
    model: Option<&emccd_nn::Denoiser>,
    out: &Path,
    opts: &CameraOpts,
) -> Result<()> {
    let truth = opts.profile()?;
    let full = opts.camera(&truth, None)?;
    let pb = progress((scenes.len() * levels.len()) as u64, "pairs");
    let mut manifest = PairsManifest {
        camera: Some("virtual-897".into()),
        profile: Some(opts.profile.clone()),
        em_gain: Some(full.em_gain),
        k_dn_per_e: Some(full.k_dn()),
        qe: Some(full.physics.qe),
        note: Some("noisy: raw 16-bit frames; clean: photo-signal in DN above bias (K·QE·photons), float32. \
               psnr_input_db: preprocessed noisy frame (eq. 4 with the true FPN and blooming) against clean, \
               data range = the clean frame's peak."
            .into()),
        pair: vec![],
    };
    for (si, scene) in scenes.iter().enumerate() {
        let img = emccd_io::Image::read_scene(scene)
            .with_context(|| format!("reading scene {}", scene.display()))?;
        let (w, h) = (img.width.min(full.width()), img.height.min(full.height()));
        let cam = if (w, h) == (full.width(), full.height()) {
            full.clone()
        } else {
            opts.camera(&truth, Some((w, h)))?
        };
        let img = img.center_crop(w, h).data;
        let stem = scene_stem(si, scene);
        for (pi, lv) in levels.iter().enumerate() {
            let (level, exposure_s) = (lv.photons, lv.exposure_s);
            let pair = cam.test_pair(&img, level, exposure_s, pair_seed(opts.seed, si, pi));
            let (e, truth) = (&pair.exposure, &pair.truth);
            let name = lv.pair_name(&stem);
            let noisy_rel = format!("noisy/{name}.tif");
            let clean_rel = format!("clean/{name}.tif");
            let preview_rel = format!("preview/{name}.png");
            let mut wr =
                StackWriter::create(out.join(&noisy_rel), w, h, SampleFormat::U16, Some(frames))?;
            wr.set_metadata(&Metadata {
                exposure_s: Some(exposure_s),
                em_gain: Some(cam.em_gain),
                camera_model: Some("virtual-897".into()),
                ..Default::default()
            });
            let mut raw = vec![0f32; w * h];
            let mut first = Vec::new();
            for k in 0..frames {
                pair.frame(k, &mut raw);
                wr.write_frame(&raw)?;
                if k == 0 {
                    first = raw.clone();
                }
            }
            wr.finish()?;
            let mut cw =
                StackWriter::create(out.join(&clean_rel), w, h, SampleFormat::F32, Some(1))?;
            cw.set_metadata(&Metadata {
                exposure_s: Some(exposure_s),
                ..Default::default()
            });
            cw.write_frame(truth)?;
            cw.finish()?;
            let raw_first = first.clone();
            // Preview and input PSNR use the preprocessed frame (true FPN and blooming removed).
            preprocess(&mut first, w, e.blooming_x, &e.fpn);
            let peak = truth.iter().copied().fold(0f32, f32::max).max(1.0);
            let p_in = emccd_eval::psnr(&first, truth, peak as f64);
            let mut panels: Vec<&[f32]> = vec![&first];
            let mut denoised_out = None;
            let den;
            if let Some(m) = &model {
                // The profile the camera was built from, as a user's calibrated profile.
                let prof = cam.profile.clone();
                let pipe = emccd_nn::pipeline::Pipeline {
                    model: m,
                    profile: &prof,
                    tiling: Default::default(),
                    ensemble: 1,
                    device: emccd_nn::device(),
                };
                den = pipe.denoise_raw(&raw_first, exposure_s)?;
                let rel = format!("denoised/{name}.tif");
                let mut dw = StackWriter::create(out.join(&rel), w, h, SampleFormat::F32, Some(1))?;
                dw.write_frame(&den)?;
                dw.finish()?;
                denoised_out = Some((
                    rel,
                    (emccd_eval::psnr(&den, truth, peak as f64) * 100.0).round() / 100.0,
                ));
                panels.push(&den);
            }
            panels.push(truth);
            let np = panels.len();
            let side = emccd_eval::scores::side_by_side(&panels, w, (0, 0), (w, h));
            emccd_io::write_png_preview(out.join(&preview_rel), np * w, h, &side, 0.0, peak)?;
            manifest.pair.push(Pair {
                scene: scene.display().to_string(),
                noisy: noisy_rel,
                clean: clean_rel,
                preview: Some(preview_rel),
                exposure_s,
                photons: level,
                exposure_ratio: lv.ratio,
                mean_electrons: None,
                frames: Some(frames),
                width: Some(w),
                height: Some(h),
                psnr_input_db: Some((p_in * 100.0).round() / 100.0),
                denoised: denoised_out.as_ref().map(|d| d.0.clone()),
                psnr_denoised_db: denoised_out.map(|d| d.1),
            });
            pb.inc(1);
        }
    }
    pb.finish_and_clear();
    emccd_io::write_atomic(
        out.join(PairsManifest::FILE),
        manifest.to_toml("`emccd simulate pairs`").as_bytes(),
    )?;
    println!(
        "{:<40} {:>9} {:>12} {:>14}",
        "pair", "photons", "PSNR in (dB)", "denoised (dB)"
    );
    for p in &manifest.pair {
        let d = p
            .psnr_denoised_db
            .map_or("–".to_string(), |v| format!("{v:.2}"));
        println!(
            "{:<40} {:>9} {:>12.2} {:>14}",
            p.noisy,
            p.photons,
            p.psnr_input_db.unwrap_or(f64::NAN),
            d
        );
    }
    let what = if model.is_some() {
        "preprocessed noisy | denoised | ground truth"
    } else {
        "preprocessed noisy | ground truth"
    };
    eprintln!(
        "wrote {} pairs to {} (previews: {what})",
        manifest.pair.len(),
        out.display()
    );
    Ok(())
}
