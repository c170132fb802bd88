//! Camera-independent network input. A preprocessed frame (DN above bias, blooming and FPN
//! removed) is divided by the photon-transfer slope `s`, so that its noise variance is
//! `x + σ_r²/s²` whatever the camera; then by a per-frame scale so values are O(1). The second
//! channel is the per-pixel noise level in the same units, `σ(x) = √(max(x, 0) + σ_r²/s²)`,
//! so one network serves any calibrated camera.
//!
//! A refinement ("hybrid") network also gets the BM3D + GAT estimate as a third channel, and its
//! scale comes from that estimate rather than from the noisy frame: at a few photoelectrons the
//! noisy frame's upper percentiles are set by single-electron EM-register spikes, not by the
//! scene, while the estimate's follow the scene's brightness.

use emccd_profile::percentile;
use serde::{Deserialize, Serialize};

/// Inputs for the network and how to undo the scaling.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Channel-major [C, H, W]: normalized frame, noise level (a hybrid's estimate after them;
    /// a temporal network's window frames before the noise level).
    pub input: Vec<f32>,
    /// Output DN = network output × `to_dn`.
    pub to_dn: f32,
}

/// The per-frame scale: the 99.5th percentile of the slope-normalized frame, floored so that
/// an almost empty frame is not blown up.
pub fn frame_scale(x_norm: &[f32]) -> f32 {
    percentile(x_norm.iter().copied(), 0.995).map_or(1.0, |p| (p as f32).max(FLOOR))
}

/// Smallest per-frame scale, in slope units (about eight photoelectrons).
const FLOOR: f32 = 4.0;

/// Side of the blocks [`Scale::Binned`] averages.
pub const BIN: usize = 4;

/// How a denoiser's per-frame scale is taken from the noisy frame (recorded in its model file:
/// training and inference must agree).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Scale {
    /// The frame's 99.5th percentile (what `frame_scale` takes; model files without the key).
    #[default]
    Percentile,
    /// The 99.5th percentile of the frame averaged over 4×4 blocks (`BIN`): the average
    /// of 16 pixels follows the scene where single pixels follow the noise (at 4 e⁻ the noisy
    /// frame's percentile is 1.4–2× the clean frame's).
    Binned,
}

impl Scale {
    /// Whether this is the rule of model files that do not record one.
    pub fn is_default(&self) -> bool {
        *self == Scale::Percentile
    }

    /// The scale of a slope-normalized frame `width` pixels wide, floored like
    /// [`frame_scale`]. A frame narrower or lower than a block falls back to the percentile.
    pub fn of(self, x_norm: &[f32], width: usize) -> f32 {
        let height = x_norm.len() / width.max(1);
        if self == Scale::Percentile || width < BIN || height < BIN {
            return frame_scale(x_norm);
        }
        let (bw, bh) = (width / BIN, height / BIN);
        let means: Vec<f32> = (0..bw * bh)
            .map(|b| {
                let (bx, by) = (b % bw * BIN, b / bw * BIN);
                let sum: f32 = (0..BIN * BIN)
                    .map(|k| x_norm[(by + k / BIN) * width + bx + k % BIN])
                    .sum();
                sum / (BIN * BIN) as f32
            })
            .collect();
        frame_scale(&means)
    }
}

/// Smallest hybrid scale, in slope units (about two photoelectrons): below it a frame is
/// essentially empty and is not blown up.
pub const HYBRID_SCALE_FLOOR: f32 = 1.0;

/// The hybrid scale: the 99.5th percentile of a slope-normalized signal estimate (the BM3D
/// estimate at inference, the clean frame in training), floored at [`HYBRID_SCALE_FLOOR`].
pub fn signal_scale(estimate_norm: &[f32]) -> f32 {
    percentile(estimate_norm.iter().copied(), 0.995)
        .map_or(HYBRID_SCALE_FLOOR, |p| p as f32)
        .max(HYBRID_SCALE_FLOOR)
}

