//! What a recording gives training without clean data: its preprocessed frames (a running
//! mean, or a set kept in memory) and, for the self-supervised adaptation methods, the pairs cut
//! from those frames alone.

use emccd_profile::CameraProfile;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::crops::{draw_orientation, orient, sub_image};
use emccd_nn::norm::{prepare_scaled, Scale};
use emccd_nn::{Error, Result};

/// An error unless `frame` has the recording's `width × height` pixels.
fn check_size(frame: &[f32], width: usize, height: usize) -> Result<()> {
    if frame.len() == width * height {
        return Ok(());
    }
    Err(Error::Data(format!(
        "a frame of {} pixels where the recording's frames have {width}×{height}",
        frame.len()
    )))
}

/// Running mean of preprocessed frames (DN above bias), in bounded memory.
#[derive(Clone, Debug)]
pub struct FrameMean {
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) sum: Vec<f64>,
    pub(crate) frames: usize,
}

impl FrameMean {
    /// An empty mean of `width × height` frames.
    pub fn new(width: usize, height: usize) -> FrameMean {
        FrameMean {
            width,
            height,
            sum: vec![0.0; width * height],
            frames: 0,
        }
    }

    /// Adds one frame; an error if its size differs.
    pub fn add(&mut self, frame: &[f32]) -> Result<()> {
        check_size(frame, self.width, self.height)?;
        for (s, &v) in self.sum.iter_mut().zip(frame) {
            *s += v as f64;
        }
        self.frames += 1;
        Ok(())
    }

    /// Frames added.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The mean frame.
    pub fn mean(&self) -> Vec<f32> {
        let n = self.frames.max(1) as f64;
        self.sum.iter().map(|&s| (s / n) as f32).collect()
    }
}

/// Preprocessed frames (DN above bias) kept in memory with their exposures, up to a capacity:
/// what the self-supervised methods train on. For neighbor sampling the frames may show
/// different scenes and exposures; Noise2Noise needs one exposure of a static scene.
#[derive(Clone, Debug)]
pub struct FrameSet {
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) capacity: usize,
    pub(crate) frames: Vec<Vec<f32>>,
    pub(crate) exposures: Vec<f64>,
}

impl FrameSet {
    /// An empty set of `width × height` frames that keeps the first `capacity` added.
    pub fn new(width: usize, height: usize, capacity: usize) -> FrameSet {
        FrameSet {
            width,
            height,
            capacity,
            frames: Vec::new(),
            exposures: Vec::new(),
        }
    }

    /// Adds a frame taken with `exposure_s` (ignored once the set is full); an error if its
    /// size differs or a pixel is not a finite number (it would end training as a diverged run).
    pub fn add(&mut self, frame: &[f32], exposure_s: f64) -> Result<()> {
        check_size(frame, self.width, self.height)?;
        if let Some(k) = frame.iter().position(|v| !v.is_finite()) {
            return Err(Error::Data(format!(
                "pixel ({}, {}) is {}: frames to train on must be finite",
                k % self.width,
                k / self.width,
                frame[k]
            )));
        }
        if self.frames.len() < self.capacity {
            self.frames.push(frame.to_vec());
            self.exposures.push(exposure_s);
        }
        Ok(())
    }

    /// Frames kept.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame is kept.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// The frames' mean photoelectrons per pixel, as `profile` converts DN.
    pub fn mean_electrons(&self, profile: &CameraProfile) -> Result<f64> {
        let k = profile.dn_per_electron()?;
        // Every kept pixel is finite: `add` refuses others.
        let n = self.frames.len() * self.width * self.height;
        let sum: f64 = self.frames.iter().flatten().map(|&v| v as f64).sum();
        let m = sum / n.max(1) as f64 / k;
        if !(m > 0.0) {
            return Err(Error::Data(
                "the recording has no signal above bias: nothing to adapt to".into(),
            ));
        }
        Ok(m)
    }
}

/// Where an adaptation's training pairs come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum AdaptMethod {
    /// Pairs synthesized with the profile's exact noise chain from the scene estimate (the
    /// frames' mean denoised by iterative BM3D at its own noise).
    #[default]
    Resynthesis,
    /// Noise2Noise on frames of the static scene: a crop of one frame is the input, the same
    /// crop of another frame the target. Their noises are independent and the target's mean is
    /// the scene, so an L2 loss learns the clean image without ever seeing it.
    Noise2noise,
    /// Spatial-redundancy sampling (SRDTrans; Neighbor2Neighbor's sub-sampler, without its
    /// regularizer): in every 2×2 cell of a frame one pixel goes to the input and an adjacent
    /// one to the target, two half-size images of one frame with independent noise. Needs a
    /// single frame, but trains on half-resolution images.
    Neighbors,
}

impl AdaptMethod {
    /// The name in the CLI and in a model file's provenance.
    pub fn name(self) -> &'static str {
        match self {
            AdaptMethod::Resynthesis => "resynthesis",
            AdaptMethod::Noise2noise => "noise2noise",
            AdaptMethod::Neighbors => "neighbors",
        }
    }

    /// Frames the method needs at least.
    pub fn min_frames(self) -> usize {
        match self {
            AdaptMethod::Noise2noise => 2,
            _ => 1,
        }
    }
}

