//! Classical denoising of a movie frame from the frames around it. Block matching follows the
//! motion: each 8×8 block of frame `t` is looked for in frame `t ± 1` around where the whole scene
//! moved (the frame's registration to frame `t`, which noise cannot fake over a whole frame: on
//! low-passed frames, each frame's place agreeing with the pairs of frames around it), then in
//! `t ± 2` around where it was found in `t ± 1`, and so on outward; each neighbour is first
//! resampled by the fraction of a pixel of its registration, so that the whole pixels its blocks
//! are read at hold the scene where frame `t` has it. The frames' single-frame estimates say
//! whether a block moved on its own (a particle, a deformation): their best match is taken where it
//! is clearly closer, and aligned to a fraction of a pixel on them ([`refine`]). The noisy frames,
//! after the generalized Anscombe transform (noise about 1 at every level, so one threshold tells
//! a match from a mismatch), accept the match or end the track;
//! they choose nothing, since a choice made on them fits their noise. The matched blocks are
//! averaged in the data's own units, each pixel of a block counting as far as the guides agree
//! there ([`agreement`]: a block that holds the edge of a spot that moved away or blinked off
//! passes the block test, but not pixel by pixel) — a motion-compensated mean that holds about `N`
//! frames' photons wherever `N` frames matched — and the mean is denoised by iterative BM3D at the
//! noise of a mean of `N` frames (gain α/N, read noise σ/√N), `N` the frames its noise is worth (a
//! resampled neighbour holds less noise; a partly matching block counts partly), each transform
//! coefficient at its own noise ([`MotionMean::noise`]: resampling takes a neighbour's fine noise,
//! not its coarse, so the mean's coarse detail is noisier than its pixels say).
//!
//! Where the scene moves, pixels that hold an excess or a deficit at one place on the sensor
//! (hot pixels the profile does not know) are taken out of every frame ([`fixed_defects`]) and
//! the frames registered again: they pull the registrations towards no move, and the mean
//! would draw each one as a trail along the motion.
//!
//! A scene that deforms differs in its far frames by more than any block's track follows, and
//! there fewer frames are worth more: the mean is of the whole window or of its [`NEAR`] frames
//! each side, whichever frame `t`'s own data, held out of both, finds clearly closer
//! ([`HeldOut`]).
//!
//! Where the neighbours hold nothing like frame `t` (a particle that moved off its track, a spot
//! that blinked), no block passes the threshold; a neighbour whose blocks as a whole differ more
//! than noise does, or that no chain of matching pairs of frames links to frame `t` (a scene
//! cut), ends the window on its side. Where fewer than [`POOLED_FROM`] frames' worth matched, the
//! estimate falls back, pixel by pixel and in proportion, to the estimate of frame `t` alone
//! ([`single`]). Neighbours are brought to frame `t`'s brightness along the window's trend
//! (bleaching). The mean is taken in the data's units and both estimates invert
//! the transform with its exact unbiased inverse, so the mean over a region stays the signal's
//! (within 1 % in the tests, down to half a count per pixel, bleaching or not).

use rayon::prelude::*;

use crate::bm3d::{kaiser, positions};
use nalgebra::DMatrix;

use crate::noise::{convolved, Covariance};
use crate::resample::{binomial, covariance, noise_kept, resampled, taps};
use crate::vst::{
    bm3d_adaptive_correlated, bm3d_iterative_spaced, forward, mean_counts, PoissonGaussian,
    Schedule,
};

/// Block side, px.
const N: usize = 8;
const _: () = assert!(N == 8, "the rows' sums are trees of eight");
/// Distance between reference blocks, px.
const STEP: usize = 2;
/// Half-width of the search in a neighbouring frame around the block's last position, px.
const SEARCH: isize = 4;
/// The match threshold on a block's summed squared difference after the transform, in units
/// of the noise: two blocks of the same content differ by 2·N² on average with a standard
/// deviation of 2·√(2·N²); three of those above is a mismatch (about 0.3 % of true matches are
/// refused). A neighbour resampled to a fraction of a pixel holds less noise (0.41–1 of its
/// variance), so its true matches differ by less and the threshold is looser for it; this is
/// how it was measured and kept.
fn threshold() -> f64 {
    let n2 = (N * N) as f64;
    2.0 * n2 + 3.0 * 2.0 * (2.0 * n2).sqrt()
}

/// How much a matched block counts in the mean, from its summed squared difference `d` to the
/// reference (noise 1): fully up to what two blocks of the same content differ by on average
/// (2·N²), then less, linearly, to nothing at the match threshold. A block that differs by more
/// than noise is partly another content; it adds its photons but also its difference.
fn weight(d: f64) -> f64 {
    let typical = 2.0 * (N * N) as f64;
    ((threshold() - d) / (threshold() - typical)).clamp(0.0, 1.0)
}

/// Guides that differ by up to this after the transform (noise 1) agree fully ([`agreement`]);
/// from twice it, not at all.
const AGREED: f32 = 0.5;

/// How much a pixel of a matched block counts, from the two frames' guides there, after the
/// transform (their absolute difference, noise 1) and in the data's units (`dn`): fully where they
/// differ by up to half the noise ([`AGREED`]), nothing from the whole noise, unless the difference
/// is a small part of the signal (under 40 %, then counting partly to 80 %). A block that holds the
/// edge of a spot passes the block test where the spot has moved away or blinked off in the
/// neighbour (at a photon per pixel the edge holds a few photons under 64 pixels' noise), and
/// averaged in it took 12–16 % of the spots' light on the validation camera's particles at 1 e⁻
/// (measured by averaging the truth along the tracks); there the guides differ by a median of 1.0
/// noise σ, on matched background by 0.03 (99 % under 0.23). A bright star's guides differ by as
/// much from frame to frame (BM3D blunts it by its sub-pixel phase), but by a few percent: without
/// the relative part the jittered stars lost 0.6 dB at 4 e⁻. Thresholds chosen on the validation
/// camera `tune` (docs/journal.md).
fn agreement(gat_difference: f32, (dn_a, dn_b): (f32, f32)) -> f64 {
    let differ = ((gat_difference as f64 - AGREED as f64) / AGREED as f64).clamp(0.0, 1.0);
    let relative = ((dn_a - dn_b).abs() / dn_a.max(dn_b).max(f32::MIN_POSITIVE)) as f64;
    let substantial = ((relative - 0.4) / 0.4).clamp(0.0, 1.0);
    1.0 - differ * substantial
}

/// Frame `t`'s motion-compensated mean over its window and, per pixel, how many frames it holds.
#[derive(Clone, Debug)]
pub struct MotionMean {
    /// The mean, in the frames' units.
    pub mean: Vec<f32>,
    /// Frames averaged at each pixel (1 where no neighbour matched; a weighted count where
    /// overlapping blocks matched in different numbers of frames).
    pub frames: Vec<f32>,
    /// The frames' worth of noise the mean holds at each pixel: `frames` where every matched
    /// block counts fully and no frame was resampled, more where blocks count partly (a
    /// weighted mean's noise is `Σw²/(Σw)²`) and where frames were resampled (their noise is
    /// smaller).
    pub noise_frames: Vec<f32>,
    /// The mean's noise covariance over the rows it was taken on, at a pixel variance of 1: its
    /// resampled neighbours' noise is coarser than white, each as its kernel left it, in
    /// proportion to its share of the mean's noise.
    pub noise: Covariance,
}

/// A neighbour whose tracked blocks differ from frame `t`'s by more than this times the best
/// neighbour's (the median over each frame's blocks of their difference over its predicted
/// noise) holds another scene: a cut, or motion too fast to follow. Below about a photon per
/// pixel a block of another scene often passes the per-block threshold (the scenes' contrast is
/// under the noise of 64 pixels), but over a whole frame's blocks the excess is plain: in the
/// tests a still scene's neighbours' medians agree within 2 %, and a cut lifts its frames'
/// well above them.
const SCENE_GATE: f64 = 1.1;

/// Where a block's track goes next, before its neighbours are heard: where the scene's move puts
/// it, and the guides' better place if they propose one, with whether it beats staying by the
/// full move gain.
struct Proposal {
    predicted: (usize, usize),
    moved: Option<((usize, usize), bool)>,
}

/// Whether a block of frame t at `from`, whose guides propose moving it from `stay` to `to` by
/// less than [`MOVE_GAIN`] but more than [`NEIGHBOURED_GAIN`], moves: where `to` is closer than
/// `stay` to where the blocks around it went (`around`: each one's place in this frame against
/// its own in frame t; their median along each axis, since some of them follow their guides'
/// noise too), and at least [`NEIGHBOURS_NEEDED`] of them are still tracked. A rotation or a
/// deformation moves neighbouring blocks alike, by fractions of a pixel that each block's
/// whole-pixel track takes up in different frames; a move the guides propose out of their
/// residual noise is the block's alone.
fn agrees(
    from: (usize, usize),
    stay: (usize, usize),
    to: (usize, usize),
    around: &[(f64, f64)],
) -> bool {
    if around.len() < NEIGHBOURS_NEEDED.max(1) {
        return false;
    }
    let mx = emccd_profile::median(around.iter().map(|a| a.0)).unwrap_or(0.0);
    let my = emccd_profile::median(around.iter().map(|a| a.1)).unwrap_or(0.0);
    let off = |c: (usize, usize)| {
        (c.0 as f64 - from.0 as f64 - mx).powi(2) + (c.1 as f64 - from.1 as f64 - my).powi(2)
    };
    off(to) < off(stay)
}

/// One step of a block's track: the frame, where the block was found, the summed squared
/// difference there (after the transform, noise 1), and the same difference in the data's units
/// over its expected noise ([`scaled_difference`]), which the scene gate compares.
#[derive(Clone, Copy)]
struct Step {
    frame: usize,
    x: usize,
    y: usize,
    d: f64,
    chi: f64,
    /// The block's place in this frame to a fraction of a pixel, as an offset from (`x`, `y`)
    /// ([`refine`]; zero for a block that moved with the scene).
    sub: (f64, f64),
}

/// The motion-compensated mean of `window[center]` (frames `w × h` with noise `p`, in time
/// order; the window may be clipped at a stack's ends). `guides` are the frames' single-frame
/// estimates, which propose where each block went; the noisy frames decide and
/// accept, since their difference's noise is what the threshold knows. Each neighbour is first
/// brought to frame `t`'s brightness along the window's trend ([`brightness`]: bleaching), and a
/// neighbour that is another scene ([`SCENE_GATE`]) ends the window on its side.
pub fn motion_mean(
    window: &[&[f32]],
    guides: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
) -> MotionMean {
    let own = window[center];
    if !trackable(window, guides, w, h) {
        return MotionMean {
            mean: own.to_vec(),
            frames: vec![1.0; w * h],
            noise_frames: vec![1.0; w * h],
            noise: Covariance::white(),
        };
    }
    let t = tracked(window, guides, center, w, h, p, STEP);
    pooled(&t, &t.own(own), center, w, h, usize::MAX, true, 0..h)
}

