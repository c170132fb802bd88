//! On-disk form: `DIR/profile.toml` (scalars, human-readable) + `DIR/maps.safetensors`
//! (`fpn_base` [H,W], optional `fpn_theta` [4,H,W], `read_noise_std` [E,H,W], all f32).

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};
use serde::{Deserialize, Serialize};

use crate::{
    BloomingFit, CameraProfile, EldParams, Error, FpnFit, PgnParams, ProfileMaps, Provenance,
    Result,
};

/// Name of the scalar file inside a profile directory.
pub const PROFILE_TOML: &str = "profile.toml";
/// Name of the maps file inside a profile directory.
pub const MAPS_FILE: &str = "maps.safetensors";
const FORMAT_VERSION: u32 = 1;

#[derive(Serialize, Deserialize)]
struct TomlProfile {
    format_version: u32,
    camera: String,
    em_gain: f64,
    width: usize,
    height: usize,
    /// Photon-transfer slope s = K·f² in DN (absent: not calibrated).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ptc_slope_dn: Option<f64>,
    f_range: [f64; 2],
    quantization_dn: f64,
    adc_max_dn: f64,
    /// Informational: median of the base FPN map (recomputed from the maps on load).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    bias_dn: Option<f64>,
    /// Informational: median read-noise std (recomputed from the maps on load).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    read_noise_dn: Option<f64>,
    exposures_s: Vec<f64>,
    fpn: FpnFit,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    blooming: Option<BloomingFit>,
    #[serde(skip_serializing_if = "Option::is_none")]
    eld: Option<EldParams>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pgn: Option<PgnParams>,
    provenance: Provenance,
    /// FNV-1a 64 of the maps file written with this one (hex): the two files are renamed into
    /// place one after the other, and a load must not pair a new toml with old maps or the
    /// reverse. Absent in profiles written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    maps_fnv1a64: Option<String>,
}

/// FNV-1a, 64 bits: a checksum that pairs the two files of a profile (not a security measure).
fn fnv1a64(bytes: &[u8]) -> String {
    format!("{:016x}", emccd_io::bytes_hash(bytes))
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    let mut b = Vec::with_capacity(v.len() * 4);
    for x in v {
        b.extend_from_slice(&x.to_le_bytes());
    }
    b
}

