//! `emccd simulate calibration|pairs`: the virtual camera.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use emccd_camera::acquisition::{CalibrationPlan, PairLevel};
use emccd_camera::{PhysicalParams, VirtualCamera};
use emccd_denoise::Estimator;
use emccd_eval::virtual_pairs::{write_pairs, PairsPlan};

use crate::common::{load_profile, progress, refuse_replacing};
use emccd_profile::Roi;

/// The name acquisitions and pairs of the virtual camera record as their camera's.
const CAMERA: &str = "virtual-897";

/// Options shared by both simulations: the camera's truth.
#[derive(clap::Args, Debug, Clone)]
pub struct CameraOpts {
    /// Truth profile: a profile directory or `default` (the bundled iXon Ultra 897 model).
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// Simulate only this region of the sensor: WIDTHxHEIGHT at its top-left corner (e.g.
    /// 128x128), or X,Y,WIDTHxHEIGHT; a size past the sensor's edge is cut at it.
    #[arg(long, value_name = "[X,Y,]WxH")]
    pub crop: Option<Roi>,
    #[command(flatten)]
    pub physics: PhysicalParams,
    /// Random seed (same seed, same files).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

impl CameraOpts {
    /// The truth profile (`--profile`, cut to `--crop`), loaded once per run.
    fn profile(&self) -> Result<emccd_profile::CameraProfile> {
        let p = load_profile(&self.profile)?;
        Ok(match self.crop {
            Some(r) => p.crop_clamped(r)?,
            None => p,
        })
    }

    /// The camera: the truth profile with the physics flags.
    fn camera(&self) -> Result<VirtualCamera> {
        let phys = PhysicalParams {
            seed: PhysicalParams::seeded(self.seed).seed,
            ..self.physics.clone()
        };
        Ok(VirtualCamera::new(self.profile()?, phys)?)
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
        /// Replace an acquisition already in the output directory.
        #[arg(long)]
        force: bool,
        #[command(flatten)]
        plan: CalibrationPlan,
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
        /// Also denoise each pair's first frame with this model (a file, or a bundled name:
        /// `default`, `microscopy`, `lowlight`, `hybrid`; `MODEL@K` for a K-orientation
        /// self-ensemble) or method (`bm3d`, `ivst`, `blend`, as `evaluate --method` takes them):
        /// writes denoised/*.tif, a noisy | denoised | truth preview and the PSNR after.
        #[arg(long, value_name = "MODEL")]
        denoise: Option<String>,
        /// Output directory.
        #[arg(short, long)]
        out: PathBuf,
        /// Replace pairs already in the output directory.
        #[arg(long)]
        force: bool,
        #[command(flatten)]
        camera: CameraOpts,
    },
}

pub fn run(c: Cmd) -> Result<()> {
    match c {
        Cmd::Calibration {
            out,
            force,
            plan,
            camera,
        } => {
            refuse_replacing(&out, "calibration.toml", "a calibration acquisition", force)?;
            calibration(&out, &plan, &camera)
        }
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
            force,
            camera,
        } => {
            refuse_replacing(&out, "pairs.toml", "test pairs", force)?;
            let levels = PairLevel::levels(
                &photons,
                exposure_s,
                &exposure_ratio,
                reference_exposure_s,
                reference_photons,
            )
            .map_err(|e| anyhow::anyhow!("--{e}"))?;
            pairs(&clean, &levels, frames, denoise.as_deref(), &out, &camera)
        }
    }
}

fn calibration(out: &Path, plan: &CalibrationPlan, opts: &CameraOpts) -> Result<()> {
    // The plan's own check, which names each setting as its flag does.
    plan.check().map_err(|e| anyhow::anyhow!("--{e}"))?;
    let cam = opts.camera()?;
    // Recorded in full (stacks, manifest, truth) beside `out` and moved there at the end: a run
    // that fails or is stopped leaves `out` as it was, an acquisition it replaces (`--force`)
    // included.
    let stage = emccd_io::StagedDir::beside(out)?;
    let pb = progress(plan.total_frames(), "frames");
    plan.record(
        &cam,
        opts.seed,
        stage.path(),
        CAMERA,
        "`emccd simulate calibration`",
        || pb.inc(1),
    )?;
    plan.write_truth(&cam, stage.path())?;
    pb.finish_and_clear();
    stage.place()?;
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
    let est = denoise
        .map(|m| Estimator::parse(m, crate::common::load_model))
        .transpose()?;
    if frames == 0 {
        bail!("--frames must be at least 1");
    }
    let scenes = emccd_io::image_files(clean)?;
    let camera = opts.camera()?;
    let contender = est.as_ref().map(Estimator::contender);
    let plan = PairsPlan {
        scenes: &scenes,
        levels,
        frames,
        seed: opts.seed,
        camera_name: CAMERA,
        profile: &opts.profile,
    };
    let pb = progress((scenes.len() * levels.len()) as u64, "pairs");
    let manifest = write_pairs(
        out,
        &plan,
        &camera,
        contender.as_ref().map(|c| &*c.run),
        || pb.inc(1),
    )?;
    pb.finish_and_clear();
    println!("{}", manifest.psnr_table());
    let what = if est.is_some() {
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
