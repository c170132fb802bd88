//! `emccd bench`: synthesis throughput on 512² frames, against emccd-detect where installed.

use anyhow::Result;
use emccd_camera::VirtualCamera;

/// Benchmarks. By default: synthesis throughput in Mpix/s on 512×512 frames of the default
/// camera, and the same frames through the Python `emccd-detect` package
/// (EMCCDDetect.sim_sub_frame) where it is installed, printing the ratio. --calibration,
/// --denoise and --bm3d measure the other stages instead.
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
    /// With --denoise: the virtual camera's truth profile, also used to denoise.
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// With --denoise: test scenes (files or directories) the camera's size; default: the six
    /// microscopy fields in DATA/clean/microscopy/fmd-confocal-bpae.
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
    use emccd_nn::bench::{Archive, ArchiveEvent};
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
        ArchiveEvent::Frame => {
            if let Some(pb) = &pb {
                pb.inc(1);
            }
        }
        ArchiveEvent::Stacks(s) => {
            if let Some(pb) = pb.take() {
                pb.finish_and_clear();
            }
            let side = emccd_camera::bench::ARCHIVE_SIDE;
            println!(
                "archive streaming: BigTIFF stacks of {side}×{side} u16 frames: {} frames ({:.0} MB) and {} frames ({:.2} GB, written in {:.0} s, {:.0} MB/s)",
                s.short_frames,
                s.short_mb(),
                s.long_frames,
                s.long_bytes / 1e9,
                s.write_s,
                s.long_bytes / 1e6 / s.write_s
            );
            println!(
                "{:<36} {:>7} {:>9} {:>9} {:>9} {:>9}",
                "command", "stack", "frames", "s", "frames/s", "peak MiB"
            );
        }
        ArchiveEvent::Row(r) => println!(
            "{:<36} {:>7} {:>9} {:>9.1} {:>9.1} {:>9.1}",
            r.command,
            r.stack,
            r.frames,
            r.seconds,
            r.frames as f64 / r.seconds,
            r.peak_rss_mib
        ),
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
    println!(
        "{:>6} {:>10} {:>10} {:>10} {:>12}",
        "σ", "noisy dB", "BM3D dB", "published", "s/image"
    );
    let images = scenes
        .iter()
        .map(|sc| emccd_io::Image::read_scene(sc))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    for &sigma in sigmas {
        let r = emccd_eval::bm3d::bsd68_row(&images, sigma);
        let p = r.published_db.map_or("–".into(), |v| format!("{v:.2}"));
        println!(
            "{:>6} {:>10.2} {:>10.2} {:>10} {:>12.2}",
            r.sigma, r.noisy_db, r.denoised_db, p, r.seconds
        );
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
    let models = emccd_nn::bench::models(model_args)?;
    let profile = crate::common::load_profile(profile_arg)?;
    let scenes = if scene_args.is_empty() {
        emccd_io::image_files(&[data_folder(data, "clean/microscopy/fmd-confocal-bpae")?])?
    } else {
        emccd_io::image_files(scene_args)?
    };
    println!(
        "camera: {} (slope {:.2} DN, read noise {:.2} DN), 10 ms",
        profile.camera,
        profile.slope()?,
        profile.read_noise_dn()
    );
    print!(
        "{:<28} {:>8} {:>10} {:>10}",
        "scene", "photons", "input dB", "BM3D dB"
    );
    for i in 0..models.len() {
        print!(" {:>10}", format!("model {}", i + 1));
    }
    println!();
    let t = emccd_nn::bench::denoise(
        &profile,
        &scenes,
        &models,
        frames,
        &mut |r| {
            print!(
                "{:<28} {:>8} {:>10.2} {:>10.2}",
                r.scene, r.photons, r.input_db, r.bm3d_db
            );
            for b in &r.model_db {
                print!(" {b:>10.2}");
            }
            println!();
        },
        &mut |skip| eprintln!("{skip}"),
    )?;
    println!();
    println!(
        "mean PSNR over {} pairs: input {:.2} dB, BM3D (GAT) {:.2} dB ({:.2} s per frame)",
        t.pairs, t.input_db, t.bm3d_db, t.bm3d_s
    );
    for (i, est) in models.iter().enumerate() {
        let m = est.model().expect("bench::models holds networks only");
        println!(
            "model {}: {} ({} params, {} steps, noise model {}): {:.2} dB ({:+.2} vs BM3D), {:.3} s per 512×512 frame",
            i + 1,
            est.name(),
            m.num_params(),
            m.meta.steps,
            m.meta.noise_model.name(),
            t.model_db[i],
            t.model_db[i] - t.bm3d_db,
            t.model_s[i]
        );
    }
    println!(
        "({} CPU threads; network on {})",
        rayon::current_num_threads(),
        emccd_nn::device_name(&emccd_nn::device())
    );
    Ok(())
}

