//! A recording's frames denoised with their neighbours ([`Method::Temporal`],
//! [`Method::TemporalNet`]) in bounded memory: each frame is preprocessed (and, for the
//! classical method, given its single-frame estimate) once, as it is read, and at most `2K + 1`
//! of them (the window of `K` frames each side) are held at a time. A frame's window stays
//! within its recording: the classical method's is clipped at the recording's ends; the
//! network's (a fixed number of frames) shows the frame's scene at its brightness, the frames
//! beyond the scene or the recording mirrored about the frame ([`net_window`]).

use std::collections::VecDeque;

use rayon::prelude::*;
use std::ops::Range;

use emccd_classical::frame::vst_params;
use emccd_classical::vst::PoissonGaussian;
use emccd_nn::norm::mirror;
use emccd_nn::{Error, Result};
use emccd_profile::CameraProfile;

use crate::denoiser::Denoiser;
use crate::Method;

/// One frame held for the windows it belongs to: its number, the preprocessed frame and its
/// single-frame estimate (the classical method's), or its [`guide`] (the network's), both DN
/// above bias.
struct Held {
    index: usize,
    frame: Vec<f32>,
    single: Vec<f32>,
}

/// Frames `want` of a recording of `count` frames taken with `exposure_s`, denoised by `fd`'s
/// temporal method with `fd.window` frames each side. The recording's frames are taken in
/// order by `next(j, Some(buf))`, from the first any window needs; the ones before it are
/// passed over by `next(j, None)`. Each wanted frame is handed to `emit(j, frame)`, in order,
/// in `fd`'s units. Errors about a frame are named by `at(j)`.
#[allow(clippy::too_many_arguments)]
pub fn denoise_frames(
    fd: &Denoiser,
    exposure_s: f64,
    count: usize,
    want: Range<usize>,
    at: &dyn Fn(usize) -> String,
    next: &mut dyn FnMut(usize, Option<&mut [f32]>) -> Result<()>,
    emit: &mut dyn FnMut(usize, Vec<f32>) -> Result<()>,
) -> Result<()> {
    let want = want.start..want.end.min(count);
    if want.is_empty() {
        return Ok(());
    }
    fd.check_model()?;
    let k = fd.window;
    let (lo, hi) = (want.start.saturating_sub(k), (want.end + k).min(count));
    let p = fd.profile;
    let noise = vst_params(p, exposure_s)?;
    let to_units = fd.units.factor(p)?;
    for j in 0..lo {
        next(j, None)?;
    }
    // A recording of more than one frame with a window: the classical method's frames are
    // members of windows, at this noise.
    let members = (k > 0 && count > 1).then_some(noise);
    let mut held: VecDeque<Held> = VecDeque::with_capacity(2 * k + 1);
    let mut buf = vec![0f32; p.len()];
    let mut due = want.start;
    for j in lo..hi {
        next(j, Some(&mut buf))?;
        held.push_back(prepare(fd, j, &buf, exposure_s, members).map_err(|e| e.at(at(j)))?);
        // Every frame whose window is now complete (or ends at the last frame read). A frame
        // is denoised as soon as frame `due + k` is read, so what is held past the frames
        // before its window is exactly its window.
        while due < want.end && (due + k <= j || j + 1 == hi) {
            while held.front().is_some_and(|h| h.index + k < due) {
                held.pop_front();
            }
            let first = held.front().expect("the frame itself is held").index;
            let frames: Vec<&[f32]> = held.iter().map(|h| h.frame.as_slice()).collect();
            let mut out = match fd.model.filter(|_| fd.method == Method::TemporalNet) {
                // The network's fixed window: the frame's scene, at its brightness.
                Some(model) => {
                    let guides: Vec<&[f32]> = held.iter().map(|h| h.single.as_slice()).collect();
                    let shown = net_window(&frames, &guides, due - first, k, p.width, noise);
                    let window: Vec<&[f32]> = shown.iter().map(Vec::as_slice).collect();
                    fd.inference(model)
                        .denoise_window(&window, exposure_s)
                        .map_err(|e| e.at(at(due)))?
                }
                None => {
                    let singles: Vec<&[f32]> = held.iter().map(|h| h.single.as_slice()).collect();
                    emccd_classical::temporal::estimate(
                        &frames,
                        &singles,
                        due - first,
                        p.width,
                        p.height,
                        noise,
                    )
                }
            };
            if to_units != 1.0 {
                out.iter_mut().for_each(|v| *v *= to_units);
            }
            emit(due, out)?;
            due += 1;
        }
    }
    Ok(())
}

