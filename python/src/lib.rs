//! `emccd._emccd`: the emccd libraries on numpy arrays, for the `emccd` Python package.
//!
//! Only glue: every computation is a call into the workspace's libraries, so a frame denoised
//! here equals the CLI's for the same request. Long work runs with the interpreter released
//! (other Python threads — a napari viewer — go on) and reports to an optional callback;
//! errors are `emccd.EmccdError` with the CLI's message. The friendly signatures (dtype
//! conversion, 2-D or 3-D input, defaults) are in `emccd/__init__.py`.

use std::path::PathBuf;
use std::sync::Mutex;

use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

use emccd_camera::{PhysicalParams, VirtualCamera};
use emccd_denoise::{bundled, Method, Units};
use emccd_nn::Model;
use emccd_profile::CameraProfile;

create_exception!(
    _emccd,
    EmccdError,
    PyException,
    "An emccd error: bad input, a file that cannot be read or written, a model or profile that does not fit. The message is the one the `emccd` command prints."
);

/// The error as the CLI prints it (without its `error: ` prefix), causes on lines of their own.
fn err(e: impl Into<anyhow::Error>) -> PyErr {
    let e = e.into();
    EmccdError::new_err(emccd_io::error_lines(e.as_ref()).join("\n  caused by: "))
}

/// The device networks run on: `BURN_DEVICE` if set (the libraries take the device they are
/// given), else the GPU of a GPU build, else the CPU.
fn device() -> burn::prelude::Device {
    emccd_nn::device(std::env::var("BURN_DEVICE").ok().as_deref())
}

/// A model argument: a bundled model by name (built into the libraries), else a file.
fn load_model(arg: &str) -> emccd_nn::Result<Model> {
    bundled::load(arg, &device())
}

/// What a stack holds, as `emccd info --json` prints it (JSON text).
#[pyfunction]
fn info(py: Python<'_>, path: PathBuf) -> PyResult<String> {
    py.detach(|| {
        let r = emccd_io::open(&path).map_err(err)?;
        Ok(r.info().summary_json(&path).to_string())
    })
}

/// Every frame of a stack as float32 [frames, height, width], and its info (JSON text).
#[pyfunction]
fn read<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyArray3<f32>>, String)> {
    let (data, info) = py.detach(|| -> PyResult<_> {
        let mut r = emccd_io::open(&path).map_err(err)?;
        let i = r.info().clone();
        let n = i.frame_len();
        let mut data = vec![0f32; n * i.frames];
        for (k, frame) in data.chunks_mut(n.max(1)).enumerate() {
            if !r
                .read_frame(frame)
                .map_err(|e| err(anyhow::Error::from(e).context(path.display().to_string())))?
            {
                return Err(err(anyhow::anyhow!(
                    "{}: the file ended at frame {} of {}",
                    path.display(),
                    k + 1,
                    i.frames
                )));
            }
        }
        Ok((data, i))
    })?;
    let arr = Array3::from_shape_vec((info.frames, info.height, info.width), data)
        .map_err(|e| err(anyhow::anyhow!("{e}")))?;
    Ok((arr.into_pyarray(py), info.summary_json(&path).to_string()))
}

/// A stack read one frame at a time (bounded memory for stacks of any length).
#[pyclass(module = "emccd._emccd")]
struct Frames {
    reader: Mutex<Box<dyn emccd_io::FrameReader>>,
    path: PathBuf,
    info: emccd_io::StackInfo,
    next: usize,
}

#[pymethods]
impl Frames {
    #[new]
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Frames> {
        let reader = py.detach(|| emccd_io::open(&path)).map_err(err)?;
        let info = reader.info().clone();
        Ok(Frames {
            reader: Mutex::new(reader),
            path,
            info,
            next: 0,
        })
    }

    /// The stack's info as `emccd info --json` prints it (JSON text).
    #[getter]
    fn info_json(&self) -> String {
        self.info.summary_json(&self.path).to_string()
    }

