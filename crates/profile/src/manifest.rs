//! The calibration manifest: which stacks were acquired, at which exposure, for which purpose.
//!
//! ```toml
//! camera = "iXon Ultra 897"
//! em_gain = 300
//! [[bias]]                      # dark frames, shutter closed, one stack per exposure
//! file = "bias/bias_10ms.tif"
//! exposure_s = 0.01             # may be omitted when the file's header records it (SIF)
//! [[flat]]                      # uniform illumination, one stack per light level
//! file = "flat/flat_01.tif"
//! exposure_s = 0.01
//! [[blooming]]                  # a bright source covering one quadrant
//! file = "blooming/bloom_1ms.tif"
//! exposure_s = 0.001
//!
//! [gain_series]                 # optional: Ryan et al. (2021) gain-series MLE
//! reference_e_per_dn = "ADU_map.tif"   # optional: a lab's own e⁻/DN map to compare with
//! [[gain_series.settings]]      # same illumination, several EM gain settings
//! em_gain = 1                   # nominal setting; the lowest one anchors the gain scale
//! file = "1x-gain.tif"
//! offset_map = "1x-gain_no-signal_S0.tif"   # per-pixel offset S0 (DN) and readout σ (DN),
//! sigma_map = "1x-gain_no-signal_sigma.tif" # or `no_signal = "stack.tif"` to measure them
//! ```
//!
//! Paths are relative to the manifest. Every file is checked before any number is computed.
//! `emccd-calib` reads it; `emccd simulate calibration` (`emccd_camera`'s acquisition) writes
//! this same type ([`Manifest::to_toml`]). It lives beside the profile, which both depend on.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// One acquisition: a stack and its exposure.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Entry {
    /// Stack file (TIFF, SIF or FITS), relative to the manifest.
    pub file: PathBuf,
    /// Exposure in seconds; taken from the file header when omitted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exposure_s: Option<f64>,
}

/// One EM gain setting of a gain series.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GainSetting {
    /// Nominal EM gain of the setting.
    pub em_gain: f64,
    /// The illuminated stack.
    pub file: PathBuf,
    /// A no-signal stack at this setting (offset and readout σ are measured from it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub no_signal: Option<PathBuf>,
    /// Per-pixel offset S0 map (DN), if measured elsewhere.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub offset_map: Option<PathBuf>,
    /// Per-pixel readout σ map (DN), if measured elsewhere.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_map: Option<PathBuf>,
}

/// The optional gain series.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GainSeries {
    /// A lab's own e⁻/DN map (or single value image) to compare the fit with.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_e_per_dn: Option<PathBuf>,
    /// The settings, any order.
    pub settings: Vec<GainSetting>,
}

/// A parsed manifest with paths resolved against its directory.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Camera name written into the profile.
    #[serde(default = "unnamed")]
    pub camera: String,
    /// EM gain setting of the bias, flat and blooming stacks.
    pub em_gain: f64,
    /// Largest value the ADC reports; default from the file's sample type (65535 for 16-bit).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adc_max_dn: Option<f64>,
    /// Bias (dark) stacks.
    #[serde(default)]
    pub bias: Vec<Entry>,
    /// Flat-field stacks.
    #[serde(default)]
    pub flat: Vec<Entry>,
    /// Blooming stacks.
    #[serde(default)]
    pub blooming: Vec<Entry>,
    /// Gain series.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gain_series: Option<GainSeries>,
    /// The manifest's own path (set by [`Manifest::load`]).
    #[serde(skip)]
    pub path: PathBuf,
}

fn unnamed() -> String {
    "unnamed camera".into()
}

impl Manifest {
    /// Reads a manifest and resolves its paths; checks that every named file exists.
    pub fn load(path: impl AsRef<Path>) -> Result<Manifest> {
        let path = path.as_ref();
        let text = emccd_io::read_regular_text(path)
            .map_err(|e| Error::Format(format!("cannot read: {e}")).at(path))?;
        Manifest::parse(&text, path)
    }

