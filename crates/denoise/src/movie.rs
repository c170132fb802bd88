//! A recording's frames denoised with their neighbours ([`Method::Temporal`],
//! [`Method::TemporalNet`]) in bounded memory: each frame is preprocessed (and, for the
//! classical method, given its single-frame estimate) once, as it is read, and at most `2K + 1`
//! of them (the window of `K` frames each side) are held at a time. A frame's window stays
//! within its recording: the classical method's is clipped at the recording's ends; the
//! network's (a fixed number of frames) shows the frame's scene at its brightness, the frames
//! beyond the scene or the recording mirrored about the frame ([`net_window`]). The network
//! denoises one frame's window while the next frame's scene is found.

use std::collections::VecDeque;

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
    /// The raw frame's identity (a hash of its values): a repeated frame has its original's.
    id: u64,
    /// Every raw value the same: no read noise, so no reading (a dropped frame).
    dropped: bool,
}

/// Frames of a recording that are no fresh readings, by number from 0: repeats of the frame
/// before (a frozen camera, acquisition software repeating frames) and constant frames (a
/// dropped frame, written as zeros). Neither is in another frame's window: a repeat's noise is
/// its original's, which the window's average would keep as signal (the interior frames of a
/// movie of one repeated frame kept 7.4–8.4 DN of error against 1.5 for one frame alone).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Irregular {
    /// Frames equal to the frame before.
    pub repeated: Vec<usize>,
    /// Frames of one value throughout.
    pub dropped: Vec<usize>,
}

impl Irregular {
    /// Warnings for a person, naming frames from 1 in `name` (the input).
    pub fn warnings(&self, name: &str) -> Vec<String> {
        let list = |v: &[usize]| -> String {
            let shown: Vec<String> = v.iter().take(8).map(|j| (j + 1).to_string()).collect();
            let more = if v.len() > 8 {
                format!(" and {} more", v.len() - 8)
            } else {
                String::new()
            };
            format!("{}{more}", shown.join(", "))
        };
        let mut w = Vec::new();
        if !self.repeated.is_empty() {
            w.push(format!(
                "{name}: {} frame(s) repeat the frame before value for value (frames {}): a frozen camera or repeated frames; each is denoised without its copies",
                self.repeated.len(),
                list(&self.repeated)
            ));
        }
        if !self.dropped.is_empty() {
            w.push(format!(
                "{name}: {} frame(s) hold one value throughout, no camera reading (frames {}): dropped frames? They are left out of their neighbours' windows and come out as they are",
                self.dropped.len(),
                list(&self.dropped)
            ));
        }
        w
    }
}

/// A hash of a raw frame's values (their bits).
fn identity(raw: &[f32]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for v in raw {
        v.to_bits().hash(&mut h);
    }
    h.finish()
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
) -> Result<Irregular> {
    let want = want.start..want.end.min(count);
    let mut irregular = Irregular::default();
    if want.is_empty() {
        return Ok(irregular);
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
    let mut last_id = None;
    // Frame `j`'s estimate handed over in `fd`'s units, or its error named.
    let mut hand_over = |(j, out): (usize, Result<Vec<f32>>)| {
        let mut out = out.map_err(|e| e.at(at(j)))?;
        if to_units != 1.0 {
            out.iter_mut().for_each(|v| *v *= to_units);
        }
        emit(j, out)
    };
    let network = fd.model.filter(|_| fd.method == Method::TemporalNet);
    // The network's input for the frame before: the previous frame's window as it is shown
    // ([`net_window`]), a working buffer, not held frames. The network runs on it while the
    // next frame's scene is found, so that the tracking's share of the two cores fills what
    // the network's serial steps leave idle.
    let mut shown_before: Option<(usize, Vec<Vec<f32>>)> = None;
    let infer = |model, (j, shown): (usize, Vec<Vec<f32>>)| {
        let window: Vec<&[f32]> = shown.iter().map(Vec::as_slice).collect();
        (j, fd.inference(model).denoise_window(&window, exposure_s))
    };
    for j in lo..hi {
        let read = next(j, Some(&mut buf))
            .and_then(|()| prepare(fd, j, &buf, exposure_s, members).map_err(|e| e.at(at(j))));
        let frame = match read {
            Ok(frame) => {
                if last_id == Some(frame.id) {
                    irregular.repeated.push(j);
                }
                last_id = Some(frame.id);
                if frame.dropped {
                    irregular.dropped.push(j);
                }
                frame
            }
            Err(e) => {
                // The frame before, whose window was complete, is handed over first (a shard
                // resumed after the error starts after it).
                if let (Some(model), Some(before)) = (network, shown_before.take()) {
                    hand_over(infer(model, before))?;
                }
                return Err(e);
            }
        };
        held.push_back(frame);
        // Every frame whose window is now complete (or ends at the last frame read). A frame's
        // window is found as soon as frame `due + k` is read, so what is held past the frames
        // before its window is exactly its window; the classical method denoises it then, the
        // network while the next frame's window is found (or after the last).
        while due < want.end && (due + k <= j || j + 1 == hi) {
            while held.front().is_some_and(|h| h.index + k < due) {
                held.pop_front();
            }
            // The window: the frame and its neighbours but their repeats and dropped frames.
            let own = held
                .iter()
                .find(|h| h.index == due)
                .expect("the frame itself is held");
            let (own_id, own_dropped) = (own.id, own.dropped);
            let members: Vec<&Held> = held
                .iter()
                .filter(|h| h.index == due || (h.id != own_id && !h.dropped && !own_dropped))
                .collect();
            let centre = members
                .iter()
                .position(|h| h.index == due)
                .expect("the frame itself");
            let frames: Vec<&[f32]> = members.iter().map(|h| h.frame.as_slice()).collect();
            let singles: Vec<&[f32]> = members.iter().map(|h| h.single.as_slice()).collect();
            match network {
                // The network's fixed window: the frame's scene, at its brightness.
                Some(model) => {
                    let (shown, before) = rayon::join(
                        || net_window(&frames, &singles, centre, k, p.width, noise),
                        || shown_before.take().map(|b| infer(model, b)),
                    );
                    if let Some(before) = before {
                        hand_over(before)?;
                    }
                    shown_before = Some((due, shown));
                }
                None => hand_over((
                    due,
                    Ok(emccd_classical::temporal::estimate(
                        &frames, &singles, centre, p.width, p.height, noise,
                    )),
                ))?,
            }
            due += 1;
        }
    }
    if let (Some(model), Some(last)) = (network, shown_before) {
        hand_over(infer(model, last))?;
    }
    Ok(irregular)
}

/// The `2k + 1` frames a temporal network is shown for frame `center` of `window` (the
/// preprocessed frames within `k` of it, clipped at the recording's ends; `width` px wide,
/// noise `noise`; `guides` each frame's [`guide`]): the frames of its scene — a scene cut or
/// motion too fast to follow ends the scene, as the classical method's tracking finds it
/// ([`emccd_classical::temporal::scene`]) — brought to its brightness along the scene's
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
    let sc = emccd_classical::temporal::scene(window, guides, center, width, height, noise);
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
) -> Result<Irregular> {
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
    Ok(Irregular::default())
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
        id: identity(raw),
        dropped: raw.iter().all(|&v| v == raw[0]),
    })
}
