//! What the virtual camera records: a calibration acquisition as a user records one — dark
//! (bias) stacks at several exposures, flat fields at several light levels, and blooming frames —
//! written as 16-bit TIFF stacks with the manifest `emccd-calib` reads
//! ([`CalibrationPlan::record`]), and the truth it is made from; and test pairs, noisy frames of
//! a clean scene with their ground truth, at the light levels asked for.

use std::fmt::Write as _;
use std::path::Path;

use emccd_io::{Metadata, SampleFormat, StackWriter};
use emccd_profile::manifest::{Entry, Manifest};

use crate::{Error, Exposure, VirtualCamera};

/// What to record (also `emccd simulate calibration`'s flags).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct CalibrationPlan {
    /// Frames per stack (at least 2: temporal statistics need two).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = CalibrationPlan::default().frames))]
    pub frames: usize,
    /// Bias (dark) exposures in seconds (comma-separated).
    #[cfg_attr(feature = "clap", arg(long = "bias-exposures", value_name = "SECONDS", value_delimiter = ',', default_values_t = CalibrationPlan::default().bias_exposures_s))]
    pub bias_exposures_s: Vec<f64>,
    /// Flat-field signal levels in DN above bias (comma-separated), at the flat-field
    /// exposure (10 ms by default).
    #[cfg_attr(feature = "clap", arg(long = "flat-levels", value_name = "DN", value_delimiter = ',', default_values_t = CalibrationPlan::default().flat_levels_dn))]
    pub flat_levels_dn: Vec<f64>,
    /// Exposure of the flat fields, s.
    #[cfg_attr(feature = "clap", arg(skip = CalibrationPlan::default().flat_exposure_s))]
    pub flat_exposure_s: f64,
    /// Blooming-frame exposures in seconds (comma-separated).
    #[cfg_attr(feature = "clap", arg(long = "blooming-exposures", value_name = "SECONDS", value_delimiter = ',', default_values_t = CalibrationPlan::default().blooming_exposures_s))]
    pub blooming_exposures_s: Vec<f64>,
}

impl Default for CalibrationPlan {
    /// The acquisition `emccd simulate calibration` makes by default: 20 frames per stack, 12
    /// dark exposures from 10 µs to 1 s, 8 flat levels from 20 to 8000 DN at 10 ms, 7 blooming
    /// exposures from 1 to 100 ms.
    fn default() -> Self {
        CalibrationPlan {
            frames: 20,
            bias_exposures_s: vec![
                1e-5, 1e-4, 1e-3, 0.003, 0.006, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0,
            ],
            flat_levels_dn: vec![20.0, 50.0, 120.0, 300.0, 700.0, 1500.0, 3500.0, 8000.0],
            flat_exposure_s: 0.01,
            blooming_exposures_s: vec![0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1],
        }
    }
}

/// What a stack is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Dark frames, shutter closed.
    Bias,
    /// Uniform illumination.
    Flat,
    /// A bright source on one quadrant, faint stray light elsewhere.
    Blooming,
}

/// One stack of the acquisition.
#[derive(Clone, Debug)]
pub struct PlannedStack {
    /// What it is for.
    pub role: Role,
    /// Its file, relative to the acquisition folder (`bias/bias_0.01s.tif`, `flat/flat_01.tif`,
    /// `blooming/bloom_0.001s.tif`).
    pub file: String,
    /// Exposure, s.
    pub exposure_s: f64,
    /// Expected photons per pixel in every frame.
    pub photons: Vec<f32>,
    /// Seed of its first frame (frame k: [`frame_seed`]`(seed, k)`).
    pub seed: u64,
}

/// The seed of frame `k` of a stack whose seed is `seed`.
pub fn frame_seed(seed: u64, k: usize) -> u64 {
    seed.wrapping_mul(1_000_003).wrapping_add(k as u64)
}

/// The most photons a scene's brightest pixel may get in one frame: beyond any pixel's full
/// well (10⁵–10⁶ e⁻), where a simulation would only count numbers.
pub const MAX_PHOTONS: f64 = 1e7;
/// The highest flat level, DN above bias: beyond any ADC's range.
pub const MAX_LEVEL_DN: f64 = 1e6;