    fn __len__(&self) -> usize {
        self.info.frames
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(
        mut slf: PyRefMut<'py, Self>,
        py: Python<'py>,
    ) -> PyResult<Option<Bound<'py, PyArray2<f32>>>> {
        if slf.next >= slf.info.frames {
            return Ok(None);
        }
        let (w, h) = (slf.info.width, slf.info.height);
        let k = slf.next;
        let path = slf.path.clone();
        let frame = {
            let this = &*slf;
            py.detach(|| -> PyResult<Option<Vec<f32>>> {
                let mut buf = vec![0f32; w * h];
                let mut r = this.reader.lock().map_err(|_| {
                    err(anyhow::anyhow!(
                        "the reader was poisoned by an earlier error"
                    ))
                })?;
                let got = r.read_frame(&mut buf).map_err(|e| {
                    err(anyhow::Error::from(e).context(format!(
                        "{}: frame {}",
                        path.display(),
                        k + 1
                    )))
                })?;
                Ok(got.then_some(buf))
            })?
        };
        match frame {
            Some(f) => {
                slf.next += 1;
                let arr =
                    Array2::from_shape_vec((h, w), f).map_err(|e| err(anyhow::anyhow!("{e}")))?;
                Ok(Some(arr.into_pyarray(py)))
            }
            None => Ok(None),
        }
    }
}

/// Writes float32 frames [frames, height, width] as a stack (`.tif`/`.tiff`, `.btf` BigTIFF,
/// `.fits`), atomically: `sample` is `float32`, `uint16` or `uint8` (rounded and clipped).
#[pyfunction]
#[pyo3(signature = (path, frames, sample, exposure_s=None, em_gain=None))]
fn write(
    py: Python<'_>,
    path: PathBuf,
    frames: PyReadonlyArray3<'_, f32>,
    sample: &str,
    exposure_s: Option<f64>,
    em_gain: Option<f64>,
) -> PyResult<()> {
    let sample = match sample {
        "float32" => emccd_io::SampleFormat::F32,
        "uint16" => emccd_io::SampleFormat::U16,
        "uint8" => emccd_io::SampleFormat::U8,
        s => {
            return Err(err(anyhow::anyhow!(
                "dtype {s}: emccd writes float32, uint16 or uint8 samples"
            )))
        }
    };
    let a = frames.as_array();
    let (f, h, w) = a.dim();
    let data: Vec<f32> = a.iter().copied().collect();
    py.detach(|| -> anyhow::Result<()> {
        let mut wr = emccd_io::StackWriter::create(&path, w, h, sample, Some(f))?;
        wr.set_metadata(&emccd_io::Metadata {
            exposure_s,
            em_gain,
            ..Default::default()
        });
        for frame in data.chunks(w * h) {
            wr.write_frame(frame)?;
        }
        wr.finish()?;
        Ok(())
    })
    .map_err(err)
}

/// A camera profile: the calibrated parameters and per-pixel maps.
#[pyclass(module = "emccd._emccd", frozen)]
#[derive(Clone)]
struct Profile {
    inner: CameraProfile,
}

#[pymethods]
impl Profile {
    /// Loads a profile folder, or `default` for the bundled iXon 897 profile.
    #[staticmethod]
    fn load(py: Python<'_>, path: String) -> PyResult<Profile> {
        py.detach(|| {
            let inner = CameraProfile::load_arg(&path).map_err(|e| {
                err(anyhow::Error::from(e).context(if path == "default" {
                    "loading the bundled default profile".to_string()
                } else {
                    format!("loading profile {path}")
                }))
            })?;
            Ok(Profile { inner })
        })
    }

