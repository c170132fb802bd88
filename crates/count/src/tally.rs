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
    /// With the likelihood: each pixel's bin counts ([`crate::likelihood::BINS`] a pixel).
    pub bins: Vec<u16>,
}

impl Tally {
    /// An empty tally of `pixels` pixels.
    pub fn new(pixels: usize) -> Tally {
        Tally {
            counts: vec![0; pixels],
            sum: vec![0.0; pixels],
            frames: 0,
            bins: Vec::new(),
        }
    }

    /// An empty tally that also keeps each pixel's bin counts.
    pub fn binned(pixels: usize) -> Tally {
        Tally {
            bins: vec![0; pixels * crate::likelihood::BINS],
            ..Tally::new(pixels)
        }
    }

    /// Adds one preprocessed frame's values to the pixels' bin counts (before [`Tally::add`],
    /// which counts the frame).
    pub fn add_bins(&mut self, frame: &[f32], binning: &[crate::likelihood::Binning]) {
        const CHUNK: usize = 4096;
        let b = crate::likelihood::BINS;
        self.bins
            .par_chunks_mut(CHUNK * b)
            .zip(frame.par_chunks(CHUNK).zip(binning.par_chunks(CHUNK)))
            .for_each(|(h, (f, bn))| {
                for ((h, &v), bn) in h.chunks_mut(b).zip(f).zip(bn) {
                    h[bn.bin(v)] += 1;
                }
            });
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
    /// spurious electrons preprocessing left (photo-electrons per pixel per frame).
    pub fn analog(&self, camera: &Camera) -> Vec<f32> {
        let n = self.frames.max(1) as f64;
        self.sum
            .iter()
            .enumerate()
            .map(|(i, &s)| (s / n / camera.g - camera.unremoved_at(i)) as f32)
            .collect()
    }

    /// The mean photo-electron rate over every pixel (the analog estimate's mean): the level
    /// [`Threshold::Auto`] chooses its threshold at.
    pub fn mean_rate(&self, camera: &Camera) -> f64 {
        let n = (self.frames.max(1) as f64) * self.sum.len().max(1) as f64;
        self.sum.iter().sum::<f64>() / n / camera.g - camera.unremoved()
    }
}

/// A recording read in order, each frame preprocessed through a profile as `emccd denoise`
/// does (blooming and the fixed pattern at the recording's exposure removed: DN above bias).
/// The fixed pattern is modelled once for the stack. Errors name the file and the frame.
pub struct Preprocessed<'a> {
    rec: &'a mut emccd_profile::Recording,
    name: String,
    fpn: Vec<f32>,
    bloom: f64,
    raw: Vec<f32>,
    /// The next frame's number, from 0.
    next: usize,
}

impl<'a> Preprocessed<'a> {
    /// The recording through `profile`, from its next frame (its first for a fresh one); an
    /// error if the profile cannot preprocess it (size, exposure).
    pub fn new(
        profile: &CameraProfile,
        rec: &'a mut emccd_profile::Recording,
    ) -> Result<Preprocessed<'a>> {
        let name = rec.path.display().to_string();
        let pixels = rec.info.width * rec.info.height;
        emccd_classical::frame::usable(profile, pixels, rec.exposure)
            .map_err(|e| Error(format!("{name}: {e}")))?;
        let mut fpn = vec![0f32; pixels];
        profile.fpn_at(rec.exposure, &mut fpn);
        let bloom = profile.blooming_factor(rec.exposure);
        Ok(Preprocessed {
            rec,
            name,
            fpn,
            bloom,
            raw: vec![0f32; pixels],
            next: 0,
        })
    }

    /// Frames in the recording.
    pub fn frames(&self) -> usize {
        self.rec.info.frames
    }

    fn at(&self, e: impl std::fmt::Display) -> Error {
        Error(format!("{}: frame {}: {e}", self.name, self.next + 1))
    }

    /// Passes over frames unread until frame `j` (from 0) is the next.
    pub fn skip_to(&mut self, j: usize) -> Result<()> {
        while self.next < j {
            self.rec.reader.skip_frame().map_err(|e| self.at(e))?;
            self.next += 1;
        }
        Ok(())
    }

    /// The next frame, preprocessed.
    pub fn next_frame(&mut self) -> Result<&[f32]> {
        match self.rec.reader.read_frame(&mut self.raw) {
            Ok(true) => {}
            Ok(false) => {
                return Err(self.at(format!(
                    "the file ended before it (its header says {} frames)",
                    self.rec.info.frames
                )))
            }
            Err(e) => return Err(self.at(e)),
        }
        if let Some(i) = self.raw.iter().position(|v| !v.is_finite()) {
            let w = self.rec.info.width;
            return Err(self.at(format!(
                "a non-finite value at pixel ({}, {}) ({}; a float64 beyond float32's ±3.4e38 reads as ±inf)",
                i % w,
                i / w,
                self.raw[i]
            )));
        }
        emccd_profile::preprocess(&mut self.raw, self.rec.info.width, self.bloom, &self.fpn);
        self.next += 1;
        Ok(&self.raw)
    }
}

