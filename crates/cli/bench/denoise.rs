//! The denoising benchmark of `emccd bench --denoise`: networks beside the input and BM3D + GAT
//! on virtual-camera test pairs (each scene at 20 and 200 photons at its peak, 10 ms), with
//! seconds per frame; each method's time includes the preprocessing it runs first. And the
//! archive benchmark of `emccd bench --archive` ([`Archive`], Unix): the binary's streaming
//! commands on a multi-gigabyte stack, with their wall time and peak memory.

use std::path::PathBuf;
use std::time::Instant;

use emccd_camera::VirtualCamera;
use emccd_profile::CameraProfile;

use emccd_denoise::Estimator;
use emccd_nn::{Error, Result};

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

impl Row {
    /// The header of the table of rows, for `models` models.
    pub fn header(models: usize) -> String {
        let mut h = format!(
            "{:<28} {:>8} {:>10} {:>10}",
            "scene", "photons", "input dB", "BM3D dB"
        );
        for i in 0..models {
            h += &format!(" {:>10}", format!("model {}", i + 1));
        }
        h
    }
}

/// One row of `emccd bench --denoise`'s table (under [`Row::header`]).
impl std::fmt::Display for Row {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:<28} {:>8} {:>10.2} {:>10.2}",
            self.scene, self.photons, self.input_db, self.bm3d_db
        )?;
        self.model_db
            .iter()
            .try_for_each(|b| write!(f, " {b:>10.2}"))
    }
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

impl Totals {
    /// The summary under the table: the means, and each of `models` (in [`denoise`]'s order)
    /// with its size, training and seconds per frame.
    pub fn summary(&self, models: &[Estimator]) -> String {
        let mut s = format!(
            "mean PSNR over {} pairs: input {:.2} dB, BM3D (GAT) {:.2} dB ({:.2} s per frame)",
            self.pairs, self.input_db, self.bm3d_db, self.bm3d_s
        );
        for (i, est) in models.iter().enumerate() {
            let Some(m) = est.model() else { continue };
            s += &format!(
                "\nmodel {}: {} ({} params, {} steps, noise model {}): {:.2} dB ({:+.2} vs BM3D), {:.3} s per 512×512 frame",
                i + 1,
                est.name(),
                m.num_params(),
                m.meta.steps,
                m.meta.noise_model.name(),
                self.model_db[i],
                self.model_db[i] - self.bm3d_db,
                self.model_s[i]
            );
        }
        s
    }
}

/// The models to benchmark: each argument a model file or bundled name (`MODEL@8` for the
/// self-ensemble); anything that runs no network (`bm3d`, `ivst`, …) is refused.
pub fn models(args: &[String]) -> Result<Vec<Estimator>> {
    args.iter()
        .map(|m| {
            let est = Estimator::parse(m, crate::common::load_model)?;
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
    let bm3d = Estimator::parse("bm3d", crate::common::load_model)?;
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
            let pre = emccd_classical::frame::preprocess(profile, &raw, 0.01)?;
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

#[cfg(unix)]
/// The archive benchmark of `emccd bench --archive`: a long and a short BigTIFF raw stack of
/// the virtual camera, streamed by `emccd info`, `emccd denoise --method none` (to OME-Zarr) and
/// a network denoise of the first frames, each run as a child process of `exe` so its wall time
/// and peak memory are its own (peak memory only grows within one process).
#[derive(Clone, Debug)]
pub struct Archive {
    /// The `emccd` binary measured.
    pub exe: PathBuf,
    /// Size of the long stack, GB.
    pub gb: f64,
    /// Where the stacks and outputs are written (and removed afterwards).
    pub dir: PathBuf,
    /// Frames of the network denoise: the short stack's length, and the first frames of each.
    pub net_frames: usize,
}

#[cfg(unix)]
/// Bytes of one of the archive benchmark's u16 frames.
const ARCHIVE_FRAME_BYTES: f64 =
    (crate::bench::camera::ARCHIVE_SIDE * crate::bench::camera::ARCHIVE_SIDE * 2) as f64;

#[cfg(unix)]
/// The two stacks of an [`Archive`] run.
#[derive(Clone, Copy, Debug)]
pub struct ArchiveStacks {
    /// Frames of the short stack.
    pub short_frames: usize,
    /// Frames of the long stack.
    pub long_frames: usize,
    /// Bytes of the long stack's file.
    pub long_bytes: f64,
    /// Seconds writing the long stack took.
    pub write_s: f64,
}

#[cfg(unix)]
impl ArchiveStacks {
    /// Megabytes of the short stack's frames.
    pub fn short_mb(&self) -> f64 {
        self.short_frames as f64 * ARCHIVE_FRAME_BYTES / 1e6
    }
}

#[cfg(unix)]
/// The line that says what was written, and the header of the rows that follow.
impl std::fmt::Display for ArchiveStacks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let side = crate::bench::camera::ARCHIVE_SIDE;
        writeln!(
            f,
            "archive streaming: BigTIFF stacks of {side}×{side} u16 frames: {} frames ({:.0} MB) and {} frames ({:.2} GB, written in {:.0} s, {:.0} MB/s)",
            self.short_frames,
            self.short_mb(),
            self.long_frames,
            self.long_bytes / 1e9,
            self.write_s,
            self.long_bytes / 1e6 / self.write_s
        )?;
        write!(
            f,
            "{:<36} {:>7} {:>9} {:>9} {:>9} {:>9}",
            "command", "stack", "frames", "s", "frames/s", "peak MiB"
        )
    }
}

#[cfg(unix)]
/// One row of the archive benchmark's table.
impl std::fmt::Display for ArchiveRow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:<36} {:>7} {:>9} {:>9.1} {:>9.1} {:>9.1}",
            self.command,
            self.stack,
            self.frames,
            self.seconds,
            self.frames as f64 / self.seconds,
            self.peak_rss_mib
        )
    }
}