    /// Writes the profile folder (profile.toml + maps.safetensors), atomically.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| {
            self.inner.save(&path).map_err(|e| {
                err(anyhow::Error::from(e)
                    .context(format!("writing the profile to {}", path.display())))
            })
        })
    }

    /// The same profile for a sub-array readout: x, y, width, height in pixels.
    fn crop(&self, x: usize, y: usize, width: usize, height: usize) -> PyResult<Profile> {
        Ok(Profile {
            inner: self
                .inner
                .crop(emccd_profile::Roi {
                    x,
                    y,
                    width,
                    height,
                })
                .map_err(err)?,
        })
    }

    /// Sensor width, px.
    #[getter]
    fn width(&self) -> usize {
        self.inner.width
    }
    /// Sensor height, px.
    #[getter]
    fn height(&self) -> usize {
        self.inner.height
    }
    /// Camera name.
    #[getter]
    fn camera(&self) -> String {
        self.inner.camera.clone()
    }
    /// EM gain setting.
    #[getter]
    fn em_gain(&self) -> f64 {
        self.inner.em_gain
    }
    /// Photon-transfer slope s = K·f², DN (None if not calibrated).
    #[getter]
    fn slope(&self) -> Option<f64> {
        self.inner.slope().ok()
    }
    /// Median bias at the shortest exposure, DN (None without bias frames).
    #[getter]
    fn bias_dn(&self) -> Option<f64> {
        self.inner.summary().bias_dn
    }
    /// Median read-noise std, DN (None without bias frames).
    #[getter]
    fn read_noise_dn(&self) -> Option<f64> {
        self.inner.summary().read_noise_dn
    }
    /// Quantization step, DN.
    #[getter]
    fn quantization_dn(&self) -> f64 {
        self.inner.quantization_dn
    }
    /// Calibrated exposures, s.
    #[getter]
    fn exposures_s(&self) -> Vec<f64> {
        self.inner.exposures_s.clone()
    }
    /// Content fingerprint (hex): what model files record as the profile they were trained for.
    #[getter]
    fn fingerprint(&self) -> String {
        self.inner.fingerprint_hex()
    }
    /// Everything `emccd profile show --json` prints (JSON text).
    fn summary_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.inner.summary()).map_err(err)
    }

    fn __repr__(&self) -> String {
        let s = self.inner.summary();
        format!(
            "Profile(camera={:?}, {}×{} px, EM gain {}, slope {}, fingerprint {})",
            s.camera,
            s.width,
            s.height,
            s.em_gain,
            s.ptc_slope_dn
                .map_or("not calibrated".into(), |v| format!("{v:.4} DN")),
            s.fingerprint
        )
    }
}

/// Calls a Python progress callback `(done, total)`; the first exception it raises is kept and
/// raised when the work returns (calibration cannot be stopped half-way; denoising stops).
struct Callback {
    f: Option<Py<PyAny>>,
    total: u64,
    done: std::sync::atomic::AtomicU64,
    error: Mutex<Option<PyErr>>,
}

impl Callback {
    fn new(f: Option<Py<PyAny>>, total: u64) -> Callback {
        Callback {
            f,
            total,
            done: 0.into(),
            error: Mutex::new(None),
        }
    }

    /// Advances by `n`; false once the callback has raised (or Ctrl-C was pressed).
    fn advance(&self, n: u64) -> bool {
        let done = self.done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n;
        Python::attach(|py| {
            let r = py.check_signals().and_then(|_| match &self.f {
                Some(f) => f.call1(py, (done, self.total)).map(|_| ()),
                None => Ok(()),
            });
            match r {
                Ok(()) => true,
                Err(e) => {
                    let mut slot = self.error.lock().unwrap_or_else(|p| p.into_inner());
                    slot.get_or_insert(e);
                    false
                }
            }
        })
    }

    fn take_error(&self) -> Option<PyErr> {
        self.error.lock().unwrap_or_else(|p| p.into_inner()).take()
    }
}

impl emccd_calib::Progress for Callback {
    fn advance(&self, frames: u64) {
        Callback::advance(self, frames);
    }
}

/// Calibrates a camera from a calibration manifest (TOML, as `emccd calibrate` takes), writes
/// the profile folder `out` (and the HTML report to `report`), and returns the profile. A
/// profile already in `out` is replaced only with `force`, as the CLI's `--force`.
#[pyfunction]
#[pyo3(signature = (manifest, out, report=None, progress=None, force=false))]
fn calibrate(
    py: Python<'_>,
    manifest: PathBuf,
    out: PathBuf,
    report: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
    force: bool,
) -> PyResult<Profile> {
    if !force && out.join("profile.toml").exists() {
        return Err(EmccdError::new_err(format!(
            "{}: already holds a camera profile (profile.toml); pass force=True to replace it",
            out.display()
        )));
    }
    let m = emccd_calib::Manifest::load(&manifest).map_err(err)?;
    let cb = Callback::new(progress, emccd_calib::total_frames(&m));
    let r = py.detach(|| -> anyhow::Result<CameraProfile> {
        let cal = emccd_calib::calibrate(&m, &emccd_calib::Options::default(), &cb)?;
        Ok(cal.save(&out, report.as_deref(), force)?)
    });
    if let Some(e) = cb.take_error() {
        return Err(e);
    }
    Ok(Profile {
        inner: r.map_err(err)?,
    })
}