/// The recording's first `limit` frames in order (all of them with `usize::MAX`), each
/// preprocessed ([`Preprocessed`]), passed to `each` with its number (from 0).
pub fn preprocessed_frames(
    profile: &CameraProfile,
    rec: &mut emccd_profile::Recording,
    limit: usize,
    mut each: impl FnMut(usize, &[f32]) -> Result<()>,
) -> Result<()> {
    let mut p = Preprocessed::new(profile, rec)?;
    for j in 0..p.frames().min(limit) {
        each(j, p.next_frame()?)?;
    }
    Ok(())
}

/// Counts output frames `outputs` (from 0) of the recording into `write(k, rate, error)`:
/// output `k` from input frames `k·per …` as `counter` makes them. Outputs for which
/// `done(k)` holds (complete in a store from an earlier run or another process) are passed
/// over with their input frames unread. Returns how many were written.
pub fn count_outputs(
    profile: &CameraProfile,
    rec: &mut emccd_profile::Recording,
    counter: &mut Counter,
    outputs: std::ops::Range<usize>,
    done: impl Fn(usize) -> bool,
    mut write: impl FnMut(usize, &[f32], &[f32]) -> Result<()>,
    mut on_frame: impl FnMut(),
) -> Result<usize> {
    let (per, frames) = (counter.per, counter.frames);
    let mut p = Preprocessed::new(profile, rec)?;
    let mut written = 0;
    for k in outputs {
        if done(k) {
            continue;
        }
        let first = k * per;
        if first >= frames {
            return Err(Error(format!(
                "output frame {} asked of {frames} frames in outputs of {per}",
                k + 1
            )));
        }
        p.skip_to(first)?;
        counter.restart_at(first);
        for _ in first..(first + per).min(frames) {
            on_frame();
            if let Some((rate, se)) = counter.add(p.next_frame()?) {
                write(k, &rate, &se)?;
                written += 1;
            }
        }
    }
    Ok(written)
}

impl Tally {
    /// The analog estimate's standard error per pixel: the EM register doubles the
    /// photo-electrons' Poisson variance (f² = 2), read noise adds its own, over the frames.
    pub fn analog_error(&self, camera: &Camera) -> Vec<f32> {
        let n = self.frames.max(1) as f64;
        self.sum
            .iter()
            .enumerate()
            .map(|(i, &s)| {
                let rate = s / n / camera.g - camera.unremoved_at(i);
                camera.analog_variance(i, rate.max(0.0), n).sqrt() as f32
            })
            .collect()
    }
}

/// The recording's light level: the mean of its first `frames` preprocessed frames (at most)
/// over the profile's DN per photo-electron, in photo-electrons per pixel per frame as the analog
/// mean sees them (with the spurious electrons preprocessing left: [`Camera::unremoved`]).
/// Reads only those frames.
pub fn light_level(
    profile: &CameraProfile,
    rec: &mut emccd_profile::Recording,
    frames: usize,
) -> Result<f64> {
    let k = profile
        .dn_per_electron()
        .map_err(|e| Error(e.to_string()))?;
    let (mut sum, mut n) = (0.0, 0usize);
    preprocessed_frames(profile, rec, frames, |_, f| {
        sum += f.iter().map(|&v| v as f64).sum::<f64>();
        n += f.len();
        Ok(())
    })?;
    Ok(sum / n.max(1) as f64 / k)
}