#[cfg(unix)]
/// One command of an [`Archive`] run, measured.
#[derive(Clone, Debug)]
pub struct ArchiveRow {
    /// What ran.
    pub command: &'static str,
    /// On which stack: `short` or `long`.
    pub stack: &'static str,
    /// Frames it processed.
    pub frames: usize,
    /// Wall time, s.
    pub seconds: f64,
    /// Peak resident memory, MiB (`wait4`'s `ru_maxrss`).
    pub peak_rss_mib: f64,
}

#[cfg(unix)]
/// What an [`Archive`] run reports as it goes.
#[derive(Debug)]
pub enum ArchiveEvent<'a> {
    /// Writing a stack of this many frames begins.
    Writing(usize),
    /// One more frame of it written.
    Frame,
    /// Both stacks are written.
    Stacks(&'a ArchiveStacks),
    /// One command measured.
    Row(&'a ArchiveRow),
}

#[cfg(unix)]
impl Archive {
    /// Runs the benchmark, reporting through `on`; the temporary folder is removed at the end
    /// (and on error).
    pub fn run(&self, on: &mut dyn FnMut(ArchiveEvent)) -> Result<()> {
        use std::ffi::OsStr;
        if !(self.gb > 0.0 && self.gb.is_finite()) {
            return Err(Error::Data(format!(
                "an archive of {} GB: the stack's size is a positive number of GB",
                self.gb
            )));
        }
        let long = ((self.gb * 1e9) / ARCHIVE_FRAME_BYTES).ceil().max(1.0) as usize;
        let tmp = tempfile::Builder::new()
            .prefix(".emccd-archive-bench.")
            .tempdir_in(&self.dir)
            .map_err(|e| Error::io(&self.dir, e))?;
        let d = tmp.path();
        let mut write = |name: &str, frames: usize| -> Result<(PathBuf, f64)> {
            let path = d.join(name);
            on(ArchiveEvent::Writing(frames));
            let t = crate::bench::camera::archive_stack(&path, frames, &mut || {
                on(ArchiveEvent::Frame)
            })?;
            Ok((path, t))
        };
        // The short stack is as long as the network's share, so both stacks run the same work
        // and differ only in length.
        let short = self.net_frames.max(1);
        let (short_path, _) = write("short.btf", short)?;
        let (long_path, write_s) = write("long.btf", long)?;
        let stacks = ArchiveStacks {
            short_frames: short,
            long_frames: long,
            long_bytes: std::fs::metadata(&long_path)
                .map_err(|e| Error::io(&long_path, e))?
                .len() as f64,
            write_s,
        };
        on(ArchiveEvent::Stacks(&stacks));
        for (label, path, frames) in [("short", &short_path, short), ("long", &long_path, long)] {
            let stack = path.as_os_str();
            let out = d.join("out.zarr");
            let net = d.join("net.zarr");
            // Shard 0 of ⌊F / net_frames⌋ holds at least net_frames frames (all of a shorter
            // stack).
            let shards = (frames / self.net_frames.max(1)).max(1);
            let shard = format!("0/{shards}");
            let o = OsStr::new;
            let runs: [(&'static str, Vec<&OsStr>, usize); 3] = [
                ("info", vec![o("info"), stack], frames),
                (
                    "denoise --method none → .zarr",
                    vec![
                        o("denoise"),
                        stack,
                        o("--method"),
                        o("none"),
                        o("-o"),
                        out.as_os_str(),
                    ],
                    frames,
                ),
                (
                    "denoise --method net (first frames)",
                    vec![
                        o("denoise"),
                        stack,
                        o("--method"),
                        o("net"),
                        o("-o"),
                        net.as_os_str(),
                        o("--shard"),
                        o(&shard),
                    ],
                    frames / shards,
                ),
            ];
            for (command, args, n) in runs {
                let (seconds, peak_rss_mib) = measure_child(&self.exe, &args)?;
                on(ArchiveEvent::Row(&ArchiveRow {
                    command,
                    stack: label,
                    frames: n,
                    seconds,
                    peak_rss_mib,
                }));
                for p in [&out, &net] {
                    if p.exists() {
                        std::fs::remove_dir_all(p).map_err(|e| Error::io(p, e))?;
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(unix)]
/// Runs `exe args` (stdout discarded, stderr kept for a failure's message) and returns its wall
/// time (s) and peak resident memory (MiB).
fn measure_child(exe: &std::path::Path, args: &[&std::ffi::OsStr]) -> Result<(f64, f64)> {
    use std::io::{Read, Seek};
    use std::process::{Command, Stdio};
    let t = Instant::now();
    // Its messages go to a file, not a pipe: a pipe nobody reads while we wait could fill.
    let io = |e| Error::io(exe, e);
    let mut log = tempfile::tempfile().map_err(io)?;
    let child = Command::new(exe)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::from(log.try_clone().map_err(io)?))
        .spawn()
        .map_err(io)?;
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: an all-zero rusage is valid, and wait4 fills it for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    let seconds = t.elapsed().as_secs_f64();
    if r != pid {
        return Err(Error::io(exe, std::io::Error::last_os_error()));
    }
    if !(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0) {
        let mut err = String::new();
        log.rewind().map_err(io)?;
        let _ = log.read_to_string(&mut err);
        return Err(Error::Data(format!("emccd {args:?} failed: {err}")));
    }
    // ru_maxrss is in KiB on Linux.
    Ok((seconds, usage.ru_maxrss as f64 / 1024.0))
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_denoise_bench_scores_every_scene_at_both_levels_and_skips_other_sizes() {
        let dir = tempfile::tempdir().unwrap();
        let profile = emccd_profile::default_profile()
            .crop(emccd_profile::Roi::corner(64, 64))
            .unwrap();
        let scene = |name: &str, w: usize, h: usize| {
            let path = dir.path().join(name);
            let data: Vec<f32> = (0..w * h)
                .map(|i| 0.2 + 0.6 * ((i % w) as f32 / w as f32))
                .collect();
            emccd_io::write_png_preview(&path, w, h, &data, 0.0, 1.0).unwrap();
            path
        };
        let scenes = [scene("a.png", 64, 64), scene("b.png", 32, 64)];
        let models = super::models(&["default".to_string()]).unwrap();
        let (mut rows, mut skipped) = (Vec::new(), Vec::new());
        let t = super::denoise(
            &profile,
            &scenes,
            &models,
            1,
            &mut |r| rows.push(r.clone()),
            &mut |s| skipped.push(s),
        )
        .unwrap();
        assert_eq!(t.pairs, super::PHOTONS.len());
        assert_eq!(rows.len(), t.pairs);
        assert!(rows
            .iter()
            .all(|r| r.scene == "a.png" && r.model_db.len() == 1));
        assert!(
            skipped.len() == 1 && skipped[0].contains("b.png"),
            "{skipped:?}"
        );
        // Denoising helps, and the totals are the rows' means.
        for r in &rows {
            assert!(
                r.bm3d_db > r.input_db && r.model_db[0] > r.input_db,
                "{r:?}"
            );
        }
        let mean = rows.iter().map(|r| r.bm3d_db).sum::<f64>() / rows.len() as f64;
        assert!((t.bm3d_db - mean).abs() < 1e-9);
        assert!(t.model_s[0] > 0.0 && t.bm3d_s > 0.0);
        // Anything that runs no network is refused as a bench model.
        assert!(super::models(&["bm3d".to_string()]).is_err());
    }
}