/// The profile `raw` (whole frames of `w × h`) is read through, the exposure it was taken at
/// and the notes to issue: `profile` checked against the frames (refused where they disagree,
/// unless `force`), or, without one, the camera characterized from the frames themselves (at
/// `exposure_s`, or a nominal second where none is given: the profile holds one fixed pattern).
fn through(
    profile: Option<&Profile>,
    raw: &[f32],
    w: usize,
    h: usize,
    exposure_s: Option<f64>,
    force: bool,
) -> anyhow::Result<(CameraProfile, f64, Vec<String>)> {
    use emccd_calib::recording::{misfit_message, Frames, NOMINAL_EXPOSURE_S};
    const SOURCE: &str = "the frames given";
    let frames = Frames::in_memory(raw, w, h, exposure_s, SOURCE);
    let Some(profile) = profile else {
        let c = frames.characterize()?;
        let p = frames.profile(&c)?;
        let mut notes = vec![format!(
            "camera characterized from the frames (no profile given): {}",
            c.summary_line()
        )];
        notes.extend(c.notes.iter().cloned());
        return Ok((p, exposure_s.unwrap_or(NOMINAL_EXPOSURE_S), notes));
    };
    let mut p = profile.inner.clone();
    let exposure_s = match exposure_s {
        Some(t) => t,
        None if p.from_recording() && p.exposures_s.len() == 1 => p.exposures_s[0],
        None => anyhow::bail!(
            "the exposure is unknown: pass exposure_s (seconds; emccd.read returns the header's as meta['exposure_s'])"
        ),
    };
    let mut notes = Vec::new();
    if !force {
        let frames = Frames {
            exposure_s: Some(exposure_s),
            ..frames
        };
        match frames.misfit(&p) {
            Ok((off, _)) if !off.is_empty() => {
                anyhow::bail!("{}", misfit_message(SOURCE, &p.camera, &off, "force=True"))
            }
            // A smear the frames show goes into a profile without a blooming calibration, as
            // `emccd denoise` does.
            Ok((_, c)) => notes.extend(emccd_calib::recording::add_measured_smear(
                &mut p, &c, exposure_s,
            )),
            Err(why) => notes.push(format!("not checked against the profile: {why}")),
        }
    }
    Ok((p, exposure_s, notes))
}