/// Training pairs cut from recorded frames alone, in the network's units (as [`prepare`]
/// would give for the input's whole frame), for the self-supervised methods.
///
/// [`prepare`]: emccd_nn::norm::prepare
pub(crate) struct RecordedPairs {
    frames: Vec<Vec<f32>>,
    width: usize,
    height: usize,
    /// Each frame's normalizing scale (slope units), from the whole frame as at inference.
    scales: Vec<f32>,
    slope: f64,
    /// Read-noise maps, one per exposure, and each frame's.
    read_noise: Vec<Vec<f32>>,
    map_of: Vec<usize>,
    method: AdaptMethod,
}

impl RecordedPairs {
    /// Pairs of `method` (not resynthesis) from `set`, whose frames it takes.
    pub(crate) fn new(
        set: FrameSet,
        profile: &CameraProfile,
        method: AdaptMethod,
        rule: Scale,
    ) -> Result<RecordedPairs> {
        if method == AdaptMethod::Resynthesis || set.len() < method.min_frames() {
            return Err(Error::Data(format!(
                "{} needs {} frame(s) of the recording, {} given",
                method.name(),
                method.min_frames(),
                set.len()
            )));
        }
        if (set.width, set.height) != (profile.width, profile.height) {
            return Err(Error::Data(format!(
                "frames are {}×{}, the profile's sensor is {}×{}",
                set.width, set.height, profile.width, profile.height
            )));
        }
        if method == AdaptMethod::Noise2noise
            && set.exposures.iter().any(|&t| t != set.exposures[0])
        {
            return Err(Error::Data(
                "noise2noise pairs frames of one static scene: the frames' exposures differ".into(),
            ));
        }
        let slope = profile.slope()?;
        let s = slope as f32;
        let scales = set
            .frames
            .iter()
            .map(|f| rule.of(&f.iter().map(|v| v / s).collect::<Vec<f32>>(), set.width))
            .collect();
        let mut exposures: Vec<f64> = Vec::new();
        let mut map_of = Vec::with_capacity(set.len());
        for &t in &set.exposures {
            emccd_profile::check_exposure(t)?;
            map_of.push(match exposures.iter().position(|&e| e == t) {
                Some(k) => k,
                None => {
                    exposures.push(t);
                    exposures.len() - 1
                }
            });
        }
        Ok(RecordedPairs {
            frames: set.frames,
            width: set.width,
            height: set.height,
            scales,
            slope,
            read_noise: exposures
                .iter()
                .map(|&t| profile.read_noise_near(t).to_vec())
                .collect(),
            map_of,
            method,
        })
    }

    /// The largest crop side, at most `crop`, a multiple of `multiple`, that the frames give
    /// (the neighbor sampler halves a window twice the crop's side).
    pub(crate) fn side(&self, crop: usize, multiple: usize) -> usize {
        let k = if self.method == AdaptMethod::Neighbors {
            2
        } else {
            1
        };
        crop.min(self.width / k).min(self.height / k) / multiple * multiple
    }

    /// Pair number `seed`: input [2, c, c] and target [c, c], 8-way augmented if `augment`.
    pub(crate) fn sample(&self, c: usize, augment: bool, seed: u64) -> (Vec<f32>, Vec<f32>) {
        let mut rng = Pcg64::seed_from_u64(seed);
        let (w, h) = (self.width, self.height);
        let i = rng.random_range(0..self.frames.len());
        let (inp, rn, tgt) = match self.method {
            AdaptMethod::Neighbors => {
                let (x0, y0) = (
                    rng.random_range(0..=w - 2 * c),
                    rng.random_range(0..=h - 2 * c),
                );
                let f = &self.frames[i];
                let (mut a, mut r, mut b) =
                    (vec![0f32; c * c], vec![0f32; c * c], vec![0f32; c * c]);
                // One pixel of the cell, then one of its two neighbors in the cell.
                const CELL: [(usize, usize); 4] = [(0, 0), (1, 0), (1, 1), (0, 1)];
                for k in 0..c * c {
                    let (cx, cy) = (x0 + 2 * (k % c), y0 + 2 * (k / c));
                    let p = rng.random_range(0..4usize);
                    let q = (p + if rng.random::<bool>() { 1 } else { 3 }) % 4;
                    let at = |j: usize| (cy + CELL[j].1) * w + cx + CELL[j].0;
                    a[k] = f[at(p)];
                    r[k] = self.read_noise[self.map_of[i]][at(p)];
                    b[k] = f[at(q)];
                }
                (a, r, b)
            }
            _ => {
                let mut j = rng.random_range(0..self.frames.len() - 1);
                if j >= i {
                    j += 1;
                }
                let (x0, y0) = (rng.random_range(0..=w - c), rng.random_range(0..=h - c));
                (
                    sub_image(&self.frames[i], w, x0, y0, c, c),
                    sub_image(&self.read_noise[self.map_of[i]], w, x0, y0, c, c),
                    sub_image(&self.frames[j], w, x0, y0, c, c),
                )
            }
        };
        let mode = draw_orientation(&mut rng, augment);
        let p = prepare_scaled(
            &orient(&inp, c, mode),
            self.slope,
            &orient(&rn, c, mode),
            self.scales[i],
        );
        let target = orient(&tgt, c, mode).iter().map(|v| v / p.to_dn).collect();
        (p.input, target)
    }
}
