//! `pairs.toml`: a folder of noisy/clean test pairs and how they were made. One schema for both
//! sides: `emccd simulate pairs` (and `tools/unseen_camera.py`, for foreign simulators) write
//! it, `emccd evaluate` reads it. Paths are relative to the manifest.

use std::path::Path;

use serde::{Deserialize, Serialize};

/// The manifest of a pairs folder.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct PairsManifest {
    /// The camera's name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
    /// The profile to denoise with: `default`, a folder relative to the manifest, or as given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub profile: Option<String>,
    /// EM gain of the noisy frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub em_gain: Option<f64>,
    /// DN per photoelectron (G/c) of the camera that made them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k_dn_per_e: Option<f64>,
    /// Quantum efficiency.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub qe: Option<f64>,
    /// What the files hold, for a reader of the folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The pairs.
    pub pair: Vec<Pair>,
}

/// One noisy stack and its truth.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Pair {
    /// The clean scene it was made from.
    pub scene: String,
    /// Raw noisy frames (DN as the camera records them).
    pub noisy: String,
    /// Ground truth: the photo-signal in DN above bias, float32.
    pub clean: String,
    /// A side-by-side preview PNG.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preview: Option<String>,
    /// Exposure of the noisy frames, s.
    pub exposure_s: f64,
    /// Expected photons at the scene's brightest value.
    pub photons: f64,
    /// Ratio to a long reference exposure (the paper's protocol), where the pairs were made so.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_ratio: Option<f64>,
    /// Mean photoelectrons per pixel, where the pairs were made at fixed mean levels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_electrons: Option<f64>,
    /// Frames in the noisy stack.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<usize>,
    /// Width, px.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width: Option<usize>,
    /// Height, px.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<usize>,
    /// PSNR of the preprocessed first noisy frame against the truth, dB.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub psnr_input_db: Option<f64>,
    /// The denoised first frame, where the writer denoised it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoised: Option<String>,
    /// Its PSNR against the truth, dB.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub psnr_denoised_db: Option<f64>,
}

/// A pair's frames, read: the noisy frames scored and their ground truth, of one size. A pair
/// whose truth is one frame scores the noisy stack's first frame (the stack's other frames are
/// repeated acquisitions); a movie pair — a truth stack as long as the noisy one, one truth per
/// frame — scores every frame, so a method that uses the neighbouring frames is scored as it
/// runs on a recording.
#[derive(Clone, Debug)]
pub struct PairFrames {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Frames scored: 1, or a movie's frame count.
    pub frames: usize,
    /// The raw noisy frames scored (DN), one after another.
    pub noisy: Vec<f32>,
    /// Their ground truth (DN above bias), one after another.
    pub clean: Vec<f32>,
}

impl PairFrames {
    /// Frame `k`'s ground truth.
    pub fn clean_frame(&self, k: usize) -> &[f32] {
        let n = self.width * self.height;
        &self.clean[k * n..(k + 1) * n]
    }
}

impl Pair {
    /// Checks the pair's files in the folder `dir` of its manifest from their headers, reading
    /// no frame: both open, the truth holds a frame, the sizes agree, and a truth stack (a
    /// movie's) is as long as the noisy stack. The error names the file at fault.
    pub fn check(&self, dir: &Path) -> crate::Result<()> {
        let err = |e: emccd_io::Error| crate::Error(emccd_io::error_lines(&e).join(": "));
        let (clean, noisy) = (dir.join(&self.clean), dir.join(&self.noisy));
        let c = emccd_io::open(&clean).map_err(err)?.info().clone();
        let n = emccd_io::open(&noisy).map_err(err)?.info().clone();
        if c.frames == 0 {
            return Err(crate::Error(format!(
                "{}: the file holds no frame",
                clean.display()
            )));
        }
        if (n.width, n.height) != (c.width, c.height) {
            return Err(crate::Error(format!(
                "{}: noisy {}×{} and clean {}×{} ({}) differ",
                noisy.display(),
                n.width,
                n.height,
                c.width,
                c.height,
                self.clean
            )));
        }
        if c.frames > 1 && n.frames != c.frames {
            return Err(crate::Error(format!(
                "{}: {} noisy frames and {} frames of truth in {}; a movie pair has one truth \
                 per frame, a still pair one truth",
                noisy.display(),
                n.frames,
                c.frames,
                self.clean
            )));
        }
        Ok(())
    }