/// An error where a stack's light `level` (photo-electrons per pixel per frame, as
/// [`light_level`] measures it, less what preprocessing leaves of the spurious charge) puts its
/// mean more than [`BELOW_BIAS`] read-noise σ below the profile's bias: no raw frames of this
/// camera give that (a denoised or bias-subtracted file fed back, another camera's frames, an
/// all-zero stack), and counting them gives rates at or below zero with no warning.
pub fn check_level(level: f64, cam: &Camera) -> Result<()> {
    let mut s: Vec<f32> = cam.sigma.clone();
    s.sort_by(f32::total_cmp);
    let sigma = s.get(s.len() / 2).copied().unwrap_or(0.0) as f64;
    let below = -level * cam.g;
    if sigma > 0.0 && below > BELOW_BIAS * sigma {
        return Err(Error(format!(
            "the frames lie {below:.1} DN ({:.0} read-noise σ) below the profile's bias on average ({level:.3} photo-electrons per pixel per frame): not this camera's raw frames (a denoised or bias-subtracted file, another camera's, an empty stack?); count takes the camera's raw frames",
            below / sigma
        )));
    }
    Ok(())
}

/// How far below the bias (read-noise σ of one value) a stack's mean may lie: a mean over a
/// frame of pixels errs by a small share of σ, a profile's bias by about one.
pub const BELOW_BIAS: f64 = 3.0;

/// A counted rate's standard error at or beyond this (f32::MAX where every frame crossed the
/// threshold) says the count holds no rate.
const UNBOUNDED: f32 = 1e30;

/// A stack counted frame by frame into output frames of `per` frames each: the rate (counted,
/// or the analog mean) and its standard error per pixel. What `emccd count` and Python's
/// `emccd.count` share; the frames come preprocessed (DN above bias), from a file or an array.
///
/// With the automatic threshold each pixel takes the estimate whose predicted error is smaller
/// at its analog rate: counting where light is faint, the analog mean where a pixel is bright
/// enough that coincidences cost more than the register's excess noise (a bright spot in a
/// faint field, which counting alone saturates).
pub struct Counter {
    camera: Camera,
    plan: Plan,
    per: usize,
    mode: Mode,
    tally: Tally,
    seen: usize,
    frames: usize,
    analog_share: f64,
}

/// Which estimate a [`Counter`] writes.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Counted,
    Analog,
    Best,
    Likelihood,
}

impl Counter {
    /// A counter for `frames` frames of `camera` in output frames of `per` (the last holds what
    /// is left). `threshold` `Auto` is resolved at `level`, the stack's photo-electrons per
    /// pixel per frame (its analog mean: [`Tally::mean_rate`] of a first pass).
    pub fn new(
        camera: Camera,
        threshold: crate::Threshold,
        level: f64,
        per: usize,
        frames: usize,
        analog: bool,
    ) -> Result<Counter> {
        if per == 0 || per > frames {
            return Err(Error(format!(
                "frames per output must be 1 to the stack's {frames}, not {per}"
            )));
        }
        let mode = match (analog, threshold) {
            (true, _) => Mode::Analog,
            (false, crate::Threshold::Auto) => Mode::Best,
            (false, crate::Threshold::Likelihood) => Mode::Likelihood,
            _ => Mode::Counted,
        };
        if mode == Mode::Likelihood && per > crate::likelihood::MAX_FRAMES {
            return Err(Error(format!(
                "the likelihood keeps 16-bit counts: at most {} frames per output, not {per} (--per)",
                crate::likelihood::MAX_FRAMES
            )));
        }
        let threshold = match threshold {
            crate::Threshold::Auto => {
                crate::Threshold::Sigma(crate::choose_k(&camera, level, per as u32))
            }
            t => t,
        };
        let plan = Plan::new(&camera, threshold);
        let pixels = camera.width * camera.height;
        Ok(Counter {
            camera,
            plan,
            per,
            mode,
            tally: Counter::empty(mode, pixels),
            seen: 0,
            frames,
            analog_share: 0.0,
        })
    }

