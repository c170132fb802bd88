//! Counting a stack: its frames preprocessed in order, thresholded and summed into a [`Tally`]
//! per output frame, in the memory of one frame.

use rayon::prelude::*;

use emccd_profile::CameraProfile;

use crate::plan::{Camera, Plan};
use crate::{Error, Result};

/// Events and signal summed over the frames of one output frame.
#[derive(Clone, Debug)]
pub struct Tally {
    /// Events per pixel.
    pub counts: Vec<u32>,
    /// Preprocessed signal per pixel, summed (DN above bias): the analog estimate's.
    pub sum: Vec<f64>,
    /// Frames added.
    pub frames: u32,
}

impl Tally {
    /// An empty tally of `pixels` pixels.
    pub fn new(pixels: usize) -> Tally {
        Tally {
            counts: vec![0; pixels],
            sum: vec![0.0; pixels],
            frames: 0,
        }
    }

    /// Adds one preprocessed frame (DN above bias) thresholded at `thresholds`.
    pub fn add(&mut self, frame: &[f32], thresholds: &[f32]) {
        const CHUNK: usize = 4096;
        self.counts
            .par_chunks_mut(CHUNK)
            .zip(self.sum.par_chunks_mut(CHUNK))
            .zip(frame.par_chunks(CHUNK).zip(thresholds.par_chunks(CHUNK)))
            .for_each(|((c, s), (f, t))| {
                for (((c, s), &v), &t) in c.iter_mut().zip(s.iter_mut()).zip(f).zip(t) {
                    *c += (v > t) as u32;
                    *s += v as f64;
                }
            });
        self.frames += 1;
    }

    /// The analog estimate: each pixel's mean signal over the register's gain, less the
    /// spurious electrons (photo-electrons per pixel per frame).
    pub fn analog(&self, camera: &Camera) -> Vec<f32> {
        let n = self.frames.max(1) as f64;
        self.sum
            .iter()
            .map(|&s| (s / n / camera.g - camera.spurious) as f32)
            .collect()
    }

    /// The mean photo-electron rate over every pixel (the analog estimate's mean): the level
    /// [`Threshold::Auto`] chooses its threshold at.
    pub fn mean_rate(&self, camera: &Camera) -> f64 {
        let n = (self.frames.max(1) as f64) * self.sum.len().max(1) as f64;
        self.sum.iter().sum::<f64>() / n / camera.g - camera.spurious
    }
}

/// The recording's frames in order, each preprocessed through `profile` as `emccd denoise`
/// does (blooming and the fixed pattern at the recording's exposure removed: DN above bias),
/// passed to `each` with its number (from 0). Errors name the file and the frame.
pub fn preprocessed_frames(
    profile: &CameraProfile,
    rec: &mut emccd_profile::Recording,
    mut each: impl FnMut(usize, &[f32]) -> Result<()>,
) -> Result<()> {
    let name = rec.path.display().to_string();
    let mut raw = vec![0f32; rec.info.width * rec.info.height];
    for j in 0..rec.info.frames {
        let at = |e: String| Error(format!("{name}: frame {}: {e}", j + 1));
        match rec.reader.read_frame(&mut raw) {
            Ok(true) => {}
            Ok(false) => {
                return Err(at(format!(
                    "the file ended before it (its header says {} frames)",
                    rec.info.frames
                )))
            }
            Err(e) => return Err(at(e.to_string())),
        }
        if let Some(i) = raw.iter().position(|v| !v.is_finite()) {
            return Err(at(format!(
                "a non-finite value at pixel ({}, {})",
                i % rec.info.width,
                i / rec.info.width
            )));
        }
        let frame = emccd_classical::frame::preprocess(profile, &raw, rec.exposure)
            .map_err(|e| at(e.to_string()))?;
        each(j, &frame)?;
    }
    Ok(())
}

/// Counts `rec` at `plan`'s thresholds, emitting a [`Tally`] every `per` frames (the last one
/// holds what is left, if the stack is not a multiple of `per`). Memory: one frame and one
/// tally, whatever the stack's length.
pub fn count(
    profile: &CameraProfile,
    rec: &mut emccd_profile::Recording,
    plan: &Plan,
    per: usize,
    mut emit: impl FnMut(&Tally) -> Result<()>,
) -> Result<()> {
    let (frames, pixels) = (rec.info.frames, rec.info.width * rec.info.height);
    if per == 0 {
        return Err(Error("frames per output must be at least 1".into()));
    }
    let mut tally = Tally::new(pixels);
    preprocessed_frames(profile, rec, |j, frame| {
        tally.add(frame, &plan.thresholds);
        if tally.frames as usize == per || j + 1 == frames {
            emit(&tally)?;
            tally = Tally::new(pixels);
        }
        Ok(())
    })
}