fn calibration_bench(frames: usize) -> Result<()> {
    let dir = tempfile::tempdir()?;
    let r = emccd_calib::bench::streaming(dir.path(), frames)?;
    let (side, threads) = (emccd_calib::bench::SIDE, rayon::current_num_threads());
    println!(
        "calibration streaming: {} frames of {side}×{side} u16 ({:.0} MB TIFF, page cache), {threads} threads",
        r.frames,
        r.bytes / 1e6
    );
    println!("{:<46} {:>9} {:>9}", "pass", "s", "GB/s");
    println!(
        "{:<46} {:>9.3} {:>9.2}",
        "reference: read the bytes, no decoding",
        r.reference_s,
        r.reference_gb_s()
    );
    println!(
        "{:<46} {:>9.3} {:>9.2}",
        "emccd: decode + per-pixel mean and variance",
        r.decode_s,
        r.decode_gb_s()
    );
    println!();
    println!(
        "ratio to the reference read: {:.2}  (target ≥ 1 GB/s: {})",
        r.reference_s / r.decode_s,
        if r.decode_gb_s() >= 1.0 {
            "met"
        } else {
            "not met"
        }
    );
    println!(
        "peak memory: {:.1} MiB (before reading the stack: {:.1} MiB; the stack itself is {:.0} MiB)",
        r.peak_mib[1],
        r.peak_mib[0],
        r.bytes / (1 << 20) as f64
    );
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
    if let Some(gb) = a.archive {
        return archive_bench(gb, &a.archive_dir, a.net_frames);
    }
    let frames = a.frames.max(1);
    let cam = VirtualCamera::default_camera();
    let mpix = cam.profile.len() as f64 / 1e6;
    let threads = rayon::current_num_threads();
    let emccd_camera::bench::Synthesis {
        ours_s: t_ours,
        pgn_s: t_pgn,
        camera_s: t_cam,
    } = emccd_camera::bench::synthesis(&cam, a.electrons, frames)?;
    println!(
        "synthesis throughput, 512×512 frames, {} e⁻/pixel, {frames} frames, {threads} threads",
        a.electrons
    );
    println!("{:<44} {:>10} {:>10}", "method", "ms/frame", "Mpix/s");
    let row = |name: &str, t: f64| println!("{:<44} {:>10.2} {:>10.1}", name, t * 1e3, mpix / t);
    row("emccd ours (eq. 5, training pairs)", t_ours);
    row("emccd pgn (Poisson-Gamma-Normal)", t_pgn);
    row("emccd virtual camera (full eq. 1 + ADC)", t_cam);
    if a.no_python {
        return Ok(());
    }
    match emccd_camera::bench::emccd_detect(frames.min(10), a.electrons) {
        Ok(t_py) => {
            row("emccd-detect sim_sub_frame (Python)", t_py);
            println!();
            println!("ratio vs emccd-detect: ours {:.1}×, virtual camera {:.1}×  (same physics: PGN + read noise + ADC)", t_py / t_ours, t_py / t_cam);
        }
        Err(why) => {
            println!("\nemccd-detect comparison skipped: {why}  (pip install emccd-detect)")
        }
    }
    Ok(())
}