/// Every value of the flag `name` positive, finite and at most `max`.
fn positive_up_to(name: &str, values: &[f64], max: f64) -> Result<(), Error> {
    match values.iter().find(|x| !(**x > 0.0 && **x <= max)) {
        Some(&x) => Err(Error::Parameter(format!(
            "{name}: every value must be a positive number{}, got {}",
            if max < f64::MAX {
                format!(" up to {}", emccd_profile::number(max))
            } else {
                String::new()
            },
            emccd_profile::number(x)
        ))),
        None => Ok(()),
    }
}

impl CalibrationPlan {
    /// Refuses a plan that cannot be calibrated from, naming the setting.
    pub fn check(&self) -> Result<(), Error> {
        if self.frames < 2 {
            return Err(Error::Parameter(
                "frames must be at least 2 (temporal statistics need two frames)".into(),
            ));
        }
        let t_max = emccd_profile::MAX_EXPOSURE_S;
        for (name, v, max) in [
            ("bias-exposures", &self.bias_exposures_s, t_max),
            ("flat-levels", &self.flat_levels_dn, MAX_LEVEL_DN),
            ("blooming-exposures", &self.blooming_exposures_s, t_max),
            ("flat exposure", &vec![self.flat_exposure_s], t_max),
        ] {
            positive_up_to(name, v, max)?;
        }
        // Each value names a file (`bias_0.01s.tif`): a repeated one would be written twice
        // into one file and listed twice in a manifest `calibrate` refuses.
        for (name, v) in [
            ("bias-exposures", &self.bias_exposures_s),
            ("flat-levels", &self.flat_levels_dn),
            ("blooming-exposures", &self.blooming_exposures_s),
        ] {
            if let Some(x) = v
                .iter()
                .enumerate()
                .find_map(|(i, x)| v[..i].contains(x).then_some(x))
            {
                return Err(Error::Parameter(format!(
                    "{name}: {} is given twice; each value is one stack",
                    emccd_profile::number(*x)
                )));
            }
        }
        Ok(())
    }

    /// Frames in the whole acquisition.
    pub fn total_frames(&self) -> u64 {
        (self.frames
            * (self.bias_exposures_s.len()
                + self.flat_levels_dn.len()
                + self.blooming_exposures_s.len())) as u64
    }

    /// The stacks `cam` records, in acquisition order; `seed` makes them reproducible.
    pub fn stacks(&self, cam: &VirtualCamera, seed: u64) -> Result<Vec<PlannedStack>, Error> {
        self.check()?;
        let (w, h) = (cam.width(), cam.height());
        let n = w * h;
        let k_qe = cam.k_dn() * cam.physics.qe;
        let mut out = Vec::new();
        for (i, &t) in self.bias_exposures_s.iter().enumerate() {
            out.push(PlannedStack {
                role: Role::Bias,
                file: format!("bias/bias_{t}s.tif"),
                exposure_s: t,
                photons: vec![0.0; n],
                seed: seed ^ (100 + i as u64),
            });
        }
        for (i, &level) in self.flat_levels_dn.iter().enumerate() {
            out.push(PlannedStack {
                role: Role::Flat,
                file: format!("flat/flat_{:02}.tif", i + 1),
                exposure_s: self.flat_exposure_s,
                photons: vec![(level / k_qe) as f32; n],
                seed: seed ^ (200 + i as u64),
            });
        }
        // Bright source in the bottom-left quadrant, faint stray light elsewhere; constant
        // flux, so the signal grows with exposure (20 000 DN at the longest exposure).
        let t_max = self
            .blooming_exposures_s
            .iter()
            .copied()
            .fold(0.0, f64::max);
        let rate = 20000.0 / k_qe / t_max;
        for (i, &t) in self.blooming_exposures_s.iter().enumerate() {
            let mut photons = vec![(0.002 * rate * t) as f32; n];
            for y in h / 2..h {
                for x in 0..w / 2 {
                    photons[y * w + x] = (rate * t) as f32;
                }
            }
            out.push(PlannedStack {
                role: Role::Blooming,
                file: format!("blooming/bloom_{t}s.tif"),
                exposure_s: t,
                photons,
                seed: seed ^ (300 + i as u64),
            });
        }
        Ok(out)
    }

