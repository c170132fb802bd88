//! A stack in memory counted as `emccd count` counts a file: what Python's `emccd.count` and
//! `emccd evaluate`'s `count` and `analog` methods run.

use emccd_profile::CameraProfile;

use crate::plan::{Camera, ReadNoise, Threshold};
use crate::tally::Counter;
use crate::{Error, Result};

/// The frames the light level (what [`Threshold::Auto`] chooses at) is measured on: enough
/// for its mean to be known to a few percent at 0.01 e⁻ per pixel on a 128² sensor. Every
/// process of a sharded run measures it on the same frames, the stack's first.
pub const LEVEL_FRAMES: usize = 100;

/// How a stack is counted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Request {
    /// The threshold.
    pub threshold: Threshold,
    /// Input frames per output frame (the whole stack with `None`).
    pub per: Option<usize>,
    /// The analog mean instead of counting.
    pub analog: bool,
    /// Clock-induced charge per frame and dark current per second replacing the profile's.
    pub spurious: Option<(f64, f64)>,
    /// Each pixel's read noise.
    pub read_noise: ReadNoise,
}

impl Default for Request {
    fn default() -> Request {
        Request {
            threshold: Threshold::Likelihood,
            per: None,
            analog: false,
            spurious: None,
            read_noise: ReadNoise::Auto,
        }
    }
}

/// A counted stack.
#[derive(Clone, Debug)]
pub struct Counted {
    /// Output frames, one after another: photo-electrons per pixel per frame.
    pub rate: Vec<f32>,
    /// Their standard errors.
    pub error: Vec<f32>,
    /// Output frames.
    pub outputs: usize,
    /// Input frames per output frame (the last holds what is left).
    pub per: usize,
    /// The register's DN per photo-electron: `rate` times it is the photo-signal in DN above
    /// bias.
    pub dn_per_electron: f64,
    /// The threshold chosen and what it predicts, for a person.
    pub notes: Vec<String>,
}

/// Counts `raw` (frames of `profile`'s size one after another, DN as the camera wrote them,
/// taken with `exposure_s`) as `req` asks.
pub fn count_stack(
    profile: &CameraProfile,
    raw: &[f32],
    exposure_s: f64,
    req: &Request,
) -> Result<Counted> {
    let px = profile.width * profile.height;
    if px == 0 || raw.is_empty() || raw.len() % px != 0 {
        return Err(Error(format!(
            "{} values are not whole {}×{} frames",
            raw.len(),
            profile.width,
            profile.height
        )));
    }
    let frames = raw.len() / px;
    let cam = Camera::from_profile(profile, exposure_s, req.spurious, req.read_noise)?;
    let pre: Vec<Vec<f32>> = raw
        .chunks(px)
        .map(|fr| emccd_classical::frame::preprocess(profile, fr, exposure_s))
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| Error(e.to_string()))?;
    let first = &pre[..frames.min(LEVEL_FRAMES)];
    let level =
        first.iter().flatten().map(|&v| v as f64).sum::<f64>() / (first.len() * px) as f64 / cam.g
            - cam.unremoved();
    crate::tally::check_level(level, &cam)?;
    let per = req.per.unwrap_or(frames);
    let g = cam.g;
    let mut counter = Counter::new(cam, req.threshold, level, per, frames, req.analog)?;
    let (fe, missed) = counter.plan().predicted();
    let mut notes = vec![match (req.threshold, counter.plan().k_sigma) {
        (Threshold::Likelihood, _) => {
            "threshold none (each pixel's values in 30 bins, the most likely rate)".to_string()
        }
        (_, Some(k)) => format!("threshold {k:.2} sigma"),
        (t, None) => format!("threshold {t:?}"),
    }];
    // What one threshold predicts; the likelihood has none.
    if req.threshold != Threshold::Likelihood {
        notes.push(format!(
            "predicted false events per pixel per frame {fe:.3e}, single photo-electron missed {:.1} %",
            100.0 * missed
        ));
    }
    let (mut rate, mut error, mut outputs) = (Vec::new(), Vec::new(), 0);
    for fr in &pre {
        if let Some((r, s)) = counter.add(fr) {
            rate.extend(r);
            error.extend(s);
            outputs += 1;
        }
    }
    Ok(Counted {
        rate,
        error,
        outputs,
        per,
        dn_per_electron: g,
        notes,
    })
}
