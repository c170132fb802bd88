//! The movie benchmark of `emccd bench --movie`: a scene drifting across the virtual camera,
//! recorded as a movie at each of [`PHOTONS`], denoised frame by frame by BM3D + GAT and
//! temporally by `--method temporal` (its default window) and `--method temporal-net`, with
//! PSNR over the movie and seconds per frame side by side, and each temporal method's time over
//! its reference's: the classical method's over one BM3D pass per frame (target at most 3×),
//! the network's over the single-frame network it was widened from, `lowlight`, run frame by
//! frame (its target is 1 s per 512² frame; the ratio says how much of that is the network's
//! own cost on the machine, which the window cannot change).

use std::path::Path;
use std::time::Instant;

use emccd_camera::VirtualCamera;
use emccd_denoise::{Estimator, Method, Units, DEFAULT_WINDOW};
use emccd_nn::tile::Tiling;
use emccd_nn::{Error, Result};
use emccd_profile::CameraProfile;

pub use super::denoise::PHOTONS;

/// One level's scores and timings.
#[derive(Clone, Debug)]
pub struct MovieRow {
    /// Photons at the scene's peak.
    pub photons: f64,
    /// The preprocessed frames' PSNR over the movie, dB.
    pub input_db: f64,
    /// BM3D + GAT frame by frame, dB.
    pub bm3d_db: f64,
    /// `temporal`, dB.
    pub temporal_db: f64,
    /// BM3D's seconds per frame.
    pub bm3d_s: f64,
    /// `temporal`'s seconds per frame (the frames' single-frame estimates included).
    pub temporal_s: f64,
    /// `temporal`'s mean over the truth's.
    pub mean_ratio: f64,
    /// `temporal-net`, dB.
    pub net_db: f64,
    /// `temporal-net`'s seconds per frame (its scene gate included).
    pub net_s: f64,
    /// The single-frame network `lowlight`'s seconds per frame.
    pub single_net_s: f64,
}

impl MovieRow {
    /// The header of the table of rows.
    pub fn header() -> String {
        format!(
            "{:>8} {:>9} {:>9} {:>12} {:>13} {:>13} {:>10} {:>11} {:>9} {:>10} {:>10} {:>10}",
            "photons",
            "input dB",
            "BM3D dB",
            "temporal dB",
            "BM3D s/frame",
            "temporal s/f",
            "time ratio",
            "mean ratio",
            "t-net dB",
            "t-net s/f",
            "net s/f",
            "t-net/net"
        )
    }
}

impl std::fmt::Display for MovieRow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:>8} {:>9.2} {:>9.2} {:>12.2} {:>13.2} {:>13.2} {:>9.2}× {:>11.4} {:>9.2} {:>10.2} {:>10.2} {:>9.2}×",
            self.photons,
            self.input_db,
            self.bm3d_db,
            self.temporal_db,
            self.bm3d_s,
            self.temporal_s,
            self.temporal_s / self.bm3d_s,
            self.mean_ratio,
            self.net_db,
            self.net_s,
            self.single_net_s,
            self.net_s / self.single_net_s
        )
    }
}

/// The scene at frame `t` of the drift: 1 px right per frame and 1 px down every second frame,
/// the edge pixels repeated where the scene leaves the frame. Whole pixels, so that the truth
/// is the scene itself, not a resampling of it.
fn drifted(img: &[f32], w: usize, h: usize, t: usize) -> Vec<f32> {
    let (dx, dy) = (t, t / 2);
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| img[y.saturating_sub(dy) * w + x.saturating_sub(dx)])
        .collect()
}