/// The `2k + 1` frames a temporal network is shown for frame `center` of `window` (the
/// preprocessed frames within `k` of it, clipped at the recording's ends; `width` px wide,
/// noise `noise`; `guides` each frame's [`guide`]): the frames of its scene — a scene cut or
/// motion too fast to follow ends the scene, as the classical method's tracking finds it
/// ([`emccd_classical::temporal::scene`]), and so does a neighbour whose whole frame does not
/// correlate with this one ([`LIKENESS_GATE`]) — brought to its brightness along the scene's
/// trend (bleaching), and the frames beyond the scene or the recording mirrored about the frame
/// ([`mirror`]), as the network saw a movie's ends in training.
pub fn net_window(
    window: &[&[f32]],
    guides: &[&[f32]],
    center: usize,
    k: usize,
    width: usize,
    noise: PoissonGaussian,
) -> Vec<Vec<f32>> {
    let height = window[center].len() / width.max(1);
    let mut sc = emccd_classical::temporal::scene(window, guides, center, width, height, noise);
    // The tracking finds a cut only where the other scene's blocks are not found again near
    // where they were; a cut to content of the same local kind (bars turned, texture for
    // texture) passes it, and a network shown the whole frame would blend it in. Over the
    // whole frame, though, the other scene does not correlate with this one.
    let binned: Vec<(Vec<f32>, usize, usize)> =
        guides.iter().map(|g| bin2(g, width, height)).collect();
    let (bw, bh) = (binned[center].1, binned[center].2);
    let like: Vec<Option<f64>> = (0..window.len())
        .map(|j| {
            (j != center && (sc.first..=sc.last).contains(&j))
                .then(|| likeness(&binned[center].0, &binned[j].0, bw, bh, LIKENESS_SEARCH))
        })
        .collect();
    let best = like
        .iter()
        .flatten()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    // An estimated correlation over n pixels has a standard error of about 1/√n.
    let margin = 4.0
        / ((bw.saturating_sub(2 * LIKENESS_SEARCH) * bh.saturating_sub(2 * LIKENESS_SEARCH)).max(1)
            as f64)
            .sqrt();
    let other = |j: usize| like[j].is_some_and(|r| r < LIKENESS_GATE * best && best - r > margin);
    let scene = (sc.first, sc.last);
    while sc.first < center && (sc.first..center).any(other) {
        sc.first += 1;
    }
    while sc.last > center && (center + 1..=sc.last).any(other) {
        sc.last -= 1;
    }
    if (sc.first, sc.last) != scene {
        sc.scale = emccd_classical::temporal::brightness_trend(window, center, sc.first, sc.last);
    }
    let len = sc.last - sc.first + 1;
    let kk = k as isize;
    (-kk..=kk)
        .map(|d| {
            let j = sc.first + mirror(center - sc.first, d, len);
            let s = sc.scale[j] as f32;
            window[j].iter().map(|&v| v * s).collect()
        })
        .collect()
}

/// A neighbour whose guide correlates with the frame's less than this times the best
/// neighbour's (and by more than the estimate's noise) shows another scene.
const LIKENESS_GATE: f64 = 0.4;

/// The search for the best whole-pixel shift between two binned guides, ± binned px (6 px of
/// the frame: two frames of a 3 px/frame drift).
const LIKENESS_SEARCH: usize = 3;

/// `v` (`w` × `h`) averaged over 2×2 blocks (an odd last row or column dropped), with its size.
fn bin2(v: &[f32], w: usize, h: usize) -> (Vec<f32>, usize, usize) {
    let (bw, bh) = (w / 2, h / 2);
    let mut out = vec![0f32; bw * bh];
    for y in 0..bh {
        for x in 0..bw {
            let (a, b) = (2 * y * w + 2 * x, (2 * y + 1) * w + 2 * x);
            out[y * bw + x] = 0.25 * (v[a] + v[a + 1] + v[b] + v[b + 1]);
        }
    }
    (out, bw, bh)
}

