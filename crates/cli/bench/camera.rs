//! The synthesis throughput benchmark of `emccd bench`: seconds per frame of the paper's
//! training noise (eq. 5), the Poisson–Gamma–Normal model and the whole virtual camera, and of
//! NASA JPL's emccd-detect beside them ([`emccd_detect`]); and the raw stacks its archive
//! benchmark streams.

use std::path::Path;
use std::time::Instant;

use emccd_camera::{Ablation, Error, NoiseModel, OursModel, PgnModel, VirtualCamera};

/// What [`synthesis`] measured: seconds per frame of each synthesis (after one warm-up frame)
/// and the conditions they were measured in.
#[derive(Clone, Copy, Debug)]
pub struct Synthesis {
    /// Eq. 5 (training pairs).
    pub ours_s: f64,
    /// The Poisson–Gamma–Normal model.
    pub pgn_s: f64,
    /// The virtual camera: eq. 1 with blooming, FPN and the ADC.
    pub camera_s: f64,
    /// Mean photoelectrons per pixel of the frames.
    pub electrons: f64,
    /// Frames timed.
    pub frames: usize,
    /// Pixels per frame.
    pub pixels: usize,
    /// Worker threads (rayon's pool).
    pub threads: usize,
}

impl Synthesis {
    /// One row of the table: a method's milliseconds per frame and megapixels per second.
    pub fn row(&self, method: &str, seconds: f64) -> String {
        let mpix = self.pixels as f64 / 1e6;
        format!(
            "{method:<44} {:>10.2} {:>10.1}",
            seconds * 1e3,
            mpix / seconds
        )
    }

    /// The emccd-detect row and the ratios, for its seconds per frame ([`emccd_detect`]).
    pub fn emccd_detect_rows(&self, seconds: f64) -> String {
        format!(
            "{}\n\nratio vs emccd-detect: ours {:.1}×, virtual camera {:.1}×  (same physics: PGN + read noise + ADC)",
            self.row("emccd-detect sim_sub_frame (Python)", seconds),
            seconds / self.ours_s,
            seconds / self.camera_s
        )
    }
}

/// The table `emccd bench` prints (emccd's three syntheses; [`Synthesis::emccd_detect_rows`]
/// adds the comparison).
impl std::fmt::Display for Synthesis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let side = (self.pixels as f64).sqrt().round();
        writeln!(
            f,
            "synthesis throughput, {side}×{side} frames, {} e⁻/pixel, {} frames, {} threads",
            self.electrons, self.frames, self.threads
        )?;
        writeln!(f, "{:<44} {:>10} {:>10}", "method", "ms/frame", "Mpix/s")?;
        writeln!(
            f,
            "{}",
            self.row("emccd ours (eq. 5, training pairs)", self.ours_s)
        )?;
        writeln!(
            f,
            "{}",
            self.row("emccd pgn (Poisson-Gamma-Normal)", self.pgn_s)
        )?;
        write!(
            f,
            "{}",
            self.row("emccd virtual camera (full eq. 1 + ADC)", self.camera_s)
        )
    }
}

fn per_frame(frames: usize, mut f: impl FnMut(u64)) -> f64 {
    f(0);
    let t = Instant::now();
    for k in 0..frames {
        f(k as u64 + 1);
    }
    t.elapsed().as_secs_f64() / frames as f64
}

/// Times `frames` (at least one) uniform frames of `cam` at `electrons` mean photoelectrons
/// per pixel, 10 ms, through each synthesis.
pub fn synthesis(cam: &VirtualCamera, electrons: f64, frames: usize) -> Result<Synthesis, Error> {
    let frames = frames.max(1);
    let n = cam.profile.len();
    let w = cam.width();
    let clean = vec![(electrons * cam.k_dn() * cam.physics.qe) as f32; n];
    let photons = vec![(electrons / cam.physics.qe) as f32; n];
    let mut out = vec![0f32; n];
    let ours = OursModel::from_profile(&cam.profile, Ablation::default())?;
    let ours_s = per_frame(frames, |s| ours.synthesize(&clean, w, &mut out, s));
    let pgn = PgnModel::from_profile(&cam.profile, 0.01)?;
    let pgn_s = per_frame(frames, |s| pgn.synthesize(&clean, w, &mut out, s));
    let e = cam.exposure(0.01);
    let camera_s = per_frame(frames, |s| e.frame(&photons, s, &mut out));
    Ok(Synthesis {
        ours_s,
        pgn_s,
        camera_s,
        electrons,
        frames,
        pixels: n,
        threads: rayon::current_num_threads(),
    })
}

