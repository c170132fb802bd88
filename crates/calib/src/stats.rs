//! Streaming per-pixel statistics of a stack: one pass, frame by frame, memory independent of
//! the number of frames.
//!
//! Sums are kept relative to the first frame (the "shifted data" form of the variance): with
//! `d = x − x₀`, `Σd` and `Σd²` in f64 give the mean and unbiased variance without the
//! cancellation of raw sums (EMCCD bias sits at hundreds of DN while read noise is a few) and,
//! unlike Welford's update, need no division per sample, so the inner loop vectorizes.

use std::path::Path;

use rayon::prelude::*;

use crate::{Error, Result};

/// Pixels per parallel work item (64 KiB of f32: large enough to amortize scheduling).
const CHUNK: usize = 16 * 1024;

/// Per-pixel mean and variance of a stack, plus the raw values of a few probe pixels.
#[derive(Clone, Debug)]
pub struct StackStats {
    /// Frame width.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// Frames accumulated.
    pub frames: usize,
    /// Samples at or above the ADC maximum (when one was given).
    pub saturated: u64,
    /// Values of the probe pixels, frame by frame (capped at [`PROBE_CAP`] per pixel).
    pub probes: Vec<(usize, Vec<f32>)>,
    /// Differences of paired frames, pooled (bias stacks: the spurious-charge fit's data).
    pub differences: Option<crate::spurious::Differences>,
    shift: Vec<f32>,
    s1: Vec<f64>,
    s2: Vec<f64>,
}

/// Most values kept per probe pixel (the normality check needs thousands, not millions).
pub const PROBE_CAP: usize = 20_000;

impl StackStats {
    /// Empty statistics for `width × height` frames, recording the raw values of `probes`.
    pub fn new(width: usize, height: usize, probes: &[usize]) -> StackStats {
        let n = width * height;
        StackStats {
            width,
            height,
            frames: 0,
            saturated: 0,
            probes: probes
                .iter()
                .filter(|&&i| i < n)
                .map(|&i| (i, Vec::new()))
                .collect(),
            differences: None,
            shift: vec![0.0; n],
            s1: vec![0.0; n],
            s2: vec![0.0; n],
        }
    }

    /// Adds one frame. Returns the index of a non-finite sample, if any (the frame is then not
    /// fully added and the statistics must be discarded).
    pub fn push(&mut self, frame: &[f32], adc_max: Option<f32>) -> std::result::Result<(), usize> {
        assert_eq!(frame.len(), self.shift.len(), "frame size");
        let first = self.frames == 0;
        let sat_at = adc_max.unwrap_or(f32::INFINITY);
        let (bad, sat) = self
            .shift
            .par_chunks_mut(CHUNK)
            .zip(self.s1.par_chunks_mut(CHUNK))
            .zip(self.s2.par_chunks_mut(CHUNK))
            .zip(frame.par_chunks(CHUNK))
            .enumerate()
            .map(|(c, (((sh, s1), s2), x))| {
                let mut finite = true;
                let mut sat = 0u64;
                if first {
                    sh.copy_from_slice(x);
                }
                for (((sh, s1), s2), &x) in sh.iter().zip(s1.iter_mut()).zip(s2.iter_mut()).zip(x) {
                    finite &= x.is_finite();
                    sat += (x >= sat_at) as u64;
                    let d = (x - *sh) as f64;
                    *s1 += d;
                    *s2 += d * d;
                }
                let bad = if finite {
                    None
                } else {
                    x.iter().position(|v| !v.is_finite()).map(|i| c * CHUNK + i)
                };
                (bad, sat)
            })
            .reduce(|| (None, 0), |a, b| (a.0.or(b.0), a.1 + b.1));
        if let Some(i) = bad {
            return Err(i);
        }
        self.saturated += sat;
        if let Some(d) = &mut self.differences {
            d.push(frame);
        }
        for (i, v) in &mut self.probes {
            if v.len() < PROBE_CAP {
                v.push(frame[*i]);
            }
        }
        self.frames += 1;
        Ok(())
    }

    /// Per-pixel temporal mean.
    pub fn mean(&self) -> Vec<f32> {
        let n = self.frames.max(1) as f64;
        self.shift
            .par_iter()
            .zip(&self.s1)
            .map(|(&s, &a)| (s as f64 + a / n) as f32)
            .collect()
    }