    /// Reads the pair's frames ([`PairFrames`]) from the folder `dir` of its manifest, after
    /// [`Pair::check`].
    pub fn read(&self, dir: &Path) -> crate::Result<PairFrames> {
        self.check(dir)?;
        let err = |e: emccd_io::Error| crate::Error(emccd_io::error_lines(&e).join(": "));
        let (_, clean) = emccd_io::read_all(dir.join(&self.clean)).map_err(err)?;
        let (info, noisy) = if clean.len() > 1 {
            emccd_io::read_all(dir.join(&self.noisy)).map_err(err)?
        } else {
            let (info, first) = emccd_io::read_first(dir.join(&self.noisy)).map_err(err)?;
            (info, vec![first])
        };
        Ok(PairFrames {
            width: info.width,
            height: info.height,
            frames: clean.len(),
            noisy: noisy.concat(),
            clean: clean.concat(),
        })
    }
}

impl Pair {
    /// Every frame of the pair's noisy stack (DN), one after another, after [`Pair::check`].
    pub fn read_noisy_stack(&self, dir: &Path) -> crate::Result<Vec<f32>> {
        let err = |e: emccd_io::Error| crate::Error(emccd_io::error_lines(&e).join(": "));
        Ok(emccd_io::read_all(dir.join(&self.noisy))
            .map_err(err)?
            .1
            .concat())
    }
}

impl PairsManifest {
    /// The manifest's file name in a pairs folder.
    pub const FILE: &'static str = "pairs.toml";

    /// The table `emccd simulate pairs` prints: each pair's noisy file, photons, and the PSNR
    /// of its input and (where a denoiser ran) of the denoised frame.
    pub fn psnr_table(&self) -> String {
        let mut t = format!(
            "{:<40} {:>9} {:>12} {:>14}",
            "pair", "photons", "PSNR in (dB)", "denoised (dB)"
        );
        for p in &self.pair {
            let d = p
                .psnr_denoised_db
                .map_or("–".to_string(), |v| format!("{v:.2}"));
            t += &format!(
                "\n{:<40} {:>9} {:>12.2} {:>14}",
                p.noisy,
                p.photons,
                p.psnr_input_db.unwrap_or(f64::NAN),
                d
            );
        }
        t
    }

    /// Reads `dir/pairs.toml` and checks every exposure; the message names the file.
    pub fn load(dir: &Path) -> crate::Result<PairsManifest> {
        let path = dir.join(Self::FILE);
        let text = emccd_io::read_regular_text(&path)
            .map_err(|e| format!("reading {}: {e}", path.display()))?;
        let m: PairsManifest =
            toml::from_str(&text).map_err(|e| format!("parsing {}: {e}", path.display()))?;
        if let Some(p) = m
            .pair
            .iter()
            .find(|p| !(p.exposure_s.is_finite() && p.exposure_s > 0.0))
        {
            return Err(crate::Error(format!(
                "{}: the pair {}: exposure_s = {} must be a positive number of seconds",
                path.display(),
                p.noisy,
                p.exposure_s
            )));
        }
        Ok(m)
    }

    /// The profile the pairs name, as an argument for loading it: a folder relative to the
    /// manifest's `dir` where one is there (as `simulate pairs` records it), else as written
    /// (`default`, an absolute path, or a manifest written before 2026-11-27, which recorded
    /// the path as typed, relative to where `simulate pairs` ran); `None` where none is named.
    pub fn profile_arg(&self, dir: &Path) -> Option<String> {
        self.profile.as_ref().map(|p| {
            let rel = dir.join(p);
            if p != "default" && rel.is_dir() {
                rel.to_string_lossy().into_owned()
            } else {
                p.clone()
            }
        })
    }

    /// The camera's name for tables: `camera`, else the folder `dir`.
    pub fn camera_name(&self, dir: &Path) -> String {
        self.camera
            .clone()
            .unwrap_or_else(|| dir.display().to_string())
    }

