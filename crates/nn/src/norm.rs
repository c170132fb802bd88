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

/// Inputs for the network and how to undo the scaling.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Channel-major [2, H, W]: normalized frame, noise level.
    pub input: Vec<f32>,
    /// Output DN = network output × `to_dn`.
    pub to_dn: f32,
}

/// The per-frame scale: the 99.5th percentile of the slope-normalized frame, floored so that
/// an almost empty frame is not blown up.
pub fn frame_scale(x_norm: &[f32]) -> f32 {
    percentile(x_norm, 0.995).map_or(1.0, |p| p.max(4.0))
}

/// Percentile of a slope-normalized frame (`q` in [0, 1]); non-finite values are ignored.
fn percentile(x: &[f32], q: f64) -> Option<f32> {
    let mut v: Vec<f32> = x.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let k = ((v.len() as f64 * q) as usize).min(v.len() - 1);
    let (_, p, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    Some(*p)
}

/// Smallest hybrid scale, in slope units (about two photoelectrons): below it a frame is
/// essentially empty and is not blown up.
pub const HYBRID_SCALE_FLOOR: f32 = 1.0;

/// The hybrid scale: the 99.5th percentile of a slope-normalized signal estimate (the BM3D
/// estimate at inference, the clean frame in training), floored at [`HYBRID_SCALE_FLOOR`].
pub fn signal_scale(estimate_norm: &[f32]) -> f32 {
    percentile(estimate_norm, 0.995)
        .unwrap_or(HYBRID_SCALE_FLOOR)
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

/// Prepares a preprocessed frame `dn` (DN above bias) with the slope `s` and read-noise std map.
pub fn prepare(dn: &[f32], slope: f64, read_noise: &[f32]) -> Prepared {
    let s = slope as f32;
    let x: Vec<f32> = dn.iter().map(|v| v / s).collect();
    prepare_scaled(dn, slope, read_noise, frame_scale(&x))
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