/// Side of the archive benchmark's frames, px.
pub const ARCHIVE_SIDE: usize = 512;

/// Writes a BigTIFF stack of `frames` 512×512 u16 raw frames of the default virtual camera at
/// about 4 e⁻ per pixel (10 ms, the exposure in its metadata) to `path` for the archive
/// benchmark; `tick` is called after each frame. Sixteen distinct frames are repeated: the
/// readers and writers see a real camera's values without gigabytes of simulation. Returns
/// the seconds the writing took.
pub fn archive_stack(path: &Path, frames: usize, tick: &mut dyn FnMut()) -> Result<f64, Error> {
    const SIDE: usize = ARCHIVE_SIDE;
    let cam = VirtualCamera::default_camera();
    let n = cam.profile.len();
    let e = cam.exposure(0.01);
    let photons: Vec<f32> = (0..n)
        .map(|i| (4.0 + 3.0 * ((i % SIDE) as f32 / 23.0).sin()) / cam.physics.qe as f32)
        .collect();
    let raws: Vec<Vec<f32>> = (0..16)
        .map(|s| {
            let mut out = vec![0f32; n];
            e.frame(&photons, s, &mut out);
            out
        })
        .collect();
    let t = Instant::now();
    let mut wr = emccd_io::StackWriter::create_as(
        path,
        emccd_io::Format::BigTiff,
        SIDE,
        SIDE,
        emccd_io::SampleFormat::U16,
        Some(frames),
    )?;
    wr.set_metadata(&emccd_io::Metadata {
        exposure_s: Some(0.01),
        ..Default::default()
    });
    for k in 0..frames {
        wr.write_frame(&raws[k % raws.len()])?;
        tick();
    }
    wr.finish()?;
    Ok(t.elapsed().as_secs_f64())
}

/// emccd-detect's timing script (run with `python3 -c`, so the binary needs no script beside
/// it): the same physics as the default virtual camera through `EMCCDDetect.sim_sub_frame`.
const EMCCD_DETECT_SPEED: &str = include_str!("emccd_detect_speed.py");

/// Seconds per 512×512 frame of NASA JPL's emccd-detect (Python) at `electrons` mean
/// photoelectrons per pixel, over `frames` frames after a warm-up; the reason where it cannot
/// run (no `python3`, emccd-detect not installed: `pip install emccd-detect`).
pub fn emccd_detect(frames: usize, electrons: f64) -> Result<f64, String> {
    let o = std::process::Command::new("python3")
        .arg("-c")
        .arg(EMCCD_DETECT_SPEED)
        .arg(frames.max(1).to_string())
        .arg(electrons.to_string())
        .output()
        .map_err(|e| format!("python3 not runnable ({e})"))?;
    if !o.status.success() {
        let err = String::from_utf8_lossy(&o.stderr);
        return Err(err.lines().last().unwrap_or("python3 failed").to_string());
    }
    let out = String::from_utf8_lossy(&o.stdout);
    out.trim().parse().map_err(|_| {
        format!(
            "emccd-detect's timing printed {:?}, not seconds",
            out.trim()
        )
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_synthesis_bench_times_every_synthesis() {
        let cam = emccd_camera::VirtualCamera::new(
            emccd_profile::default_profile()
                .crop(emccd_profile::Roi::corner(64, 64))
                .unwrap(),
            Default::default(),
        )
        .unwrap();
        let t = super::synthesis(&cam, 4.0, 2).unwrap();
        for s in [t.ours_s, t.pgn_s, t.camera_s] {
            assert!(s > 0.0 && s.is_finite(), "{t:?}");
        }
    }
}
