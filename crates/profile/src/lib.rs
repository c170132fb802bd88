//! The camera profile: every calibrated number and per-pixel map that the rest of `emccd` passes
//! around, and its on-disk form — a directory holding a human-readable `profile.toml` and a
//! `maps.safetensors` with the per-pixel maps.
//!
//! The profile describes the camera in the paper's terms (eq. 1): the photon-transfer slope
//! `s = K·f²`, the range of the excess noise factor `f`, the quantization step, the fixed pattern
//! `FPN_t = exp(σ(ln t; θ))` (per-pixel and shared forms), the blooming factor `x(t) = a·t^b`,
//! and per-pixel read-noise std maps at the calibrated exposures. It also carries the parameters of
//! the two comparison noise models (ELD and the Poisson–Gamma–Normal model) so that all three are
//! calibrated from the same frames. Estimating these numbers is `emccd-calib`'s job; simulating a
//! camera from them is `emccd-camera`'s.
//!
//! The bundled default (an iXon Ultra 897 model), cut to a sub-array as a recording with a
//! cropped sensor would need:
//!
//! ```
//! # fn main() -> emccd_profile::Result<()> {
//! let p = emccd_profile::default_profile().crop(emccd_profile::Roi::corner(64, 64))?;
//! assert_eq!((p.width, p.height), (64, 64));
//! // The photon-transfer slope s = K·f² with f² = 2: K DN per photoelectron.
//! assert_eq!(p.dn_per_electron()?, p.slope()? / 2.0);
//! let mut fpn = vec![0f32; p.len()];
//! p.fpn_at(0.01, &mut fpn); // the fixed pattern of a 10 ms frame, DN
//! assert!(fpn.iter().all(|v| v.is_finite()));
//! # Ok(())
//! # }
//! ```

#![deny(missing_docs)]

mod blooming;
mod default;
mod error;
pub mod export;
mod fpn;
pub mod manifest;
mod recording;
mod store;
mod vst;

pub use blooming::{apply_blooming, column_means, preprocess, remove_blooming};
pub use default::{default_profile, DEFAULT_PROFILE_SEED};
pub use error::{Error, Result};
pub use fpn::{logistic, FpnCurves, FpnForm};
pub use recording::Recording;
pub use vst::PoissonGaussian;

/// A rectangular region of a sensor: its top-left pixel (from 0) and its size, in pixels. As
/// text `X,Y,WxH` (e.g. `128,128,256x256`), or `WxH` for a region at the top-left corner.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Roi {
    /// First column.
    pub x: usize,
    /// First row.
    pub y: usize,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl Roi {
    /// The `width`×`height` region at the top-left corner.
    pub fn corner(width: usize, height: usize) -> Roi {
        Roi {
            x: 0,
            y: 0,
            width,
            height,
        }
    }
}

impl std::str::FromStr for Roi {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Roi, String> {
        let bad = || {
            format!(
                "'{s}': a region is X,Y,WxH (top-left pixel from 0, then the size, e.g. \
                 128,128,256x256) or WxH at the top-left corner (e.g. 128x128)"
            )
        };
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let (x, y, size) = match parts[..] {
            [size] => ("0", "0", size),
            [x, y, size] => (x, y, size),
            _ => return Err(bad()),
        };
        let (w, h) = size.split_once(['x', 'X']).ok_or_else(bad)?;
        let num = |v: &str| v.trim().parse::<usize>().map_err(|_| bad());
        let r = Roi {
            x: num(x)?,
            y: num(y)?,
            width: num(w)?,
            height: num(h)?,
        };
        if r.width == 0 || r.height == 0 {
            return Err(format!("'{s}': the region's size must be positive"));
        }
        Ok(r)
    }
}

impl std::fmt::Display for Roi {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{},{},{}x{}", self.x, self.y, self.width, self.height)
    }
}

use serde::{Deserialize, Serialize};

/// Blooming factor against exposure, `x(t) = a·t^b` (paper appendix A.2; `b ≈ −0.96`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BloomingFit {
    /// Prefactor `a` (x at t = 1 s).
    pub a: f64,
    /// Exponent `b`.
    pub b: f64,
    /// Exposures (s) the law was measured over. Outside them `x` stays at the nearest end's
    /// value: a power law with `b ≈ −1` extrapolated to 10 µs would claim the column mean is
    /// added ten times over.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range_s: Option<[f64; 2]>,
}

impl BloomingFit {
    /// The blooming factor at exposure `t` seconds.
    pub fn factor(&self, exposure_s: f64) -> f64 {
        // max/min, not clamp: a range the profile's checks would refuse still gives a number.
        let t = match self.range_s {
            Some([lo, hi]) => exposure_s.max(lo).min(hi),
            None => exposure_s,
        };
        self.a * t.powf(self.b)
    }
}

/// How the fixed pattern depends on exposure.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FpnFit {
    /// Which form preprocessing uses.
    pub form: FpnForm,
    /// Exposure of the base map (the shortest calibrated bias exposure), seconds.
    pub base_exposure_s: f64,
    /// Shared logistic coefficients θ = (θ0, θ1, θ2, θ3) of
    /// `σ(u) = θ0 + θ1 / (1 + exp(−θ2·(u − θ3)))`, `u = ln t`.
    pub shared_theta: [f64; 4],
}