/// The largest correlation coefficient between `a` and `b` (`w` × `h`) over whole-pixel shifts
/// of `b` within ±`r`, on `a`'s pixels `r` or more from its edges (0 for a frame too small, or
/// one without contrast).
fn likeness(a: &[f32], b: &[f32], w: usize, h: usize, r: usize) -> f64 {
    if w <= 2 * r || h <= 2 * r {
        return 0.0;
    }
    let ri = r as isize;
    let shifts: Vec<(isize, isize)> = (-ri..=ri)
        .flat_map(|dy| (-ri..=ri).map(move |dx| (dx, dy)))
        .collect();
    shifts
        .par_iter()
        .map(|&(dx, dy)| {
            let (mut sa, mut sb, mut saa, mut sbb, mut sab, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
            for y in r..h - r {
                let yb = (y as isize + dy) as usize;
                for x in r..w - r {
                    let xb = (x as isize + dx) as usize;
                    let (p, q) = (a[y * w + x] as f64, b[yb * w + xb] as f64);
                    sa += p;
                    sb += q;
                    saa += p * p;
                    sbb += q * q;
                    sab += p * q;
                    n += 1.0;
                }
            }
            let cov = sab / n - (sa / n) * (sb / n);
            let (va, vb) = (saa / n - (sa / n).powi(2), sbb / n - (sb / n).powi(2));
            if va > 0.0 && vb > 0.0 {
                cov / (va * vb).sqrt()
            } else {
                0.0
            }
        })
        .collect::<Vec<f64>>()
        .into_iter()
        .fold(0.0, f64::max)
}

/// A cheap smooth estimate of a preprocessed frame `width` px wide, for the temporal network's
/// scene gate (it proposes the tracked blocks' moves and predicts their noise, as a frame's
/// single-frame estimate does for the classical method, at a fraction of its cost): the frame
/// filtered by the binomial kernel (1 4 6 4 1)/16 along each axis, its edges mirrored.
pub fn guide(frame: &[f32], width: usize) -> Vec<f32> {
    emccd_classical::resample::binomial(frame, width)
}

/// The frames of `profile`'s size that `values` values make, one after another; an error when
/// they are not whole frames.
pub fn frame_count(profile: &CameraProfile, values: usize) -> Result<usize> {
    let n = profile.len();
    if n == 0 || values % n != 0 {
        return Err(Error::Data(format!(
            "{values} values are not frames of {}×{}",
            profile.width, profile.height
        )));
    }
    Ok(values / n)
}

/// A recording's raw frames held in memory (each the profile's size, one after another)
/// denoised as `emccd denoise` denoises a file: by `fd`'s temporal method from each frame's
/// window, by the others frame by frame. Each frame is handed to `emit(j, frame)`, in order, in
/// `fd`'s units; errors about a frame name it as `frame J` (from 1).
pub fn denoise_slice(
    fd: &Denoiser,
    exposure_s: f64,
    raw: &[f32],
    emit: &mut dyn FnMut(usize, Vec<f32>) -> Result<()>,
) -> Result<()> {
    let (n, count) = (fd.profile.len(), frame_count(fd.profile, raw.len())?);
    let at = |j: usize| format!("frame {}", j + 1);
    if fd.method.temporal() {
        return denoise_frames(
            fd,
            exposure_s,
            count,
            0..count,
            &at,
            &mut |j, buf| {
                if let Some(buf) = buf {
                    buf.copy_from_slice(&raw[j * n..(j + 1) * n]);
                }
                Ok(())
            },
            emit,
        );
    }
    for (j, frame) in raw.chunks(n).enumerate() {
        emit(j, fd.run(frame, exposure_s).map_err(|e| e.at(at(j)))?)?;
    }
    Ok(())
}

/// Raw frame `index` preprocessed, with its single-frame estimate (the classical method's: as
/// a window's member where `members` gives the frames' noise, else the frame's output) or its
/// [`guide`] (the network's): refused when a value is not finite (as [`Denoiser::run`] refuses
/// it).
fn prepare(
    fd: &Denoiser,
    index: usize,
    raw: &[f32],
    exposure_s: f64,
    members: Option<PoissonGaussian>,
) -> Result<Held> {
    fd.check_finite(raw)?;
    let frame = fd.preprocess(raw, exposure_s)?;
    // The classical method tracks motion on each frame's own estimate; the network's window is
    // gated with a cheap one.
    let single = match (fd.method, members) {
        (Method::TemporalNet, _) => guide(&frame, fd.profile.width),
        // Its full-resolution pass on a coarser grid: a guide and a fallback. Without
        // neighbours the frame's estimate is its output, as a per-frame method's.
        (Method::Temporal, Some(noise)) => {
            let p = fd.profile;
            emccd_classical::temporal::window_single(&frame, p.width, p.height, noise)
        }
        _ => fd.estimate(&frame, exposure_s)?,
    };
    Ok(Held {
        index,
        frame,
        single,
    })
}
