//! `emccd bench`: synthesis throughput on 512² frames, against emccd-detect where installed.

use anyhow::Result;
use emccd_camera::VirtualCamera;

/// Benchmarks. By default: synthesis throughput in Mpix/s on 512×512 frames of the default
/// camera, and the same frames through the Python `emccd-detect` package
/// (EMCCDDetect.sim_sub_frame) where it is installed, printing the ratio. --calibration,
/// --characterize, --denoise, --movie, --count, --bm3d and --archive measure the other stages instead.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Frames per measurement (after one warm-up frame).
    #[arg(long, default_value_t = 20)]
    pub frames: usize,
    /// Mean photoelectrons per pixel of the test frame.
    #[arg(long, default_value_t = 20.0)]
    pub electrons: f64,
    /// Skip the emccd-detect comparison.
    #[arg(long)]
    pub no_python: bool,
    /// Instead, measure calibration streaming: per-pixel mean/variance over a generated stack of
    /// this many 512×512 16-bit frames (read from the page cache), with the peak memory.
    #[arg(long, value_name = "FRAMES")]
    pub calibration: Option<usize>,
    /// Instead, measure denoising models (comma-separated files, or `default`, `microscopy`, `lowlight`;
    /// `MODEL@8` = averaged over 8 flips/transposes): seconds
    /// per 512×512 frame, and PSNR on virtual-camera test pairs (--scenes at 20 and 200 photons,
    /// 10 ms) beside the input's and BM3D's (with the same VST).
    #[arg(long, value_delimiter = ',', value_name = "MODELS")]
    pub denoise: Vec<String>,
    /// Instead, measure temporal denoising: this many frames of a scene (the first of
    /// --scenes) drifting across the virtual camera (1 px right per frame, 1 px down every
    /// second frame), at 20 and 200 photons at its peak, denoised frame by frame by BM3D + GAT
    /// and by the `lowlight` network, by `--method temporal` and by `--method temporal-net`:
    /// PSNR over the movie, seconds per frame, the classical method's time over BM3D's and the
    /// temporal network's over the single-frame network's.
    #[arg(long, value_name = "FRAMES")]
    pub movie: Option<usize>,
    /// Instead, measure photon counting: this many 512² frames of the virtual camera at 0.1
    /// photo-electrons per pixel, held in memory, preprocessed and counted as `emccd count` does
    /// (automatic threshold), beside the analog mean of the same frames (the reference) and the
    /// preprocessing alone: megapixels per second.
    #[arg(long, value_name = "FRAMES")]
    pub count: Option<usize>,
    /// Instead, measure the characterization a command without --profile makes: this many
    /// frames of the --profile camera (512² for the default) at 1 e⁻ per pixel in the mean
    /// (a dim background and bright patches), beside one pass over the same values (each
    /// pixel's mean), and the numbers found beside the camera's.
    #[arg(long, value_name = "FRAMES")]
    pub characterize: Option<usize>,
    /// With --denoise, --movie, --count or --characterize: the virtual camera's truth profile, also used to
    /// denoise and count.
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// With --denoise or --movie: test scenes (files or directories) the camera's size;
    /// default: the six microscopy fields in DATA/clean/microscopy/fmd-confocal-bpae.
    #[arg(long, num_args = 1..)]
    pub scenes: Vec<std::path::PathBuf>,
    /// Instead, validate BM3D on BSD68 with additive Gaussian noise of these σ (8-bit units,
    /// comma-separated), against the published 31.07 / 28.57 / 25.62 dB at σ = 15 / 25 / 50.
    #[arg(long, value_delimiter = ',', value_name = "SIGMAS")]
    pub bm3d: Vec<f64>,
    /// With --bm3d: use only the first N images.
    #[arg(long)]
    pub images: Option<usize>,
    /// The project's data folder (--bm3d reads DATA/clean/natural/BSD68; --denoise's default
    /// scenes are under it too).
    #[arg(long, default_value = "../shared/data")]
    pub data: std::path::PathBuf,
    /// Instead, measure archive-scale streaming: write a BigTIFF raw stack of this many GB
    /// (512×512 u16 frames of the virtual camera) and one of --net-frames frames, run `emccd info`,
    /// `emccd denoise --method none` (to OME-Zarr) and a network denoise of the first
    /// --net-frames frames on each as child processes, and print wall time, throughput and peak
    /// memory (`wait4`'s `ru_maxrss`) of each; the files are removed afterwards.
    #[arg(long, value_name = "GB")]
    pub archive: Option<f64>,
    /// With --archive: where the stacks and outputs are written (needs about 3× the size free).
    #[arg(long, default_value = ".")]
    pub archive_dir: std::path::PathBuf,
    /// With --archive: frames of the network denoise (the first ones of each stack).
    #[arg(long, default_value_t = 1000)]
    pub net_frames: usize,
}