    /// Records the acquisition with `cam` into `dir` (made if missing): every stack of
    /// [`CalibrationPlan::stacks`] as a 16-bit TIFF streamed frame by frame, then its manifest
    /// `calibration.toml` (written atomically, naming the camera `camera_name` and the writer
    /// `written_by`), which is returned. `tick` is called after every frame. The room the stacks
    /// need is checked first; a run that fails leaves what it wrote, so a caller that wants all
    /// or nothing records into an [`emccd_io::StagedDir`] (as `emccd simulate calibration` does).
    pub fn record(
        &self,
        cam: &VirtualCamera,
        seed: u64,
        dir: &Path,
        camera_name: &str,
        written_by: &str,
        mut tick: impl FnMut(),
    ) -> Result<Manifest, Error> {
        let stacks = self.stacks(cam, seed)?;
        // 16-bit frames; the headers are a few kB.
        let bytes = (self.frames as u64)
            .saturating_mul(cam.profile.len() as u64 * 2)
            .saturating_add(1 << 16)
            .saturating_mul(stacks.len() as u64);
        emccd_io::check_room(dir, bytes)?;
        let mut manifest = Manifest {
            camera: camera_name.into(),
            em_gain: cam.em_gain,
            ..Default::default()
        };
        for stack in stacks {
            let path = dir.join(&stack.file);
            if let Some(parent) = path.parent() {
                std::fs::create_dir_all(parent)
                    .map_err(|e| emccd_io::Error::from(e).with_path(parent))?;
            }
            let mut w = StackWriter::create(
                &path,
                cam.width(),
                cam.height(),
                SampleFormat::U16,
                Some(self.frames),
            )?;
            w.set_metadata(&Metadata {
                exposure_s: Some(stack.exposure_s),
                em_gain: Some(cam.em_gain),
                camera_model: Some(camera_name.into()),
                ..Default::default()
            });
            let e = cam.exposure(stack.exposure_s);
            let mut buf = vec![0f32; cam.profile.len()];
            for k in 0..self.frames {
                e.frame(&stack.photons, frame_seed(stack.seed, k), &mut buf);
                w.write_frame(&buf)?;
                tick();
            }
            w.finish()?;
            let entry = Entry {
                file: stack.file.into(),
                exposure_s: Some(stack.exposure_s),
            };
            match stack.role {
                Role::Bias => manifest.bias.push(entry),
                Role::Flat => manifest.flat.push(entry),
                Role::Blooming => manifest.blooming.push(entry),
            }
        }
        emccd_io::write_atomic(
            dir.join("calibration.toml"),
            manifest.to_toml(written_by).as_bytes(),
        )?;
        Ok(manifest)
    }

    /// Writes the truth of this acquisition made by `cam` beside it in `dir`: `truth.toml`
    /// ([`CalibrationPlan::truth_toml`]) and the camera's own profile in `truth/`, what a
    /// calibration of the recorded stacks is checked against.
    pub fn write_truth(&self, cam: &VirtualCamera, dir: &Path) -> Result<(), Error> {
        cam.profile.save(dir.join("truth")).map_err(Error::Truth)?;
        emccd_io::write_atomic(dir.join("truth.toml"), self.truth_toml(cam)?.as_bytes())?;
        Ok(())
    }