/// Parameters of the ELD noise model (Wei et al. 2021) for comparison training.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EldParams {
    /// System gain K in DN per photoelectron (ELD has no excess noise, so this is the PTC slope).
    pub k_dn: f64,
    /// Tukey-lambda shape λ of the read noise.
    pub tukey_lambda: f64,
    /// Tukey-lambda scale of the read noise, DN.
    pub tukey_scale_dn: f64,
    /// Std of the per-row offset, DN.
    pub row_sigma_dn: f64,
}

/// Parameters of the theoretical Poisson–Gamma–Normal EMCCD model (Ryan et al. 2021).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PgnParams {
    /// EM gain G (mean electrons out per electron in).
    pub em_gain: f64,
    /// Electrons per DN after the EM register.
    pub e_per_dn: f64,
    /// Clock-induced charge, electrons per pixel per frame.
    pub cic_e: f64,
    /// Dark current, electrons per pixel per second.
    pub dark_e_per_s: f64,
    /// Read noise, DN (std).
    pub read_sigma_dn: f64,
}

/// Where a profile's numbers came from.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// `modeled`, `calibrated` or `virtual-camera truth`.
    pub source: String,
    /// Free text: what is measured and what is assumed.
    #[serde(default)]
    pub notes: String,
}

/// Per-pixel maps, row-major `height × width`.
#[derive(Clone, Debug, PartialEq)]
pub struct ProfileMaps {
    /// FPN at the base (shortest) exposure, DN.
    pub fpn_base: Vec<f32>,
    /// Per-pixel logistic coefficients, 4 planes (θ0..θ3), or empty if only the shared form exists.
    pub fpn_theta: Vec<f32>,
    /// One read-noise std map (DN) per entry of [`CameraProfile::exposures_s`].
    pub read_noise: Vec<Vec<f32>>,
}

/// Everything known about one camera at one EM gain setting.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraProfile {
    /// Camera name.
    pub camera: String,
    /// EM gain setting the profile was calibrated at.
    pub em_gain: f64,
    /// Sensor width in pixels.
    pub width: usize,
    /// Sensor height in pixels.
    pub height: usize,
    /// Photon-transfer slope `s = K·f²`, DN per DN of signal; `None` when no flat fields were
    /// calibrated.
    pub ptc_slope_dn: Option<f64>,
    /// Range of the excess noise factor drawn during synthesis.
    pub f_range: [f64; 2],
    /// Quantization step q, DN.
    pub quantization_dn: f64,
    /// Largest value the ADC reports.
    pub adc_max_dn: f64,
    /// Fixed-pattern fit.
    pub fpn: FpnFit,
    /// Blooming fit; `None` when no blooming frames were calibrated (preprocessing then skips
    /// blooming removal).
    pub blooming: Option<BloomingFit>,
    /// Exposures (s) at which read-noise maps were measured, ascending; empty (with an empty
    /// `fpn_base`) when no bias frames were calibrated.
    pub exposures_s: Vec<f64>,
    /// ELD comparison-model parameters.
    pub eld: Option<EldParams>,
    /// PGN comparison-model parameters.
    pub pgn: Option<PgnParams>,
    /// Where the numbers came from.
    pub provenance: Provenance,
    /// Per-pixel maps.
    pub maps: ProfileMaps,
}

/// The summary `emccd profile show --json` prints.
#[derive(Clone, Debug, Serialize)]
pub struct ProfileSummary {
    /// Camera name.
    pub camera: String,
    /// EM gain setting.
    pub em_gain: f64,
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Photon-transfer slope s = K·f², DN (null if not calibrated).
    pub ptc_slope_dn: Option<f64>,
    /// Excess-noise-factor range.
    pub f_range: [f64; 2],
    /// System gain range K = s/f², DN per photoelectron (null if not calibrated).
    pub k_range_dn: Option<[f64; 2]>,
    /// Quantization step, DN.
    pub quantization_dn: f64,
    /// Median of the FPN map at the shortest exposure, DN (null without bias frames).
    pub bias_dn: Option<f64>,
    /// Median read-noise std over pixels and exposures, DN (null without bias frames).
    pub read_noise_dn: Option<f64>,
    /// FPN form used by preprocessing.
    pub fpn_form: FpnForm,
    /// Shared FPN coefficients.
    pub fpn_shared_theta: [f64; 4],
    /// Blooming prefactor a (null if not calibrated).
    pub blooming_a: Option<f64>,
    /// Blooming exponent b (null if not calibrated).
    pub blooming_b: Option<f64>,
    /// Calibrated exposures, s.
    pub exposures_s: Vec<f64>,
    /// ELD parameters, if calibrated.
    pub eld: Option<EldParams>,
    /// PGN parameters, if calibrated.
    pub pgn: Option<PgnParams>,
    /// Source of the numbers.
    pub provenance: Provenance,
    /// Content fingerprint (hex).
    pub fingerprint: String,
}