/// The motion-compensated mean of rows `rows` of frame `center` from its tracked window `t`:
/// the matched blocks of the frames at most `reach` frames from it, and the frame itself if
/// `with_own`. Without it (the held-out mean, [`held_out`]), a pixel no block matched is the
/// frame's own estimate (its guide).
#[allow(clippy::too_many_arguments)]
fn pooled(
    t: &Tracked,
    own: &[f32],
    center: usize,
    w: usize,
    h: usize,
    reach: usize,
    with_own: bool,
    rows: std::ops::Range<usize>,
) -> MotionMean {
    let Tracked {
        frames,
        tracks,
        first,
        last,
        kept: frame_kept,
        fraction,
        guides,
        guides_gat,
        ..
    } = t;
    let (first, last) = (*first, *last);
    // What the frame itself counts in its own mean: once, or not at all (held out).
    let counted = if with_own { 1.0 } else { 0.0 };
    let (xs, ys) = (positions(w, N, STEP), positions(h, N, STEP));
    let win = kaiser(N);
    // Each output row gathers, in a fixed order (block rows, then blocks), Σ k·(the matched blocks'
    // values), Σ k·m and Σ k, for the window weight k of each block and the m frames matched at the
    // pixel (each weighted by its block's match and the guides' agreement): the sums never depend
    // on how the rows were shared among threads, so a frame's estimate is the same bits on every
    // run (its decisions downstream hang on them). A block's steps within the scene, as (frame, x,
    // y, weight in the mean).
    type Kept = Vec<(usize, usize, usize, f64, (f64, f64))>;
    let kept = |steps: &[Step]| -> Kept {
        steps
            .iter()
            .filter(|s| (first..=last).contains(&s.frame) && s.frame.abs_diff(center) <= reach)
            .map(|s| (s.frame, s.x, s.y, weight(s.d), s.sub))
            .collect()
    };
    let kept: Vec<Vec<Kept>> = tracks
        .iter()
        .map(|row| row.iter().map(|steps| kept(steps)).collect())
        .collect();
    // A row's mean, frames held, frames' worth of noise, and the frames' noise shares.
    type Row = (Vec<f32>, Vec<f32>, Vec<f32>, Shares);
    let rows: Vec<Row> = rows
        .into_par_iter()
        .map(|yo| {
            let (mut num, mut den, mut cnt) = (vec![0f64; w], vec![0f64; w], vec![0f64; w]);
            let mut held_noise = vec![0f64; w];
            let mut shares = Shares::default();
            // Each matched frame's pixel weights in the block's row, with its frame and offset.
            let mut weights: Vec<(usize, (f64, f64), [f64; N])> = Vec::new();
            for (bi, &y) in ys.iter().enumerate() {
                if yo < y || yo >= y + N {
                    continue;
                }
                let r = yo - y;
                for (&x, blocks) in xs.iter().zip(&kept[bi]) {
                    // The block's row of N pixels: frame by frame, each pixel's sums (in the
                    // same order per pixel as pixel by pixel, so the same bits), a frame's
                    // row read in one run.
                    let at = yo * w + x;
                    let mut sum: [f64; N] =
                        std::array::from_fn(|q| counted * frames[center][at + q] as f64);
                    let (mut m, mut noise) = ([counted; N], [counted; N]);
                    let (own_gat, own_dn) = (&guides_gat[center][at..], &guides[center][at..]);
                    let mut buf = [[0f32; N]; 3];
                    weights.clear();
                    for &(f, bx, by, wt, sub) in blocks {
                        let mut used = [0f64; N];
                        let there = (by + r) * w + bx;
                        let (g_gat, g_dn, values, kept_f): (&[f32], &[f32], &[f32], f64) =
                            if sub == (0.0, 0.0) {
                                (
                                    &guides_gat[f][there..],
                                    &guides[f][there..],
                                    &frames[f][there..],
                                    frame_kept[f],
                                )
                            } else {
                                let row = (bx, by + r);
                                shifted_row(&guides_gat[f], w, h, row, sub, &mut buf[0]);
                                shifted_row(&guides[f], w, h, row, sub, &mut buf[1]);
                                shifted_row(&frames[f], w, h, row, sub, &mut buf[2]);
                                (&buf[0], &buf[1], &buf[2], frame_kept[f] * noise_kept(sub))
                            };
                        for q in 0..N {
                            // Most pixels agree within half the noise: the data's units are
                            // read only where they do not.
                            let differ = (own_gat[q] - g_gat[q]).abs();
                            let wt = if differ <= AGREED {
                                wt
                            } else {
                                wt * agreement(differ, (own_dn[q], g_dn[q]))
                            };
                            sum[q] += wt * values[q] as f64;
                            m[q] += wt;
                            // The mean's noise over one frame's: Σ k·w² / (Σ w)².
                            noise[q] += kept_f * wt * wt;
                            used[q] = wt;
                        }
                        weights.push((f, sub, used));
                    }
                    // Each frame's share of the mean's noise variance here, w²/m² (the
                    // blocks' window weighing the pixels), for the mean's covariance. An
                    // approximation: the overlapping blocks' means are averaged again, and a
                    // frame's blocks at different offsets count as independent; only the
                    // shares' proportions matter (the covariance is normalized).
                    let share = |used: &[f64; N]| -> f64 {
                        (0..N)
                            .filter(|&q| m[q] > 0.0)
                            .map(|q| win[r * N + q] * (used[q] / m[q]).powi(2))
                            .sum()
                    };
                    shares.add((center, (0.0, 0.0)), share(&[counted; N]));
                    for (f, sub, used) in &weights {
                        shares.add((*f, *sub), share(used));
                    }
                    for q in 0..N {
                        let k = win[r * N + q];
                        num[x + q] += k * sum[q];
                        den[x + q] += k * m[q];
                        cnt[x + q] += k;
                        if noise[q] > 0.0 {
                            held_noise[x + q] += k * m[q] * m[q] / noise[q];
                        }
                    }
                }
            }
            let mean = (0..w)
                .map(|q| {
                    if den[q] > 0.0 {
                        (num[q] / den[q]) as f32
                    } else if with_own {
                        own[yo * w + q]
                    } else {
                        guides[center][yo * w + q]
                    }
                })
                .collect();
            // Per pixel, a blocks' quantity weighted as the blocks are (1 where no block is).
            let per_pixel = |sums: &[f64]| -> Vec<f32> {
                (0..w)
                    .map(|q| {
                        if cnt[q] > 0.0 {
                            (sums[q] / cnt[q]) as f32
                        } else {
                            1.0
                        }
                    })
                    .collect()
            };
            // The frames a pixel holds (the blocks' m), and the frames its noise is worth.
            (mean, per_pixel(&den), per_pixel(&held_noise), shares)
        })
        .collect();
    let (mut mean, mut frames, mut noise_frames) = (Vec::new(), Vec::new(), Vec::new());
    let mut shares = Shares::default();
    for (m, f, n, s) in rows {
        mean.extend(m);
        frames.extend(f);
        noise_frames.extend(n);
        for (key, v) in s.0 {
            shares.add(key, v);
        }
    }
    MotionMean {
        mean,
        frames,
        noise_frames,
        noise: shares.covariance(fraction),
    }
}

/// Each matched frame's share of a motion-compensated mean's noise variance, by the frame and
/// the fraction of a pixel its blocks were shifted by after its registration (to 1/16 px):
/// what the mean's [`Covariance`] is made of.
#[derive(Default)]
struct Shares(Vec<(ShareKey, f64)>);

/// A frame and its blocks' offset after its registration.
type ShareKey = (usize, (f64, f64));

impl Shares {
    /// Adds `v` to frame `key.0`'s share at the block offset `key.1`.
    fn add(&mut self, (f, sub): ShareKey, v: f64) {
        let q = |e: f64| (e * 16.0).round() / 16.0;
        let key = (f, (q(sub.0), q(sub.1)));
        match self.0.iter_mut().find(|(k, _)| *k == key) {
            Some((_, s)) => *s += v,
            None => self.0.push((key, v)),
        }
    }

    /// The mean's covariance at a pixel variance of 1: each frame's noise resampled by its
    /// registration's `fraction`, then by its blocks' offset, weighted by its share.
    fn covariance(&self, fraction: &[(f64, f64)]) -> Covariance {
        let mut c = Covariance::empty();
        for &((f, sub), v) in &self.0 {
            let axis = |e: f64, s: f64| {
                let c = covariance(e);
                if s == 0.0 {
                    c
                } else {
                    convolved(&c, &covariance(s))
                }
            };
            c.add(v, &axis(fraction[f].0, sub.0), &axis(fraction[f].1, sub.1));
        }
        c.normalized()
    }
}

/// What the tracking of a window's blocks found ([`tracked`]).
struct Tracked {
    /// The window's frames, brought to the centre frame's brightness and resampled to the
    /// fraction of a pixel of their registration.
    frames: Vec<Vec<f32>>,
    /// Every reference block's track (rows of blocks, each its steps).
    tracks: Vec<Vec<Vec<Step>>>,
    /// The first and last frames of the centre's scene.
    first: usize,
    last: usize,
    /// Each frame's brightness factor (the trend of the centre's scene).
    scale: Vec<f64>,
    /// The fraction of its noise's variance each frame kept when it was resampled to a
    /// fraction of a pixel ([`noise_kept`]; 1 for a frame not resampled).
    kept: Vec<f64>,
    /// The fraction of a pixel each frame was resampled by.
    fraction: Vec<(f64, f64)>,
    /// The frames' single-frame estimates, brought and resampled as `frames` are (DN).
    guides: Vec<Vec<f32>>,
    /// The same after the transform (noise 1).
    guides_gat: Vec<Vec<f32>>,
    /// The pixels taken out of every frame as defects ([`fixed_defects`]).
    defects: Vec<usize>,
    /// The frames' width, px.
    w: usize,
}

impl Tracked {
    /// Frame `center`'s data as its mean takes it: `frame` with the window's defects taken out.
    fn own<'a>(&self, frame: &'a [f32]) -> std::borrow::Cow<'a, [f32]> {
        if self.defects.is_empty() {
            return frame.into();
        }
        let mut own = frame.to_vec();
        inpaint(&mut own, &self.defects, self.w);
        own.into()
    }
}

/// The frames of a window that show frame `center`'s scene, and the factors that bring each to
/// its brightness: what [`motion_mean`] gates and scales its mean with, for a method that
/// averages otherwise (the temporal network is shown only its frame's scene, at its
/// brightness).
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// The first and last frames of the window that hold the centre's scene: a cut or motion
    /// too fast to follow ends it ([`SCENE_GATE`], or fewer than half the centre's blocks
    /// found again in a frame).
    pub first: usize,
    /// See `first`.
    pub last: usize,
    /// Per window frame, the factor that brings it to the centre frame's brightness along the
    /// scene's trend (bleaching).
    pub scale: Vec<f64>,
}

/// The scene of `window[center]` ([`Scene`]), from the same block tracking as [`motion_mean`]
/// (`guides` propose the moves, as there; any smooth estimate of each frame will do).
pub fn scene(
    window: &[&[f32]],
    guides: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
) -> Scene {
    // A frame narrower than a block has none to track (a spectroscopy strip, a narrow sub-array).
    let step = if w >= N && h >= N {
        scene_step(w, h)
    } else {
        N
    };
    scene_on_grid(window, guides, center, w, h, p, step)
}

/// [`scene`] from the reference blocks every `step` px each way.
fn scene_on_grid(
    window: &[&[f32]],
    guides: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
    step: usize,
) -> Scene {
    if !trackable(window, guides, w, h) {
        return Scene {
            first: center,
            last: center,
            scale: vec![1.0; window.len()],
        };
    }
    let t = tracked(window, guides, center, w, h, p, step);
    // The mean needs no more (a block that found no match adds nothing to it), but a method
    // that is shown whole frames does: a frame that fewer than half the blocks' tracks reached
    // is another scene too (a cut to a scene as bright, whose blocks' differences over their
    // noise the gate never sees, since no track reaches it).
    let blocks: usize = t.tracks.iter().map(Vec::len).sum();
    let held = |f: usize| {
        let reached = t
            .tracks
            .iter()
            .flatten()
            .filter(|steps| steps.iter().any(|s| s.frame == f))
            .count();
        2 * reached >= blocks
    };
    let (mut first, mut last) = (center, center);
    while first > t.first && held(first - 1) {
        first -= 1;
    }
    while last < t.last && held(last + 1) {
        last += 1;
    }
    let scale = if (first, last) == (t.first, t.last) {
        t.scale
    } else {
        brightness(window, center, first..=last)
    };
    Scene { first, last, scale }
}

/// Whether `window` holds neighbours to track: more than one frame, each at least a block in
/// size. Panics unless every frame of `window` has its guide and every frame and guide is
/// `w × h`.
fn trackable(window: &[&[f32]], guides: &[&[f32]], w: usize, h: usize) -> bool {
    assert_eq!(window.len(), guides.len(), "a guide for every frame");
    for f in window.iter().chain(guides) {
        assert_eq!(f.len(), w * h, "frame size");
    }
    window.len() > 1 && w >= N && h >= N
}

/// How many reference blocks [`scene`] tracks at least: as many as every 4th px each way of a
/// 256² frame gives (63²), the size of the movie suite's frames, on which the gate was chosen.
/// Its decisions are a median over the blocks and a count of those that reach each frame,
/// whose precision depends on how many blocks there are, not on the frame's size.
const SCENE_BLOCKS: usize = 63 * 63;

/// Distance between the reference blocks [`scene`] tracks, px: every 4th px each way (a quarter
/// of the mean's blocks), or every 8th (a block's width: they still tile the frame, and a
/// block's neighbours are as far away) where that still leaves [`SCENE_BLOCKS`], as at 512² and
/// larger, in a quarter of the time.
fn scene_step(w: usize, h: usize) -> usize {
    if positions(w, N, N).len() * positions(h, N, N).len() >= SCENE_BLOCKS {
        N
    } else {
        4
    }
}

