//! `emccd bench`: synthesis throughput on 512² frames, against emccd-detect where installed.

use std::process::Command;
use std::time::Instant;

use anyhow::Result;
use emccd_camera::{Ablation, NoiseModel, OursModel, PgnModel, VirtualCamera};

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

/// Wall time and peak resident memory of a child process.
struct ChildRun {
    seconds: f64,
    peak_rss_mib: f64,
}

/// Runs this binary with `args` (stdout and stderr discarded unless it fails) and measures it.
fn measure_child(args: &[&std::ffi::OsStr]) -> Result<ChildRun> {
    use std::process::Stdio;
    let t = Instant::now();
    // Its messages go to a file, not a pipe: a pipe nobody reads while we wait could fill.
    let mut log = tempfile::tempfile()?;
    let child = Command::new(std::env::current_exe()?)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::from(log.try_clone()?))
        .spawn()?;
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: an all-zero rusage is valid, and wait4 fills it for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    let seconds = t.elapsed().as_secs_f64();
    if r != pid {
        anyhow::bail!(
            "waiting for {:?}: {}",
            args,
            std::io::Error::last_os_error()
        );
    }
    if !(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0) {
        use std::io::{Read, Seek};
        let mut err = String::new();
        log.rewind()?;
        let _ = log.read_to_string(&mut err);
        anyhow::bail!("emccd {:?} failed: {err}", args);
    }
    Ok(ChildRun {
        seconds,
        // ru_maxrss is in KiB on Linux.
        peak_rss_mib: usage.ru_maxrss as f64 / 1024.0,
    })
}