/// The provenance source of a profile characterized from a recording.
pub const RECORDING_SOURCE: &str = "characterized from a recording";

/// The largest EM gain a profile may hold (EMCCD registers reach about 1000; some modes more).
pub const MAX_EM_GAIN: f64 = 1e4;
/// The longest exposure a profile may hold, seconds (about 2.8 hours).
pub const MAX_EXPOSURE_S: f64 = 1e4;

/// A number for a message: short whatever its size (`1e308`, not three hundred digits).
pub fn number(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-3..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// An exposure is a positive, finite number of seconds (a header or a flag can say anything).
pub fn check_exposure(exposure_s: f64) -> Result<()> {
    if !(exposure_s.is_finite() && exposure_s > 0.0) {
        return Err(Error::Parameter(format!(
            "exposure {} s: it must be a positive number of seconds",
            number(exposure_s)
        )));
    }
    Ok(())
}

/// Clock-induced charge (e⁻ per pixel per frame) and dark current (e⁻ per pixel per second) a
/// camera can have, as a data sheet or a flag gives them: 0–10 and 0–10⁵.
pub fn check_spurious(cic: f64, dark: f64) -> Result<()> {
    if !((0.0..=10.0).contains(&cic) && (0.0..=1e5).contains(&dark)) {
        return Err(Error::Parameter(format!(
            "clock-induced charge {cic} e⁻ per frame and dark current {dark} e⁻/s must be 0–10 and 0–10⁵"
        )));
    }
    Ok(())
}

/// Median of `f32` or `f64` values, NaNs ignored (the mean of the middle two for an even
/// count); `None` when no value is left, so each caller says what an empty set means.
pub fn median<T: Into<f64>>(values: impl IntoIterator<Item = T>) -> Option<f64> {
    let mut v: Vec<f64> = values
        .into_iter()
        .map(Into::into)
        .filter(|x: &f64| !x.is_nan())
        .collect();
    if v.is_empty() {
        return None;
    }
    let (mid, odd) = (v.len() / 2, v.len() % 2 == 1);
    let (lower, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    let m = *m;
    Some(if odd {
        m
    } else {
        0.5 * (lower.iter().copied().fold(f64::MIN, f64::max) + m)
    })
}

/// The `q`-quantile (`q` in [0, 1]) of `f32` or `f64` values by nearest rank: the value of
/// sorted rank ⌊n·q⌋ (the largest for `q` = 1); non-finite values are ignored. `None` when no
/// value is left. One rule for every caller: network input scaling, report colour ranges and
/// the blooming source search. The values are selected in their own type (a frame of `f32` is
/// not copied to `f64`).
pub fn percentile<T>(values: impl IntoIterator<Item = T>, q: f64) -> Option<f64>
where
    T: Copy + PartialOrd + Into<f64>,
{
    let mut v: Vec<T> = values
        .into_iter()
        .filter(|&x| x.into().is_finite())
        .collect();
    if v.is_empty() {
        return None;
    }
    let k = ((v.len() as f64 * q) as usize).min(v.len() - 1);
    // Finite values are totally ordered by partial_cmp.
    let (_, p, _) = v.select_nth_unstable_by(k, |a, b| {
        a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal)
    });
    Some((*p).into())
}

impl CameraProfile {
    /// Pixels per frame.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// True for a 0×0 profile.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The photon-transfer slope, or an error saying which acquisition provides it.
    pub fn slope(&self) -> Result<f64> {
        self.ptc_slope_dn.ok_or_else(|| {
            Error::Parameter(
                "the profile has no photon-transfer slope: calibrate it with flat-field stacks"
                    .into(),
            )
        })
    }

    /// DN per photoelectron, K = s / 2: an EM register's output has twice the variance of the
    /// photoelectrons' Poisson noise (excess noise factor √2), so the photon-transfer slope s is
    /// 2K. The one conversion between DN above bias and photoelectrons.
    pub fn dn_per_electron(&self) -> Result<f64> {
        Ok(self.slope()? / 2.0)
    }

    /// Whether the fixed pattern was measured on dark frames (a calibrated profile): it then
    /// holds the mean signal of the clock-induced charge and dark current as well, which
    /// preprocessing removes with it. A modeled profile's pattern is the bias alone.
    pub fn fpn_holds_spurious(&self) -> bool {
        self.provenance.source == "calibrated"
    }

    /// Whether the profile was characterized from a recording (`emccd calibrate
    /// --from-recording`, or a command run without `--profile`) rather than calibrated from a
    /// calibration acquisition.
    pub fn from_recording(&self) -> bool {
        self.provenance.source == RECORDING_SOURCE
    }

    /// Whether bias frames were calibrated (FPN and read-noise maps exist).
    pub fn has_bias(&self) -> bool {
        !self.exposures_s.is_empty()
            && self.maps.read_noise.len() == self.exposures_s.len()
            && self.maps.read_noise.iter().all(|m| m.len() == self.len())
            && self.maps.fpn_base.len() == self.len()
    }

    /// Checks that every part synthesis and simulation need is present.
    pub fn require_complete(&self) -> Result<()> {
        self.slope()?;
        if !self.has_bias() {
            return Err(Error::Parameter(
                "the profile has no FPN or read-noise maps: calibrate it with bias stacks".into(),
            ));
        }
        Ok(())
    }

    /// System gain `K = s/f²` for a given excess noise factor (NaN without a slope).
    pub fn k_dn(&self, f: f64) -> f64 {
        self.ptc_slope_dn.unwrap_or(f64::NAN) / (f * f)
    }

    /// The blooming factor `x_t` (0 when blooming was not calibrated: nothing is removed).
    pub fn blooming_factor(&self, exposure_s: f64) -> f64 {
        self.blooming.map_or(0.0, |b| b.factor(exposure_s))
    }

    /// Median of the base FPN map (the camera's bias level), DN; NaN without bias frames.
    pub fn bias_dn(&self) -> f64 {
        if self.maps.fpn_base.is_empty() {
            return f64::NAN;
        }
        median(self.maps.fpn_base.iter().copied()).unwrap_or(0.0)
    }

    /// Median read-noise std over all pixels and exposures, DN; NaN without bias frames.
    pub fn read_noise_dn(&self) -> f64 {
        if self.maps.read_noise.is_empty() {
            return f64::NAN;
        }
        median(self.maps.read_noise.iter().flat_map(|m| m.iter().copied())).unwrap_or(0.0)
    }

    /// The read-noise map measured closest (in log exposure) to `exposure_s`.
    pub fn read_noise_near(&self, exposure_s: f64) -> &[f32] {
        &self.maps.read_noise[self.exposure_index_near(exposure_s)]
    }

    /// The calibrated exposure nearest `exposure_s` (in log), s: that of
    /// [`CameraProfile::read_noise_near`]'s map.
    pub fn exposure_near(&self, exposure_s: f64) -> f64 {
        self.exposures_s
            .get(self.exposure_index_near(exposure_s))
            .copied()
            .unwrap_or(exposure_s)
    }

    fn exposure_index_near(&self, exposure_s: f64) -> usize {
        self.exposures_s
            .iter()
            .enumerate()
            .min_by(|a, b| {
                let da = (a.1.ln() - exposure_s.ln()).abs();
                let db = (b.1.ln() - exposure_s.ln()).abs();
                da.total_cmp(&db)
            })
            .map(|(i, _)| i)
            .unwrap_or(0)
    }

    /// The calibrated exposure range (shortest, longest), s.
    pub fn exposure_range(&self) -> (f64, f64) {
        let lo = self
            .fpn
            .base_exposure_s
            .min(self.exposures_s.first().copied().unwrap_or(f64::MAX));
        (lo, self.exposures_s.last().copied().unwrap_or(0.0))
    }

    /// Whether `exposure_s` lies inside the calibrated exposure range.
    pub fn exposure_in_range(&self, exposure_s: f64) -> bool {
        let (lo, hi) = self.exposure_range();
        exposure_s >= lo * (1.0 - 1e-9) && exposure_s <= hi * (1.0 + 1e-9)
    }

    /// Whether frames of `width`×`height` exposed `exposure_s` (taken from `source`, for the
    /// messages) can be corrected with this profile: the exposure is a positive number of
    /// seconds, the frames are the sensor's size, and the exposure is in the calibrated range
    /// or near enough ([`CameraProfile::check_exposure_range`]: `Ok(Some(warning))` where the
    /// fixed pattern is extrapolated).
    pub fn check_frames(
        &self,
        width: usize,
        height: usize,
        exposure_s: f64,
        source: &str,
        extrapolate: bool,
    ) -> Result<Option<String>> {
        check_exposure(exposure_s)
            .map_err(|e| Error::Parameter(format!("the exposure from {source}: {e}")))?;
        if (width, height) != (self.width, self.height) {
            return Err(Error::Parameter(format!(
                "frames are {width}×{height}, the profile's sensor is {}×{} (a sub-array readout needs the profile cropped to its region)",
                self.width, self.height
            )));
        }
        self.check_exposure_range(exposure_s, source, extrapolate)
    }

    /// Whether frames taken with `exposure_s` can be corrected: inside the calibrated range,
    /// `Ok(None)`; outside it but within a factor 2, or further with `extrapolate`, `Ok(Some)`
    /// with a warning (the fixed pattern there is the model's extrapolation); further without
    /// it, an error. `source` says where the exposure came from, for the messages.
    pub fn check_exposure_range(
        &self,
        exposure_s: f64,
        source: &str,
        extrapolate: bool,
    ) -> Result<Option<String>> {
        if self.exposure_in_range(exposure_s) {
            return Ok(None);
        }
        let (lo, hi) = self.exposure_range();
        let what = format!(
            "exposure {} s (from {source}) is outside the calibrated range {}–{} s",
            number(exposure_s),
            number(lo),
            number(hi)
        );
        if (exposure_s < lo / 2.0 || exposure_s > hi * 2.0) && !extrapolate {
            return Err(Error::Parameter(format!("{what}; its fixed pattern would be extrapolated far from the calibration. Calibrate with bias frames at this exposure, or pass --extrapolate to use the model's extrapolation")));
        }
        Ok(Some(format!(
            "{what}; the fixed pattern is the model's extrapolation"
        )))
    }

    /// The same sensor at EM gain `em_gain` read out through an amplifier `read_noise_scale`
    /// times noisier: the photon-transfer slope and the model parameters that follow from it
    /// scale with the gain, the read-noise maps (and the ELD/PGN read noise) with the factor.
    /// Used to build a second, different camera for experiments.
    pub fn variant(&self, em_gain: f64, read_noise_scale: f64) -> Result<CameraProfile> {
        if !(em_gain > 0.0 && read_noise_scale > 0.0) {
            return Err(Error::Parameter(format!(
                "EM gain ({em_gain}) and read-noise scale ({read_noise_scale}) must be positive"
            )));
        }
        let g = em_gain / self.em_gain;
        let mut p = self.clone();
        p.camera = format!(
            "{} at EM gain {em_gain}, read noise ×{read_noise_scale}",
            self.camera
        );
        p.em_gain = em_gain;
        p.ptc_slope_dn = self.ptc_slope_dn.map(|s| s * g);
        for m in &mut p.maps.read_noise {
            m.iter_mut().for_each(|v| *v *= read_noise_scale as f32);
        }
        if let Some(e) = &mut p.eld {
            e.k_dn *= g;
            e.tukey_scale_dn *= read_noise_scale;
        }
        if let Some(q) = &mut p.pgn {
            q.em_gain = em_gain;
            q.read_sigma_dn *= read_noise_scale;
        }
        p.provenance.notes = format!(
            "{} Variant: EM gain {em_gain}, read noise ×{read_noise_scale}.",
            self.provenance.notes
        );
        Ok(p)
    }

    /// The summary printed by `emccd profile show`.
    pub fn summary(&self) -> ProfileSummary {
        ProfileSummary {
            camera: self.camera.clone(),
            em_gain: self.em_gain,
            width: self.width,
            height: self.height,
            ptc_slope_dn: self.ptc_slope_dn,
            f_range: self.f_range,
            k_range_dn: self
                .ptc_slope_dn
                .map(|_| [self.k_dn(self.f_range[1]), self.k_dn(self.f_range[0])]),
            quantization_dn: self.quantization_dn,
            bias_dn: Some(self.bias_dn()).filter(|v| v.is_finite()),
            read_noise_dn: Some(self.read_noise_dn()).filter(|v| v.is_finite()),
            fpn_form: self.fpn.form,
            fpn_shared_theta: self.fpn.shared_theta,
            blooming_a: self.blooming.map(|b| b.a),
            blooming_b: self.blooming.map(|b| b.b),
            exposures_s: self.exposures_s.clone(),
            eld: self.eld.clone(),
            pgn: self.pgn.clone(),
            provenance: self.provenance.clone(),
            fingerprint: self.fingerprint_hex(),
        }
    }

    /// What `emccd profile show` prints: the summary's numbers, one per line, with what is not
    /// calibrated said so.
    pub fn summary_text(&self) -> String {
        use std::fmt::Write;
        let s = self.summary();
        let mut out = String::new();
        // Writing to a String cannot fail.
        macro_rules! w {
            ($($t:tt)*) => {{
                let _ = writeln!(out, $($t)*);
            }};
        }
        w!("{}  ({})", s.camera, s.provenance.source);
        w!(
            "  sensor            {} × {} px, EM gain {}",
            s.width,
            s.height,
            s.em_gain
        );
        const NONE: &str = "not calibrated";
        match (s.ptc_slope_dn, s.k_range_dn) {
            (Some(slope), Some(k)) => {
                w!("  PTC slope s=K·f²  {slope:.3} DN");
                w!(
                    "  noise factor f    {:.3} – {:.3}  (K = {:.3} – {:.3} DN/e⁻)",
                    s.f_range[0],
                    s.f_range[1],
                    k[0],
                    k[1]
                );
            }
            _ => w!("  PTC slope s=K·f²  {NONE} (no flat fields)"),
        }
        w!("  quantization q    {} DN", s.quantization_dn);
        match (s.bias_dn, s.read_noise_dn) {
            (Some(b), Some(r)) => {
                w!(
                    "  bias (FPN median) {b:.2} DN at {} s",
                    self.fpn.base_exposure_s
                );
                w!("  read noise        {r:.3} DN (median over pixels and exposures)");
                w!(
                    "  FPN form          {:?}, shared θ = {:?}",
                    s.fpn_form,
                    s.fpn_shared_theta
                );
            }
            _ => w!("  bias, read noise  {NONE} (no bias frames)"),
        }
        match (s.blooming_a, s.blooming_b) {
            (Some(a), Some(b)) => w!(
                "  blooming x(t)     {a:.4e} · t^{b:.4}   (x(10 ms) = {:.4})",
                self.blooming_factor(0.01)
            ),
            _ => w!("  blooming x(t)     {NONE} (no blooming frames; preprocessing removes none)"),
        }
        let e = &s.exposures_s;
        w!(
            "  exposures         {} read-noise maps, {} s – {} s",
            e.len(),
            e.first().unwrap_or(&0.0),
            e.last().unwrap_or(&0.0)
        );
        if let Some(eld) = &s.eld {
            w!(
                "  ELD               K={} DN/e⁻, Tukey λ={} scale={} DN, row σ={} DN",
                eld.k_dn,
                eld.tukey_lambda,
                eld.tukey_scale_dn,
                eld.row_sigma_dn
            );
        }
        if let Some(pgn) = &s.pgn {
            w!(
                "  PGN               G={}, {:.3} e⁻/DN, CIC={} e⁻, dark={} e⁻/s, read σ={} DN",
                pgn.em_gain,
                pgn.e_per_dn,
                pgn.cic_e,
                pgn.dark_e_per_s,
                pgn.read_sigma_dn
            );
        }
        w!("  fingerprint       {}", s.fingerprint);
        if !s.provenance.notes.is_empty() {
            w!("  notes             {}", s.provenance.notes);
        }
        out
    }

    /// [`CameraProfile::fingerprint`] as the 16 hex digits that model files, stores and reports
    /// record.
    pub fn fingerprint_hex(&self) -> String {
        format!("{:016x}", self.fingerprint())
    }

    /// A 64-bit FNV-1a hash of every parameter and map, so a model can record which profile it was
    /// trained for and warn when used with another.
    pub fn fingerprint(&self) -> u64 {
        use std::hash::Hasher;
        let mut h = fnv::FnvHasher::default();
        let mut eat = |bytes: &[u8]| h.write(bytes);
        eat(self.to_toml_string().as_bytes());
        for m in [&self.maps.fpn_base, &self.maps.fpn_theta]
            .into_iter()
            .chain(self.maps.read_noise.iter())
        {
            for v in m.iter() {
                eat(&v.to_le_bytes());
            }
        }
        h.finish()
    }

    /// The profile of a `w`×`h` frame recorded with the sensor's top-left corner (a scene or
    /// test frame smaller than the sensor): this profile itself when the frame is the whole
    /// sensor, else its [`CameraProfile::crop`]; an error for a larger or empty frame.
    pub fn top_left(&self, w: usize, h: usize) -> Result<std::borrow::Cow<'_, CameraProfile>> {
        if (w, h) == (self.width, self.height) {
            Ok(std::borrow::Cow::Borrowed(self))
        } else {
            self.crop(crate::Roi::corner(w, h))
                .map(std::borrow::Cow::Owned)
        }
    }

    /// [`CameraProfile::crop`] with a region that may run past the sensor: cut at its edge
    /// (`--crop 1024x1024` of a 512² sensor is the whole sensor). A region starting past the
    /// edge is refused as given.
    pub fn crop_clamped(&self, roi: Roi) -> Result<CameraProfile> {
        if roi.x < self.width && roi.y < self.height {
            self.crop(Roi {
                width: roi.width.min(self.width - roi.x),
                height: roi.height.min(self.height - roi.y),
                ..roi
            })
        } else {
            self.crop(roi)
        }
    }

    /// The profile of the sub-array `roi` (for simulating or calibrating a region of interest,
    /// or for recordings made with sub-array readout).
    pub fn crop(&self, roi: Roi) -> Result<CameraProfile> {
        let Roi {
            x: x0,
            y: y0,
            width: w,
            height: h,
        } = roi;
        let fits = |o: usize, n: usize, of: usize| o.checked_add(n).is_some_and(|e| e <= of);
        if w == 0 || h == 0 || !fits(x0, w, self.width) || !fits(y0, h, self.height) {
            return Err(Error::Parameter(format!(
                "crop {w}×{h} at ({x0},{y0}) does not fit the {}×{} sensor",
                self.width, self.height
            )));
        }
        let cut = |m: &[f32]| -> Vec<f32> {
            let mut out = Vec::with_capacity(w * h);
            for y in y0..y0 + h {
                out.extend_from_slice(&m[y * self.width + x0..y * self.width + x0 + w]);
            }
            out
        };
        let n = self.len();
        let mut p = self.clone();
        p.width = w;
        p.height = h;
        p.maps.fpn_base = cut(&self.maps.fpn_base);
        p.maps.fpn_theta = self
            .maps
            .fpn_theta
            .chunks(n.max(1))
            .flat_map(|c| cut(c))
            .collect();
        p.maps.read_noise = self.maps.read_noise.iter().map(|m| cut(m)).collect();
        Ok(p)
    }

    /// Checks sizes and values; every constructor and loader calls this.
    pub fn validate(&self) -> Result<()> {
        let n = self.len();
        let bad = |what: String| Err(Error::Parameter(what));
        if n == 0 {
            return bad("the profile has no pixels".into());
        }
        // Every number within what a camera can have: a hand-edited or damaged file must not
        // load and then turn every frame into zeros.
        let within = |key: &str, v: f64, lo: f64, hi: f64, unit: &str| -> Result<()> {
            if v >= lo && v <= hi {
                return Ok(());
            }
            bad(format!(
                "{key} = {} is outside what a camera can have ({} to {}{unit})",
                number(v),
                number(lo),
                number(hi)
            ))
        };
        within("em_gain", self.em_gain, 0.0, MAX_EM_GAIN, "")?;
        if let Some(s) = self.ptc_slope_dn {
            within("ptc_slope_dn", s, 1e-4, 1e6, " DN per count")?;
        }
        if let Some(b) = self.blooming {
            within("[blooming] a", b.a, 0.0, 1.0, "")?;
            within("[blooming] b", b.b, -3.0, 1.0, "")?;
            if let Some([lo, hi]) = b.range_s {
                within(
                    "[blooming] range_s's first value",
                    lo,
                    1e-9,
                    MAX_EXPOSURE_S,
                    " s",
                )?;
                within(
                    "[blooming] range_s's last value",
                    hi,
                    lo,
                    MAX_EXPOSURE_S,
                    " s",
                )?;
                for t in [lo, hi] {
                    within(
                        &format!("the blooming factor a·t^b at {} s", number(t)),
                        b.factor(t),
                        0.0,
                        1.0,
                        "",
                    )?;
                }
            }
        }
        within("f_range's first value", self.f_range[0], 1.0, 100.0, "")?;
        within(
            "f_range's last value",
            self.f_range[1],
            self.f_range[0],
            100.0,
            "",
        )?;
        within("quantization_dn", self.quantization_dn, 0.0, 1e4, " DN")?;
        within("adc_max_dn", self.adc_max_dn, 1.0, 2f64.powi(32), " DN")?;
        within(
            "[fpn] base_exposure_s",
            self.fpn.base_exposure_s,
            1e-9,
            MAX_EXPOSURE_S,
            " s",
        )?;
        // The shared curve is ln(FPN) = θ0 + θ1 / (1 + e^(−θ2 (ln t − θ3))), the pattern at t
        // its base map times the curve's change from the base exposure. The calibration fits θ2
        // in 0.01–20 and θ3 within 15 e-folds of the exposures; θ1 may be large where θ3 lies
        // far beyond them, so what is bounded is the change itself over the calibrated
        // exposures: a thousandfold is beyond any dark current a cooled EMCCD gathers.
        let th = self.fpn.shared_theta;
        within("[fpn] shared_theta's θ0 (ln DN)", th[0], -1e6, 1e6, "")?;
        within("[fpn] shared_theta's θ1", th[1], -1e6, 1e6, "")?;
        within(
            "[fpn] shared_theta's θ2 (per e-fold of exposure)",
            th[2],
            -100.0,
            100.0,
            "",
        )?;
        within("[fpn] shared_theta's θ3 (ln s)", th[3], -50.0, 50.0, "")?;
        let base = fpn::logistic(self.fpn.base_exposure_s.ln(), th);
        // (An exposure that is no positive number is refused below, by its own key.)
        for &t in self
            .exposures_s
            .iter()
            .filter(|t| t.is_finite() && **t > 0.0)
        {
            within(
                &format!(
                    "[fpn] shared_theta's change of the pattern from {} s to {} s",
                    number(self.fpn.base_exposure_s),
                    number(t)
                ),
                (fpn::logistic(t.ln(), th) - base).exp(),
                1e-3,
                1e3,
                "×",
            )?;
        }
        if let Some(e) = &self.eld {
            within("[eld] k_dn", e.k_dn, 1e-4, 1e6, " DN per electron")?;
            within("[eld] tukey_lambda", e.tukey_lambda, -1.0, 1.0, "")?;
            within("[eld] tukey_scale_dn", e.tukey_scale_dn, 0.0, 1e5, " DN")?;
            within("[eld] row_sigma_dn", e.row_sigma_dn, 0.0, 1e5, " DN")?;
        }
        if let Some(g) = &self.pgn {
            within("[pgn] em_gain", g.em_gain, 1.0, MAX_EM_GAIN, "")?;
            within("[pgn] e_per_dn", g.e_per_dn, 1e-4, 1e4, " e⁻ per DN")?;
            within("[pgn] cic_e", g.cic_e, 0.0, 10.0, " e⁻ per pixel")?;
            within(
                "[pgn] dark_e_per_s",
                g.dark_e_per_s,
                0.0,
                1e6,
                " e⁻ per pixel per s",
            )?;
            within("[pgn] read_sigma_dn", g.read_sigma_dn, 0.0, 1e5, " DN")?;
        }
        for &t in &self.exposures_s {
            within("an exposure of exposures_s", t, 1e-9, MAX_EXPOSURE_S, " s")?;
        }
        let no_bias = self.exposures_s.is_empty() && self.maps.fpn_base.is_empty();
        if no_bias {
            if !self.maps.fpn_theta.is_empty() || !self.maps.read_noise.is_empty() {
                return bad("FPN coefficients or read-noise maps without a base FPN map".into());
            }
            return Ok(());
        }
        if self.maps.fpn_base.len() != n {
            return bad(format!(
                "fpn_base has {} values, expected {n}",
                self.maps.fpn_base.len()
            ));
        }
        if !self.maps.fpn_theta.is_empty() && self.maps.fpn_theta.len() != 4 * n {
            return bad(format!(
                "fpn_theta has {} values, expected 4×{n}",
                self.maps.fpn_theta.len()
            ));
        }
        if self.fpn.form == FpnForm::PerPixel && self.maps.fpn_theta.is_empty() {
            return bad("fpn.form is per-pixel but the profile has no fpn_theta map".into());
        }
        if self.maps.read_noise.len() != self.exposures_s.len() {
            return bad(format!(
                "{} read-noise maps for {} exposures",
                self.maps.read_noise.len(),
                self.exposures_s.len()
            ));
        }
        if self.exposures_s.is_empty() {
            return bad("a profile needs at least one read-noise map".into());
        }
        if self.exposures_s.windows(2).any(|w| !(w[1] > w[0]))
            || self.exposures_s.iter().any(|&t| !(t > 0.0))
        {
            return bad("exposures_s must be positive and strictly ascending".into());
        }
        for (t, m) in self.exposures_s.iter().zip(&self.maps.read_noise) {
            if m.len() != n {
                return bad(format!(
                    "read-noise map at {t} s has {} values, expected {n}",
                    m.len()
                ));
            }
            if m.iter().any(|v| !(*v >= 0.0 && *v <= 1e5)) {
                return bad(format!(
                    "read-noise map at {} s holds a value outside 0 to 100000 DN",
                    number(*t)
                ));
            }
        }
        if self
            .maps
            .fpn_base
            .iter()
            .any(|v| !(v.abs() <= 2f64.powi(32) as f32))
        {
            return bad("fpn_base holds a value beyond any ADC's range (or not a number)".into());
        }
        if self.maps.fpn_theta.iter().any(|v| !v.is_finite()) {
            return bad("fpn_theta holds a non-finite value".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{median, percentile, Roi};

    #[test]
    fn a_frame_smaller_than_the_sensor_gets_the_top_left_profile() {
        let p = crate::default_profile()
            .crop(crate::Roi::corner(16, 12))
            .unwrap();
        assert!(matches!(
            p.top_left(16, 12).unwrap(),
            std::borrow::Cow::Borrowed(_)
        ));
        let c = p.top_left(8, 4).unwrap();
        assert_eq!((c.width, c.height), (8, 4));
        assert_eq!(c.maps.fpn_base[8 + 3], p.maps.fpn_base[16 + 3]);
        for (w, h) in [(17, 12), (16, 13), (0, 4)] {
            assert!(p.top_left(w, h).is_err(), "{w}×{h}");
        }
    }

    #[test]
    fn the_text_summary_says_what_is_calibrated_and_what_is_not() {
        let p = crate::default_profile()
            .crop(crate::Roi::corner(16, 12))
            .unwrap();
        let t = p.summary_text();
        assert!(t.starts_with(&p.camera), "{t}");
        assert!(t.contains("16 × 12 px"), "{t}");
        assert!(
            t.contains(&format!("fingerprint       {}", p.fingerprint_hex())),
            "{t}"
        );
        assert_eq!(p.fingerprint_hex().len(), 16);
        let mut bare = p.clone();
        bare.blooming = None;
        assert!(bare
            .summary_text()
            .contains("blooming x(t)     not calibrated"));
    }

    #[test]
    fn regions_parse_and_print_back() {
        let r: Roi = "128,64,256x32".parse().unwrap();
        assert_eq!((r.x, r.y, r.width, r.height), (128, 64, 256, 32));
        assert_eq!(r.to_string().parse::<Roi>().unwrap(), r);
        let c: Roi = "64X48".parse().unwrap();
        assert_eq!(
            c,
            Roi {
                x: 0,
                y: 0,
                width: 64,
                height: 48
            }
        );
        for bad in [
            "",
            "64",
            "1,2",
            "a,b,3x3",
            "1,2,0x5",
            "1,2,3x",
            "-1,0,4x4",
            "1,2,3,4x4",
        ] {
            assert!(bad.parse::<Roi>().is_err(), "{bad}");
        }
    }

    #[test]
    fn median_of_odd_even_nan_and_empty_sets() {
        assert_eq!(median([3.0f32, 1.0, 2.0]), Some(2.0));
        assert_eq!(median([4.0f64, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median([f32::NAN, 5.0, 1.0]), Some(3.0));
        assert_eq!(median([f64::NAN]), None);
        assert_eq!(median(Vec::<f32>::new()), None);
    }

    #[test]
    fn percentile_by_nearest_rank() {
        let v: Vec<f32> = (0..100).rev().map(|i| i as f32).collect();
        assert_eq!(percentile(v.iter().copied(), 0.0), Some(0.0));
        assert_eq!(percentile(v.iter().copied(), 0.01), Some(1.0));
        assert_eq!(percentile(v.iter().copied(), 0.995), Some(99.0));
        assert_eq!(percentile(v.iter().copied(), 1.0), Some(99.0));
        assert_eq!(percentile([f64::INFINITY, f64::NAN, 2.0], 0.9), Some(2.0));
        assert_eq!(percentile([f32::NAN], 0.5), None);
    }
}