#[cfg(not(unix))]
fn archive_bench(_: f64, _: &std::path::Path, _: usize) -> Result<()> {
    anyhow::bail!("--archive measures child processes with wait4(2): Unix only")
}

#[cfg(unix)]
fn archive_bench(gb: f64, dir: &std::path::Path, net_frames: usize) -> Result<()> {
    use crate::bench::denoise::{Archive, ArchiveEvent};
    let bench = Archive {
        exe: std::env::current_exe()?,
        gb,
        dir: dir.to_path_buf(),
        net_frames,
    };
    let mut pb = None;
    bench.run(&mut |e| match e {
        ArchiveEvent::Writing(frames) => {
            if let Some(done) = pb.replace(crate::common::progress(frames as u64, "writing")) {
                done.finish_and_clear();
            }
        }
        ArchiveEvent::Frame => pb.iter().for_each(|pb| pb.inc(1)),
        ArchiveEvent::Stacks(s) => {
            pb.take().iter().for_each(|pb| pb.finish_and_clear());
            println!("{s}");
        }
        ArchiveEvent::Row(r) => println!("{r}"),
    })?;
    println!(
        "({} CPU threads; the stacks and outputs were in {} and are removed)",
        rayon::current_num_threads(),
        dir.display()
    );
    Ok(())
}

/// `data/sub`, or an error that says how to point --data at the project's data.
fn data_folder(data: &std::path::Path, sub: &str) -> Result<std::path::PathBuf> {
    let dir = data.join(sub);
    if !dir.is_dir() {
        anyhow::bail!(
            "{}: no such folder; --data names the project's data folder (../shared/data from the repository root)",
            dir.display()
        );
    }
    Ok(dir)
}

fn bm3d_bench(sigmas: &[f64], limit: Option<usize>, data: &std::path::Path) -> Result<()> {
    let mut scenes = emccd_io::image_files(&[data_folder(data, "clean/natural/BSD68")?])?;
    if let Some(n) = limit {
        scenes.truncate(n);
    }
    println!(
        "BM3D on BSD68 ({} images), additive Gaussian noise, PSNR for 8-bit range",
        scenes.len()
    );
    println!("{}", crate::bench::bsd68::Bsd68Row::header());
    let images = scenes
        .iter()
        .map(|sc| emccd_io::Image::read_scene(sc))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    for &sigma in sigmas {
        println!("{}", crate::bench::bsd68::bsd68_row(&images, sigma));
    }
    Ok(())
}

fn denoise_bench(
    model_args: &[String],
    profile_arg: &str,
    scene_args: &[std::path::PathBuf],
    frames: usize,
    data: &std::path::Path,
) -> Result<()> {
    let models = crate::bench::denoise::models(model_args)?;
    let profile = crate::common::load_profile(profile_arg)?;
    let scenes = scenes_or_default(scene_args, data)?;
    println!(
        "camera: {} (slope {:.2} DN, read noise {:.2} DN), 10 ms",
        profile.camera,
        profile.slope()?,
        profile.read_noise_dn()
    );
    println!("{}", crate::bench::denoise::Row::header(models.len()));
    let t = crate::bench::denoise::denoise(
        &profile,
        &scenes,
        &models,
        frames,
        &mut |r| println!("{r}"),
        &mut |skip| eprintln!("{skip}"),
    )?;
    println!("\n{}", t.summary(&models));
    println!(
        "({} CPU threads; network on {})",
        rayon::current_num_threads(),
        emccd_nn::device_name(&crate::common::device())
    );
    Ok(())
}

