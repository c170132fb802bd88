//! Whether a camera profile fits a recording: the recording's own characterization
//! ([`super::characterize`]) set beside the profile's bias, read noise, photon-transfer slope and
//! EM gain, each compared with a tolerance that the estimate's error and what it cannot separate
//! (the excess noise factor from one frame, the fixed pattern in a peak's width) allow.

use emccd_profile::CameraProfile;

use super::{Characterization, SlopeFrom};

/// A profile's bias may sit this many of its read-noise σ from the recording's zero-electron
/// peak (besides 4 standard errors): drift between calibration and recording, and the mean
/// clock-induced charge a calibrated pattern holds, stay far below it; another camera's bias
/// (≥ 10 σ off, the mark) far above.
pub const BIAS_SIGMAS: f64 = 5.0;

/// The photon-transfer slope may differ by this factor (besides 3 standard errors) where a movie
/// measures it: the estimate's bias is ≤ 2.4 % on the cameras measured (docs/results.md), another
/// gain setting or camera is ≥ 30 % away.
pub const SLOPE_FACTOR: f64 = 1.15;

/// Where one frame gives only the register's gain `K`, the profile's slope over it is the excess
/// noise factor `f²`, 2 for a high-gain register; it may lie this factor from 2 (besides 3
/// standard errors): one frame's `K` carries the fixed pattern's error (up to 19 % on the
/// cameras measured), so only a gain off by more than about 30 % is caught.
pub const SINGLE_FRAME_FACTOR: f64 = 1.3;

/// The read noise may differ by this factor (besides 3 standard errors) where the frame
/// differences measure it cleanly; another readout rate or pre-amplifier changes it by more.
pub const READ_NOISE_FACTOR: f64 = 1.3;

/// The header's EM gain may differ from the profile's by this share: gain settings are whole
/// numbers a camera reports exactly, and a profile holds at the gain it was calibrated at.
pub const EM_GAIN_SHARE: f64 = 0.02;

/// What disagrees between `profile` and the recording characterized as `c`, one sentence each
/// with the numbers (empty: the profile fits). `header_em_gain` is the EM gain the recording's
/// header records, if any; `exposure_s` the recording's exposure (the profile's bias there).
pub fn disagreements(
    c: &Characterization,
    profile: &CameraProfile,
    exposure_s: f64,
    header_em_gain: Option<f64>,
) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(g) = header_em_gain.filter(|&g| g > 0.0) {
        let pg = profile.em_gain;
        if pg > 0.0 && (g - pg).abs() > EM_GAIN_SHARE * pg {
            out.push(format!(
                "the header records EM gain {g}, the profile was calibrated at EM gain {pg}"
            ));
        }
    }
    if profile.has_bias() && profile.len() > 0 {
        let mut fpn = vec![0f32; profile.len()];
        profile.fpn_at(exposure_s, &mut fpn);
        let bias = emccd_profile::median(fpn.iter().copied()).unwrap_or(f64::NAN);
        let sigma = emccd_profile::median(profile.read_noise_near(exposure_s).iter().copied())
            .unwrap_or(f64::NAN);
        // The medians of the two maps: where the bias drifts across the sensor, the darkest
        // pixels' own peak is that of wherever they lie.
        let own = emccd_profile::median(c.bias_map.values.iter().copied()).unwrap_or(f64::NAN);
        let off = (own - bias).abs();
        if off > BIAS_SIGMAS * sigma + 4.0 * finite(c.bias_dn.se) {
            out.push(format!(
                "bias: the recording's zero-electron level is {own:.1} ± {:.1} DN, the profile's bias {bias:.1} DN ({:.0} of its read-noise σ away; at most {BIAS_SIGMAS} expected)",
                c.bias_dn.se,
                off / sigma
            ));
        }
        let r = &c.read_noise_dn;
        let ratio = r.value / sigma;
        let allowed = |factor: f64| factor.ln() + 3.0 * finite(r.se) / r.value;
        // A movie's frame differences measure the temporal read noise (the pattern cancelled);
        // the peak's width and one frame's differences hold the pattern too: an upper bound.
        let clean = c.frames > 1 && c.pattern_dn.is_some();
        if (clean && ratio.ln().abs() > allowed(READ_NOISE_FACTOR))
            || (!clean && -ratio.ln() > allowed(READ_NOISE_FACTOR))
        {
            out.push(format!(
                "read noise: the recording's is {:.2} ± {:.2} DN{}, the profile's {sigma:.2} DN ({ratio:.2}×)",
                r.value,
                r.se,
                if clean { "" } else { " (an upper bound: it holds the fixed pattern)" }
            ));
        }
    }
    if let Some(s) = profile.ptc_slope_dn {
        match (c.slope_from, c.gain_dn) {
            (SlopeFrom::TemporalPtc, _) => {
                let e = c.slope_dn;
                let ratio = e.value / s;
                if ratio.ln().abs() > SLOPE_FACTOR.ln() + 3.0 * finite(e.se) / e.value {
                    out.push(format!(
                        "gain: the recording's photon-transfer slope is {:.1} ± {:.1} DN per DN, the profile's {s:.1} ({ratio:.2}×)",
                        e.value, e.se
                    ));
                }
            }
            (SlopeFrom::EmTail, Some(k)) => {
                let f2 = s / k.value;
                let allowed = SINGLE_FRAME_FACTOR.ln() + 3.0 * finite(k.se) / k.value;
                if (f2 / 2.0).ln().abs() > allowed {
                    out.push(format!(
                        "gain: the recording's EM register gives {:.1} ± {:.1} DN per electron, the profile's slope {s:.1} DN per DN implies {:.1} (an excess noise factor f² = {f2:.2} where about 2 is expected)",
                        k.value,
                        k.se,
                        s / 2.0
                    ));
                }
            }
            (SlopeFrom::EmTail, None) => {}
        }
    }
    out
}

/// A standard error, or 0 where none could be given.
fn finite(se: f64) -> f64 {
    if se.is_finite() {
        se
    } else {
        0.0
    }
}

/// The refusal of profile `name` for the recordings `source` that `misfit` (from
/// [`disagreements`]) describes, with the ways on.
pub fn misfit_message(source: &str, name: &str, misfit: &[String], force: &str) -> String {
    format!(
        "{source}: the recording does not fit profile {name}:\n  - {}\nCalibrate this camera (`emccd calibrate`), characterize it from its recordings (`emccd calibrate --from-recording FILE... -o PROFILE`, or give no profile), or pass {force} to use this profile anyway",
        misfit.join("\n  - ")
    )
}
