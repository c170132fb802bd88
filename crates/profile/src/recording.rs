//! A raw recording opened for correction with a profile.

use std::path::{Path, PathBuf};

use crate::{CameraProfile, Error, Result};

/// A recording opened and checked against a profile (sensor size, exposure rules), ready to
/// stream frame by frame.
pub struct Recording {
    /// Its path.
    pub path: PathBuf,
    /// Its frames.
    pub reader: Box<dyn emccd_io::FrameReader>,
    /// What it holds.
    pub info: emccd_io::StackInfo,
    /// Its exposure (s): the one given, else the header's.
    pub exposure: f64,
    /// What a user should hear about it, each naming the file: the reader's remarks on the
    /// header, and an exposure whose fixed pattern is extrapolated.
    pub warnings: Vec<String>,
}

impl Recording {
    /// Opens `path` and checks it against `profile`: `exposure_s` overrides the header's
    /// exposure (`source` names where it came from, e.g. `--exposure-s`); an exposure outside
    /// the calibrated range is accepted only near it or with `extrapolate`
    /// ([`CameraProfile::check_frames`]).
    pub fn open(
        path: &Path,
        profile: &CameraProfile,
        exposure_s: Option<f64>,
        source: &str,
        extrapolate: bool,
    ) -> Result<Recording> {
        let reader = emccd_io::open(path)?;
        let info = reader.info().clone();
        let header = &info.metadata.warnings;
        let checked = match (exposure_s, info.metadata.exposure_s) {
            (Some(t), _) => Ok((t, source)),
            (None, Some(t)) => Ok((t, "the file header")),
            // A profile characterized from a recording holds one fixed pattern, flat in
            // exposure: where the header says nothing, the recording is taken at its exposure.
            (None, None) if profile.from_recording() && profile.exposures_s.len() == 1 => Ok((
                profile.exposures_s[0],
                "the profile characterized from a recording",
            )),
            (None, None) => Err(Error::Parameter(format!(
                "the header records no exposure; pass {source}"
            ))),
        }
        .and_then(|(t, source)| {
            // A crop cannot stand in for on-chip binning: binned pixels hold several pixels'
            // charge, read out and amplified once.
            let size = (info.width, info.height);
            if let Some((bx, by)) = info.metadata.binning.filter(|&(x, y)| x * y > 1) {
                if size != (profile.width, profile.height) {
                    return Err(Error::Parameter(format!(
                        "frames are {}×{}, binned {bx}×{by} on the chip; the profile's frames are \
                         {}×{}. Binning sums {} pixels' charge before the EM register, so a \
                         binned pixel's offset, gain and noise are not a crop's: calibrate a \
                         profile from bias and flat stacks taken with the same binning and region",
                        size.0,
                        size.1,
                        profile.width,
                        profile.height,
                        bx * by
                    )));
                }
            }
            let w = profile.check_frames(info.width, info.height, t, source, extrapolate)?;
            Ok((t, w))
        });
        let (exposure, extrapolated) = match checked {
            Ok(c) => c,
            // What the reader noticed about the header often explains the failure.
            Err(e) if !header.is_empty() => {
                return Err(Error::Parameter(format!(
                    "{e} (the reader noted: {})",
                    header.join("; ")
                ))
                .at(path))
            }
            Err(e) => return Err(e.at(path)),
        };
        let name = path.display();
        let warnings = header
            .iter()
            .map(|w| format!("{name}: {w}"))
            .chain(extrapolated.map(|w| format!("{name}: {w}")))
            .collect();
        Ok(Recording {
            path: path.to_path_buf(),
            reader,
            info,
            exposure,
            warnings,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stack(dir: &Path, name: &str, w: usize, h: usize, exposure: Option<f64>) -> PathBuf {
        let path = dir.join(name);
        let mut wr =
            emccd_io::StackWriter::create(&path, w, h, emccd_io::SampleFormat::U16, Some(2))
                .unwrap();
        wr.set_metadata(&emccd_io::Metadata {
            exposure_s: exposure,
            ..Default::default()
        });
        for k in 0..2 {
            wr.write_frame(&vec![500.0 + k as f32; w * h]).unwrap();
        }
        wr.finish().unwrap();
        path
    }

    #[test]
    fn opens_checks_and_names_the_file() {
        let p = crate::default_profile()
            .crop(crate::Roi::corner(16, 12))
            .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let (lo, hi) = p.exposure_range();
        let mid = 0.5 * (lo + hi);

        // The header's exposure, inside the calibrated range: no warning.
        let ok = stack(dir.path(), "ok.tif", 16, 12, Some(mid));
        let r = Recording::open(&ok, &p, None, "--exposure-s", false).unwrap();
        assert_eq!((r.exposure, r.info.frames), (mid, 2));
        assert!(r.warnings.is_empty(), "{:?}", r.warnings);
        // The given exposure overrides it; just outside the range is a warning naming the file.
        let r = Recording::open(&ok, &p, Some(hi * 1.5), "--exposure-s", false).unwrap();
        assert_eq!(r.exposure, hi * 1.5);
        assert!(r.warnings.len() == 1 && r.warnings[0].contains("ok.tif"));
        // Far outside it only with `extrapolate`.
        assert!(Recording::open(&ok, &p, Some(hi * 3.0), "--exposure-s", false).is_err());
        assert!(Recording::open(&ok, &p, Some(hi * 3.0), "--exposure-s", true).is_ok());

        // No exposure anywhere: the error names the file and the option to pass.
        let bare = stack(dir.path(), "bare.tif", 16, 12, None);
        let e = Recording::open(&bare, &p, None, "--exposure-s", false)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("bare.tif") && e.contains("--exposure-s"), "{e}");
        // Another sensor size.
        let big = stack(dir.path(), "big.tif", 20, 12, Some(mid));
        let e = Recording::open(&big, &p, None, "--exposure-s", false)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("big.tif") && e.contains("20×12"), "{e}");
    }
}