/// Every reference block of `window[center]` (every `step` px each way) tracked outward
/// through the window, the scene's frames found and brought to the centre's brightness.
fn tracked(
    window: &[&[f32]],
    guides: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
    step: usize,
) -> Tracked {
    let scale = brightness(window, center, 0..=window.len() - 1);
    // The guides too: a dimmer neighbour's guide would propose moves towards brighter content.
    let mut frames = scaled(window, &scale);
    let to_gat =
        |f: &Vec<f32>| -> Vec<f32> { f.iter().map(|&z| forward(z as f64, p) as f32).collect() };
    let given = guides;
    let mut guides = scaled(guides, &scale);
    let mut gat: Vec<Vec<f32>> = frames.iter().map(to_gat).collect();
    let limit = threshold();
    let (xs, ys) = (positions(w, N, step), positions(h, N, step));
    // The frames are registered low-passed ([`binomial`]): on the raw frames at a photon per
    // pixel the registrations of a drift came out off by a pixel and more.
    let (mut scene_at, mut linked, chained) = registered(&gat, center, w, h);
    // Where the scene moves, pixels that keep their excess or deficit at one place on the
    // sensor are defects the profile does not know ([`fixed_defects`]): they pull every
    // registration towards no move, and the mean would draw each one as a trail along the
    // motion. Taken out of every frame, and each pair of frames registered again within a
    // pixel of where the first registrations to frame `t` put it: without them, registered
    // afresh, a dim scene's frames found wrong places pixels off along an axis with little
    // texture, which the defects' pull towards no move had kept them from (`tune`'s 128²
    // drift at 0.5 e⁻ −0.31 dB afresh). Where the scene stays, they are left: the data cannot
    // tell them from the scene's own sharp points there.
    let defects = if spans(&scene_at, &linked, DEFECT_MOVE) {
        fixed_defects(&gat, w, h)
    } else {
        Vec::new()
    };
    if !defects.is_empty() {
        for f in frames.iter_mut().chain(guides.iter_mut()) {
            inpaint(f, &defects, w);
        }
        // Only the defects' pixels changed.
        for (g, f) in gat.iter_mut().zip(&frames) {
            for &i in &defects {
                g[i] = forward(f[i] as f64, p) as f32;
            }
        }
        let smooth: Vec<Vec<f32>> = gat.par_iter().map(|g| binomial(g, w)).collect();
        (scene_at, linked) = places(&smooth, &chained, center, w, h);
    }
    // Each neighbour resampled by its fraction of a pixel (Keys' cubic kernel), so that the whole
    // pixels its blocks are read at hold the scene where frame t has it: blocks read at whole
    // pixels were up to half a pixel off on a drift or a jitter. The place comes from the whole
    // frame, not from any block, so it does not follow the frame's noise (a block's own
    // sub-pixel place did, and biased the mean). The resampled frame's noise is smaller
    // ([`noise_kept`]), and its predicted variance with it, or the scene gate would take the
    // frames left as they were for another scene.
    let fraction: Vec<(f64, f64)> = scene_at
        .iter()
        .map(|&(x, y)| (x - x.round(), y - y.round()))
        .collect();
    let kept: Vec<f64> = fraction.iter().map(|&e| noise_kept(e)).collect();
    resample_all(&mut frames, &fraction, w, h);
    resample_all(&mut guides, &fraction, w, h);
    gat.par_iter_mut()
        .zip(&frames)
        .zip(&fraction)
        .filter(|(_, &e)| e != (0.0, 0.0))
        .for_each(|((g, f), _)| *g = to_gat(f));
    // Each pixel's noise variance, predicted from the frame's own estimate: a frame brought up
    // by `s` has `s` times the shot noise variance of its new level and `s²` times the read
    // noise's.
    let variance: Vec<Vec<f32>> = guides
        .iter()
        .zip(&scale)
        .zip(&kept)
        .map(|((g, &s), &k)| {
            g.iter()
                .map(|&z| {
                    (k * (s * p.alpha * (z as f64 - p.mu).max(0.0) + s * s * p.sigma * p.sigma))
                        as f32
                })
                .collect()
        })
        .collect();
    let guides_gat: Vec<Vec<f32>> = guides.iter().map(to_gat).collect();
    let step_of = |f: usize, prev: usize| -> (isize, isize) {
        (
            scene_at[f].0.round() as isize - scene_at[prev].0.round() as isize,
            scene_at[f].1.round() as isize - scene_at[prev].1.round() as isize,
        )
    };
    // Every reference block's track, outward in both directions until a block fails, all
    // blocks a frame at a time, so that a move the guides propose can be weighed against the
    // moves its neighbours' blocks propose in the same frame.
    let (nx, ny) = (xs.len(), ys.len());
    // The blocks a block's width away each way (and diagonally), in steps of the grid.
    let r = (NEIGHBOURS_AT / step).max(1) as isize;
    let mut tracks: Vec<Vec<Vec<Step>>> = (0..ny)
        .map(|_| {
            (0..nx)
                .map(|_| Vec::with_capacity(window.len() - 1))
                .collect()
        })
        .collect();
    let shifted =
        |c: usize, d: isize, len: usize| (c as isize + d).clamp(0, (len - N) as isize) as usize;
    for dir in [-1isize, 1] {
        let mut at: Vec<Option<(usize, usize)>> = ys
            .iter()
            .flat_map(|&y| xs.iter().map(move |&x| Some((x, y))))
            .collect();
        let mut f = center as isize + dir;
        while f >= 0 && (f as usize) < window.len() {
            let fu = f as usize;
            let mv = step_of(fu, (fu as isize - dir) as usize);
            // Each live block's proposal: where the scene's move puts it, and the guides' best
            // place within the search around there if it is closer than staying by
            // [`NEIGHBOURED_GAIN`] (and whether by [`MOVE_GAIN`] too). The guides (the frames'
            // single-frame estimates, transformed too) decide alone, since a decision on the
            // noisy frames is a decision on their noise; the noisy frames' difference at the
            // chosen place then accepts or ends the track. Only a position closer than staying
            // by the gain can win, so the search gives up on every other one as soon as its
            // partial sum says so (most of them, within a row or two).
            let proposals: Vec<Option<Proposal>> = at
                .par_iter()
                .enumerate()
                .map(|(i, &pos)| {
                    let (px, py) = pos?;
                    let (x, y) = (xs[i % nx], ys[i / nx]);
                    let predicted = (shifted(px, mv.0, w), shifted(py, mv.1, h));
                    let stay = ssd(&guides_gat[center], &guides_gat[fu], w, (x, y), predicted);
                    let best = best_match(
                        &guides_gat[center],
                        &guides_gat[fu],
                        w,
                        h,
                        (x, y),
                        predicted,
                        stay - NEIGHBOURED_GAIN,
                    );
                    Some(Proposal {
                        predicted,
                        moved: best.map(|(d, bx, by)| ((bx, by), d < stay - MOVE_GAIN)),
                    })
                })
                .collect();
            let next: Vec<Option<(usize, usize, f64, f64, (f64, f64))>> = (0..nx * ny)
                .into_par_iter()
                .map(|i| {
                    let p = proposals[i].as_ref()?;
                    let (x, y) = (xs[i % nx], ys[i / nx]);
                    let chosen = match p.moved {
                        Some((b, true)) => b,
                        Some((b, false)) => {
                            let (gx, gy) = ((i % nx) as isize, (i / nx) as isize);
                            let around: Vec<(f64, f64)> = [
                                (-r, 0),
                                (r, 0),
                                (0, -r),
                                (0, r),
                                (-r, -r),
                                (r, -r),
                                (-r, r),
                                (r, r),
                            ]
                            .iter()
                            .filter_map(|&(dx, dy)| {
                                let (qx, qy) = (gx + dx, gy + dy);
                                if qx < 0 || qy < 0 || qx as usize >= nx || qy as usize >= ny {
                                    return None;
                                }
                                let j = qy as usize * nx + qx as usize;
                                let q = proposals[j].as_ref()?;
                                let to = q.moved.map_or(q.predicted, |(m, _)| m);
                                Some((
                                    to.0 as f64 - xs[j % nx] as f64,
                                    to.1 as f64 - ys[j / nx] as f64,
                                ))
                            })
                            .collect();
                            if agrees((x, y), p.predicted, b, &around) {
                                b
                            } else {
                                p.predicted
                            }
                        }
                        None => p.predicted,
                    };
                    // A block that moved on its own (a particle) is rarely a whole number of
                    // pixels away: aligned to the fraction its guides say, its noisy frames are
                    // compared there, and read there for the mean. At whole pixels a bright
                    // spot half a pixel off fails the threshold on its own light and the
                    // estimate falls back to the frame alone: on the validation camera's
                    // particles +0.14 / +1.0 / +1.8 dB at 1 / 4 / 16 e⁻ (docs/journal.md). A
                    // block that moved with the scene was read from a frame resampled to the
                    // scene's fraction already.
                    let sub = if chosen != p.predicted {
                        refine(&guides_gat[center], &guides_gat[fu], w, h, (x, y), chosen)
                    } else {
                        None
                    };
                    let d = match sub {
                        Some(e) => {
                            let mut patch = [0f64; (N + 2) * (N + 2)];
                            shifted_patch(&gat[fu], w, h, chosen, e, &mut patch);
                            patch_ssd(&gat[center], w, (x, y), &patch)
                        }
                        _ => ssd(&gat[center], &gat[fu], w, (x, y), chosen),
                    };
                    if d > limit {
                        return None;
                    }
                    let chi = scaled_difference(
                        (&frames[center], &frames[fu]),
                        (&variance[center], &variance[fu]),
                        w,
                        (x, y),
                        chosen,
                    );
                    Some((chosen.0, chosen.1, d, chi, sub.unwrap_or((0.0, 0.0))))
                })
                .collect();
            for (i, n) in next.iter().enumerate() {
                at[i] = n.map(|(bx, by, d, chi, sub)| {
                    tracks[i / nx][i % nx].push(Step {
                        frame: fu,
                        x: bx,
                        y: by,
                        d,
                        chi,
                        sub,
                    });
                    (bx, by)
                });
            }
            if at.iter().all(Option::is_none) {
                break;
            }
            f += dir;
        }
    }
    let (first, last) = same_scene(&tracks, center, window.len(), &linked);
    let (first, last) = alike(given, center, (first, last), w, h);
    let mut scale = scale;
    if (first, last) != (0, window.len() - 1) {
        // The trend of this scene's frames alone.
        scale = brightness(window, center, first..=last);
        let mut scene = scaled(&window[first..=last], &scale[first..=last]);
        for f in &mut scene {
            inpaint(f, &defects, w);
        }
        frames.splice(first..=last, scene);
        resample_all(&mut frames[first..=last], &fraction[first..=last], w, h);
    }
    Tracked {
        frames,
        tracks,
        first,
        last,
        scale,
        kept,
        fraction,
        guides,
        guides_gat,
        defects,
        w,
    }
}

/// What [`registered`] returns: each frame's place, whether it is linked, and the registration
/// to frame `center` its pairs were looked for around.
type Registered = (Vec<(f64, f64)>, Vec<bool>, Vec<(f64, f64)>);

/// Where the scene is in each frame of a window relative to frame `center` (the frames after
/// the transform, `gat`), and which frames a chain of matching pairs links to it ([`places`]),
/// each pair registered within a pixel of where each frame's registration to frame `center`
/// puts it, itself looked for around where the registrations of each frame to the one before
/// it on the way out, added up, put it. Returns the places, the links and the registrations to
/// frame `center`.
fn registered(gat: &[Vec<f32>], center: usize, w: usize, h: usize) -> Registered {
    let smooth: Vec<Vec<f32>> = gat.par_iter().map(|g| binomial(g, w)).collect();
    // How the whole scene moved into each frame from the one before it on the way out from
    // frame `t` (the track's previous frame).
    let moves: Vec<(f64, f64)> = (0..gat.len())
        .map(|f| match f.cmp(&center) {
            std::cmp::Ordering::Less => {
                global_shift(&smooth[f + 1], &smooth[f], w, h, (0, 0), SEARCH).shift
            }
            std::cmp::Ordering::Greater => {
                global_shift(&smooth[f - 1], &smooth[f], w, h, (0, 0), SEARCH).shift
            }
            std::cmp::Ordering::Equal => (0.0, 0.0),
        })
        .collect();
    // Where the scene is in each frame relative to frame `t`, to a fraction of a pixel: each
    // frame registered to frame `t` itself within a pixel of where the moves, added up, put
    // it. Moves rounded frame by frame lose a slow drift (0.3 px a frame is a whole pixel every
    // third frame), and fractions added up add up their noise too (a still scene's to a whole
    // pixel within a few frames at a photon per pixel). Then every frame's place is made to
    // agree with the registrations of the pairs of frames around it ([`places`]). Each block's
    // move is looked for around the whole pixel nearest the scene's.
    let mut chained = vec![(0.0, 0.0); gat.len()];
    let chain = |prev: (f64, f64), f: usize| -> (f64, f64) {
        let added = (prev.0 + moves[f].0, prev.1 + moves[f].1);
        let around = (added.0.round() as isize, added.1.round() as isize);
        global_shift(&smooth[center], &smooth[f], w, h, around, 1).shift
    };
    for f in (0..center).rev() {
        chained[f] = chain(chained[f + 1], f);
    }
    for f in center + 1..gat.len() {
        chained[f] = chain(chained[f - 1], f);
    }
    let (at, linked) = places(&smooth, &chained, center, w, h);
    (at, linked, chained)
}

/// How far the scene must move within a window, px along an axis from its first place to its
/// last, for [`fixed_defects`] to be looked for: 2. A sharp point of the scene then spends
/// most frames off any one pixel of the sensor.
const DEFECT_MOVE: f64 = 2.0;

/// Whether the places of the `linked` frames span at least `reach` px along an axis.
fn spans(places: &[(f64, f64)], linked: &[bool], reach: f64) -> bool {
    let span = |axis: fn(&(f64, f64)) -> f64| {
        let along = places
            .iter()
            .zip(linked)
            .filter(|(_, &l)| l)
            .map(|(p, _)| axis(p));
        let (lo, hi) = along.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        hi - lo
    };
    span(|p| p.0) >= reach || span(|p| p.1) >= reach
}

/// How many robust standard deviations (1.4826 median absolute deviations over the frame) a
/// pixel's median difference to its neighbours must lie from the frame's median for
/// [`fixed_defects`] to take it: 7, at which noise alone flags no pixel of a 512² frame.
const DEFECT_Z: f64 = 7.0;

/// The interior pixels whose difference to the mean of their eight neighbours, in the median
/// over the frames (after the transform, `gat`), lies beyond [`DEFECT_Z`] robust standard
/// deviations: a hot pixel the profile does not know (emccd-detect draws its hot pixels anew
/// for each acquisition; a real camera's calibration from another day misses some), or one
/// the profile subtracts that is no longer hot. Only what holds in most frames at one place
/// on the sensor: a bright point of a moving scene passes a pixel in a few frames and leaves
/// the median alone.
fn fixed_defects(gat: &[Vec<f32>], w: usize, h: usize) -> Vec<usize> {
    if w < 3 || h < 3 || gat.len() < 3 {
        return Vec::new();
    }
    let middle = |v: &mut [f32]| {
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    // Each interior pixel's median difference over the frames, on the interior's grid.
    let (iw, ih) = (w - 2, h - 2);
    let medians: Vec<f32> = (1..h - 1)
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut d = vec![0f32; gat.len()];
            (1..w - 1)
                .map(|x| {
                    let i = y * w + x;
                    for (v, g) in d.iter_mut().zip(gat) {
                        let around = g[i - w - 1]
                            + g[i - w]
                            + g[i - w + 1]
                            + g[i - 1]
                            + g[i + 1]
                            + g[i + w - 1]
                            + g[i + w]
                            + g[i + w + 1];
                        *v = g[i] - around / 8.0;
                    }
                    middle(&mut d)
                })
                .collect::<Vec<f32>>()
        })
        .collect();
    let centre = middle(&mut medians.clone());
    let spread = 1.4826
        * middle(
            &mut medians
                .iter()
                .map(|m| (m - centre).abs())
                .collect::<Vec<_>>(),
        );
    if !spread.is_finite() || spread <= 0.0 {
        return Vec::new();
    }
    let limit = DEFECT_Z as f32 * spread;
    // A defect's neighbours share none of its difference: each is lower by an eighth of it
    // (the defect is among its own neighbours). A star's core is a blob, whose pixels around
    // the brightest stand out from theirs about as much (a bright star shaken by tip-tilt by
    // less than its width stays on its pixels in most frames).
    let isolated = |k: usize, m: f32| {
        let (x, y) = ((k % iw) as isize, (k / iw) as isize);
        let (mut sum, mut n) = (0.0f32, 0);
        for (dx, dy) in [
            (-1, -1),
            (0, -1),
            (1, -1),
            (-1, 0),
            (1, 0),
            (-1, 1),
            (0, 1),
            (1, 1),
        ] {
            let (qx, qy) = (x + dx, y + dy);
            if qx >= 0 && qy >= 0 && (qx as usize) < iw && (qy as usize) < ih {
                sum += medians[qy as usize * iw + qx as usize] - centre;
                n += 1;
            }
        }
        n > 0
            && (m - centre).signum() * sum / (n as f32) < (m - centre).abs() * DEFECT_SHARED as f32
    };
    medians
        .iter()
        .enumerate()
        .filter(|&(k, &m)| (m - centre).abs() > limit && isolated(k, m))
        .map(|(k, _)| (k / iw + 1) * w + k % iw + 1)
        .collect()
}

