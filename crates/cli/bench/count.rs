//! The counting benchmark of `emccd bench --count`: frames of the virtual camera at a faint
//! level, held in memory, preprocessed and counted as `emccd count` does (automatic threshold,
//! one output frame), beside the analog mean of the same frames through the same code (the
//! reference) and the preprocessing alone; throughput in megapixels per second. The target of
//! issue 38 is 200 Mpix/s on 2 cores.

use std::time::Instant;

use emccd_camera::VirtualCamera;
use emccd_count::{Camera, Counter, Threshold};
use emccd_nn::{Error, Result};
use emccd_profile::CameraProfile;

/// Photo-electrons per pixel per frame of the benchmark's frames: where counting pays.
pub const LEVEL: f64 = 0.1;

/// Seconds each stage took over the frames.
#[derive(Clone, Debug)]
pub struct CountTimes {
    /// Frames and their pixels each.
    pub frames: usize,
    /// Pixels per frame.
    pub pixels: usize,
    /// Preprocessing alone (the fixed pattern and blooming removed).
    pub preprocess_s: f64,
    /// Preprocessing and counting with the automatic threshold.
    pub count_s: f64,
    /// Preprocessing and the likelihood (binned values, the most likely rate).
    pub likelihood_s: f64,
    /// Preprocessing and the analog mean.
    pub analog_s: f64,
    /// The counted mean rate over the truth's, the likelihood's and the analog one's.
    pub ratios: (f64, f64, f64),
}

impl std::fmt::Display for CountTimes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mpix = (self.frames * self.pixels) as f64 / 1e6;
        writeln!(
            f,
            "{:<36} {:>9} {:>10} {:>12}",
            "stage", "seconds", "Mpix/s", "vs analog"
        )?;
        for (name, s) in [
            ("preprocessing alone", self.preprocess_s),
            ("preprocessing + analog mean (ref.)", self.analog_s),
            ("preprocessing + counting (auto)", self.count_s),
            ("preprocessing + likelihood", self.likelihood_s),
        ] {
            writeln!(
                f,
                "{name:<36} {s:>9.3} {:>10.1} {:>11.2}×",
                mpix / s,
                self.analog_s / s
            )?;
        }
        write!(
            f,
            "mean rate over the truth's: counted {:.4}, likelihood {:.4}, analog {:.4}",
            self.ratios.0, self.ratios.1, self.ratios.2
        )
    }
}

/// Runs the benchmark on `frames` uniform frames of `profile`'s virtual camera at [`LEVEL`]
/// photo-electrons per pixel, 10 ms each.
pub fn count(profile: &CameraProfile, frames: usize) -> Result<CountTimes> {
    if frames < 2 {
        return Err(Error::Data(format!("--count {frames}: at least 2 frames")));
    }
    let cam = VirtualCamera::new(profile.clone(), Default::default())?;
    let exposure = 0.01;
    let e = cam.exposure(exposure);
    let pixels = cam.width() * cam.height();
    let photons = vec![(LEVEL / cam.physics.qe) as f32; pixels];
    let raw: Vec<Vec<f32>> = (0..frames)
        .map(|k| {
            let mut f = vec![0f32; pixels];
            e.frame(&photons, 9000 + k as u64, &mut f);
            f
        })
        .collect();
    let mut fpn = vec![0f32; pixels];
    profile.fpn_at(exposure, &mut fpn);
    let bloom = profile.blooming_factor(exposure);
    let camera = Camera::from_profile(profile, exposure, None, Default::default())
        .map_err(|e| Error::Data(e.0))?;
    let run = |mut take: Box<dyn FnMut(&[f32]) + '_>| -> f64 {
        let clock = Instant::now();
        let mut buf = vec![0f32; pixels];
        for f in &raw {
            buf.copy_from_slice(f);
            emccd_profile::preprocess(&mut buf, cam.width(), bloom, &fpn);
            take(&buf);
        }
        clock.elapsed().as_secs_f64()
    };
    let preprocess_s = run(Box::new(|_| {}));
    let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
    // Seconds, and the output's mean rate over the truth's.
    let measure = |threshold: Threshold, analog: bool| -> Result<(f64, f64)> {
        let mut counter = Counter::new(camera.clone(), threshold, LEVEL, frames, frames, analog)
            .map_err(|e| Error::Data(e.0))?;
        let mut rate = None;
        let s = run(Box::new(|f| {
            if let Some((r, _)) = counter.add(f) {
                rate = Some(r);
            }
        }));
        Ok((
            s,
            mean(&rate.expect("the last frame completes the output")) / LEVEL,
        ))
    };
    let (count_s, counted) = measure(Threshold::Auto, false)?;
    let (likelihood_s, likely) = measure(Threshold::Likelihood, false)?;
    let (analog_s, analog) = measure(Threshold::Auto, true)?;
    Ok(CountTimes {
        frames,
        pixels,
        preprocess_s,
        count_s,
        likelihood_s,
        analog_s,
        ratios: (counted, likely, analog),
    })
}