/// Hybrid inputs [3, H, W] (normalized frame, noise level, normalized estimate) for a
/// preprocessed frame `dn` and a signal estimate `estimate` of it (both DN above bias), with the
/// per-frame `scale` in slope units (see [`signal_scale`]).
pub fn prepare_hybrid(
    dn: &[f32],
    estimate: &[f32],
    slope: f64,
    read_noise: &[f32],
    scale: f32,
) -> Prepared {
    let n = dn.len();
    let p = prepare_scaled(dn, slope, read_noise, scale);
    let mut input = p.input;
    input.reserve_exact(n);
    input.extend(estimate.iter().map(|v| v / p.to_dn));
    Prepared {
        input,
        to_dn: p.to_dn,
    }
}

/// Prepares a preprocessed frame `dn` (DN above bias, `width` pixels wide) with the slope `s`
/// and read-noise std map, scaled by `rule`.
pub fn prepare(dn: &[f32], width: usize, slope: f64, read_noise: &[f32], rule: Scale) -> Prepared {
    let s = slope as f32;
    let x: Vec<f32> = dn.iter().map(|v| v / s).collect();
    prepare_scaled(dn, slope, read_noise, rule.of(&x, width))
}

/// [`prepare`] with the per-frame scale given (training crops take their whole frame's).
pub fn prepare_scaled(dn: &[f32], slope: f64, read_noise: &[f32], scale: f32) -> Prepared {
    let n = dn.len();
    let s = slope as f32;
    let x: Vec<f32> = dn.iter().map(|v| v / s).collect();
    let mut input = vec![0f32; 2 * n];
    for i in 0..n {
        let r = read_noise[i] / s;
        input[i] = x[i] / scale;
        input[n + i] = (x[i].max(0.0) + r * r).sqrt() / scale;
    }
    Prepared {
        input,
        to_dn: scale * s,
    }
}

/// The frame that stands in for frame `t + d` of a movie of `count` frames when it is missing
/// (beyond an end): the frame the same distance on the other side, `t − d`, else the nearest
/// frame to `t + d` other than `t` (a stack shorter than the window), else `t` itself (one
/// frame). What a temporal network is shown at a movie's ends, in training and at inference.
pub fn mirror(t: usize, d: isize, count: usize) -> usize {
    let inside = |j: isize| (0..count as isize).contains(&j);
    let (t, n) = (t as isize, count as isize);
    if inside(t + d) {
        (t + d) as usize
    } else if inside(t - d) {
        (t - d) as usize
    } else if n > 1 {
        let j = (t + d).clamp(0, n - 1);
        (if j == t { t - d.signum() } else { j }).clamp(0, n - 1) as usize
    } else {
        0
    }
}

/// Temporal-network inputs [F + 1, H, W] ([`crate::Inputs::Movie`]): the preprocessed frames
/// of a window `frames` (DN above bias, in time order), each divided by the slope and by one
/// scale, then the noise level of frame `center` in the same units. One scale for the whole
/// window, the centre frame's by `rule`, keeps the frames' relative brightness (bleaching, a
/// blink) and scales the centre exactly as a single-frame network's input would be.
pub fn prepare_movie(
    frames: &[&[f32]],
    center: usize,
    width: usize,
    slope: f64,
    read_noise: &[f32],
    rule: Scale,
) -> Prepared {
    let s = slope as f32;
    let x: Vec<f32> = frames[center].iter().map(|v| v / s).collect();
    prepare_movie_scaled(frames, center, slope, read_noise, rule.of(&x, width))
}