/// Denoises raw frames [frames, height, width] (DN, the profile's size) taken with
/// `exposure_s`, as `emccd denoise` does: returns float32 frames in DN above bias or
/// photoelectrons, and the warnings the CLI would print. `method="temporal"` estimates each
/// frame from the `window` frames before and after it too (the frames are one recording).
#[pyfunction]
#[pyo3(signature = (frames, profile, exposure_s, model=None, method=None, units="dn", tile=512, overlap=32, ensemble=1, extrapolate=false, progress=None, window=None, cic=None, dark=None, force=false))]
#[allow(clippy::too_many_arguments)]
fn denoise<'py>(
    py: Python<'py>,
    frames: PyReadonlyArray3<'py, f32>,
    profile: Option<&Profile>,
    exposure_s: Option<f64>,
    model: Option<String>,
    method: Option<String>,
    units: &str,
    tile: usize,
    overlap: usize,
    ensemble: usize,
    extrapolate: bool,
    progress: Option<Py<PyAny>>,
    window: Option<usize>,
    cic: Option<f64>,
    dark: Option<f64>,
    force: bool,
) -> PyResult<(Bound<'py, PyArray3<f32>>, Vec<String>)> {
    let a = frames.as_array();
    let (f, h, w) = a.dim();
    let raw: Vec<f32> = a.iter().copied().collect();
    // Subtracted from a camera characterized from a recording (these frames, or a profile
    // `calibrate --from-recording` made); a calibrated or modeled profile holds or models its own.
    let recorded = profile.is_none_or(|p| p.inner.from_recording());
    let spurious = match (cic, dark) {
        (None, None) => None,
        (Some(c), Some(d)) if recorded => {
            emccd_profile::check_spurious(c, d).map_err(err)?;
            Some((c, d))
        }
        (Some(_), Some(_)) => return Err(err(anyhow::anyhow!(
            "cic and dark are for a camera characterized from a recording (no profile, or one `calibrate --from-recording` made): this profile's bias holds or models its own spurious charge"
        ))),
        _ => return Err(err(anyhow::anyhow!("cic and dark must be given together"))),
    };
    let exposure_given = exposure_s;
    let (mut p, exposure_s, mut notes) = py
        .detach(|| through(profile, &raw, w, h, exposure_s, force))
        .map_err(err)?;
    match spurious {
        Some((c, d)) => {
            let exposure = exposure_given.or(profile.map(|_| exposure_s));
            notes.push(
                emccd_calib::recording::remove_spurious(&mut p, c, d, exposure).map_err(err)?,
            )
        }
        None if recorded => notes.push("the clock-induced charge and dark current cannot be told from light in the frames: the output keeps them (pass cic and dark from the camera's data sheet to remove them)".into()),
        None => {}
    }
    let p = &p;
    let method = method
        .map(|m| m.parse::<Method>())
        .transpose()
        .map_err(err)?;
    let units: Units = units.parse().map_err(err)?;
    units.factor(p).map_err(err)?;
    emccd_nn::tile::Tiling::check_tile(tile)
        .map_err(|e| err(anyhow::anyhow!("tile {tile}: {e}")))?;
    emccd_denoise::check_ensemble(ensemble)
        .map_err(|e| err(anyhow::anyhow!("ensemble {ensemble}: {e}")))?;
    let cb = Callback::new(progress, f as u64);
    let r = py.detach(|| -> anyhow::Result<(Vec<f32>, Vec<String>)> {
        let mut warnings = Vec::new();
        let r = emccd_denoise::resolve(method, model.as_deref(), load_model)?;
        let window = r.window(window)?;
        let fd = r.denoiser(
            p,
            f,
            emccd_nn::tile::Tiling { tile, overlap },
            ensemble,
            units,
            window,
        )?;
        if let Some(wn) = p.check_frames(w, h, exposure_s, "exposure_s", extrapolate)? {
            warnings.push(wn);
        }
        if fd.model.is_some() {
            warnings.extend(r.profile_warning(p));
        }
        let mut out = Vec::with_capacity(raw.len());
        emccd_denoise::movie::denoise_slice(&fd, exposure_s, &raw, &mut |k, frame| {
            out.extend(frame);
            if !cb.advance(1) {
                return Err(emccd_nn::Error::Data(format!(
                    "stopped after frame {}",
                    k + 1
                )));
            }
            Ok(())
        })?;
        Ok((out, warnings))
    });
    if let Some(e) = cb.take_error() {
        return Err(e);
    }
    let (out, warnings) = r.map_err(err)?;
    notes.extend(warnings);
    let warnings = notes;
    let arr = Array3::from_shape_vec((f, h, w), out).map_err(|e| err(anyhow::anyhow!("{e}")))?;
    Ok((arr.into_pyarray(py), warnings))
}