    /// Per-pixel unbiased temporal variance (0 with fewer than 2 frames).
    pub fn variance(&self) -> Vec<f32> {
        let n = self.frames as f64;
        if self.frames < 2 {
            return vec![0.0; self.s1.len()];
        }
        self.s1
            .par_iter()
            .zip(&self.s2)
            .map(|(&a, &b)| ((b - a * a / n) / (n - 1.0)).max(0.0) as f32)
            .collect()
    }

    /// Per-pixel temporal standard deviation.
    pub fn std(&self) -> Vec<f32> {
        self.variance().into_iter().map(f32::sqrt).collect()
    }
}

/// What [`accumulate`] reports while it runs.
pub trait Progress: Sync {
    /// `frames` more frames were read.
    fn advance(&self, frames: u64);
}

/// No progress reporting.
pub struct Silent;
impl Progress for Silent {
    fn advance(&self, _: u64) {}
}

/// Reads a whole stack frame by frame into [`StackStats`] (with the paired-frame differences
/// into `differences` when given). Errors (naming the file) for a stack of fewer than `min_frames` frames, frames of the wrong size, NaN or infinite samples,
/// and unreadable or truncated files.
pub fn accumulate(
    path: &Path,
    expect: Option<(usize, usize)>,
    min_frames: usize,
    probes: &[usize],
    adc_max: Option<f32>,
    differences: Option<crate::spurious::Differences>,
    progress: &dyn Progress,
) -> Result<(emccd_io::StackInfo, StackStats)> {
    let mut r = emccd_io::open(path).map_err(|e| Error::io(path, e))?;
    let info = r.info().clone();
    if let Some((w, h)) = expect {
        if (info.width, info.height) != (w, h) {
            return Err(Error::input(
                path,
                format!(
                    "frames are {}×{}, but the other stacks are {w}×{h}",
                    info.width, info.height
                ),
            ));
        }
    }
    if info.frames < min_frames {
        return Err(Error::input(
            path,
            format!(
                "holds {} frame(s); temporal statistics need at least {min_frames}",
                info.frames
            ),
        ));
    }
    let mut st = StackStats::new(info.width, info.height, probes);
    st.differences = differences;
    let mut buf = vec![0f32; info.frame_len()];
    loop {
        let more = r.read_frame(&mut buf).map_err(|e| {
            Error::input(
                path,
                format!("frame {}: {}", st.frames + 1, crate::error::io_message(e)),
            )
        })?;
        if !more {
            break;
        }
        if let Err(i) = st.push(&buf, adc_max) {
            return Err(Error::input(
                path,
                format!(
                    "frame {} has a non-finite value at pixel ({}, {})",
                    st.frames + 1,
                    i % info.width,
                    i / info.width
                ),
            ));
        }
        progress.advance(1);
    }
    if st.frames < min_frames {
        return Err(Error::input(
            path,
            format!(
                "only {} frame(s) could be read; need at least {min_frames}",
                st.frames
            ),
        ));
    }
    Ok((info, st))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_variance_match_two_pass() {
        let (w, h, n) = (130, 7, 25);
        let mut st = StackStats::new(w, h, &[3]);
        let mut all = Vec::new();
        for k in 0..n {
            let f: Vec<f32> = (0..w * h)
                .map(|i| 500.0 + ((i * 7919 + k * 104729) % 97) as f32 * 0.37)
                .collect();
            st.push(&f, None).unwrap();
            all.push(f);
        }
        let (m, v) = (st.mean(), st.variance());
        for i in [0, 17, w * h - 1] {
            let mu = all.iter().map(|f| f[i] as f64).sum::<f64>() / n as f64;
            let var = all.iter().map(|f| (f[i] as f64 - mu).powi(2)).sum::<f64>() / (n - 1) as f64;
            assert!(
                (m[i] as f64 - mu).abs() < 1e-4 && (v[i] as f64 - var).abs() < 1e-3 * var.max(1.0)
            );
        }
        assert_eq!(st.probes[0].1.len(), n);
    }

    #[test]
    fn nan_is_located() {
        let mut st = StackStats::new(4, 3, &[]);
        let mut f = vec![1.0f32; 12];
        f[6] = f32::NAN;
        assert_eq!(st.push(&f, None), Err(6));
    }
}