    /// The truth of this acquisition made by `cam`, as `truth.toml` holds it (the maps are in
    /// the truth profile beside it, `truth/`).
    pub fn truth_toml(&self, cam: &VirtualCamera) -> Result<String, Error> {
        let p = &cam.profile;
        let slope = p.slope().map_err(|e| Error::Parameter(e.to_string()))?;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# The virtual camera's true parameters. The full truth profile (maps) is in truth/."
        );
        let _ = writeln!(s, "# Raw model: D = round(B[m/c + FPN_t] + N(0, σ²)), m ~ Gamma(Poisson(QE·φ + dark·t + CIC), G).");
        let _ = writeln!(s, "profile = \"truth\"");
        let _ = writeln!(s, "width = {}\nheight = {}", p.width, p.height);
        let _ = writeln!(s, "em_gain = {}", cam.em_gain);
        let _ = writeln!(s, "e_per_dn = {}", cam.e_per_dn);
        let _ = writeln!(s, "k_dn_per_e = {}  # G / c", cam.k_dn());
        let _ = writeln!(
            s,
            "ptc_slope_dn = {slope}  # 2G/c: the EM register's f² = 2"
        );
        let _ = writeln!(
            s,
            "qe = {}\ncic_e = {}\ndark_e_per_s = {}",
            cam.physics.qe, cam.physics.cic_e, cam.physics.dark_e_per_s
        );
        let _ = writeln!(
            s,
            "hot_pixels = {}  # dark current {} e-/s",
            cam.hot_pixels.len(),
            cam.physics.hot_dark_e_per_s
        );
        let _ = writeln!(
            s,
            "hot_pixel_indices = {:?}",
            &cam.hot_pixels[..cam.hot_pixels.len().min(1000)]
        );
        let _ = writeln!(
            s,
            "bias_dn = {}  # median FPN at {} s",
            p.bias_dn(),
            p.fpn.base_exposure_s
        );
        let _ = writeln!(
            s,
            "read_noise_dn = {}  # median read-noise std",
            p.read_noise_dn()
        );
        let _ = writeln!(
            s,
            "fpn_form = \"{:?}\"\nfpn_shared_theta = {:?}",
            p.fpn.form, p.fpn.shared_theta
        );
        if let Some(b) = p.blooming {
            let _ = writeln!(s, "blooming_a = {}\nblooming_b = {}", b.a, b.b);
        }
        let _ = writeln!(s, "bias_exposures_s = {:?}", self.bias_exposures_s);
        let _ = writeln!(
            s,
            "flat_signal_dn = {:?}  # photo-signal above bias at {} s",
            self.flat_levels_dn, self.flat_exposure_s
        );
        let _ = writeln!(s, "\n[blooming_factor]  # x_t per blooming exposure");
        for &t in &self.blooming_exposures_s {
            let _ = writeln!(s, "\"{t}\" = {}", p.blooming_factor(t));
        }
        Ok(s)
    }
}

/// One light level of test pairs: an exposure and the photons the scene's brightest value (1.0)
/// collects in it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairLevel {
    /// Exposure of the noisy frames, s.
    pub exposure_s: f64,
    /// Expected photons at the scene's brightest value.
    pub photons: f64,
    /// Ratio to a long reference exposure, for levels made by the paper's protocol.
    pub ratio: Option<f64>,
}

impl PairLevel {
    /// The paper's protocol: a short exposure at `ratio` to a long reference exposure, with the
    /// reference's photons divided by the ratio.
    pub fn from_ratio(reference_exposure_s: f64, reference_photons: f64, ratio: f64) -> PairLevel {
        PairLevel {
            exposure_s: reference_exposure_s / ratio,
            photons: reference_photons / ratio,
            ratio: Some(ratio),
        }
    }

    /// The levels of a pairs run: each of `photons` at `exposure_s`, or, where `ratios` is not
    /// empty, [`PairLevel::from_ratio`] of each against the reference exposure and photons.
    /// Every number must be positive and finite; an error names the setting as a flag would
    /// (`photons`, `exposure-s`, `exposure-ratio`, `reference-exposure-s`, `reference-photons`).
    pub fn levels(
        photons: &[f64],
        exposure_s: f64,
        ratios: &[f64],
        reference_exposure_s: f64,
        reference_photons: f64,
    ) -> Result<Vec<PairLevel>, Error> {
        let t_max = emccd_profile::MAX_EXPOSURE_S;
        for (name, v, max) in [
            ("photons", photons, MAX_PHOTONS),
            ("exposure-s", &[exposure_s][..], t_max),
            ("exposure-ratio", ratios, f64::MAX),
            ("reference-exposure-s", &[reference_exposure_s][..], t_max),
            ("reference-photons", &[reference_photons][..], MAX_PHOTONS),
        ] {
            positive_up_to(name, v, max)?;
        }
        Ok(if ratios.is_empty() {
            photons
                .iter()
                .map(|&photons| PairLevel {
                    exposure_s,
                    photons,
                    ratio: None,
                })
                .collect()
        } else {
            ratios
                .iter()
                .map(|&r| PairLevel::from_ratio(reference_exposure_s, reference_photons, r))
                .collect()
        })
    }

    /// The name of a scene's pair at this level (`stem_p20`, or `stem_r100` by ratio).
    pub fn pair_name(&self, stem: &str) -> String {
        match self.ratio {
            Some(r) => format!("{stem}_r{r}"),
            None => format!("{stem}_p{}", self.photons),
        }
    }
}