/// The test scenes: those given, else the six microscopy fields under the data folder.
fn scenes_or_default(
    scene_args: &[std::path::PathBuf],
    data: &std::path::Path,
) -> Result<Vec<std::path::PathBuf>> {
    Ok(if scene_args.is_empty() {
        emccd_io::image_files(&[data_folder(data, "clean/microscopy/fmd-confocal-bpae")?])?
    } else {
        emccd_io::image_files(scene_args)?
    })
}

fn movie_bench(
    frames: usize,
    profile_arg: &str,
    scene_args: &[std::path::PathBuf],
    data: &std::path::Path,
) -> Result<()> {
    let profile = crate::common::load_profile(profile_arg)?;
    let scenes = scenes_or_default(scene_args, data)?;
    let scene = scenes
        .first()
        .ok_or_else(|| anyhow::anyhow!("--scenes: no image found"))?;
    println!(
        "camera: {} ({}×{}, slope {:.2} DN, read noise {:.2} DN), 10 ms; {frames} frames of {} drifting",
        profile.camera,
        profile.width,
        profile.height,
        profile.slope()?,
        profile.read_noise_dn(),
        scene.display()
    );
    println!("{}", crate::bench::movie::MovieRow::header());
    crate::bench::movie::movie(&profile, scene, frames, &mut |r| println!("{r}"))?;
    println!(
        "(time ratio: temporal over BM3D per frame; net: the single-frame `lowlight` network, \
         t-net/net: temporal-net over it; {} CPU threads)",
        rayon::current_num_threads()
    );
    Ok(())
}

fn calibration_bench(frames: usize) -> Result<()> {
    let dir = tempfile::tempdir()?;
    println!("{}", crate::bench::calib::streaming(dir.path(), frames)?);
    Ok(())
}

pub fn run(a: Args) -> Result<()> {
    if let Some(frames) = a.calibration {
        return calibration_bench(frames);
    }
    if !a.denoise.is_empty() {
        return denoise_bench(&a.denoise, &a.profile, &a.scenes, a.frames, &a.data);
    }
    if !a.bm3d.is_empty() {
        return bm3d_bench(&a.bm3d, a.images, &a.data);
    }
    if let Some(frames) = a.count {
        let profile = crate::common::load_profile(&a.profile)?;
        println!(
            "camera: {} ({}×{}), {frames} frames at {} e⁻ per pixel, 10 ms",
            profile.camera,
            profile.width,
            profile.height,
            crate::bench::count::LEVEL
        );
        println!("{}", crate::bench::count::count(&profile, frames)?);
        println!("({} CPU threads)", rayon::current_num_threads());
        return Ok(());
    }
    if let Some(frames) = a.characterize {
        let profile = crate::common::load_profile(&a.profile)?;
        println!(
            "camera: {} ({}×{}), 10 ms",
            profile.camera, profile.width, profile.height
        );
        let t = crate::bench::characterize::characterize(
            &profile,
            frames,
            crate::bench::characterize::LEVEL,
        )?;
        println!("{t}");
        println!("({} CPU threads)", rayon::current_num_threads());
        return Ok(());
    }
    if let Some(frames) = a.movie {
        return movie_bench(frames, &a.profile, &a.scenes, &a.data);
    }
    if let Some(gb) = a.archive {
        return archive_bench(gb, &a.archive_dir, a.net_frames);
    }
    let frames = a.frames.max(1);
    let cam = VirtualCamera::default_camera();
    let t = crate::bench::camera::synthesis(&cam, a.electrons, frames)?;
    println!("{t}");
    if a.no_python {
        return Ok(());
    }
    match crate::bench::camera::emccd_detect(frames.min(10), a.electrons) {
        Ok(t_py) => println!("{}", t.emccd_detect_rows(t_py)),
        Err(why) => {
            println!("\nemccd-detect comparison skipped: {why}  (pip install emccd-detect)")
        }
    }
    Ok(())
}