/// How much of a defect's difference to its neighbours they may share on average, in the
/// same direction, for [`fixed_defects`] to take it: a quarter. A defect's neighbours share
/// −1/8 of it; the pixels around a star's brightest share about half of its.
const DEFECT_SHARED: f64 = 0.25;

/// Each of the interior pixels `defects` (ascending, as [`fixed_defects`] finds them) of
/// `frame` replaced by the mean of its neighbours that are not defects (left where all eight
/// are).
fn inpaint(frame: &mut [f32], defects: &[usize], w: usize) {
    for &i in defects {
        let around = [
            i - w - 1,
            i - w,
            i - w + 1,
            i - 1,
            i + 1,
            i + w - 1,
            i + w,
            i + w + 1,
        ];
        let (sum, n) = around
            .iter()
            .filter(|&&j| defects.binary_search(&j).is_err())
            .fold((0.0f64, 0usize), |(s, n), &j| (s + frame[j] as f64, n + 1));
        if n > 0 {
            frame[i] = (sum / n as f64) as f32;
        }
    }
}

/// How many frames apart two frames of a window may be for their registration to enter
/// [`places`]: 5. On the validation camera, pairs up to 2, 3, 5, 8 and 12 apart gave +0.15,
/// +0.18, +0.22, +0.21 and +0.21 dB over registering each raw frame to frame `t` alone (the
/// low-pass alone: +0.17; measured before [`PAIR_GATE`] and [`SNAP`]).
const PAIRS_APART: usize = 5;

/// A pair of frames enters [`places`] only if their mean squared difference at their
/// registration is within this times the best of the pairs that share one of its frames (the
/// better of its two frames' best pairs): a pair across a scene cut holds two scenes, and its
/// registration is noise that the least squares would spread to the frames of frame `t`'s
/// scene. Each frame's best, not the window's: after the transform a dim scene's frames differ
/// less than a bright one's (below a count per pixel its noise is under 1), and on a cut from a
/// bright scene to a dim one the window's best pair gated out the bright scene's own pairs
/// (`tune`'s cuts at 0.5 / 1 e⁻ −1.2 / −1.7 dB once an unlinked frame ended the scene).
const PAIR_GATE: f64 = 2.0;

/// The least best pair [`PAIR_GATE`] counts from: 4 times what two frames of noise alone differ
/// by per pixel after the transform (noise 1) and the low-pass ([`binomial`] keeps 70/256 of a
/// pixel's variance per axis). Without it, frames of noise-free or very bright scenes (from about
/// 1 600 e⁻ per pixel on fine texture, in a simulation) whose pairs differ only by the misfit the
/// parabolas leave at a half-pixel shift were gated apart by pairs a whole number of pixels
/// apart, which match exactly; a cut's pairs differed by far more on every validation cut (16
/// times this left them gated). On `tune` 1 and 4 times it changed no movie by over 0.02 dB.
const PAIR_FLOOR: f64 = 4.0 * 2.0 * (70.0 / 256.0) * (70.0 / 256.0);

/// The scene's place in every frame relative to frame `center` (fixed at 0) that agrees best,
/// in least squares, with the registrations of the pairs of frames up to [`PAIRS_APART`] apart
/// that match about as well as their frames' best pairs ([`PAIR_GATE`]), each registered within
/// a pixel of where `first` (each frame registered to frame `center`) puts it, and which frames
/// a chain of such pairs links to frame `center`. Each place rests on up to 2·[`PAIRS_APART`]
/// registrations, so each registration's own noise (its draw of the two frames' noise at each
/// shift) averages out. What no pair can see is a frame's own apparent shift (its noise
/// mimicking a move of its scene): frame `center`'s stays in every neighbour's place. A frame
/// not linked to frame `center` holds another scene ([`same_scene`] ends the scene before it)
/// and keeps its place in `first`; with at least two more pairs than unknown places, a place
/// that does not differ from frame `center`'s by more than [`SNAP`] standard errors (nor by half
/// a pixel) is frame `center`'s (a window of 3 frames or fewer is never snapped). Frames too
/// small for any pair to be registered keep `first`, all linked; a frame whose own pairs alone
/// are shifted too far for the frames' size is not linked.
fn places(
    smooth: &[Vec<f32>],
    first: &[(f64, f64)],
    center: usize,
    w: usize,
    h: usize,
) -> (Vec<(f64, f64)>, Vec<bool>) {
    let len = first.len();
    let pairs: Vec<(usize, usize)> = (0..len)
        .flat_map(|i| (i + 1..(i + PAIRS_APART + 1).min(len)).map(move |j| (i, j)))
        .collect();
    let registered: Vec<Registration> = pairs
        .par_iter()
        .map(|&(i, j)| {
            let around = (
                (first[j].0 - first[i].0).round() as isize,
                (first[j].1 - first[i].1).round() as isize,
            );
            global_shift(&smooth[i], &smooth[j], w, h, around, 1)
        })
        .collect();
    // Each frame's best pair.
    let mut best = vec![f64::INFINITY; len];
    for (&(i, j), r) in pairs.iter().zip(&registered) {
        best[i] = best[i].min(r.msd);
        best[j] = best[j].min(r.msd);
    }
    if best.iter().all(|b| b.is_infinite()) {
        return (first.to_vec(), vec![true; len]);
    }
    let kept: Vec<((usize, usize), (f64, f64))> = pairs
        .iter()
        .zip(&registered)
        .filter(|(&(i, j), r)| {
            r.msd.is_finite() && r.msd <= PAIR_GATE * best[i].min(best[j]).max(PAIR_FLOOR)
        })
        .map(|(&p, r)| (p, r.shift))
        .collect();
    // The frames linked to frame `center`, and their unknowns' indices (frame `center`'s place
    // is 0, not an unknown).
    let mut linked = vec![false; len];
    linked[center] = true;
    let mut grown = true;
    while grown {
        grown = false;
        for &((i, j), _) in &kept {
            if linked[i] != linked[j] {
                linked[i] = true;
                linked[j] = true;
                grown = true;
            }
        }
    }
    let mut index = vec![usize::MAX; len];
    let mut unknowns = 0;
    for f in (0..len).filter(|&f| linked[f] && f != center) {
        index[f] = unknowns;
        unknowns += 1;
    }
    if unknowns == 0 {
        return (first.to_vec(), linked);
    }
    // The normal equations: the linked pairs' graph Laplacian without frame `center`'s row and
    // column, one right-hand side per axis; positive definite, since every unknown is linked
    // to frame `center`.
    let used: Vec<_> = kept.iter().filter(|((i, _), _)| linked[*i]).collect();
    let mut normal = DMatrix::<f64>::zeros(unknowns, unknowns);
    let mut rhs = DMatrix::<f64>::zeros(unknowns, 2);
    for &&((i, j), (sx, sy)) in &used {
        for (f, sign) in [(i, -1.0), (j, 1.0)] {
            if f == center {
                continue;
            }
            normal[(index[f], index[f])] += 1.0;
            rhs[(index[f], 0)] += sign * sx;
            rhs[(index[f], 1)] += sign * sy;
        }
        if i != center && j != center {
            normal[(index[i], index[j])] -= 1.0;
            normal[(index[j], index[i])] -= 1.0;
        }
    }
    let Some(cholesky) = normal.clone().cholesky() else {
        return (first.to_vec(), linked);
    };
    let solved = cholesky.solve(&rhs);
    let mut at: Vec<(f64, f64)> = (0..len)
        .map(|f| {
            if f == center {
                (0.0, 0.0)
            } else if linked[f] {
                (solved[(index[f], 0)], solved[(index[f], 1)])
            } else {
                first[f]
            }
        })
        .collect();
    // Each place's standard error: the pairs' scatter about the solution (both axes pooled)
    // through the least squares' covariance.
    let dof = used.len() as f64 - unknowns as f64;
    if dof >= 2.0 {
        let scatter = used
            .iter()
            .map(|&&((i, j), (sx, sy))| {
                (sx - (at[j].0 - at[i].0)).powi(2) + (sy - (at[j].1 - at[i].1)).powi(2)
            })
            .sum::<f64>()
            / (2.0 * dof);
        let mut covariance = cholesky.inverse();
        let fit = (&normal, &rhs, &used[..], &index[..]);
        if let Some((smooth, c)) = smooth_motion(fit, &linked, &at, scatter) {
            at = smooth;
            covariance = c;
        }
        for f in (0..len).filter(|&f| linked[f] && f != center) {
            let limit = (SNAP * (covariance[(index[f], index[f])] * scatter).sqrt()).min(0.5);
            let (x, y) = &mut at[f];
            for axis in [x, y] {
                if axis.abs() < limit {
                    *axis = 0.0;
                }
            }
        }
    }
    (at, linked)
}

/// The scene's acceleration the places' smoothness prior expects, px per frame²
/// ([`smooth_motion`]): 0.03. Chosen on the validation camera `tune` with [`SMOOTH_GATE`]
/// (docs/journal.md).
const ACCELERATION: f64 = 0.03;

/// How much more the pairs' registrations may scatter about the smooth places than about the
/// free ones, as a mean square per pair against the free fit's per degree of freedom, for the
/// smooth places to be taken ([`smooth_motion`]): 4. A jitter's or a cut's registrations are
/// far from any smooth motion and are refused by far more; a dim drift's pairs hold misfits of
/// a pixel and more (a registration near a periodic texture's wrong period) that the smooth
/// places do not follow, so at 1.5 its smooth places were refused too.
const SMOOTH_GATE: f64 = 4.0;

/// The smooth places of [`smooth_motion`] and their covariance.
type Smooth = (Vec<(f64, f64)>, DMatrix<f64>);

/// [`places`]' normal equations, right-hand sides, pairs used and unknowns' indices.
type Fit<'a> = (
    &'a DMatrix<f64>,
    &'a DMatrix<f64>,
    &'a [&'a ((usize, usize), (f64, f64))],
    &'a [usize],
);

/// [`places`]' least squares (`normal` · places = `rhs`, the pairs `used`, the unknowns'
/// `index` per frame; the frames `linked`, the free solution `at` and its scatter per degree
/// of freedom) with a prior
/// that the scene moves smoothly: each three consecutive linked frames' second difference is
/// 0 with a standard deviation of [`ACCELERATION`], weighed against the registrations' own
/// scatter. Below a photon per pixel a 128² frame's registration to another can be off by
/// half a pixel and more along an axis with little texture; a drift or a stage's slow motion
/// puts every frame's place on a smooth curve, which 25 frames' registrations fix far better
/// than each frame's own (on `tune`'s drift at 0.5 e⁻ the places' error 1.3 → 0.75 px rms,
/// +0.23 dB; with the true places +0.6). Taken only where the pairs agree with it
/// ([`SMOOTH_GATE`]); returns the places and their covariance (per unit of scatter).
fn smooth_motion(
    (normal, rhs, used, index): Fit,
    linked: &[bool],
    at: &[(f64, f64)],
    scatter: f64,
) -> Option<Smooth> {
    let strength = scatter / (ACCELERATION * ACCELERATION);
    let mut prior = normal.clone();
    for f in 1..index.len().saturating_sub(1) {
        // Frame `center` (no unknown) is at 0, so its term adds nothing to the right-hand side.
        let terms = [(f - 1, 1.0), (f, -2.0), (f + 1, 1.0)];
        if terms.iter().any(|&(g, _)| !linked[g]) {
            continue;
        }
        for &(i, a) in &terms {
            for &(j, b) in &terms {
                if index[i] != usize::MAX && index[j] != usize::MAX {
                    prior[(index[i], index[j])] += strength * a * b;
                }
            }
        }
    }
    let cholesky = prior.cholesky()?;
    let solved = cholesky.solve(rhs);
    let smooth: Vec<(f64, f64)> = at
        .iter()
        .enumerate()
        .map(|(f, &p)| match index[f] {
            usize::MAX => p,
            k => (solved[(k, 0)], solved[(k, 1)]),
        })
        .collect();
    let misfit = used
        .iter()
        .map(|&&((i, j), (sx, sy))| {
            (sx - (smooth[j].0 - smooth[i].0)).powi(2) + (sy - (smooth[j].1 - smooth[i].1)).powi(2)
        })
        .sum::<f64>()
        / (2.0 * used.len() as f64);
    (misfit <= SMOOTH_GATE * scatter).then(|| (smooth, cholesky.inverse()))
}

/// A place along an axis within this many standard errors of frame `t`'s, and within half a
/// pixel of it, is taken as frame `t`'s ([`places`]): a frame of a still scene is then not
/// resampled by its registration's noise, which at half an electron per pixel on a dim 128²
/// scene is a good part of a pixel. 3 on the validation camera (2, 3, 4 without the half pixel:
/// +0.01 / +0.05, +0.01 / +0.07, −0.00 / +0.08 dB at 1 / 4 and 0.5 / 16 e⁻, 4 losing on the
/// drift and rotation; 3 with it +0.01 / +0.06). Without the half pixel a 1 px/frame drift on
/// the tests' small scene was taken for still (27.7 → 26.8 dB).
const SNAP: f64 = 3.0;

/// Each of `frames` [`resampled`] by its `fraction`, in parallel (a frame with none is left).
fn resample_all(frames: &mut [Vec<f32>], fraction: &[(f64, f64)], w: usize, h: usize) {
    frames
        .par_iter_mut()
        .zip(fraction)
        .filter(|(_, &e)| e != (0.0, 0.0))
        .for_each(|(f, &e)| *f = resampled(f, w, h, e));
}