/// The seed of scene `scene`'s pair at level `level` of a run seeded with `seed`.
pub fn pair_seed(seed: u64, scene: usize, level: usize) -> u64 {
    seed.wrapping_mul(7919) ^ ((scene as u64) << 20) ^ level as u64
}

/// A test pair of one scene at one light level: the ground truth (the photo-signal in DN above
/// bias) and as many noisy raw frames as asked for, frame k drawn from
/// [`frame_seed`]`(seed, k)`, so a pair is the same however many of its frames are drawn.
pub struct TestPair<'a> {
    /// The exposure's truth: the fixed pattern and blooming factor that preprocessing removes.
    pub exposure: Exposure<'a>,
    /// The ground truth, DN above bias.
    pub truth: Vec<f32>,
    photons: Vec<f32>,
    seed: u64,
}

impl VirtualCamera {
    /// The test pair of `scene` (values in [0, 1], the camera's size) at `photons` expected
    /// photons at its brightest value (1.0), exposed for `exposure_s`.
    pub fn test_pair(
        &self,
        scene: &[f32],
        photons: f64,
        exposure_s: f64,
        seed: u64,
    ) -> TestPair<'_> {
        let exposure = self.exposure(exposure_s);
        let photons: Vec<f32> = scene.iter().map(|&v| (v as f64 * photons) as f32).collect();
        TestPair {
            truth: exposure.ground_truth(&photons),
            exposure,
            photons,
            seed,
        }
    }
}