/// Photon counting of raw frames [frames, h, w] (DN as the camera wrote them) through
/// `profile` at `exposure_s`, as `emccd count` does: returns the rate (photo-electrons per pixel
/// per frame) and its standard error, each [outputs, h, w] (one output per `per` frames, or one
/// for the whole stack), and notes (the threshold and what it predicts).
#[pyfunction]
#[pyo3(signature = (frames, profile, exposure_s, threshold="likelihood", per=None, analog=false, extrapolate=false, cic=None, dark=None, read_noise="auto", force=false))]
#[allow(clippy::too_many_arguments)]
#[allow(clippy::type_complexity)]
fn count<'py>(
    py: Python<'py>,
    frames: PyReadonlyArray3<'py, f32>,
    profile: Option<&Profile>,
    exposure_s: Option<f64>,
    threshold: &str,
    per: Option<usize>,
    analog: bool,
    extrapolate: bool,
    cic: Option<f64>,
    dark: Option<f64>,
    read_noise: &str,
    force: bool,
) -> PyResult<(
    Bound<'py, PyArray3<f32>>,
    Bound<'py, PyArray3<f32>>,
    Vec<String>,
)> {
    let threshold: emccd_count::Threshold = threshold
        .parse()
        .map_err(|e: String| err(anyhow::anyhow!(e)))?;
    let read_noise: emccd_count::ReadNoise = read_noise
        .parse()
        .map_err(|e: String| err(anyhow::anyhow!(e)))?;
    let a = frames.as_array();
    let (_, h, w) = a.dim();
    let raw: Vec<f32> = a.iter().copied().collect();
    let r = py.detach(
        || -> anyhow::Result<(Vec<f32>, Vec<f32>, usize, Vec<String>)> {
            let (p, exposure_s, mut notes) = through(profile, &raw, w, h, exposure_s, force)?;
            let p = &p;
            // A recording cannot tell spurious electrons from light: without the data
            // sheet's numbers they stay in the rate.
            let spurious = cic.zip(dark).or_else(|| {
                (p.from_recording() && p.pgn.is_none()).then(|| {
                    notes.push("the clock-induced charge and dark current cannot be told from light in a recording: the rate includes them (pass cic and dark from the camera's data sheet to remove them)".into());
                    (0.0, 0.0)
                })
            });
            if let Some(wn) = p.check_frames(w, h, exposure_s, "exposure_s", extrapolate)? {
                notes.push(wn);
            }
            let req = emccd_count::Request {
                threshold,
                per,
                analog,
                spurious,
                read_noise,
            };
            let c = emccd_count::count_stack(p, &raw, exposure_s, &req)?;
            notes.extend(c.notes);
            Ok((c.rate, c.error, c.outputs, notes))
        },
    );
    let (rate, se, outputs, notes) = r.map_err(err)?;
    let shape = (outputs, h, w);
    let rate = Array3::from_shape_vec(shape, rate).map_err(|e| err(anyhow::anyhow!("{e}")))?;
    let se = Array3::from_shape_vec(shape, se).map_err(|e| err(anyhow::anyhow!("{e}")))?;
    Ok((rate.into_pyarray(py), se.into_pyarray(py), notes))
}

/// Noisy/clean pairs from the virtual camera built on `profile`: `clean` (float32 [h, w], 0–1)
/// scaled so its brightest value collects `photons` photons per exposure, or so that the mean
/// pixel holds `mean_electrons` photoelectrons (through the camera's quantum efficiency); returns the raw
/// frames [frames, h, w] (DN, what the camera records) and the ground truth [h, w] (the
/// photo-signal, DN above bias). A scene smaller than the sensor uses its top-left sub-array.
#[pyfunction]
#[pyo3(signature = (clean, profile, photons, mean_electrons, exposure_s, frames=1, seed=0))]
#[allow(clippy::too_many_arguments)]
fn simulate_pairs<'py>(
    py: Python<'py>,
    clean: PyReadonlyArray2<'py, f32>,
    profile: &Profile,
    photons: Option<f64>,
    mean_electrons: Option<f64>,
    exposure_s: f64,
    frames: usize,
    seed: u64,
) -> PyResult<(Bound<'py, PyArray3<f32>>, Bound<'py, PyArray2<f32>>)> {
    let a = clean.as_array();
    let (h, w) = a.dim();
    let img: Vec<f32> = a.iter().copied().collect();
    let p = profile.inner.clone();
    let (noisy, truth) = py
        .detach(|| -> anyhow::Result<(Vec<f32>, Vec<f32>)> {
            if frames == 0 {
                anyhow::bail!("frames must be at least 1");
            }
            emccd_profile::check_exposure(exposure_s)
                .map_err(|e| anyhow::anyhow!("exposure_s: {e}"))?;
            if let Some(i) = img.iter().position(|v| !v.is_finite() || *v < 0.0) {
                anyhow::bail!(
                    "the clean scene holds {} at pixel ({}, {}); it must be finite and non-negative (0–1)",
                    img[i],
                    i % w,
                    i / w
                );
            }
            if w > p.width || h > p.height || w == 0 || h == 0 {
                anyhow::bail!(
                    "the scene is {w}×{h}; the profile's sensor is {}×{}",
                    p.width,
                    p.height
                );
            }
            let p = if (w, h) == (p.width, p.height) {
                p
            } else {
                p.crop(emccd_profile::Roi::corner(w, h))?
            };
            let cam = VirtualCamera::new(p, PhysicalParams::seeded(seed))?;
            let photons = match (photons, mean_electrons) {
                (Some(p), None) => p,
                (None, Some(e)) => cam.peak_photons(&img, e),
                _ => anyhow::bail!("give one of photons (at the brightest pixel) or mean_electrons (per pixel)"),
            };
            // Zero photons is a dark (bias) frame: shutter closed, the camera's own signal only.
            if !(photons.is_finite() && photons >= 0.0) {
                anyhow::bail!("{photons} photons at the brightest pixel: it must be a non-negative number (is the scene all zero?)");
            }
            let pair = cam.test_pair(&img, photons, exposure_s, seed);
            let mut noisy = vec![0f32; frames * w * h];
            for (k, out) in noisy.chunks_mut(w * h).enumerate() {
                pair.frame(k, out);
            }
            Ok((noisy, pair.truth))
        })
        .map_err(err)?;
    let noisy =
        Array3::from_shape_vec((frames, h, w), noisy).map_err(|e| err(anyhow::anyhow!("{e}")))?;
    let truth = Array2::from_shape_vec((h, w), truth).map_err(|e| err(anyhow::anyhow!("{e}")))?;
    Ok((noisy.into_pyarray(py), truth.into_pyarray(py)))
}

