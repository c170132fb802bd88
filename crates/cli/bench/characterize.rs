//! The characterization benchmark of `emccd bench --characterize`: a movie of the virtual camera
//! at EMCCD light levels, held in memory, characterized as a command without `--profile` does
//! ([`emccd_calib::recording::characterize`]), beside one pass over the same values (each
//! pixel's mean over the frames: the least any characterization reads) as the reference; and
//! the numbers it found beside the camera's own.

use std::time::Instant;

use emccd_camera::VirtualCamera;
use emccd_nn::{Error, Result};
use emccd_profile::CameraProfile;
use rayon::prelude::*;

/// Mean photoelectrons per pixel per frame of the benchmark's movie: an EMCCD's light level.
pub const LEVEL: f64 = 1.0;

/// What [`characterize`] measured.
#[derive(Clone, Debug)]
pub struct CharacterizeTimes {
    /// Frames, and their size.
    pub frames: usize,
    /// Frame width and height, px.
    pub size: (usize, usize),
    /// The scene's mean photoelectrons per pixel per frame.
    pub electrons: f64,
    /// Seconds for the reference pass.
    pub reference_s: f64,
    /// Seconds for the characterization.
    pub characterize_s: f64,
    /// The camera's DN per e⁻, bias (median of its map) and read noise (median), DN.
    pub truth: [f64; 3],
    /// The same, characterized.
    pub found: [f64; 3],
    /// The characterized bias map less the camera's (its fixed pattern and that pattern's
    /// smear), DN: its mean over the frame, over the dim
    /// background and over the bright patches (where few values are at zero electrons).
    pub bias_error: [f64; 3],
    /// The characterization's one-line summary.
    pub summary: String,
}

impl std::fmt::Display for CharacterizeTimes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (w, h) = self.size;
        writeln!(
            f,
            "{} frames of {w}×{h} at {:.2} e⁻ per pixel",
            self.frames, self.electrons
        )?;
        writeln!(
            f,
            "{:<34} {:>9} {:>13} {:>10}",
            "stage", "seconds", "s/100 frames", "vs ref."
        )?;
        let per100 = |s: f64| s * 100.0 / self.frames as f64;
        for (name, s) in [
            ("each pixel's mean (reference)", self.reference_s),
            ("characterization", self.characterize_s),
        ] {
            writeln!(
                f,
                "{name:<34} {s:>9.3} {:>13.3} {:>9.1}×",
                per100(s),
                s / self.reference_s
            )?;
        }
        writeln!(f, "{:<14} {:>10} {:>14}", "", "camera", "characterized")?;
        for (i, name) in ["DN per e⁻", "bias, DN", "read noise, DN"]
            .iter()
            .enumerate()
        {
            writeln!(
                f,
                "{name:<14} {:>10.2} {:>14.2}",
                self.truth[i], self.found[i]
            )?;
        }
        writeln!(
            f,
            "bias map − camera's: {:+.2} DN in the mean, {:+.2} on the background, {:+.2} on the patches",
            self.bias_error[0], self.bias_error[1], self.bias_error[2]
        )?;
        write!(f, "summary: {}", self.summary)
    }
}

/// The scene's photoelectrons at `(x, y)`: a dim background (a tenth of an electron, where the
/// zero-electron peak is) and smooth bright patches, `electrons` in the mean over the frame.
fn scene(x: usize, y: usize, electrons: f64) -> f64 {
    let (u, v) = (x as f64 / 24.0, y as f64 / 31.0);
    let patch = (u.sin() * v.sin()).max(0.0).powi(2);
    // sin²·sin² averages 1/4 and is kept where it is positive, half the frame: the patches'
    // mean is an eighth of their peak.
    0.1 + (electrons - 0.1).max(0.0) * 8.0 * patch
}

/// Runs the benchmark on `frames` frames of `profile`'s virtual camera at `electrons` per pixel
/// in the mean, 10 ms each.
pub fn characterize(
    profile: &CameraProfile,
    frames: usize,
    electrons: f64,
) -> Result<CharacterizeTimes> {
    if frames < 2 {
        return Err(Error::Data(format!(
            "--characterize {frames}: at least 2 frames"
        )));
    }
    let cam = VirtualCamera::new(profile.clone(), Default::default())?;
    let exposure = 0.01;
    let e = cam.exposure(exposure);
    let (w, h) = (cam.width(), cam.height());
    let photons: Vec<f32> = (0..w * h)
        .map(|i| (scene(i % w, i / w, electrons) / cam.physics.qe) as f32)
        .collect();
    let mean_e = photons.iter().map(|&p| p as f64).sum::<f64>() * cam.physics.qe / (w * h) as f64;
    let raw: Vec<Vec<f32>> = (0..frames)
        .map(|k| {
            let mut f = vec![0f32; w * h];
            e.frame(&photons, 7000 + k as u64, &mut f);
            f
        })
        .collect();
    let clock = Instant::now();
    let means: Vec<f64> = (0..w * h)
        .into_par_iter()
        .map(|i| raw.iter().map(|f| f[i] as f64).sum::<f64>() / frames as f64)
        .collect();
    let reference_s = clock.elapsed().as_secs_f64();
    std::hint::black_box(&means);
    let clock = Instant::now();
    let c =
        emccd_calib::recording::characterize(&raw, w, h).map_err(|e| Error::Data(e.to_string()))?;
    let characterize_s = clock.elapsed().as_secs_f64();
    let median = |v: &[f32]| emccd_profile::median(v.iter().copied()).unwrap_or(f64::NAN);
    let mut fpn = vec![0f32; w * h];
    profile.fpn_at(exposure, &mut fpn);
    // The bias as the camera reads it: the smear adds a share of each column's mean, the fixed
    // pattern's too.
    emccd_profile::apply_blooming(&mut fpn, w, profile.blooming_factor(exposure));
    let truth = [
        profile
            .dn_per_electron()
            .map_err(|e| Error::Data(e.to_string()))?,
        median(&fpn),
        median(profile.read_noise_near(exposure)),
    ];
    let found = [
        c.dn_per_electron(),
        median(&c.bias_map.values),
        c.read_noise_dn.value,
    ];
    let error = |keep: &dyn Fn(f64) -> bool| {
        let (mut sum, mut n) = (0.0, 0usize);
        for i in 0..w * h {
            if keep(scene(i % w, i / w, electrons)) {
                sum += (c.bias_map.values[i] - fpn[i]) as f64;
                n += 1;
            }
        }
        sum / n.max(1) as f64
    };
    let bias_error = [error(&|_| true), error(&|e| e < 0.2), error(&|e| e > 2.0)];
    Ok(CharacterizeTimes {
        bias_error,
        frames,
        size: (w, h),
        electrons: mean_e,
        reference_s,
        characterize_s,
        truth,
        found,
        summary: c.summary_line(),
    })
}