/// Runs the benchmark: the virtual camera of `profile` (also used to denoise) records `frames`
/// frames of `scene` (the camera's size) drifting, at each of [`PHOTONS`], 10 ms per frame;
/// `on_row` gets each level's row as it comes.
pub fn movie(
    profile: &CameraProfile,
    scene: &Path,
    frames: usize,
    on_row: &mut dyn FnMut(&MovieRow),
) -> Result<Vec<MovieRow>> {
    if frames < 2 {
        return Err(Error::Data(format!(
            "--movie {frames}: a movie needs at least 2 frames"
        )));
    }
    let cam = VirtualCamera::new(profile.clone(), Default::default())?;
    let e = cam.exposure(0.01);
    let emccd_io::Image {
        width: w,
        height: h,
        data: img,
    } = emccd_io::Image::read_scene(scene)?;
    if (w, h) != (cam.width(), cam.height()) {
        return Err(Error::Data(format!(
            "{}: {w}×{h}, the camera is {}×{}",
            scene.display(),
            cam.width(),
            cam.height()
        )));
    }
    let bm3d = Estimator::parse("bm3d", crate::common::load_model)?;
    let single_net = Estimator::parse("lowlight", crate::common::load_model)?;
    let temporal = emccd_denoise::resolve(Some(Method::Temporal), None, crate::common::load_model)?;
    let fd = temporal.denoiser(
        profile,
        frames,
        Tiling::default(),
        1,
        Units::default(),
        DEFAULT_WINDOW,
    )?;
    let net = emccd_denoise::resolve(Some(Method::TemporalNet), None, crate::common::load_model)?;
    let window = net.window(None)?;
    let nd = net.denoiser(
        profile,
        frames,
        Tiling::default(),
        1,
        Units::default(),
        window,
    )?;
    let mut rows = Vec::new();
    for (li, &level) in PHOTONS.iter().enumerate() {
        let (mut raw, mut truth) = (Vec::new(), Vec::new());
        for t in 0..frames {
            let phot: Vec<f32> = drifted(&img, w, h, t)
                .iter()
                .map(|&v| (v as f64 * level) as f32)
                .collect();
            truth.extend(e.ground_truth(&phot));
            let mut frame = vec![0f32; w * h];
            e.frame(&phot, 5000 + (li * frames + t) as u64, &mut frame);
            raw.extend(frame);
        }
        let peak = emccd_eval::scores::truth_peak(&truth);
        let mut pre = Vec::with_capacity(raw.len());
        let mut bm = Vec::with_capacity(raw.len());
        let mut bm3d_s = 0.0;
        for frame in raw.chunks(w * h) {
            pre.extend(emccd_classical::frame::preprocess(profile, frame, 0.01)?);
            let clock = Instant::now();
            bm.extend(bm3d.run(profile, frame, 0.01)?);
            bm3d_s += clock.elapsed().as_secs_f64();
        }
        let clock = Instant::now();
        for frame in raw.chunks(w * h) {
            single_net.run(profile, frame, 0.01)?;
        }
        let single_net_s = clock.elapsed().as_secs_f64() / frames as f64;
        // The whole movie by one temporal method, and its seconds.
        let timed = |fd: &emccd_denoise::Denoiser| -> Result<(Vec<f32>, f64)> {
            let mut out = Vec::with_capacity(raw.len());
            let clock = Instant::now();
            emccd_denoise::movie::denoise_slice(fd, 0.01, &raw, &mut |_, f| {
                out.extend(f);
                Ok(())
            })?;
            Ok((out, clock.elapsed().as_secs_f64()))
        };
        let (out, temporal_s) = timed(&fd)?;
        let (by_net, net_s) = timed(&nd)?;
        let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
        let row = MovieRow {
            photons: level,
            input_db: emccd_eval::psnr(&pre, &truth, peak),
            bm3d_db: emccd_eval::psnr(&bm, &truth, peak),
            temporal_db: emccd_eval::psnr(&out, &truth, peak),
            bm3d_s: bm3d_s / frames as f64,
            temporal_s: temporal_s / frames as f64,
            mean_ratio: mean(&out) / mean(&truth),
            net_db: emccd_eval::psnr(&by_net, &truth, peak),
            net_s: net_s / frames as f64,
            single_net_s,
        };
        on_row(&row);
        rows.push(row);
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_drift_moves_whole_pixels_and_keeps_the_scene() {
        let img: Vec<f32> = (0..12).map(|v| v as f32).collect();
        assert_eq!(drifted(&img, 4, 3, 0), img);
        // t = 2: 2 px right, 1 px down, the first column and row repeated.
        assert_eq!(
            drifted(&img, 4, 3, 2),
            [0., 0., 0., 1., 0., 0., 0., 1., 4., 4., 4., 5.]
        );
    }
}