    /// Starts a new output frame at input frame `frame` (from 0): what was added is dropped.
    pub fn restart_at(&mut self, frame: usize) {
        self.tally = Counter::empty(self.mode, self.camera.sigma.len());
        self.seen = frame;
    }

    fn empty(mode: Mode, pixels: usize) -> Tally {
        if mode == Mode::Likelihood {
            Tally::binned(pixels)
        } else {
            Tally::new(pixels)
        }
    }

    /// Input frames per output frame.
    pub fn per(&self) -> usize {
        self.per
    }

    /// The thresholds and what they predict.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// The camera counted.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The share of the last output frame's pixels that took the analog estimate (0 unless
    /// the threshold is automatic, 1 with `analog`).
    pub fn analog_share(&self) -> f64 {
        self.analog_share
    }

    /// Adds the next preprocessed frame; returns an output frame (rate, standard error) when
    /// this one completes it.
    pub fn add(&mut self, frame: &[f32]) -> Option<(Vec<f32>, Vec<f32>)> {
        if let Some(binning) = self.plan.binning() {
            self.tally.add_bins(frame, binning);
        }
        self.tally.add(frame, &self.plan.thresholds);
        self.seen += 1;
        if self.tally.frames as usize == self.per || self.seen == self.frames {
            let t = std::mem::replace(
                &mut self.tally,
                Counter::empty(self.mode, self.camera.sigma.len()),
            );
            let cam = &self.camera;
            Some(match self.mode {
                Mode::Analog => {
                    self.analog_share = 1.0;
                    (t.analog(cam), t.analog_error(cam))
                }
                Mode::Counted => self.plan.estimate(&t.counts, t.frames),
                Mode::Best | Mode::Likelihood => {
                    let (ra, sa) = (t.analog(cam), t.analog_error(cam));
                    let (mut rate, mut se) = if self.mode == Mode::Likelihood {
                        self.plan
                            .estimate_binned(&t.bins, t.frames, &ra)
                            .expect("a likelihood plan")
                    } else {
                        self.plan.estimate(&t.counts, t.frames)
                    };
                    // Both errors predicted at the pixel's level as its eight neighbours' analog
                    // mean shows it: not at its own, whose noise would then decide which of
                    // its two estimates it takes (a faint pixel read low would take the analog
                    // mean, and the stack's mean would run low).
                    let (w, h) = (cam.width, cam.height);
                    let n = t.frames as f64;
                    let analog: Vec<bool> = (0..rate.len())
                        .into_par_iter()
                        .map(|i| {
                            let (x, y) = (i % w, i / w);
                            let (mut sum, mut k) = (0.0, 0);
                            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                                    if (xx, yy) != (x, y) {
                                        sum += ra[yy * w + xx] as f64;
                                        k += 1;
                                    }
                                }
                            }
                            let level = if k > 0 { sum / k as f64 } else { ra[i] as f64 }.max(0.0);
                            let own = match self.plan.bin_model(i) {
                                Some(m) => m.variance(level, t.frames),
                                None => self.plan.model(i).variance(level, t.frames),
                            };
                            own > cam.analog_variance(i, level, n)
                        })
                        .collect();
                    // A pixel over the threshold in (nearly) every frame has no counted rate at
                    // all (its error unbounded: 36 e⁻ a frame came out 19.995 ± 3.4e38): the
                    // analog mean is its estimate whatever its neighbours show. Only a bright
                    // pixel is, so the choice biases no faint one.
                    let mut taken = 0usize;
                    for (i, &a) in analog.iter().enumerate() {
                        if a || !(se[i] < UNBOUNDED) {
                            rate[i] = ra[i];
                            se[i] = sa[i];
                            taken += 1;
                        }
                    }
                    self.analog_share = taken as f64 / rate.len().max(1) as f64;
                    (rate, se)
                }
            })
        } else {
            None
        }
    }
}