impl TestPair<'_> {
    /// Noisy raw frame `k` (DN, integer-valued) into `out`.
    pub fn frame(&self, k: usize, out: &mut [f32]) {
        self.exposure
            .frame(&self.photons, frame_seed(self.seed, k), out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PhysicalParams;

    #[test]
    fn pair_levels_by_photons_or_by_ratio() {
        let l = PairLevel::levels(&[20.0, 200.0], 0.01, &[], 1.6, 16000.0).unwrap();
        assert_eq!(l.len(), 2);
        assert_eq!(
            (l[1].exposure_s, l[1].photons, l[1].ratio),
            (0.01, 200.0, None)
        );
        assert_eq!(l[0].pair_name("s"), "s_p20");
        // Ratios replace the photons: the paper's protocol against the reference exposure.
        let r = PairLevel::levels(&[20.0], 0.01, &[100.0], 1.6, 16000.0).unwrap();
        assert_eq!(r.len(), 1);
        assert!((r[0].exposure_s - 0.016).abs() < 1e-12 && (r[0].photons - 160.0).abs() < 1e-9);
        assert_eq!(r[0].pair_name("s"), "s_r100");
        // A bad number is refused by the name of its setting.
        for (args, name) in [
            ((vec![0.0], 0.01, vec![]), "photons"),
            ((vec![20.0], f64::NAN, vec![]), "exposure-s"),
            ((vec![20.0], 0.01, vec![-1.0]), "exposure-ratio"),
        ] {
            let e = PairLevel::levels(&args.0, args.1, &args.2, 1.6, 16000.0).unwrap_err();
            assert!(e.to_string().starts_with(&format!("{name}: ")), "{e}");
        }
        let e = PairLevel::levels(&[20.0], 0.01, &[], 1.6, f64::INFINITY).unwrap_err();
        assert!(e.to_string().starts_with("reference-photons: "), "{e}");
    }

    #[test]
    fn stacks_of_the_plan() {
        let p = emccd_profile::default_profile()
            .crop(emccd_profile::Roi::corner(8, 6))
            .unwrap();
        let cam = VirtualCamera::new(p, PhysicalParams::default()).unwrap();
        let plan = CalibrationPlan {
            frames: 2,
            bias_exposures_s: vec![0.01, 0.1],
            flat_levels_dn: vec![100.0],
            flat_exposure_s: 0.01,
            blooming_exposures_s: vec![0.001, 0.01],
        };
        let s = plan.stacks(&cam, 1).unwrap();
        assert_eq!(s.len(), 5);
        assert_eq!(plan.total_frames(), 10);
        assert_eq!(
            (s[0].role, s[0].file.as_str()),
            (Role::Bias, "bias/bias_0.01s.tif")
        );
        assert!(s[0].photons.iter().all(|&v| v == 0.0));
        // a flat of 100 DN above bias: photons × QE × K = 100
        let k_qe = cam.k_dn() * cam.physics.qe;
        assert!((s[2].photons[0] as f64 * k_qe - 100.0).abs() < 1e-3);
        assert_eq!(s[2].file, "flat/flat_01.tif");
        // the longest blooming exposure puts 20 000 DN in the bright (bottom-left) quadrant
        let last = &s[4];
        assert!((last.photons[5 * 8] as f64 * k_qe - 20000.0).abs() < 1.0);
        assert!(last.photons[0] < last.photons[5 * 8] / 100.0);
        let truth = plan.truth_toml(&cam).unwrap();
        assert!(
            truth.contains("bias_exposures_s = [0.01, 0.1]") && truth.contains("[blooming_factor]")
        );
        let bad = CalibrationPlan {
            frames: 1,
            ..plan.clone()
        };
        assert!(bad.check().unwrap_err().to_string().contains("at least 2"));
        let bad = CalibrationPlan {
            flat_levels_dn: vec![-1.0],
            ..plan
        };
        assert!(bad.check().unwrap_err().to_string().contains("flat-levels"));
    }

    #[test]
    fn a_recorded_acquisition_reads_back_through_its_manifest() {
        let p = emccd_profile::default_profile()
            .crop(emccd_profile::Roi::corner(8, 6))
            .unwrap();
        let cam = VirtualCamera::new(p, PhysicalParams::default()).unwrap();
        let plan = CalibrationPlan {
            frames: 3,
            bias_exposures_s: vec![0.01],
            flat_levels_dn: vec![100.0, 200.0],
            blooming_exposures_s: vec![0.01],
            ..Default::default()
        };
        let dir = tempfile::tempdir().unwrap();
        let mut frames = 0;
        let m = plan
            .record(&cam, 5, dir.path(), "cam", "a test", || frames += 1)
            .unwrap();
        assert_eq!(frames, plan.total_frames());
        let back = Manifest::load(dir.path().join("calibration.toml")).unwrap();
        assert_eq!(
            (back.bias.len(), back.flat.len(), back.blooming.len()),
            (1, 2, 1)
        );
        assert_eq!(back.camera, "cam");
        // The second flat's third frame is the frame the plan's seed gives.
        let stack = &plan.stacks(&cam, 5).unwrap()[2];
        let mut r = emccd_io::open(dir.path().join(&m.flat[1].file)).unwrap();
        let mut got = vec![0f32; 48];
        for _ in 0..3 {
            assert!(r.read_frame(&mut got).unwrap());
        }
        let mut want = vec![0f32; 48];
        cam.exposure(0.01)
            .frame(&stack.photons, frame_seed(stack.seed, 2), &mut want);
        assert_eq!(got, want);
        // The truth beside it: the camera's own profile and its numbers.
        plan.write_truth(&cam, dir.path()).unwrap();
        let truth = emccd_profile::CameraProfile::load(dir.path().join("truth")).unwrap();
        assert_eq!(truth.fingerprint_hex(), cam.profile.fingerprint_hex());
        let text = std::fs::read_to_string(dir.path().join("truth.toml")).unwrap();
        assert_eq!(text, plan.truth_toml(&cam).unwrap());
    }

    #[test]
    fn a_test_pair_is_the_same_however_many_frames_are_drawn() {
        let p = emccd_profile::default_profile()
            .crop(emccd_profile::Roi::corner(16, 16))
            .unwrap();
        let cam = VirtualCamera::new(p, Default::default()).unwrap();
        let scene: Vec<f32> = (0..256).map(|i| (i % 16) as f32 / 15.0).collect();
        let level = PairLevel::from_ratio(1.6, 16000.0, 100.0);
        assert_eq!((level.exposure_s, level.photons), (0.016, 160.0));
        assert_eq!(level.pair_name("kodim01"), "kodim01_r100");
        let pair = cam.test_pair(&scene, level.photons, level.exposure_s, 9);
        let e = cam.exposure(level.exposure_s);
        let phot: Vec<f32> = scene.iter().map(|&v| v * 160.0).collect();
        assert_eq!(pair.truth, e.ground_truth(&phot));
        let (mut a, mut b) = (vec![0f32; 256], vec![0f32; 256]);
        pair.frame(3, &mut a);
        e.frame(&phot, frame_seed(9, 3), &mut b);
        assert_eq!(a, b);
        pair.frame(2, &mut b);
        assert_ne!(a, b, "frames differ");
    }
}