/// The first and last frames of the window that hold frame `center`'s scene: walking out from
/// it, a frame beyond the first or last frame that a chain of gated pairs links to it
/// (`linked`, from [`places`]), or one whose tracked blocks' median difference over their
/// predicted noise ([`scaled_difference`]) is above [`SCENE_GATE`] times the best-matching
/// neighbour's, ends the scene on that side (it and every frame beyond). The best neighbour
/// stands for noise alone because the predicted noise is only a model (EMCCD frames are not
/// exactly Poisson–Gaussian, and the estimates it comes from are smoothed), and a window rarely
/// holds no frame of its own scene. A frame most blocks' tracks never reached is left to the
/// blocks that did. The links see what the medians can miss: on a dim frame just after a cut,
/// its own scene's frames resampled by its own apparent shift matched it worse than the other
/// scene's, left whole, and set the floor.
fn same_scene(
    tracks: &[Vec<Vec<Step>>],
    center: usize,
    len: usize,
    linked: &[bool],
) -> (usize, usize) {
    let blocks: usize = tracks.iter().map(Vec::len).sum();
    let medians: Vec<Option<f64>> = (0..len)
        .map(|f| {
            let ds: Vec<f64> = tracks
                .iter()
                .flatten()
                .flat_map(|steps| steps.iter().filter(|s| s.frame == f).map(|s| s.chi))
                .collect();
            if f == center || 2 * ds.len() < blocks {
                None
            } else {
                emccd_profile::median(ds)
            }
        })
        .collect();
    let floor = medians
        .iter()
        .flatten()
        .copied()
        .fold(f64::INFINITY, f64::min);
    // The links' scene: from the first to the last linked frame (a cut leaves the other
    // scene's frames unlinked at one end; a frame unlinked between linked ones is a pair's
    // misfit, not another scene).
    let (lo, hi) = (
        linked.iter().position(|&l| l).unwrap_or(center),
        linked.iter().rposition(|&l| l).unwrap_or(center),
    );
    let other =
        |f: usize| !(lo..=hi).contains(&f) || medians[f].is_some_and(|m| m > SCENE_GATE * floor);
    let mut first = center;
    while first > 0 && !other(first - 1) {
        first -= 1;
    }
    let mut last = center;
    while last + 1 < len && !other(last + 1) {
        last += 1;
    }
    (first, last)
}