    /// Parses manifest text as if read from `path`.
    pub fn parse(text: &str, path: &Path) -> Result<Manifest> {
        let bad = |message: String| Error::Format(message).at(path);
        let mut m: Manifest = toml::from_str(text).map_err(|e| bad(e.to_string()))?;
        m.path = path.to_path_buf();
        let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        for e in m
            .bias
            .iter_mut()
            .chain(m.flat.iter_mut())
            .chain(m.blooming.iter_mut())
        {
            fix(&mut e.file);
        }
        if let Some(gs) = &mut m.gain_series {
            if let Some(r) = &mut gs.reference_e_per_dn {
                fix(r);
            }
            for s in &mut gs.settings {
                fix(&mut s.file);
                for p in [&mut s.no_signal, &mut s.offset_map, &mut s.sigma_map]
                    .into_iter()
                    .flatten()
                {
                    fix(p);
                }
            }
        }
        if !(m.em_gain >= 1.0 && m.em_gain <= crate::MAX_EM_GAIN) {
            return Err(bad(format!(
                "em_gain must be 1 to {}, got {}",
                crate::number(crate::MAX_EM_GAIN),
                crate::number(m.em_gain)
            )));
        }
        if m.bias.is_empty()
            && m.flat.is_empty()
            && m.blooming.is_empty()
            && m.gain_series.is_none()
        {
            return Err(bad("names no acquisitions: add [[bias]], [[flat]], [[blooming]] or [gain_series] entries".into()));
        }
        for e in m.bias.iter().chain(&m.flat).chain(&m.blooming) {
            if let Some(t) = e.exposure_s {
                if !(t > 0.0 && t <= crate::MAX_EXPOSURE_S) {
                    return Err(bad(format!(
                        "{}: exposure_s must be positive and at most {} s, got {}",
                        e.file.display(),
                        crate::number(crate::MAX_EXPOSURE_S),
                        crate::number(t)
                    )));
                }
            }
        }
        if let Some(gs) = &m.gain_series {
            if gs.settings.len() < 2 {
                return Err(bad(
                    "a gain series needs at least two EM gain settings".into()
                ));
            }
            for s in &gs.settings {
                if !(s.em_gain >= 1.0 && s.em_gain <= crate::MAX_EM_GAIN) {
                    return Err(bad(format!(
                        "{}: gain-series em_gain must be 1 to {}, got {}",
                        s.file.display(),
                        crate::number(crate::MAX_EM_GAIN),
                        crate::number(s.em_gain)
                    )));
                }
                if s.no_signal.is_none() && (s.offset_map.is_none() || s.sigma_map.is_none()) {
                    return Err(bad(format!(
                        "{}: give either `no_signal` (a stack) or both `offset_map` and `sigma_map`",
                        s.file.display()
                    )));
                }
            }
        }
        // One stack is one acquisition: listed twice it would count as two light levels (a
        // smaller error, an extra point on the line) or two blooming exposures.
        let mut seen: Vec<(PathBuf, &str)> = Vec::new();
        for (e, kind) in m
            .bias
            .iter()
            .map(|e| (e, "[[bias]]"))
            .chain(m.flat.iter().map(|e| (e, "[[flat]]")))
            .chain(m.blooming.iter().map(|e| (e, "[[blooming]]")))
        {
            let id = std::fs::canonicalize(&e.file).unwrap_or_else(|_| e.file.clone());
            if let Some((_, first)) = seen.iter().find(|(p, _)| *p == id) {
                return Err(Error::Format(format!(
                    "listed twice in {} (under {first} and {kind}): each entry must be its own acquisition",
                    path.display()
                ))
                .at(&e.file));
            }
            seen.push((id, kind));
        }
        for p in m.files() {
            if let Some(kind) = emccd_io::not_a_file(&p) {
                return Err(Error::Format(format!(
                    "named in {} but {kind}, not a stack",
                    path.display()
                ))
                .at(&p));
            }
            if !p.is_file() {
                return Err(
                    Error::Format(format!("named in {} but not found", path.display())).at(&p),
                );
            }
        }
        Ok(m)
    }

    /// The manifest as TOML (paths as they stand: relative ones stay relative), after a comment
    /// line saying who wrote it.
    pub fn to_toml(&self, written_by: &str) -> String {
        let body = toml::to_string_pretty(self).expect("a calibration manifest is plain data");
        format!("# Calibration acquisition written by {written_by}; paths are relative to this file.\n{body}")
    }

    /// Every file the manifest names.
    pub fn files(&self) -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = self
            .bias
            .iter()
            .chain(&self.flat)
            .chain(&self.blooming)
            .map(|e| e.file.clone())
            .collect();
        if let Some(gs) = &self.gain_series {
            v.extend(gs.reference_e_per_dn.iter().cloned());
            for s in &gs.settings {
                v.push(s.file.clone());
                v.extend(
                    [&s.no_signal, &s.offset_map, &s.sigma_map]
                        .into_iter()
                        .flatten()
                        .cloned(),
                );
            }
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_file_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let m = dir.path().join("m.toml");
        let err = Manifest::parse(
            "em_gain = 300\n[[bias]]\nfile = \"nope.tif\"\nexposure_s = 0.01\n",
            &m,
        )
        .unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("nope.tif") && msg.contains("not found"),
            "{msg}"
        );
    }

    #[test]
    fn empty_and_malformed_manifests_are_refused() {
        let m = Path::new("/tmp/m.toml");
        assert!(Manifest::parse("em_gain = 300\n", m)
            .unwrap_err()
            .to_string()
            .contains("no acquisitions"));
        assert!(Manifest::parse("em_gain = 300\n[[bias]]\nfil = \"x\"\n", m).is_err());
        let e = Manifest::parse(
            "em_gain = 300\n[[flat]]\nfile = \"x\"\nexposure_s = -1\n",
            m,
        )
        .unwrap_err();
        assert!(e.to_string().contains("positive"), "{e}");
        // Numbers no acquisition has: refused here, before a profile claims them.
        for (text, want) in [
            (
                "em_gain = 1e308\n[[flat]]\nfile = \"x\"\nexposure_s = 1\n",
                "em_gain",
            ),
            (
                "em_gain = 300\n[[flat]]\nfile = \"x\"\nexposure_s = 1e308\n",
                "1e308",
            ),
        ] {
            let e = Manifest::parse(text, m).unwrap_err().to_string();
            assert!(e.contains(want) && e.len() < 200, "{e}");
        }
    }
}