fn archive_bench(gb: f64, dir: &std::path::Path, net_frames: usize) -> Result<()> {
    use std::ffi::OsStr;
    let (w, h) = (512usize, 512usize);
    let frame_bytes = (w * h * 2) as f64;
    let long = ((gb * 1e9) / frame_bytes).ceil().max(1.0) as usize;
    let tmp = tempfile::Builder::new()
        .prefix(".emccd-archive-bench.")
        .tempdir_in(dir)?;
    let d = tmp.path();
    // Sixteen distinct raw frames of the virtual camera at about 4 e⁻ per pixel, repeated: the
    // readers and writers see a real camera's values without 8 GB of simulation.
    let cam = VirtualCamera::default_camera();
    let n = cam.profile.len();
    let e = cam.exposure(0.01);
    let photons: Vec<f32> = (0..n)
        .map(|i| (4.0 + 3.0 * ((i % w) as f32 / 23.0).sin()) / cam.physics.qe as f32)
        .collect();
    let raws: Vec<Vec<f32>> = (0..16)
        .map(|s| {
            let mut out = vec![0f32; n];
            e.frame(&photons, s, &mut out);
            out
        })
        .collect();
    let write = |name: &str, frames: usize| -> Result<(std::path::PathBuf, f64)> {
        let path = d.join(name);
        let t = Instant::now();
        let mut wr = emccd_io::StackWriter::create_as(
            &path,
            emccd_io::Format::BigTiff,
            w,
            h,
            emccd_io::SampleFormat::U16,
            Some(frames),
        )?;
        wr.set_metadata(&emccd_io::Metadata {
            exposure_s: Some(0.01),
            ..Default::default()
        });
        let pb = crate::common::progress(frames as u64, "writing");
        for k in 0..frames {
            wr.write_frame(&raws[k % raws.len()])?;
            pb.inc(1);
        }
        wr.finish()?;
        pb.finish_and_clear();
        Ok((path, t.elapsed().as_secs_f64()))
    };
    // The short stack is as long as the network's share, so both stacks run the same work and
    // differ only in length.
    let short = net_frames.max(1);
    let (short_path, _) = write("short.btf", short)?;
    let (long_path, t_write) = write("long.btf", long)?;
    let size = std::fs::metadata(&long_path)?.len() as f64;
    println!(
        "archive streaming: BigTIFF stacks of 512×512 u16 frames: {short} frames ({:.0} MB) and {long} frames ({:.2} GB, written in {t_write:.0} s, {:.0} MB/s)",
        short as f64 * frame_bytes / 1e6,
        size / 1e9,
        size / 1e6 / t_write
    );
    println!(
        "{:<36} {:>7} {:>9} {:>9} {:>9} {:>9}",
        "command", "stack", "frames", "s", "frames/s", "peak MiB"
    );
    for (label, path, frames) in [("short", &short_path, short), ("long", &long_path, long)] {
        let stack = path.as_os_str();
        let out = d.join("out.zarr");
        let net = d.join("net.zarr");
        // Shard 0 of ⌊F / net_frames⌋ holds at least net_frames frames (all of a shorter stack).
        let shards = (frames / net_frames.max(1)).max(1);
        let first = frames / shards;
        let shard = format!("0/{shards}");
        let runs: [(&str, Vec<&OsStr>, usize); 3] = [
            ("info", vec![OsStr::new("info"), stack], frames),
            (
                "denoise --method none → .zarr",
                vec![
                    OsStr::new("denoise"),
                    stack,
                    OsStr::new("--method"),
                    OsStr::new("none"),
                    OsStr::new("-o"),
                    out.as_os_str(),
                ],
                frames,
            ),
            (
                "denoise --method net (first frames)",
                vec![
                    OsStr::new("denoise"),
                    stack,
                    OsStr::new("--method"),
                    OsStr::new("net"),
                    OsStr::new("-o"),
                    net.as_os_str(),
                    OsStr::new("--shard"),
                    OsStr::new(&shard),
                ],
                first,
            ),
        ];
        for (what, args, n) in runs {
            let r = measure_child(&args)?;
            println!(
                "{:<36} {:>7} {:>9} {:>9.1} {:>9.1} {:>9.1}",
                what,
                label,
                n,
                r.seconds,
                n as f64 / r.seconds,
                r.peak_rss_mib
            );
            for o in [&out, &net] {
                if o.exists() {
                    std::fs::remove_dir_all(o)?;
                }
            }
        }
    }
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
    for &sigma in sigmas {
        let (mut pn, mut pd, mut secs) = (0.0, 0.0, 0.0);
        for (i, sc) in scenes.iter().enumerate() {
            let img = emccd_io::Image::read_scene(sc)?;
            let clean: Vec<f32> = img.data.iter().map(|v| v * 255.0).collect();
            let seed = 1000 * sigma as u64 + i as u64;
            let t = emccd_eval::bm3d::gaussian_trial(&clean, img.width, img.height, sigma, seed);
            pn += t.noisy_db;
            pd += t.denoised_db;
            secs += t.seconds;
        }
        let n = scenes.len().max(1) as f64;
        let p =
            emccd_eval::bm3d::published_bsd68_db(sigma).map_or("–".into(), |v| format!("{v:.2}"));
        println!(
            "{:>6} {:>10.2} {:>10.2} {:>10} {:>12.2}",
            sigma,
            pn / n,
            pd / n,
            p,
            secs / n
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
    use emccd_nn::registry::{load, Estimator};
    let bm3d = Estimator::parse("bm3d", load)?;
    let mut models = Vec::with_capacity(model_args.len());
    for m in model_args {
        let est = Estimator::parse(m, load)?;
        if est.model().is_none() {
            anyhow::bail!("--denoise {m}: not a model (a file, or `default`, `microscopy`, `lowlight`; `MODEL@8` for the self-ensemble)");
        }
        models.push(est);
    }
    let profile = crate::common::load_profile(profile_arg)?;
    let cam = VirtualCamera::new(profile.clone(), Default::default())?;
    let scenes = if scene_args.is_empty() {
        emccd_io::image_files(&[data_folder(data, "clean/microscopy/fmd-confocal-bpae")?])?
    } else {
        emccd_io::image_files(scene_args)?
    };
    let e = cam.exposure(0.01);
    let k = models.len();
    let (mut pin, mut pbm, mut n, mut bm_secs) = (0.0, 0.0, 0usize, 0.0);
    let (mut pout, mut secs, mut timed) = (vec![0.0; k], vec![0.0; k], vec![0usize; k]);
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
    for i in 0..k {
        print!(" {:>10}", format!("model {}", i + 1));
    }
    println!();
    for (si, sc) in scenes.iter().enumerate() {
        let emccd_io::Image {
            width: w,
            height: h,
            data: img,
        } = emccd_io::Image::read_scene(sc)?;
        if (w, h) != (cam.width(), cam.height()) {
            eprintln!(
                "skipping {}: {w}×{h}, the camera is {}×{}",
                sc.display(),
                cam.width(),
                cam.height()
            );
            continue;
        }
        for (li, &level) in [20.0f64, 200.0].iter().enumerate() {
            let phot: Vec<f32> = img.iter().map(|&v| (v as f64 * level) as f32).collect();
            let truth = e.ground_truth(&phot);
            let mut raw = vec![0f32; w * h];
            e.frame(&phot, 1000 + (si * 2 + li) as u64, &mut raw);
            let peak = truth.iter().copied().fold(0f32, f32::max).max(1.0) as f64;
            let pre = emccd_nn::pipeline::preprocess(&profile, &raw, 0.01)?;
            // Every method's time includes the preprocessing it runs first.
            let t = Instant::now();
            let bm = bm3d.run(&profile, &raw, 0.01)?;
            bm_secs += t.elapsed().as_secs_f64();
            let (a, c) = (
                emccd_eval::psnr(&pre, &truth, peak),
                emccd_eval::psnr(&bm, &truth, peak),
            );
            print!(
                "{:<28} {:>8} {:>10.2} {:>10.2}",
                sc.file_name().unwrap_or_default().to_string_lossy(),
                level,
                a,
                c
            );
            for (mi, est) in models.iter().enumerate() {
                let t = Instant::now();
                let den = est.run(&profile, &raw, 0.01)?;
                if timed[mi] < frames.max(1) {
                    secs[mi] += t.elapsed().as_secs_f64();
                    timed[mi] += 1;
                }
                let b = emccd_eval::psnr(&den, &truth, peak);
                print!(" {b:>10.2}");
                pout[mi] += b;
            }
            println!();
            pin += a;
            pbm += c;
            n += 1;
        }
    }
    let nn = n.max(1) as f64;
    println!();
    println!(
        "mean PSNR over {n} pairs: input {:.2} dB, BM3D (GAT) {:.2} dB ({:.2} s per frame)",
        pin / nn,
        pbm / nn,
        bm_secs / nn
    );
    for (i, est) in models.iter().enumerate() {
        let m = est.model().expect("a model argument runs a network");
        println!(
            "model {}: {} ({} params, {} steps, noise model {}): {:.2} dB ({:+.2} vs BM3D), {:.3} s per 512×512 frame",
            i + 1,
            est.name(),
            burn::module::Module::num_params(&m.net),
            m.meta.steps,
            m.meta.noise_model.name(),
            pout[i] / nn,
            pout[i] / nn - pbm / nn,
            secs[i] / timed[i].max(1) as f64
        );
    }
    println!(
        "({} CPU threads; network on {})",
        rayon::current_num_threads(),
        emccd_nn::device_name(&emccd_nn::device())
    );
    Ok(())
}

/// Peak resident memory of this process (Linux), MiB.
fn peak_rss_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn calibration_bench(frames: usize) -> Result<()> {
    use std::io::Read;
    let (w, h) = (512usize, 512usize);
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("stack.tif");
    let mut wr =
        emccd_io::StackWriter::create(&path, w, h, emccd_io::SampleFormat::U16, Some(frames))?;
    let mut f = vec![0f32; w * h];
    for k in 0..frames {
        for (i, v) in f.iter_mut().enumerate() {
            *v = 500.0 + ((i * 7919 + k * 104729) % 23) as f32;
        }
        wr.write_frame(&f)?;
    }
    wr.finish()?;
    let bytes = std::fs::metadata(&path)?.len() as f64;
    let rss_before = peak_rss_mib().unwrap_or(f64::NAN);
    // Reference: reading the same bytes from the page cache and doing nothing with them.
    let t = Instant::now();
    let mut file = std::fs::File::open(&path)?;
    let mut buf = vec![0u8; 1 << 20];
    let mut sink = 0u64;
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        sink = sink.wrapping_add(buf[n - 1] as u64);
    }
    let t_ref = t.elapsed().as_secs_f64();
    std::hint::black_box(sink);
    let t = Instant::now();
    let (_, st) = emccd_calib::stats::accumulate(&path, None, 2, &[], None, &emccd_calib::Silent)?;
    let t_cal = t.elapsed().as_secs_f64();
    std::hint::black_box(st.mean());
    let threads = rayon::current_num_threads();
    println!("calibration streaming: {frames} frames of {w}×{h} u16 ({:.0} MB TIFF, page cache), {threads} threads", bytes / 1e6);
    println!("{:<46} {:>9} {:>9}", "pass", "s", "GB/s");
    println!(
        "{:<46} {:>9.3} {:>9.2}",
        "reference: read the bytes, no decoding",
        t_ref,
        bytes / t_ref / 1e9
    );
    println!(
        "{:<46} {:>9.3} {:>9.2}",
        "emccd: decode + per-pixel mean and variance",
        t_cal,
        bytes / t_cal / 1e9
    );
    println!();
    println!(
        "ratio to the reference read: {:.2}  (target ≥ 1 GB/s: {})",
        t_ref / t_cal,
        if bytes / t_cal >= 1e9 {
            "met"
        } else {
            "not met"
        }
    );
    println!(
        "peak memory: {:.1} MiB (before reading the stack: {:.1} MiB; the stack itself is {:.0} MiB)",
        peak_rss_mib().unwrap_or(f64::NAN),
        rss_before,
        bytes / (1 << 20) as f64
    );
    Ok(())
}

fn time_frames(frames: usize, mut f: impl FnMut(u64)) -> f64 {
    f(0);
    let t = Instant::now();
    for k in 0..frames {
        f(k as u64 + 1);
    }
    t.elapsed().as_secs_f64() / frames as f64
}

/// emccd-detect's timing script (run with `python3 -c`, so the binary needs no tools/ folder).
const EMCCD_DETECT_SPEED: &str = include_str!("../../../tools/emccd_detect_speed.py");

pub fn run(a: Args) -> Result<()> {
    if let Some(frames) = a.calibration {
        return calibration_bench(frames.max(2));
    }
    if !a.denoise.is_empty() {
        return denoise_bench(&a.denoise, &a.profile, &a.scenes, a.frames, &a.data);
    }
    if !a.bm3d.is_empty() {
        return bm3d_bench(&a.bm3d, a.images, &a.data);
    }
    if let Some(gb) = a.archive {
        if !(gb > 0.0 && gb.is_finite()) {
            anyhow::bail!("--archive {gb}: the stack's size is a positive number of GB");
        }
        return archive_bench(gb, &a.archive_dir, a.net_frames);
    }
    let frames = a.frames.max(1);
    let cam = VirtualCamera::default_camera();
    let n = cam.profile.len();
    let mpix = n as f64 / 1e6;
    let threads = rayon::current_num_threads();
    let k_qe = cam.k_dn() * cam.physics.qe;
    let clean = vec![(a.electrons * k_qe) as f32; n];
    let photons = vec![(a.electrons / cam.physics.qe) as f32; n];
    let mut out = vec![0f32; n];

    let ours = OursModel::from_profile(&cam.profile, Ablation::default())?;
    let t_ours = time_frames(frames, |s| ours.synthesize(&clean, 512, &mut out, s));
    let pgn = PgnModel::from_profile(&cam.profile, 0.01)?;
    let t_pgn = time_frames(frames, |s| pgn.synthesize(&clean, 512, &mut out, s));
    let e = cam.exposure(0.01);
    let t_cam = time_frames(frames, |s| e.frame(&photons, s, &mut out));

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
    let py = Command::new("python3")
        .arg("-c")
        .arg(EMCCD_DETECT_SPEED)
        .arg(frames.min(10).to_string())
        .arg(a.electrons.to_string())
        .output();
    match py {
        Ok(o) if o.status.success() => {
            let t_py: f64 = String::from_utf8_lossy(&o.stdout)
                .trim()
                .parse()
                .unwrap_or(f64::NAN);
            row("emccd-detect sim_sub_frame (Python)", t_py);
            println!();
            println!("ratio vs emccd-detect: ours {:.1}×, virtual camera {:.1}×  (same physics: PGN + read noise + ADC)", t_py / t_ours, t_py / t_cam);
        }
        Ok(o) => {
            let err = String::from_utf8_lossy(&o.stderr);
            let last = err.lines().last().unwrap_or("").to_string();
            println!("\nemccd-detect comparison skipped: {last}  (pip install emccd-detect)");
        }
        Err(e) => println!("\nemccd-detect comparison skipped: python3 not runnable ({e})"),
    }
    Ok(())
}