fn tensor_f32(view: &TensorView<'_>, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
    if view.dtype() != Dtype::F32 {
        return Err(Error::Format(format!(
            "{name}: dtype {:?}, expected F32",
            view.dtype()
        )));
    }
    if view.shape() != shape {
        return Err(Error::Format(format!(
            "{name}: shape {:?}, expected {:?}",
            view.shape(),
            shape
        )));
    }
    Ok(view
        .data()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

impl CameraProfile {
    fn to_toml_struct(&self) -> TomlProfile {
        TomlProfile {
            format_version: FORMAT_VERSION,
            camera: self.camera.clone(),
            em_gain: self.em_gain,
            width: self.width,
            height: self.height,
            ptc_slope_dn: self.ptc_slope_dn,
            f_range: self.f_range,
            quantization_dn: self.quantization_dn,
            adc_max_dn: self.adc_max_dn,
            bias_dn: Some((self.bias_dn() * 1000.0).round() / 1000.0).filter(|v| v.is_finite()),
            read_noise_dn: Some((self.read_noise_dn() * 1000.0).round() / 1000.0)
                .filter(|v| v.is_finite()),
            exposures_s: self.exposures_s.clone(),
            fpn: self.fpn.clone(),
            blooming: self.blooming,
            eld: self.eld.clone(),
            pgn: self.pgn.clone(),
            provenance: self.provenance.clone(),
            maps_fnv1a64: None,
        }
    }

    /// The `profile.toml` text.
    pub fn to_toml_string(&self) -> String {
        toml_text(&self.to_toml_struct())
    }

    /// Writes `dir/profile.toml` and `dir/maps.safetensors` together: both are written in full
    /// before either replaces an earlier profile's, so a failure (a full disk) leaves the earlier
    /// profile loading as it was, and a folder this call made is removed again.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        self.save_as(dir.as_ref(), true)
    }

    /// [`save`](Self::save) where no profile may be in `dir`, checked as the profile is placed,
    /// not only when a run starts: of two runs writing a new profile into one folder at once,
    /// the later is refused rather than replacing the first's.
    pub fn save_new(&self, dir: impl AsRef<Path>) -> Result<()> {
        self.save_as(dir.as_ref(), false)
    }

    fn save_as(&self, dir: &Path, replace: bool) -> Result<()> {
        self.validate()?;
        let taken = || {
            Error::Format(format!(
                "already holds a profile ({PROFILE_TOML}), placed while this run was working (another run writing there?); this run's profile was not written: write it elsewhere, or pass --force to replace that one"
            ))
            .at(dir)
        };
        if dir.exists() {
            // Its two files are replaced together (`write_atomic_together`).
            return if self.save_into(dir, replace)? {
                Ok(())
            } else {
                Err(taken())
            };
        }
        // A new profile folder is written beside its name and renamed into place: a run that
        // fails or is stopped leaves no folder.
        let stage = emccd_io::StagedDir::beside(dir).map_err(|e| Error::from(e).at(dir))?;
        self.save_into(stage.path(), true)?;
        if !replace && dir.join(PROFILE_TOML).exists() {
            return Err(taken());
        }
        stage.place().map_err(|e| Error::from(e).at(dir))
    }

    /// Writes the two files into `dir`; `false` (nothing written) where `replace` is off and a
    /// profile is there as they are placed.
    fn save_into(&self, dir: &Path, replace: bool) -> Result<bool> {
        let (h, w, e) = (self.height, self.width, self.exposures_s.len());
        let base = f32_bytes(&self.maps.fpn_base);
        let theta = f32_bytes(&self.maps.fpn_theta);
        let mut rn = Vec::with_capacity(e * h * w * 4);
        for m in &self.maps.read_noise {
            rn.extend_from_slice(&f32_bytes(m));
        }
        let mut tensors: Vec<(&str, TensorView<'_>)> = Vec::new();
        // A profile without bias frames has no maps at all (an empty tensor would be misread).
        if !self.maps.fpn_base.is_empty() {
            tensors.push((
                "fpn_base",
                TensorView::new(Dtype::F32, vec![h, w], &base).map_err(st_err)?,
            ));
            tensors.push((
                "read_noise_std",
                TensorView::new(Dtype::F32, vec![e, h, w], &rn).map_err(st_err)?,
            ));
        }
        if !self.maps.fpn_theta.is_empty() {
            tensors.push((
                "fpn_theta",
                TensorView::new(Dtype::F32, vec![4, h, w], &theta).map_err(st_err)?,
            ));
        }
        let mut meta = HashMap::new();
        meta.insert("format".to_string(), "emccd-profile-maps".to_string());
        meta.insert("exposures_s".to_string(), format!("{:?}", self.exposures_s));
        let bytes = emccd_io::safetensors_sorted(
            safetensors::serialize(tensors, Some(meta)).map_err(st_err)?,
        );
        let toml = TomlProfile {
            maps_fnv1a64: Some(fnv1a64(&bytes)),
            ..self.to_toml_struct()
        };
        let (maps, text) = (dir.join(MAPS_FILE), toml_text(&toml));
        let marker = dir.join(PROFILE_TOML);
        let files: [(&Path, &[u8]); 2] = [(&maps, &bytes), (&marker, text.as_bytes())];
        if replace {
            emccd_io::write_atomic_together(&files).map(|()| true)
        } else {
            emccd_io::write_new_together(&files)
        }
        .map_err(|e| Error::Io(std::io::Error::other(e)))
    }

    /// Loads a profile by the argument `--profile` (and `profile=`) takes: a directory, or
    /// `default` for the bundled profile, made from its seed (in a third of a second; bit for
    /// bit the files the repository once shipped, which a test checks), so it is part of every
    /// build wherever it runs.
    pub fn load_arg(arg: &str) -> Result<CameraProfile> {
        if arg == "default" {
            return Ok(crate::default_profile());
        }
        CameraProfile::load(arg)
    }

    /// Loads and validates a profile directory.
    pub fn load(dir: impl AsRef<Path>) -> Result<CameraProfile> {
        let dir = dir.as_ref();
        if !dir.is_dir() {
            return Err(Error::Format(
                "not a profile directory (expected profile.toml and maps.safetensors inside)"
                    .into(),
            )
            .at(dir));
        }
        let tpath = dir.join(PROFILE_TOML);
        let text = emccd_io::read_regular_text(&tpath).map_err(|e| Error::from(e).at(&tpath))?;
        let t: TomlProfile =
            toml::from_str(&text).map_err(|e| Error::Format(format!("{e}")).at(&tpath))?;
        if t.format_version != FORMAT_VERSION {
            return Err(Error::Format(format!(
                "format_version {} is not supported (this build reads {FORMAT_VERSION})",
                t.format_version
            ))
            .at(&tpath));
        }
        let mpath = dir.join(MAPS_FILE);
        let bytes = emccd_io::read_regular(&mpath).map_err(|e| Error::from(e).at(&mpath))?;
        if let Some(want) = &t.maps_fnv1a64 {
            if *want != fnv1a64(&bytes) {
                return Err(Error::Format(format!(
                    "{MAPS_FILE} is not the maps file saved with {PROFILE_TOML} (checksum differs): \
                     a save interrupted between its two files, or files from two profiles; save \
                     or copy the profile again"
                ))
                .at(dir));
            }
        }
        let st = safetensors::SafeTensors::deserialize(&bytes).map_err(|e| st_err(e).at(&mpath))?;
        let (h, w, e) = (t.height, t.width, t.exposures_s.len());
        let get = |name: &str, shape: &[usize]| -> Result<Vec<f32>> {
            let v = st
                .tensor(name)
                .map_err(|_| Error::Format(format!("missing tensor {name}")))?;
            tensor_f32(&v, name, shape)
        };
        let has = |name: &str| st.names().contains(&name);
        let fpn_base = if has("fpn_base") || e > 0 {
            get("fpn_base", &[h, w]).map_err(|e| e.at(&mpath))?
        } else {
            Vec::new()
        };
        let fpn_theta = if has("fpn_theta") {
            get("fpn_theta", &[4, h, w]).map_err(|e| e.at(&mpath))?
        } else {
            Vec::new()
        };
        let read_noise = if e > 0 {
            let rn = get("read_noise_std", &[e, h, w]).map_err(|e| e.at(&mpath))?;
            rn.chunks(h * w).map(|c| c.to_vec()).collect()
        } else {
            Vec::new()
        };
        let p = CameraProfile {
            camera: t.camera,
            em_gain: t.em_gain,
            width: w,
            height: h,
            ptc_slope_dn: t.ptc_slope_dn,
            f_range: t.f_range,
            quantization_dn: t.quantization_dn,
            adc_max_dn: t.adc_max_dn,
            fpn: t.fpn,
            blooming: t.blooming,
            exposures_s: t.exposures_s,
            eld: t.eld,
            pgn: t.pgn,
            provenance: t.provenance,
            maps: ProfileMaps {
                fpn_base,
                fpn_theta,
                read_noise,
            },
        };
        p.validate().map_err(|e| e.at(dir))?;
        Ok(p)
    }
}

fn toml_text(t: &TomlProfile) -> String {
    let body = toml::to_string_pretty(t).expect("profile serializes");
    format!(
        "# emccd camera profile. Per-pixel maps are in {MAPS_FILE} beside this file.\n\
         # Model (paper eq. 1): D = B[K(I + f·Np) + FPN_t] + Nr + Nq, with s = K·f².\n{body}"
    )
}

fn st_err(e: safetensors::SafeTensorError) -> Error {
    Error::Format(format!("safetensors: {e}"))
}

/// [`emccd_io::write_atomic`] (a temporary file renamed into place, removed on Ctrl-C).

#[cfg(test)]
mod tests {
    use crate::default_profile;

    #[test]
    fn save_load_roundtrip_is_exact() {
        let p = default_profile()
            .crop(crate::Roi {
                x: 10,
                y: 20,
                width: 32,
                height: 24,
            })
            .unwrap();
        let dir = tempfile::tempdir().unwrap();
        p.save(dir.path()).unwrap();
        let q = crate::CameraProfile::load(dir.path()).unwrap();
        assert_eq!(p, q);
        assert_eq!(p.fingerprint(), q.fingerprint());
    }

    #[test]
    fn a_profile_is_saved_as_the_same_bytes_every_time() {
        let p = default_profile().crop(crate::Roi::corner(8, 8)).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let first = dir.path().join("0");
        p.save(&first).unwrap();
        let want = std::fs::read(first.join(super::MAPS_FILE)).unwrap();
        // The metadata map's hash order changes from one save to the next (two keys: sixteen
        // saves in one order by chance is 1 in 2¹⁵).
        for k in 1..16 {
            let d = dir.path().join(k.to_string());
            p.save(&d).unwrap();
            assert!(
                std::fs::read(d.join(super::MAPS_FILE)).unwrap() == want,
                "save {k}"
            );
        }
        assert_eq!(crate::CameraProfile::load(&first).unwrap(), p);
    }

    /// A hand-edited profile.toml with a number no camera has does not load, and the message
    /// names the key and keeps the number short (these loaded before, and BM3D then wrote
    /// zeros, or a reversed blooming range panicked).
    #[test]
    fn numbers_no_camera_has_are_refused_by_key() {
        let p = default_profile().crop(crate::Roi::corner(8, 8)).unwrap();
        let dir = tempfile::tempdir().unwrap();
        p.save(dir.path()).unwrap();
        let toml_path = dir.path().join(super::PROFILE_TOML);
        let text = std::fs::read_to_string(&toml_path).unwrap();
        let range = "range_s = [\n    0.001,\n    0.1,\n]";
        assert!(text.contains(range), "{text}");
        let cases = [
            (
                "ptc_slope_dn = 20.14",
                "ptc_slope_dn = inf",
                "ptc_slope_dn = inf",
            ),
            (
                "ptc_slope_dn = 20.14",
                "ptc_slope_dn = 1e308",
                "ptc_slope_dn = 1e308",
            ),
            (
                "ptc_slope_dn = 20.14",
                "ptc_slope_dn = 1e-300",
                "ptc_slope_dn = 1e-300",
            ),
            ("a = 0.00015", "a = 1e10", "[blooming] a = 1e10"),
            (
                range,
                "range_s = [0.1, 0.001]",
                "range_s's last value = 0.001",
            ),
            (range, "range_s = [nan, 0.1]", "range_s's first value = NaN"),
            ("em_gain = 300.0", "em_gain = 1e308", "em_gain = 1e308"),
            // The shared FPN curve (it loaded, and moved the corrected mean by 18 %).
            (
                "    1.2,\n",
                "    inf,\n",
                "[fpn] shared_theta's θ2 (per e-fold of exposure) = inf",
            ),
            (
                "    0.105,\n",
                "    1e308,\n",
                "[fpn] shared_theta's θ1 = 1e308",
            ),
            (
                "    0.105,\n",
                "    30.0,\n",
                "[fpn] shared_theta's change of the pattern from",
            ),
            ("0.2,\n]\nmaps", "1e308,\n]\nmaps", "exposures_s = 1e308"),
        ];
        for (from, to, want) in cases {
            assert!(text.contains(from), "{from}");
            std::fs::write(&toml_path, text.replacen(from, to, 1)).unwrap();
            let e = crate::CameraProfile::load(dir.path())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(want) && e.contains("outside what a camera"),
                "{to}: {e}"
            );
        }
        // A range the checks refuse still gives a number where a profile is made in code.
        let mut b = p.blooming.unwrap();
        b.range_s = Some([0.1, 0.001]);
        assert!(b.factor(0.01).is_finite());
    }

    #[test]
    fn damaged_profiles_are_named_errors() {
        let p = default_profile().crop(crate::Roi::corner(8, 8)).unwrap();
        let dir = tempfile::tempdir().unwrap();
        p.save(dir.path()).unwrap();
        let maps = dir.path().join(super::MAPS_FILE);
        let b = std::fs::read(&maps).unwrap();
        std::fs::write(&maps, &b[..b.len() / 2]).unwrap();
        let e = crate::CameraProfile::load(dir.path())
            .unwrap_err()
            .to_string();
        assert!(e.contains("maps.safetensors"), "{e}");
        let e = crate::CameraProfile::load(dir.path().join("nope"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a profile directory"), "{e}");
    }

    /// A torn pair (the toml of one save with the maps of another, of the same size) does not
    /// load; a toml from before the checksum existed still does.
    #[test]
    fn the_two_files_of_a_profile_must_belong_together() {
        let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        let p = default_profile().crop(crate::Roi::corner(8, 8)).unwrap();
        p.save(a.path()).unwrap();
        default_profile()
            .crop(crate::Roi {
                x: 100,
                y: 100,
                width: 8,
                height: 8,
            })
            .unwrap()
            .save(b.path())
            .unwrap();
        let maps = |d: &std::path::Path| d.join(super::MAPS_FILE);
        let own = std::fs::read(maps(a.path())).unwrap();
        std::fs::copy(maps(b.path()), maps(a.path())).unwrap();
        let e = crate::CameraProfile::load(a.path())
            .unwrap_err()
            .to_string();
        assert!(e.contains("not the maps file saved with"), "{e}");
        std::fs::write(maps(a.path()), own).unwrap();
        assert_eq!(crate::CameraProfile::load(a.path()).unwrap(), p);
        let toml = a.path().join(super::PROFILE_TOML);
        let text = std::fs::read_to_string(&toml).unwrap();
        assert!(text.contains("maps_fnv1a64"));
        let old: String = text
            .lines()
            .filter(|l| !l.starts_with("maps_fnv1a64"))
            .map(|l| format!("{l}\n"))
            .collect();
        std::fs::write(&toml, old).unwrap();
        assert_eq!(crate::CameraProfile::load(a.path()).unwrap(), p);
    }
}