    /// The manifest as TOML, after a comment line saying who wrote it.
    pub fn to_toml(&self, written_by: &str) -> String {
        let body = toml::to_string_pretty(self).expect("a pairs manifest is plain data");
        format!(
            "# Noisy/clean pairs written by {written_by}; paths are relative to this file.\n{body}"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_reads_the_foreign_writers_subset() {
        let m = PairsManifest {
            camera: Some("virtual-897".into()),
            profile: Some("default".into()),
            pair: vec![Pair {
                scene: "a.png".into(),
                noisy: "noisy/a.tif".into(),
                clean: "clean/a.tif".into(),
                exposure_s: 0.01,
                photons: 20.0,
                frames: Some(1),
                ..Default::default()
            }],
            ..Default::default()
        };
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("pairs.toml"), m.to_toml("a test")).unwrap();
        let back = PairsManifest::load(dir.path()).unwrap();
        assert_eq!(back.pair[0].noisy, "noisy/a.tif");
        assert_eq!(back.pair[0].frames, Some(1));
        assert_eq!(back.camera.as_deref(), Some("virtual-897"));
        // what tools/unseen_camera.py writes: no camera constants, mean levels per pair
        std::fs::write(
            dir.path().join("pairs.toml"),
            "[[pair]]\nscene = \"s\"\nnoisy = \"n.tif\"\nclean = \"c.tif\"\nexposure_s = 0.1\nphotons = 3.0\nmean_electrons = 1.0\n",
        )
        .unwrap();
        let m = PairsManifest::load(dir.path()).unwrap();
        assert_eq!(m.pair[0].mean_electrons, Some(1.0));
        assert!(m.camera.is_none());
        std::fs::write(
            dir.path().join("pairs.toml"),
            "[[pair]]\nscene = \"s\"\nnoisy = \"n.tif\"\nclean = \"c.tif\"\nexposure_s = 0\nphotons = 3.0\n",
        )
        .unwrap();
        let e = PairsManifest::load(dir.path()).unwrap_err();
        assert!(e.0.contains("n.tif") && e.0.contains("positive"), "{e}");
    }

    /// A truth stack as long as the noisy stack makes a movie pair: every frame is read; a
    /// truth of one frame scores the noisy stack's first frame; other lengths are refused.
    #[test]
    fn a_truth_stack_makes_a_movie_pair() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, frames: &[f32]| {
            let mut wr = emccd_io::StackWriter::create(
                dir.path().join(name),
                2,
                2,
                emccd_io::SampleFormat::F32,
                Some(frames.len()),
            )
            .unwrap();
            for &v in frames {
                wr.write_frame(&[v; 4]).unwrap();
            }
            wr.finish().unwrap();
        };
        write("noisy.tif", &[10.0, 20.0, 30.0]);
        write("truth3.tif", &[1.0, 2.0, 3.0]);
        write("truth2.tif", &[1.0, 2.0]);
        write("truth1.tif", &[1.0]);
        let pair = |clean: &str| Pair {
            noisy: "noisy.tif".into(),
            clean: clean.into(),
            ..Default::default()
        };
        let f = pair("truth3.tif").read(dir.path()).unwrap();
        assert_eq!(f.frames, 3);
        assert_eq!(
            (f.noisy[4], f.noisy[11], f.clean_frame(2)),
            (20.0, 30.0, &[3.0; 4][..])
        );
        let f = pair("truth1.tif").read(dir.path()).unwrap();
        assert_eq!((f.frames, f.noisy.len()), (1, 4));
        let e = pair("truth2.tif").read(dir.path()).unwrap_err();
        assert!(e.0.contains("3 noisy frames and 2"), "{e}");
    }

    #[test]
    fn pairs_are_read_with_their_profile_and_camera_name() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, w: usize, v: f32| {
            let path = dir.path().join(name);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            let mut wr =
                emccd_io::StackWriter::create(&path, w, 2, emccd_io::SampleFormat::F32, Some(1))
                    .unwrap();
            wr.write_frame(&vec![v; w * 2]).unwrap();
            wr.finish().unwrap();
        };
        write("noisy/a.tif", 3, 100.0);
        write("clean/a.tif", 3, 7.0);
        write("clean/b.tif", 4, 7.0);
        std::fs::create_dir(dir.path().join("prof")).unwrap();
        let pair = |clean: &str| Pair {
            noisy: "noisy/a.tif".into(),
            clean: clean.into(),
            ..Default::default()
        };
        let f = pair("clean/a.tif").read(dir.path()).unwrap();
        assert_eq!(
            (f.width, f.height, f.noisy[0], f.clean[5]),
            (3, 2, 100.0, 7.0)
        );
        let e = pair("clean/b.tif").read(dir.path()).unwrap_err();
        assert!(e.0.contains("3×2") && e.0.contains("4×2"), "{e}");
        let e = pair("clean/c.tif").read(dir.path()).unwrap_err();
        assert!(e.0.contains("c.tif"), "{e}");
        let named = |p: &str| PairsManifest {
            profile: Some(p.into()),
            ..Default::default()
        };
        let d = dir.path();
        assert_eq!(
            named("prof").profile_arg(d),
            Some(d.join("prof").to_string_lossy().into())
        );
        assert_eq!(named("default").profile_arg(d).as_deref(), Some("default"));
        assert_eq!(named("/x/y").profile_arg(d).as_deref(), Some("/x/y"));
        assert_eq!(PairsManifest::default().profile_arg(d), None);
        assert_eq!(
            PairsManifest::default().camera_name(d),
            d.display().to_string()
        );
    }
}