/// Two 2-D images of one shape, as (height, width) and row-major pixels.
fn image_pair(
    a: &PyReadonlyArray2<'_, f32>,
    b: &PyReadonlyArray2<'_, f32>,
) -> PyResult<((usize, usize), Vec<f32>, Vec<f32>)> {
    let (da, db) = (a.as_array().dim(), b.as_array().dim());
    if da != db {
        return Err(err(anyhow::anyhow!(
            "the images differ in shape: {da:?} and {db:?}"
        )));
    }
    let flat = |x: &PyReadonlyArray2<'_, f32>| x.as_array().iter().copied().collect();
    Ok((da, flat(a), flat(b)))
}

/// PSNR in dB of `test` against `reference` (2-D float32), with data range `data_range`.
#[pyfunction]
fn psnr(
    test: PyReadonlyArray2<'_, f32>,
    reference: PyReadonlyArray2<'_, f32>,
    data_range: f64,
) -> PyResult<f64> {
    let (_, t, r) = image_pair(&test, &reference)?;
    Ok(emccd_eval::psnr(&t, &r, data_range))
}

/// SSIM (Gaussian window σ = 1.5, as scikit-image with `gaussian_weights=True`) of `test`
/// against `reference` (2-D float32), with data range `data_range`.
#[pyfunction]
fn ssim(
    test: PyReadonlyArray2<'_, f32>,
    reference: PyReadonlyArray2<'_, f32>,
    data_range: f64,
) -> PyResult<f64> {
    let ((h, w), t, r) = image_pair(&test, &reference)?;
    Ok(emccd_eval::ssim(
        &t,
        &r,
        w,
        h,
        data_range,
        Default::default(),
    ))
}

/// The names of the bundled models and the denoising methods, the default method, and the
/// default on a movie (a 3-D stack of more than one frame).
#[pyfunction]
fn catalog() -> (
    Vec<&'static str>,
    Vec<&'static str>,
    &'static str,
    &'static str,
) {
    (
        bundled::BUNDLED.iter().map(|b| b.name).collect(),
        Method::ALL.iter().map(|m| m.name()).collect(),
        emccd_denoise::DEFAULT_METHOD.name(),
        emccd_denoise::DEFAULT_MOVIE_METHOD.name(),
    )
}

#[pymodule]
fn _emccd(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("EmccdError", m.py().get_type::<EmccdError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("DEFAULT_WINDOW", emccd_denoise::DEFAULT_WINDOW)?;
    m.add("MAX_WINDOW", emccd_denoise::MAX_WINDOW)?;
    m.add_class::<Frames>()?;
    m.add_class::<Profile>()?;
    m.add_function(wrap_pyfunction!(info, m)?)?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(write, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(denoise, m)?)?;
    m.add_function(wrap_pyfunction!(count, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_pairs, m)?)?;
    m.add_function(wrap_pyfunction!(psnr, m)?)?;
    m.add_function(wrap_pyfunction!(ssim, m)?)?;
    m.add_function(wrap_pyfunction!(catalog, m)?)?;
    Ok(())
}