/// The scene `first..=last` of frame `center` (`w` × `h`, `guides` the frames' single-frame
/// estimates) narrowed to the frames whose whole frame looks like frame `center`'s. The tracking
/// finds a cut only where the other scene's blocks are not found again near where they were: a
/// cut to content of the same local kind (bars turned, texture for texture) passes it, and so
/// does one to a scene so dim that a block's difference stays within its noise (camera B's cut
/// at 0.5 e⁻, its second scene at 0.14 e⁻ a pixel, took the first in). Over the whole frame,
/// though, the other scene does not correlate with this one: a neighbour whose 2×2-binned guide
/// correlates with frame `center`'s less than [`LIKENESS_GATE`] times the next frame inward's
/// (frame `center`'s best neighbour's, for its own neighbours), and by more than the
/// correlation's noise, ends the scene on its side, where that reference reaches
/// [`LIKENESS_FLOOR`]. Judged against the best neighbour alone, the test cut the far frames of
/// diffusing particles, whose whole frames decorrelate frame by frame (`tune`'s particles −0.16
/// to −0.33 dB). Its cost: 49 shifts of up to 24 binned guides a window (not yet benchmarked).
fn alike(
    guides: &[&[f32]],
    center: usize,
    (first, last): (usize, usize),
    w: usize,
    h: usize,
) -> (usize, usize) {
    let (own, bw, bh) = bin2(guides[center], w, h);
    let like: Vec<Option<f64>> = (0..guides.len())
        .map(|j| {
            (j != center && (first..=last).contains(&j))
                .then(|| likeness(&own, &bin2(guides[j], w, h).0, bw, bh, LIKENESS_SEARCH))
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
    // Against the next frame inward (frame `center`'s best neighbour for its own neighbours): a
    // cut is an abrupt fall, a scene that changes (particles diffusing) falls frame by frame.
    let inward = |j: usize| if j < center { j + 1 } else { j - 1 };
    let reference = |j: usize| {
        if inward(j) == center {
            best
        } else {
            like[inward(j)].unwrap_or(best)
        }
    };
    let other = |j: usize| {
        let reference = reference(j);
        reference >= LIKENESS_FLOOR
            && like[j].is_some_and(|r| r < LIKENESS_GATE * reference && reference - r > margin)
    };
    let (mut first, mut last) = (first, last);
    while first < center && (first..center).any(other) {
        first += 1;
    }
    while last > center && (center + 1..=last).any(other) {
        last -= 1;
    }
    (first, last)
}

/// A neighbour whose guide correlates with the frame's less than this times the next frame
/// inward's (and by more than the estimate's noise) shows another scene ([`alike`]).
const LIKENESS_GATE: f64 = 0.4;

/// The correlation the next frame inward must reach for [`alike`] to judge a frame against it: a
/// scene without structure (a uniform region) correlates from frame to frame only through its
/// estimates' smooth residual noise, whose few independent samples the margin does not allow for.
const LIKENESS_FLOOR: f64 = 0.5;

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

/// Each of `frames` times its factor in `scale`.
fn scaled(frames: &[&[f32]], scale: &[f64]) -> Vec<Vec<f32>> {
    frames
        .iter()
        .zip(scale)
        .map(|(f, &s)| f.iter().map(|&z| z * s as f32).collect())
        .collect()
}

/// Per window frame, the factor that brings it to frame `center`'s brightness along the window's
/// trend: the least-squares slope of the log of the frames' means over time, fitted on the frames
/// `within` around `center` that change by under 10 % from one to the next (a larger step is a cut
/// or a flash, whose frames the matching refuses anyway). Without it a bleaching scene's first and
/// last frames, whose neighbours are all brighter or all dimmer, would be biased by the trend (4
/// %/frame bleaching: 4 % at the ends of a 5-frame window). Only the trend is taken, not each
/// frame's own mean, so the noise of the mean still averages over the window.
fn brightness(
    window: &[&[f32]],
    center: usize,
    within: std::ops::RangeInclusive<usize>,
) -> Vec<f64> {
    let means: Vec<f64> = window
        .iter()
        .map(|f| f.iter().map(|&v| v as f64).sum::<f64>() / f.len().max(1) as f64)
        .collect();
    let mut one = vec![1.0; window.len()];
    let step_ok = |a: f64, b: f64| a > 0.0 && b > 0.0 && (a / b).ln().abs() <= 0.1;
    let (mut lo, mut hi) = (center, center);
    while lo > *within.start() && step_ok(means[lo - 1], means[lo]) {
        lo -= 1;
    }
    while hi < *within.end() && step_ok(means[hi + 1], means[hi]) {
        hi += 1;
    }
    if hi == lo {
        return one;
    }
    let n = (hi - lo + 1) as f64;
    let xbar = (lo..=hi).map(|f| f as f64).sum::<f64>() / n;
    let ybar = (lo..=hi).map(|f| means[f].ln()).sum::<f64>() / n;
    let sxy: f64 = (lo..=hi)
        .map(|f| (f as f64 - xbar) * (means[f].ln() - ybar))
        .sum();
    let sxx: f64 = (lo..=hi).map(|f| (f as f64 - xbar).powi(2)).sum();
    let slope = sxy / sxx;
    for (f, s) in one.iter_mut().enumerate().take(hi + 1).skip(lo) {
        *s = (-slope * (f as f64 - center as f64)).exp();
    }
    one
}

/// How much closer (summed squared difference after the transform, in units of the noise of one
/// pixel) the guides must put a block at its proposed move than where the scene's move puts it for
/// the track to move on the guides' word alone: 0.15·N² (a smaller move gain needs the blocks
/// around to agree, [`NEIGHBOURED_GAIN`]). A track goes on from where its block was last found, so
/// a move the guides' own residual errors propose (on flat regions, along an edge, a star blunted
/// by its sub-pixel phase) is carried to every frame beyond it, and there the block is matched off
/// the scene. On a still scene the guides' blocks differ by a median of about 0.1 at half a
/// photo-electron per pixel and 6 at 16 (they are sharper and keep more of the noise's texture), so
/// 0.05·N² (3.2, chosen when blocks followed the scene's motion alone) let noise move blocks from a
/// few photo-electrons up. On the validation camera `tune` with 12 frames each side, 0.15·N² over
/// 0.05·N²: +0.51 / +0.37 dB at 1 / 4 and 0.5 / 16 e⁻ (still scenes at 4 / 16 e⁻ +1.9 / +1.5, the
/// stars +2.2 / +1.9 at 1 / 0.5 e⁻), with the particles at 0.5 e⁻ −0.7 and the rotation −0.5 (their
/// own moves need the smaller gain there; on camera A's 256² rotation at 0.5 e⁻, −0.6 dB with 6
/// frames each side); 0.3·N² +0.55 / +0.30; a gain scaled to the window's median difference was
/// between (docs/journal.md). Taking every move the guides favour fits their residual noise (a
/// still scene at ~1 count 21.3 dB where 0.05·N² gave 26.2). Choosing on the noisy frames instead
/// picks the neighbours' blocks that resemble frame `t`'s noise, which then averages out less and
/// biases the mean (measured: 2–5 % on a uniform scene at half a count per pixel).
const MOVE_GAIN: f64 = 0.15 * (N * N) as f64;

/// The move gain under [`MOVE_GAIN`] at which a block still moves where the blocks around it moved
/// alike ([`agrees`]): 0.02·N². A rotation's or a deformation's moves at the dim end, and the
/// blunted stars' at any level, are real but beat staying by less than [`MOVE_GAIN`]. On the
/// validation camera `tune` (12 frames each side), over [`MOVE_GAIN`] alone: +0.09 / +0.07 dB
/// at 1 / 4 and 0.5 / 16 e⁻ and +0.06 on the 32-frame movies (the deformation up to +0.5, the
/// rotation +0.1 to +0.3, the stars up to +0.4; no movie below by more than 0.11); 0.05·N² with
/// the neighbours' mean +0.06 / +0.04; 0.02·N² with their mean +0.08 at 1 / 4 e⁻ but the still
/// scene −0.15; no gain at all (every move the guides favour, with the neighbours' say) −0.6, the
/// still scenes −1.8 and their means 1 % high: the neighbours' own proposals are noise then.
const NEIGHBOURED_GAIN: f64 = 0.02 * (N * N) as f64;

/// How far apart the blocks are whose moves confirm a block's, px: 8, a block's width, so that
/// no pixel of theirs is the block's own and their guides' noise is theirs. 12 px measured 0.01 dB
/// below it on `tune`.
const NEIGHBOURS_AT: usize = 8;

/// How many of the eight blocks around a block ([`NEIGHBOURS_AT`] away each way and diagonally)
/// must be still tracked for their moves to confirm its own: 3 (a corner block has 3).
const NEIGHBOURS_NEEDED: usize = 3;

/// The shift (within `reach` px of `around`) that best carries frame `from` onto frame `to`
/// (both after the transform): the whole-pixel one with the least mean squared difference over
/// the pixels far enough from the border, refined to a fraction of a pixel by the vertex of the
/// parabola through it and its neighbours along each axis. A drift or a tip-tilt jitter moves
/// every block alike, and where noise hides the move from each block (below a photon or so per
/// pixel) the whole frame still shows it; a still scene gives no whole-pixel shift, so no
/// block is moved by noise (only resampled by the noise's fraction, which costs still scenes
/// nothing measurable).
fn global_shift(
    from: &[f32],
    to: &[f32],
    w: usize,
    h: usize,
    around: (isize, isize),
    reach: isize,
) -> Registration {
    let s = (reach + around.0.abs().max(around.1.abs())) as usize;
    if w <= 2 * s || h <= 2 * s {
        return Registration {
            shift: (0.0, 0.0),
            msd: f64::INFINITY,
        };
    }
    let side = (2 * reach + 1) as usize;
    // The shift of the surface's `k`th point, row by row.
    let shift = |k: usize| {
        (
            around.0 + (k % side) as isize - reach,
            around.1 + (k / side) as isize - reach,
        )
    };
    // Each shift's sum over the rows in row order, the shifts side by side: the same bits on
    // every run (a row is too little work to share among threads).
    let surface: Vec<f64> = (0..side * side)
        .into_par_iter()
        .map(|k| {
            let (dx, dy) = shift(k);
            let xb = (s as isize + dx) as usize;
            (s..h - s)
                .map(|y| {
                    let yb = (y as isize + dy) as usize;
                    squared_difference(
                        &from[y * w + s..y * w + w - s],
                        &to[yb * w + xb..][..w - 2 * s],
                    )
                })
                .sum::<f64>()
        })
        .collect();
    let mut best = (f64::INFINITY, (0, 0));
    for (k, &d) in surface.iter().enumerate() {
        let (dx, dy) = shift(k);
        // Ties go to the smaller move.
        let nearer = dx * dx + dy * dy < best.1 .0 * best.1 .0 + best.1 .1 * best.1 .1;
        if d < best.0 || (d == best.0 && nearer) {
            best = (d, (dx, dy));
        }
    }
    // The vertex of the parabola through the surface's minimum and its neighbours, per axis:
    // over a whole frame the noise adds the same at every shift, and the surface is smooth.
    let (bx, by) = (best.1 .0 - around.0, best.1 .1 - around.1);
    let at = |dx: isize, dy: isize| surface[(dy + reach) as usize * side + (dx + reach) as usize];
    let vertex = |m: f64, o: f64, p: f64| {
        let c = m - 2.0 * o + p;
        if c > 0.0 {
            ((m - p) / (2.0 * c)).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    // Each axis's fraction, and the parabola's change from the whole pixel to it (≤ 0).
    let fraction = |m: f64, o: f64, p: f64| {
        let f = vertex(m, o, p);
        (f, f * (p - m) / 2.0 + (m - 2.0 * o + p) * f * f / 2.0)
    };
    let (fx, dx) = if bx.abs() < reach {
        fraction(at(bx - 1, by), at(bx, by), at(bx + 1, by))
    } else {
        (0.0, 0.0)
    };
    let (fy, dy) = if by.abs() < reach {
        fraction(at(bx, by - 1), at(bx, by), at(bx, by + 1))
    } else {
        (0.0, 0.0)
    };
    let pixels = ((w - 2 * s) * (h - 2 * s)) as f64;
    Registration {
        shift: ((bx + around.0) as f64 + fx, (by + around.1) as f64 + fy),
        // Infinite where no shift gave a number (a frame with NaN in it).
        msd: if best.0.is_finite() {
            (best.0 + dx + dy).max(0.0) / pixels
        } else {
            f64::INFINITY
        },
    }
}

/// A whole-frame registration ([`global_shift`]).
struct Registration {
    /// The shift, px.
    shift: (f64, f64),
    /// The mean squared difference per pixel at the shift, as the parabolas through the whole
    /// pixels' put it (a pair half a pixel apart would otherwise count its misfit at the whole
    /// pixel as difference; infinite where the frame is too small to be shifted that far).
    msd: f64,
}

/// The summed squared difference of the blocks at `a` in `one` and at `b` in `other` (the data's
/// units), each pixel's over the variance the two frames' noise gives it: about N² for blocks
/// of the same content at any brightness. The transform's noise is 1 only above a few counts
/// per pixel (below, a dim scene's blocks differ by a fifth of a bright one's), so a bright
/// frame's neighbour from a dim scene would differ about as little after it as one of its own.
fn scaled_difference(
    (one, other): (&[f32], &[f32]),
    (v_one, v_other): (&[f32], &[f32]),
    w: usize,
    a: (usize, usize),
    b: (usize, usize),
) -> f64 {
    (0..N)
        .map(|r| {
            let (ia, ib) = ((a.1 + r) * w + a.0, (b.1 + r) * w + b.0);
            let (x, y) = (&one[ia..][..N], &other[ib..][..N]);
            let (vx, vy) = (&v_one[ia..][..N], &v_other[ib..][..N]);
            // A row's eight terms added as a tree, as [`squared_difference`]'s lanes (N is 8).
            tree_sum(std::array::from_fn(|q| {
                let diff = (x[q] - y[q]) as f64;
                diff * diff / (vx[q] + vy[q]) as f64
            }))
        })
        .sum()
}

/// The summed squared difference of the blocks at `a` in `one` and at `b` in `other`.
fn ssd(one: &[f32], other: &[f32], w: usize, a: (usize, usize), b: (usize, usize)) -> f64 {
    (0..N)
        .map(|r| {
            let x = &one[(a.1 + r) * w + a.0..][..N];
            let y = &other[(b.1 + r) * w + b.0..][..N];
            squared_difference(x, y)
        })
        .sum()
}

/// The `(N + 2)²` pixels of `frame` around the block at `b` (one pixel beyond each side), sampled
/// `e` px further along each axis (Keys' cubic kernel, the edge pixels repeated): every pixel at
/// the same fraction, so the taps are computed once.
fn shifted_patch(
    frame: &[f32],
    w: usize,
    h: usize,
    b: (usize, usize),
    e: (f64, f64),
    out: &mut [f64; (N + 2) * (N + 2)],
) {
    const P: usize = N + 2;
    let (ox, wx) = taps(e.0);
    let (oy, wy) = taps(e.1);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    // Along x over the rows the taps reach (P + 3), then along y.
    let mut rows = [0f64; (N + 5) * (N + 2)];
    for j in 0..P + 3 {
        let row = clamp(b.1 as isize - 1 + oy - 1 + j as isize, h) * w;
        for q in 0..P {
            let x0 = b.0 as isize - 1 + q as isize + ox - 1;
            rows[j * P + q] = (0..4)
                .map(|k| wx[k] * frame[row + clamp(x0 + k as isize, w)] as f64)
                .sum();
        }
    }
    for r in 0..P {
        for q in 0..P {
            out[r * P + q] = (0..4).map(|k| wy[k] * rows[(r + k) * P + q]).sum();
        }
    }
}

/// The `N` pixels of `frame` from (`b.0`, `b.1`) along the row, sampled `e` px further along each
/// axis (Keys' cubic kernel, the edge pixels repeated; the taps computed once for the row).
fn shifted_row(
    frame: &[f32],
    w: usize,
    h: usize,
    b: (usize, usize),
    e: (f64, f64),
    out: &mut [f32; N],
) {
    let (ox, wx) = taps(b.0 as f64 + e.0);
    let (oy, wy) = taps(b.1 as f64 + e.1);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    for (q, o) in out.iter_mut().enumerate() {
        let x0 = ox + q as isize - 1;
        let v: f64 = (0..4)
            .map(|j| {
                let row = clamp(oy - 1 + j as isize, h) * w;
                wy[j]
                    * (0..4)
                        .map(|k| wx[k] * frame[row + clamp(x0 + k as isize, w)] as f64)
                        .sum::<f64>()
            })
            .sum();
        *o = v as f32;
    }
}

/// The summed squared difference between block `a` of `one` and the inside of a
/// [`shifted_patch`].
fn patch_ssd(one: &[f32], w: usize, a: (usize, usize), patch: &[f64; (N + 2) * (N + 2)]) -> f64 {
    let mut s = 0.0;
    for r in 0..N {
        for q in 0..N {
            s += (one[(a.1 + r) * w + a.0 + q] as f64 - patch[(r + 1) * (N + 2) + q + 1]).powi(2);
        }
    }
    s
}

/// Where block `a` of `one` lies in `other` to a fraction of a pixel, as an offset from the
/// whole-pixel place `b` (Lucas–Kanade: Gauss–Newton steps on the Keys-interpolated block,
/// its slopes by central differences), or `None` where the block's content has no slope to
/// align on or the offset does not fit better than `b`.
fn refine(
    one: &[f32],
    other: &[f32],
    w: usize,
    h: usize,
    a: (usize, usize),
    b: (usize, usize),
) -> Option<(f64, f64)> {
    const P: usize = N + 2;
    let mut patch = [0f64; P * P];
    let mut e = (0.0f64, 0.0f64);
    shifted_patch(other, w, h, b, e, &mut patch);
    let at_whole = patch_ssd(one, w, a, &patch);
    for _ in 0..4 {
        let (mut hxx, mut hxy, mut hyy, mut gx, mut gy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for r in 1..=N {
            for q in 1..=N {
                let ix = 0.5 * (patch[r * P + q + 1] - patch[r * P + q - 1]);
                let iy = 0.5 * (patch[(r + 1) * P + q] - patch[(r - 1) * P + q]);
                let diff = one[(a.1 + r - 1) * w + a.0 + q - 1] as f64 - patch[r * P + q];
                hxx += ix * ix;
                hxy += ix * iy;
                hyy += iy * iy;
                gx += diff * ix;
                gy += diff * iy;
            }
        }
        let det = hxx * hyy - hxy * hxy;
        if !(det > 1e-6 * (hxx + hyy).powi(2)) {
            return None;
        }
        let (dx, dy) = ((hyy * gx - hxy * gy) / det, (hxx * gy - hxy * gx) / det);
        e = (e.0 + dx, e.1 + dy);
        if e.0.abs() > 0.75 || e.1.abs() > 0.75 {
            return None;
        }
        shifted_patch(other, w, h, b, e, &mut patch);
        if dx.abs() < 0.01 && dy.abs() < 0.01 {
            break;
        }
    }
    (patch_ssd(one, w, a, &patch) < at_whole).then_some(e)
}

/// The summed squared difference of two runs of pixels of the same length, in `f64`. Most of
/// the tracking's time: the squares are added in eight lanes (pixel `i` to lane `i % 8`), the
/// lanes then as a tree (halves, then quarters), which vector units do side by side where a
/// sum from left to right waits on each addition in turn; the order is fixed, so the bits are
/// the same on every run.
fn squared_difference(a: &[f32], b: &[f32]) -> f64 {
    debug_assert_eq!(a.len(), b.len());
    let mut lanes = [0f64; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for j in 0..8 {
            let d = (x[j] - y[j]) as f64;
            lanes[j] += d * d;
        }
    }
    for (j, (p, q)) in ra.iter().zip(rb).enumerate() {
        let d = (p - q) as f64;
        lanes[j] += d * d;
    }
    tree_sum(lanes)
}

/// Eight terms added as a tree (halves, then quarters): the same order on every call.
fn tree_sum(lanes: [f64; 8]) -> f64 {
    let half: [f64; 4] = std::array::from_fn(|j| lanes[j] + lanes[j + 4]);
    (half[0] + half[2]) + (half[1] + half[3])
}

/// The position within [`SEARCH`] px of `around` in `other` whose block is closest to the block
/// at `at` in `own`, with its summed squared difference, if any is under `under` (ties go to the
/// position nearest `around`).
fn best_match(
    own: &[f32],
    other: &[f32],
    w: usize,
    h: usize,
    at: (usize, usize),
    around: (usize, usize),
    under: f64,
) -> Option<(f64, usize, usize)> {
    let span = |c: usize, len: usize| {
        (
            (c as isize - SEARCH).max(0) as usize,
            ((c as isize + SEARCH) as usize).min(len - N),
        )
    };
    // No summed square is under zero: where the guides already agree about as well as
    // noise-free content can (most blocks of a still or slowly moving scene), there is nothing
    // to search for.
    if under <= 0.0 {
        return None;
    }
    let ((x0, x1), (y0, y1)) = (span(around.0, w), span(around.1, h));
    let mut best: Option<(f64, usize, usize)> = None;
    for cy in y0..=y1 {
        for cx in x0..=x1 {
            let mut d = 0.0;
            let bound = best.map_or(under, |b| b.0);
            for r in 0..N {
                let a = &own[(at.1 + r) * w + at.0..][..N];
                let b = &other[(cy + r) * w + cx..][..N];
                d += squared_difference(a, b);
                if d > bound {
                    break;
                }
            }
            let dist = |x: usize, y: usize| {
                (x as isize - around.0 as isize).pow(2) + (y as isize - around.1 as isize).pow(2)
            };
            let better = match best {
                None => d < under,
                Some(b) => d < b.0 || (d == b.0 && dist(cx, cy) < dist(b.1, b.2)),
            };
            if better {
                best = Some((d, cx, cy));
            }
        }
    }
    best
}

/// The frames' worth of matches from which a pixel takes the mean's estimate alone; from one
/// frame (the pixel's own) to this it goes over from the frame's own estimate linearly. Four
/// frames hold four times the photons: where a spot moved on its own and matched in a few
/// frames, their mean's estimate still keeps it sharper than the frame's alone, though BM3D
/// ran at the noise of the whole window's mean. Measured on the validation camera `tune` against
/// going over to the typical pixel's frames (the rule before): particles +0.9 dB at 1 e⁻, the
/// other movies −0.02 to +0.13 dB (docs/journal.md).
const POOLED_FROM: f64 = 4.0;

/// The estimate of `window[center]` (DN above bias, noise `p`) from its window: iterative BM3D of
/// the motion-compensated mean at a mean's noise, falling back to `singles[center]` (the frame's
/// own estimate) where fewer than [`POOLED_FROM`] frames matched. The mean is over the whole
/// window, or over the [`NEAR`] frames each side where the held-out test prefers them
/// ([`HeldOut`]). `singles` are the window's single-frame estimates, [`single`] of each frame (a
/// stack computes each once). One frame's worth of matches or fewer gives `singles[center]`
/// unchanged.
pub fn estimate(
    window: &[&[f32]],
    singles: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
) -> Vec<f32> {
    let (own, single) = (window[center], singles[center]);
    if !trackable(window, singles, w, h) {
        return single.to_vec();
    }
    let t = tracked(window, singles, center, w, h, p, STEP);
    let own = t.own(own);
    let own = &own[..];
    let mut mm = pooled(&t, own, center, w, h, usize::MAX, true, 0..h);
    let typical = emccd_profile::median(mm.frames.iter().copied()).unwrap_or(1.0) as f64;
    if typical < 1.5 {
        return single.to_vec();
    }
    if held_out_of(&t, own, center, w, h, p).is_some_and(|c| c.prefers_near()) {
        mm = pooled(&t, own, center, w, h, NEAR, true, 0..h);
    }
    // The mean's noise: that of a mean of as many frames as its noise is worth.
    let worth = emccd_profile::median(mm.noise_frames.iter().copied()).unwrap_or(1.0) as f64;
    let pooled = bm3d_adaptive_correlated(&mm.mean, w, h, p.of_mean(worth), &mm.noise);
    pooled
        .iter()
        .zip(single)
        .zip(&mm.frames)
        .map(|((&a, &b), &n)| {
            let wt = ((n as f64 - 1.0) / (POOLED_FROM - 1.0)).clamp(0.0, 1.0) as f32;
            wt * a + (1.0 - wt) * b
        })
        .collect()
}

/// The frames each side of frame `t` the shorter window holds, which [`estimate`] takes instead
/// of the whole window where the held-out test prefers it ([`HeldOut`]). A scene that deforms
/// changes from frame to frame in ways no block's whole-pixel track follows, and its far frames
/// add their distortion: on the validation camera `tune` (128², 1 e⁻) the deformation was
/// 19.26 / 18.68 / 17.98 / 17.77 dB with 3 / 5 / 8 / 12 frames each side (docs/journal.md).
pub const NEAR: usize = 3;

/// Side of the square at the frame's centre that the held-out test denoises twice, px: about
/// 0.6 s per 512² frame on 2 cores (a fifth of one BM3D pass of the frame), where the test's
/// noise is still about a fifth of the deformation's difference at a photon per pixel.
const HELD_OUT_SIDE: usize = 128;

/// How many of its standard deviations the held-out difference must reach for the near frames
/// to be taken. The test is noisy where a few bright pixels hold the error (a
/// jittered star field: one frame in 16 at 4 e⁻ came out just above zero and lost 2.4 dB with
/// the near frames); at two standard deviations no frame of the validation movies took them
/// where they were worse, and every frame of the deformation at 1 e⁻ took them (docs/journal.md).
const HELD_OUT_Z: f64 = 2.0;

/// Frame `t` estimated without its own data, from the whole window and from the [`NEAR`]
/// frames each side, over a square at its centre: each the motion-compensated mean of the
/// neighbours alone (the same tracks), denoised as [`estimate`] denoises the mean. Since frame
/// `t`'s noise is in neither, the squared difference of each to frame `t` is its squared
/// error plus the same noise term on average, so their difference estimates how much worse
/// the whole window is — a choice made on data the estimates were not made from. Not quite:
/// the tracking accepted each block on its difference to the noisy frame `t`, so the whole
/// window's mean fits frame `t`'s noise a little more, and the difference leans towards the
/// whole window (the test's deforming scene: 960 ± 199 against a true 1849).
#[derive(Clone, Debug)]
pub struct HeldOut {
    /// The square compared: its left and top edges and its width and height, px.
    pub rect: (usize, usize, usize, usize),
    /// The estimate from the whole window's neighbours over the square (DN, row by row).
    pub whole: Vec<f32>,
    /// The estimate from the near frames' neighbours over the square.
    pub near: Vec<f32>,
    /// Σ (frame − whole)² − Σ (frame − near)² over the square (DN²): on average the whole
    /// window's squared error less the near frames'.
    pub difference: f64,
    /// The standard deviation of `difference` from frame `t`'s noise, 2·√(Σ var·(whole −
    /// near)²), with each pixel's variance from the noise model at its own estimate.
    pub sd: f64,
}

impl HeldOut {
    /// Whether the near frames are clearly better: the difference above [`HELD_OUT_Z`] of its
    /// standard deviations.
    pub fn prefers_near(&self) -> bool {
        self.difference > HELD_OUT_Z * self.sd
    }
}

/// The held-out comparison of `window[center]`'s whole window with its [`NEAR`] frames each
/// side ([`HeldOut`]; `guides` as for [`motion_mean`]); `None` where the window's scene holds
/// no frame beyond them, or the frame is smaller than a block.
pub fn held_out(
    window: &[&[f32]],
    guides: &[&[f32]],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
) -> Option<HeldOut> {
    if !trackable(window, guides, w, h) {
        return None;
    }
    let t = tracked(window, guides, center, w, h, p, STEP);
    held_out_of(&t, &t.own(window[center]), center, w, h, p)
}

/// [`held_out`] on a tracked window.
fn held_out_of(
    t: &Tracked,
    own: &[f32],
    center: usize,
    w: usize,
    h: usize,
    p: PoissonGaussian,
) -> Option<HeldOut> {
    if t.first + NEAR >= center && t.last <= center + NEAR {
        return None;
    }
    let (cw, ch) = (w.min(HELD_OUT_SIDE), h.min(HELD_OUT_SIDE));
    let (x0, y0) = ((w - cw) / 2, (h - ch) / 2);
    let square = |v: &[f32]| -> Vec<f32> {
        (0..ch)
            .flat_map(|r| v[r * w + x0..][..cw].iter().copied())
            .collect()
    };
    let without_own = |reach: usize| -> Vec<f32> {
        let mm = pooled(t, own, center, w, h, reach, false, y0..y0 + ch);
        let worth = emccd_profile::median(square(&mm.noise_frames).into_iter()).unwrap_or(1.0);
        bm3d_adaptive_correlated(
            &square(&mm.mean),
            cw,
            ch,
            p.of_mean((worth as f64).max(1.0)),
            &mm.noise,
        )
    };
    let (whole, near) = (without_own(usize::MAX), without_own(NEAR));
    let (mut difference, mut variance) = (0.0, 0.0);
    for r in 0..ch {
        let at = (y0 + r) * w + x0;
        let (frame, guide) = (&own[at..][..cw], &t.guides[center][at..][..cw]);
        for q in 0..cw {
            let (y, a, b) = (
                frame[q] as f64,
                whole[r * cw + q] as f64,
                near[r * cw + q] as f64,
            );
            difference += (y - a).powi(2) - (y - b).powi(2);
            let var = p.alpha * (guide[q] as f64 - p.mu).max(0.0) + p.sigma * p.sigma;
            variance += var * (a - b).powi(2);
        }
    }
    Some(HeldOut {
        rect: (x0, y0, cw, ch),
        whole,
        near,
        difference,
        sd: 2.0 * variance.sqrt(),
    })
}

/// A frame's single-frame estimate (DN above bias, noise `p`): iterative BM3D below one count
/// per pixel (mean signal over α), one plain BM3D pass from there ([`single_schedule`]). What a
/// frame denoised without neighbours (`--window 0`) is.
pub fn single(frame: &[f32], w: usize, h: usize, p: PoissonGaussian) -> Vec<f32> {
    single_spaced(frame, w, h, p, 1)
}

/// [`single`] as a window's member, what [`estimate`] tracks motion on and falls back to: its
/// full-resolution pass with reference blocks [`SINGLE_STEP`] apart.
pub fn window_single(frame: &[f32], w: usize, h: usize, p: PoissonGaussian) -> Vec<f32> {
    single_spaced(frame, w, h, p, SINGLE_STEP)
}

/// [`single`]'s passes with the full-resolution one's reference blocks `min_step` apart.
fn single_spaced(
    frame: &[f32],
    w: usize,
    h: usize,
    p: PoissonGaussian,
    min_step: usize,
) -> Vec<f32> {
    let passes = single_schedule(mean_counts(frame, p)).0;
    bm3d_iterative_spaced(frame, w, h, p, &passes, min_step, &Covariance::white())
}

/// How far apart the reference blocks of a frame's own estimate are in its full-resolution
/// pass, px: 4, where BM3D's own profile puts them 3 apart. The estimate is a guide and a
/// fallback, and that pass was a third of the method's time (on 512² movies at 1 e⁻). On the
/// validation camera `tune`: −0.005 / −0.009 dB on average at 0.5 / 16 and 1 / 4 e⁻ (the
/// particles −0.02 to −0.05, the rest within ±0.04) for 0.59 of the estimate's time; 4 px in
/// the binned passes too cost the jittered stars 0.14 dB at 1 e⁻ (docs/journal.md).
pub const SINGLE_STEP: usize = 4;

/// The passes of [`single`] at `counts` mean counts per pixel: [`Schedule::for_counts`]'s
/// below one count, one plain pass from there. Measured on the validation movies (docs/journal.md):
/// from one count the binned first pass and the two full passes that follow blunt the small
/// bright spots that the fallback keeps where nothing matched (particles at 4 e⁻ +0.45 dB
/// with one pass, the other motions within ±0.05), at half the cost; below it the plain
/// transform's bias at a fraction of a count misleads the scene gate (a dim cut at 0.5 e⁻
/// −4.3 dB, its mean 11 % high) and the iterative passes stay.
pub fn single_schedule(counts: f64) -> Schedule {
    if counts < 1.0 {
        Schedule::for_counts(counts)
    } else {
        Schedule::single()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_move_is_taken_where_the_blocks_around_it_moved_alike() {
        let (from, stay, to) = ((20, 20), (20, 20), (21, 20));
        // The blocks around it went 0.6 px right (a rotation's slow motion): closer to there.
        assert!(agrees(from, stay, to, &[(0.6, 0.0); 8]));
        // They stayed, or went less than half the way: staying is closer.
        assert!(!agrees(from, stay, to, &[(0.0, 0.0); 8]));
        assert!(!agrees(from, stay, to, &[(0.4, 0.0); 8]));
        // They went the other way, or up.
        assert!(!agrees(from, stay, to, &[(-1.0, 0.0); 8]));
        assert!(!agrees(from, stay, to, &[(0.0, 1.0); 8]));
        // Mixed: their median decides (5 right by a pixel, 3 staying: 1 px right), and a few
        // far off do not move it (5 staying, 3 by 4 px: their mean would say 1.5 px).
        let mixed = [(1.0, 0.0); 5]
            .iter()
            .chain(&[(0.0, 0.0); 3])
            .copied()
            .collect::<Vec<_>>();
        assert!(agrees(from, stay, to, &mixed));
        let outliers = [(0.0, 0.0); 5]
            .iter()
            .chain(&[(4.0, 0.0); 3])
            .copied()
            .collect::<Vec<_>>();
        assert!(!agrees(from, stay, to, &outliers));
        // Too few of them still tracked to say.
        assert!(!agrees(from, stay, to, &[(1.0, 0.0); 2]));
        assert!(!agrees(from, stay, to, &[]));
        // The scene's own move (`stay` already off `from`) is not counted twice.
        assert!(!agrees(from, (22, 20), (23, 20), &[(2.0, 0.0); 8]));
        assert!(agrees(from, (22, 20), (23, 20), &[(2.7, 0.0); 8]));
    }

    /// A spot moved by a fraction of a pixel is found there: to within the Keys kernel's error
    /// on a spot this narrow (σ = 1.2 px, well under 0.05 px for the moves here), whichever
    /// whole pixel the search left it at; a flat block has no slope to align on.
    #[test]
    fn a_spot_is_aligned_to_a_fraction_of_a_pixel() {
        let (w, h) = (32, 32);
        let spot = |cx: f64, cy: f64| -> Vec<f32> {
            (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f64, (i / w) as f64);
                    let r2 = (x - cx).powi(2) + (y - cy).powi(2);
                    (20.0 + 200.0 * (-r2 / (2.0 * 1.2 * 1.2)).exp()) as f32
                })
                .collect()
        };
        let one = spot(15.5, 15.5);
        for (dx, dy) in [(0.3, -0.2), (-0.45, 0.1), (0.0, 0.4), (0.7, 0.6)] {
            let other = spot(15.5 + dx, 15.5 + dy);
            // The block at (12, 12) in `one` lies at (12 + dx, 12 + dy) in `other`; the search
            // left it at the nearest whole pixel.
            let b = ((12.0 + dx).round() as usize, (12.0 + dy).round() as usize);
            let e = refine(&one, &other, w, h, (12, 12), b).expect("a spot has slopes");
            let want = (12.0 + dx - b.0 as f64, 12.0 + dy - b.1 as f64);
            assert!(
                (e.0 - want.0).abs() < 0.05 && (e.1 - want.1).abs() < 0.05,
                "moved ({dx}, {dy}): found {e:?}, want {want:?}"
            );
        }
        let flat = vec![20.0f32; w * h];
        assert_eq!(refine(&flat, &flat, w, h, (12, 12), (12, 12)), None);
    }

    /// The lanes' sum is the plain sum of the squares, whatever the length (whole lanes, a
    /// remainder, none), to within the rounding of a few additions in a different order.
    #[test]
    fn squared_differences_are_summed_whole() {
        for len in [0, 1, 7, 8, 9, 16, 21, 250] {
            let a: Vec<f32> = (0..len).map(|i| (i as f32 * 0.37).sin() * 40.0).collect();
            let b: Vec<f32> = (0..len).map(|i| (i as f32 * 0.11).cos() * 25.0).collect();
            let plain: f64 = a
                .iter()
                .zip(&b)
                .map(|(p, q)| ((p - q) as f64).powi(2))
                .sum();
            let lanes = squared_difference(&a, &b);
            assert!(
                (lanes - plain).abs() <= 1e-12 * plain.max(1.0),
                "{len}: {lanes} vs {plain}"
            );
        }
    }

    /// At 512² the scene is found from every 8th px as from every 4th: a drift's five frames are
    /// all its scene, and a cut to a checkerboard of 3-px squares (nothing of the pattern lies
    /// within a block's search in it) ends it, at about 10 counts per pixel. The statistic the
    /// grid samples, the share of the blocks whose tracks reach each frame, is the same from
    /// both where only the frame's lower 3/8 turns to the checkerboard: its standard error from
    /// 4096 blocks is at most √(0.25 / 4096) = 0.008, and the sparse grid's blocks are some of
    /// the dense one's, so the two differ by less; allowed 0.03. The sparser grid holds
    /// [`SCENE_BLOCKS`] blocks, and 256² keeps the denser one.
    #[test]
    fn the_scene_is_found_from_a_sparser_grid_of_as_many_blocks() {
        let (w, h) = (512, 512);
        assert_eq!((scene_step(w, h), scene_step(256, 256)), (N, 4));
        let p = PoissonGaussian {
            alpha: 1.0,
            sigma: 0.5,
            mu: 0.0,
        };
        let mut noise = gaussian(17);
        let mut shoot = |truth: Vec<f32>| -> Vec<f32> {
            truth
                .iter()
                .map(|&c| c + noise((c as f64 + 0.25).sqrt()))
                .collect()
        };
        let board: Vec<f32> = (0..w * h)
            .map(|i| 20.0 * (((i % w) / 3 + (i / w) / 3) % 2) as f32)
            .collect();
        let drift: Vec<Vec<f32>> = (0..5)
            .map(|t| shoot(pattern(w, h, t as f64, t as f64 / 2.0)))
            .collect();
        let cut: Vec<Vec<f32>> = (0..5)
            .map(|t| {
                shoot(if t < 3 {
                    pattern(w, h, 0.0, 0.0)
                } else {
                    board.clone()
                })
            })
            .collect();
        for (frames, want) in [(&drift, (0, 4)), (&cut, (0, 2))] {
            let window: Vec<&[f32]> = frames.iter().map(Vec::as_slice).collect();
            let guides: Vec<Vec<f32>> = frames.iter().map(|f| binomial(f, w)).collect();
            let guides: Vec<&[f32]> = guides.iter().map(Vec::as_slice).collect();
            let found = |step| scene_on_grid(&window, &guides, 2, w, h, p, step);
            let (dense, sparse) = (found(4), found(N));
            assert_eq!((sparse.first, sparse.last), want);
            assert_eq!(sparse, dense);
        }
        let part: Vec<Vec<f32>> = (0..5)
            .map(|t| {
                let mut truth = pattern(w, h, 0.0, 0.0);
                if t > 2 {
                    truth[320 * w..].copy_from_slice(&board[320 * w..]);
                }
                shoot(truth)
            })
            .collect();
        let window: Vec<&[f32]> = part.iter().map(Vec::as_slice).collect();
        let guides: Vec<Vec<f32>> = part.iter().map(|f| binomial(f, w)).collect();
        let guides: Vec<&[f32]> = guides.iter().map(Vec::as_slice).collect();
        let reached = |step| -> Vec<f64> {
            let t = tracked(&window, &guides, 2, w, h, p, step);
            let blocks: usize = t.tracks.iter().map(Vec::len).sum();
            (0..5)
                .map(|f| {
                    let hit = t.tracks.iter().flatten();
                    let hit = hit.filter(|s| s.iter().any(|s| s.frame == f)).count();
                    hit as f64 / blocks as f64
                })
                .collect()
        };
        let (dense, sparse) = (reached(4), reached(N));
        // Not degenerate: the blocks wholly above row 320 (313 of 505 rows of them, 0.62) reach
        // the changed frames, the others do not (measured 0.628 / 0.623).
        assert!((0.55..0.70).contains(&sparse[3]), "{sparse:?}");
        for f in [0, 1, 3, 4] {
            assert!((dense[f] - sparse[f]).abs() < 0.03, "{dense:?} {sparse:?}");
        }
    }

    /// Nearly normal noise of standard deviation `sd` per call (12 uniforms of a fixed LCG
    /// seeded with `seed`, less 6).
    fn gaussian(seed: u64) -> impl FnMut(f64) -> f32 {
        let mut state = seed;
        move |sd: f64| {
            let mut uniform = || {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            (sd * ((0..12).map(|_| uniform()).sum::<f64>() - 6.0)) as f32
        }
    }

    /// A smooth pattern moved by (`dx`, `dy`) px, sampled on a `w × h` grid.
    fn pattern(w: usize, h: usize, dx: f64, dy: f64) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64 - dx, (i / w) as f64 - dy);
                (10.0 + 3.0 * (x / 4.0).sin() + 2.0 * (y / 5.0).cos() + (0.07 * x * y / 9.0).sin())
                    as f32
            })
            .collect()
    }

    /// A frame resampled by a fraction of a pixel is the scene moved by it (Keys' cubic kernel
    /// on a smooth pattern that swings by about 12: within 0.05 away from the edges, where not
    /// resampling would be off by up to 0.2), a uniform
    /// frame stays uniform (the weights sum to 1), and independent noise keeps the share of
    /// its variance [`noise_kept`] says (64 k pixels: the variance's standard error is 0.6 %,
    /// and 3 % is five of it).
    #[test]
    fn a_frame_is_resampled_by_a_fraction_of_a_pixel() {
        let (w, h) = (64, 64);
        for e in [(0.3, -0.4), (-0.5, 0.5), (0.1, 0.0)] {
            let moved = pattern(w, h, e.0, e.1);
            let back = resampled(&moved, w, h, e);
            let still = pattern(w, h, 0.0, 0.0);
            for y in 4..h - 4 {
                for x in 4..w - 4 {
                    let d = (back[y * w + x] - still[y * w + x]).abs();
                    assert!(d < 0.05, "{e:?} at ({x}, {y}): off by {d}");
                }
            }
            let flat = resampled(&vec![2.5; w * h], w, h, e);
            assert!(
                flat.iter().all(|&v| (v - 2.5).abs() < 1e-5),
                "{e:?}: a flat frame"
            );
        }
        assert_eq!(noise_kept((0.0, 0.0)), 1.0);
        // Keys' taps at half a pixel: −1/16, 9/16, 9/16, −1/16.
        assert!((noise_kept((0.5, 0.0)) - 0.640625).abs() < 1e-12);
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let n = 256;
        let noise: Vec<f32> = (0..n * n)
            .map(|_| StandardNormal.sample(&mut rng))
            .collect();
        let var = |v: &[f32]| {
            let m = v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
            v.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / v.len() as f64
        };
        for e in [(0.5, 0.5), (0.25, -0.1)] {
            let inner: Vec<f32> = {
                let r = resampled(&noise, n, n, e);
                (2..n - 2)
                    .flat_map(|y| (2..n - 2).map(move |x| (x, y)))
                    .map(|(x, y)| r[y * n + x])
                    .collect()
            };
            let kept = var(&inner) / var(&noise);
            assert!(
                (kept / noise_kept(e) - 1.0).abs() < 0.03,
                "{e:?}: kept {kept:.4}, predicted {:.4}",
                noise_kept(e)
            );
        }
    }

    /// [`places`] on noise-free frames: a drift of (0.6, 0.3) px a frame comes back within 0.1 px
    /// of the truth (the parabola's lean, as below), a still scene's places are frame t's
    /// (within 0.01 px: the sums at opposite shifts round differently), the frames after a cut
    /// to other content keep the places they were given and are not linked to frame t (no pair
    /// links them), on noisy frames a dim scene's pairs do not gate out a bright scene's own,
    /// and frames too small to be shifted keep their places, all linked.
    #[test]
    fn the_places_agree_with_the_pairs_of_frames() {
        let (w, h) = (64, 64);
        let center = 3;
        let given = |smooth: &[Vec<f32>], near: &dyn Fn(usize) -> (f64, f64)| -> Vec<(f64, f64)> {
            (0..smooth.len())
                .map(|f| {
                    let (x, y) = near(f);
                    let around = (x.round() as isize, y.round() as isize);
                    global_shift(&smooth[center], &smooth[f], w, h, around, 1).shift
                })
                .collect()
        };
        let truth = |f: usize| (0.6 * (f as f64 - 3.0), 0.3 * (f as f64 - 3.0));
        let drift: Vec<Vec<f32>> = (0..7)
            .map(|f| binomial(&pattern(w, h, truth(f).0, truth(f).1), w))
            .collect();
        let (at, linked) = places(&drift, &given(&drift, &truth), center, w, h);
        assert!(linked.iter().all(|&l| l));
        // Half a pixel a frame: pairs an even number of frames apart match exactly, the others
        // only as well as the parabolas fit; all stay linked ([`PAIR_FLOOR`]).
        let half = |f: usize| (0.5 * (f as f64 - 3.0), 0.0);
        let halves: Vec<Vec<f32>> = (0..7)
            .map(|f| binomial(&pattern(w, h, half(f).0, half(f).1), w))
            .collect();
        let (_, linked) = places(&halves, &given(&halves, &half), center, w, h);
        assert!(linked.iter().all(|&l| l), "{linked:?}");
        for (f, &(x, y)) in at.iter().enumerate() {
            let (tx, ty) = truth(f);
            assert!(
                (x - tx).abs() < 0.1 && (y - ty).abs() < 0.1,
                "frame {f}: ({x:.3}, {y:.3}), truth ({tx:.2}, {ty:.2})"
            );
        }
        let still: Vec<Vec<f32>> = (0..7)
            .map(|_| binomial(&pattern(w, h, 0.0, 0.0), w))
            .collect();
        let (at, _) = places(&still, &given(&still, &|_| (0.0, 0.0)), center, w, h);
        let near_zero = |p: &(f64, f64)| p.0.abs() < 0.01 && p.1.abs() < 0.01;
        assert!(at.iter().all(near_zero), "{at:?}");
        // Frames 5 and 6 hold a pattern of other scales, turned.
        let other: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i / w) as f64, (i % w) as f64);
                (10.0 + 5.0 * (x / 2.0).sin() * (y / 3.0).cos()) as f32
            })
            .collect();
        let cut: Vec<Vec<f32>> = (0..7)
            .map(|f| {
                binomial(
                    &if f < 5 {
                        pattern(w, h, 0.0, 0.0)
                    } else {
                        other.clone()
                    },
                    w,
                )
            })
            .collect();
        let first = given(&cut, &|_| (0.0, 0.0));
        let (at, linked) = places(&cut, &first, center, w, h);
        assert_eq!(at[5..], first[5..]);
        assert!(at[..5].iter().all(near_zero), "{at:?}");
        assert_eq!(linked, [true, true, true, true, true, false, false]);
        // A cut from a bright noisy scene to a dim one, whose frames differ less (a quarter of
        // the noise's variance): each scene's frames are linked to their own, from either side.
        let mut noise = gaussian(7);
        let noisy: Vec<Vec<f32>> = (0..7)
            .map(|f| {
                let (scene, sd) = if f < 5 {
                    (pattern(w, h, 0.0, 0.0), 1.0)
                } else {
                    (other.clone(), 0.5)
                };
                let frame: Vec<f32> = scene.iter().map(|&v| v + noise(sd)).collect();
                binomial(&frame, w)
            })
            .collect();
        for (center, own) in [(3, 0..5), (5, 5..7)] {
            let first: Vec<(f64, f64)> = (0..7)
                .map(|f| global_shift(&noisy[center], &noisy[f], w, h, (0, 0), 1).shift)
                .collect();
            let (_, linked) = places(&noisy, &first, center, w, h);
            let expected: Vec<bool> = (0..7).map(|f| own.contains(&f)).collect();
            assert_eq!(linked, expected, "frame {center}");
        }
        let tiny: Vec<Vec<f32>> = (0..5).map(|f| vec![f as f32; 4]).collect();
        let first = vec![(0.25, -0.5); 5];
        assert_eq!(places(&tiny, &first, 2, 2, 2), (first, vec![true; 5]));
    }

    /// The places' smoothness prior ([`smooth_motion`]): on a drift under noise that leaves
    /// each frame's registration to frame t off by tenths of a pixel, the places come back
    /// closer to the truth than half those registrations' error (25 frames' pairs on one
    /// smooth curve); a jitter's places, a random whole and fractional move each frame, are
    /// the free solution's (its pairs would scatter far more about any smooth curve): within
    /// 0.1 px of the truth, as noise-free registrations are.
    #[test]
    fn a_drift_is_registered_along_one_smooth_path_and_a_jitter_is_not() {
        let (w, h, center) = (64, 64, 12);
        let mut noise = gaussian(11);
        let drift = |f: usize| (0.6 * (f as f64 - 12.0), 0.3 * (f as f64 - 12.0));
        let frames: Vec<Vec<f32>> = (0..25)
            .map(|f| {
                let (dx, dy) = drift(f);
                let scene = pattern(w, h, dx, dy);
                binomial(
                    &scene.iter().map(|&v| v + noise(6.0)).collect::<Vec<_>>(),
                    w,
                )
            })
            .collect();
        let rounded = |p: (f64, f64)| (p.0.round() as isize, p.1.round() as isize);
        let first: Vec<(f64, f64)> = (0..25)
            .map(|f| global_shift(&frames[center], &frames[f], w, h, rounded(drift(f)), 1).shift)
            .collect();
        let rms = |at: &[(f64, f64)]| {
            let sum: f64 = (0..25)
                .map(|f| (at[f].0 - drift(f).0).powi(2) + (at[f].1 - drift(f).1).powi(2))
                .sum();
            (sum / 24.0).sqrt()
        };
        let (at, linked) = places(&frames, &first, center, w, h);
        assert!(linked.iter().all(|&l| l));
        assert!(
            rms(&first) > 0.1,
            "the noise hides the move: {:.3}",
            rms(&first)
        );
        assert!(
            rms(&at) < 0.5 * rms(&first),
            "smooth {:.3}, each frame's own {:.3}",
            rms(&at),
            rms(&first)
        );
        // Whole pixels and fifths, a different move each frame.
        let jitter = |f: usize| {
            let k = (f * 7 + 3) % 11;
            let fifth = |j: usize| 0.2 * ((j % 3) as f64 - 1.0);
            (
                k as f64 - 5.0 + fifth(f),
                ((k * 5) % 7) as f64 - 3.0 + fifth(f + 1),
            )
        };
        let jittered: Vec<Vec<f32>> = (0..25)
            .map(|f| {
                let (dx, dy) = jitter(f);
                let (cx, cy) = jitter(center);
                binomial(&pattern(w, h, dx - cx, dy - cy), w)
            })
            .collect();
        let truth = |f: usize| {
            (
                jitter(f).0 - jitter(center).0,
                jitter(f).1 - jitter(center).1,
            )
        };
        let first: Vec<(f64, f64)> = (0..25)
            .map(|f| {
                global_shift(&jittered[center], &jittered[f], w, h, rounded(truth(f)), 1).shift
            })
            .collect();
        let (at, _) = places(&jittered, &first, center, w, h);
        for (f, &(x, y)) in at.iter().enumerate() {
            let (tx, ty) = truth(f);
            assert!(
                (x - tx).abs() < 0.1 && (y - ty).abs() < 0.1,
                "frame {f}: ({x:.3}, {y:.3}), truth ({tx:.2}, {ty:.2})"
            );
        }
    }

    /// The registration finds a move of whole and fractional pixels, searched widely or within
    /// a pixel of a prediction, within 0.1 px: the parabola through the squared differences at
    /// whole pixels leans towards the nearest whole pixel (the difference is not a parabola),
    /// here by up to 0.07 px, which leaves the whole pixel each block is looked for around
    /// right wherever the move is more than 0.1 px from a half.
    #[test]
    fn the_scene_is_registered_to_a_fraction_of_a_pixel() {
        let (w, h) = (64, 64);
        let still = pattern(w, h, 0.0, 0.0);
        for (dx, dy) in [(0.3, -0.4), (2.6, 1.2), (-1.3, 0.2)] {
            let moved = pattern(w, h, dx, dy);
            let (fx, fy) = global_shift(&still, &moved, w, h, (0, 0), SEARCH).shift;
            assert!(
                (fx - dx).abs() < 0.1 && (fy - dy).abs() < 0.1,
                "moved ({dx}, {dy}): found ({fx:.3}, {fy:.3})"
            );
            let near = (dx.round() as isize, dy.round() as isize);
            let (gx, gy) = global_shift(&still, &moved, w, h, near, 1).shift;
            assert!(
                (gx - dx).abs() < 0.1 && (gy - dy).abs() < 0.1,
                "moved ({dx}, {dy}), searched from {near:?}: found ({gx:.3}, {gy:.3})"
            );
        }
        let (sx, sy) = global_shift(&still, &still, w, h, (0, 0), SEARCH).shift;
        assert!(
            sx.abs() < 0.1 && sy.abs() < 0.1,
            "still: ({sx:.3}, {sy:.3})"
        );
    }
}