/// [`prepare_movie`] with the scale given (training crops take their whole frame's).
pub fn prepare_movie_scaled(
    frames: &[&[f32]],
    center: usize,
    slope: f64,
    read_noise: &[f32],
    scale: f32,
) -> Prepared {
    let n = frames[center].len();
    let p = prepare_scaled(frames[center], slope, read_noise, scale);
    let k = scale * slope as f32;
    let mut input = Vec::with_capacity((frames.len() + 1) * n);
    for (j, f) in frames.iter().enumerate() {
        if j == center {
            input.extend_from_slice(&p.input[..n]);
        } else {
            input.extend(f.iter().map(|v| v / k));
        }
    }
    input.extend_from_slice(&p.input[n..]);
    Prepared {
        input,
        to_dn: p.to_dn,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of `n` pixels: a smooth scene of `mean` slope units with every `every`-th
    /// pixel raised by `spike` units (an EM spike or a hot pixel).
    fn frame(n: usize, mean: f32, spike: f32, every: usize) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let scene = mean * (1.0 + 0.5 * ((i as f32) * 0.01).sin());
                if i % every == 0 {
                    scene + spike
                } else {
                    scene
                }
            })
            .collect()
    }

    #[test]
    fn the_input_is_the_same_for_every_camera_that_records_the_same_electrons() {
        // Camera B has 7.5× camera A's DN per electron (slope, signal and read noise alike):
        // the network must see the same numbers, and the output must come back in B's DN.
        let x = frame(4096, 3.0, 0.0, 4097);
        let (sa, sb) = (20.0f64, 150.0f64);
        let dn_a: Vec<f32> = x.iter().map(|v| v * sa as f32).collect();
        let dn_b: Vec<f32> = x.iter().map(|v| v * sb as f32).collect();
        let (ra, rb) = (vec![3.0f32; 4096], vec![3.0f32 * 7.5; 4096]);
        let (a, b) = (
            prepare(&dn_a, 64, sa, &ra, Scale::Percentile),
            prepare(&dn_b, 64, sb, &rb, Scale::Percentile),
        );
        for (u, v) in a.input.iter().zip(&b.input) {
            assert!((u - v).abs() <= 1e-5 * u.abs().max(1.0), "{u} vs {v}");
        }
        assert!((b.to_dn / a.to_dn - 7.5).abs() < 1e-5);
    }

    #[test]
    fn the_noise_channel_is_the_poisson_gaussian_std_in_the_frames_units() {
        let dn = [-10.0f32, 0.0, 40.0, 400.0];
        let rn = [5.0f32; 4];
        let p = prepare_scaled(&dn, 20.0, &rn, 8.0);
        for (i, &d) in dn.iter().enumerate() {
            let (x, r) = (d / 20.0, 5.0f32 / 20.0);
            assert!((p.input[i] - x / 8.0).abs() < 1e-6);
            // Negative counts (read noise below bias) have the read noise alone.
            let sd = (x.max(0.0) + r * r).sqrt() / 8.0;
            assert!((p.input[4 + i] - sd).abs() < 1e-6);
        }
        assert_eq!(p.to_dn, 160.0);
    }

    #[test]
    fn the_scale_ignores_rare_spikes_and_is_floored_at_low_light() {
        // At a mean of about 1 photoelectron (0.5 slope units) the floor sets the scale:
        // a dim frame is not blown up to its noise. Spikes on 0.4 % of the pixels (fewer
        // than the 0.5 % above the 99.5th percentile) change nothing there.
        assert_eq!(frame_scale(&frame(10_000, 0.5, 0.0, 10_001)), 4.0);
        assert_eq!(frame_scale(&frame(10_000, 0.5, 50.0, 250)), 4.0);
        // A bright frame's scale is its scene's 99.5th percentile (1.5 × 40 here), and
        // hot pixels on 0.4 % of it move the scale by less than the scene's own spread.
        let clean = frame_scale(&frame(10_000, 40.0, 0.0, 10_001));
        assert!((clean - 60.0).abs() < 0.5, "{clean}");
        let hot = frame_scale(&frame(10_000, 40.0, 1e6, 250));
        assert!((hot - clean).abs() < 0.5, "{hot} vs {clean}");
        // Non-finite values are ignored rather than poisoning the scale.
        let mut nan = frame(10_000, 40.0, 0.0, 10_001);
        nan[3] = f32::NAN;
        nan[5] = f32::INFINITY;
        assert!((frame_scale(&nan) - clean).abs() < 0.5);
        assert_eq!(frame_scale(&[]), 1.0);
    }

    #[test]
    fn the_binned_scale_follows_the_scene_where_the_percentile_follows_spikes() {
        // A 64×64 scene with 2 % of its pixels raised by a spike: the percentile lands on the
        // spikes, the 4×4 block means move by a sixteenth of a spike.
        let (w, n) = (64, 64 * 64);
        let clean = frame(n, 40.0, 0.0, n + 1);
        let spiky = frame(n, 40.0, 200.0, 50);
        let (pc, ps) = (frame_scale(&clean), frame_scale(&spiky));
        assert!(ps > 1.5 * pc, "{ps} vs {pc}");
        // A block mean holds at most one spike (they are 50 px apart) at 1/16 of its height:
        // the binned scale can rise by 200/16 = 12.5 units at most, the percentile rose by 200.
        let (bc, bs) = (Scale::Binned.of(&clean, w), Scale::Binned.of(&spiky, w));
        assert!(bs >= bc && bs - bc <= 200.0 / 16.0 + 0.5, "{bs} vs {bc}");
        // Floored like the percentile, and the same rule for frames too small to bin.
        assert_eq!(Scale::Binned.of(&frame(n, 0.5, 0.0, n + 1), w), 4.0);
        let tiny = frame(6, 40.0, 0.0, 7);
        assert_eq!(Scale::Binned.of(&tiny, 3), frame_scale(&tiny));
        assert_eq!(Scale::Percentile.of(&spiky, w), ps);
    }

    #[test]
    fn the_ends_mirror_about_the_frame() {
        assert_eq!(mirror(0, -1, 10), 1);
        assert_eq!(mirror(0, -2, 10), 2);
        assert_eq!(mirror(1, -2, 10), 3);
        assert_eq!(mirror(1, -1, 10), 0);
        assert_eq!(mirror(9, 2, 10), 7);
        // Shorter than the window: the nearest other frame; one frame: itself.
        assert_eq!(mirror(0, 2, 2), 1);
        assert_eq!(mirror(0, -2, 2), 1);
        assert_eq!(mirror(1, 2, 2), 0);
        assert_eq!(mirror(0, 1, 1), 0);
    }

    #[test]
    fn a_movie_input_scales_every_frame_by_the_centre_frames_scale() {
        let bright = frame(4096, 40.0, 0.0, 4097);
        let dim: Vec<f32> = bright.iter().map(|v| v * 0.5).collect();
        let rn = vec![2.0f32; 4096];
        let frames: Vec<&[f32]> = vec![&dim, &bright, &dim];
        let m = prepare_movie(&frames, 1, 64, 2.0, &rn, Scale::Percentile);
        let single = prepare(&bright, 64, 2.0, &rn, Scale::Percentile);
        assert_eq!(m.input.len(), 4 * 4096);
        assert_eq!(m.to_dn, single.to_dn);
        // The centre and the noise level are the single-frame input's; a neighbour at half the
        // light is half the centre (one scale for the window).
        assert_eq!(&m.input[4096..2 * 4096], &single.input[..4096]);
        assert_eq!(&m.input[3 * 4096..], &single.input[4096..]);
        for i in 0..4096 {
            assert!((m.input[i] - 0.5 * m.input[4096 + i]).abs() < 1e-6);
        }
    }

    #[test]
    fn a_hybrid_input_scales_like_its_estimate_not_its_noise() {
        let est = frame(4096, 0.5, 0.0, 4097);
        assert_eq!(signal_scale(&est), HYBRID_SCALE_FLOOR);
        let bright = frame(4096, 40.0, 0.0, 4097);
        let noisy_spikes = frame(4096, 40.0, 500.0, 50);
        let s = signal_scale(&bright);
        let p = prepare_hybrid(&noisy_spikes, &bright, 1.0, &vec![0.0; 4096], s);
        assert_eq!(p.input.len(), 3 * 4096);
        assert!((p.input[2 * 4096 + 1] - bright[1] / s).abs() < 1e-6);
        assert_eq!(p.to_dn, s);
    }
}
