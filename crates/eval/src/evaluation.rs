//! Scoring denoisers on folders of test pairs (what `emccd evaluate` runs): every method on
//! every pair of every camera, the per-pair [`Score`]s, the results document, and the panels a
//! person looks at (input | each method | ground truth).

use std::path::{Path, PathBuf};

use emccd_profile::CameraProfile;

use crate::virtual_pairs::Denoise;
use crate::{PairFrames, PairsManifest, Score, Summaries};

/// A folder of pairs (one camera) with the profile its frames are denoised through.
pub struct PairsDir {
    /// The folder holding `pairs.toml`.
    pub dir: PathBuf,
    /// The camera's name in tables ([`PairsManifest::camera_name`]).
    pub name: String,
    /// The manifest.
    pub manifest: PairsManifest,
    /// The profile: the one given, else the one `pairs.toml` names, else the bundled default.
    pub profile: CameraProfile,
}

impl PairsDir {
    /// Opens `dir` with the profile `profile` names (`--profile`: a directory or `default`),
    /// else the one its `pairs.toml` names, else the bundled default.
    pub fn open(dir: &Path, profile: Option<&str>) -> crate::Result<PairsDir> {
        let manifest = PairsManifest::load(dir)?;
        let load = |arg: &str, whose: String| {
            CameraProfile::load_arg(arg)
                .map_err(|e| format!("loading {whose}: {}", emccd_io::error_lines(&e).join(": ")))
        };
        let profile = match (profile, manifest.profile_arg(dir)) {
            (Some(p), _) => load(p, format!("profile {p}"))?,
            (None, Some(p)) => load(
                &p,
                format!(
                    "profile {p}, which {} names",
                    dir.join(PairsManifest::FILE).display()
                ),
            )?,
            (None, None) => load("default", "the bundled default profile".into())?,
        };
        Ok(PairsDir {
            dir: dir.to_path_buf(),
            name: manifest.camera_name(dir),
            manifest,
            profile,
        })
    }

    /// The prefix of this camera's panel files when several cameras share a folder: the name
    /// of the folder above the pairs (`lowlight-a/pairs` → `lowlight-a-`).
    fn panel_prefix(&self) -> String {
        let d = &self.dir;
        format!(
            "{}-",
            d.parent()
                .and_then(|d| d.file_name())
                .or(d.file_name())
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default()
        )
    }
}

/// A method under comparison: its name in tables and the denoiser that runs it.
pub struct Contender<'a> {
    /// Name (as `evaluate --method` was given it).
    pub name: &'a str,
    /// The denoiser: profile, raw frames (one, or a movie's) and exposure in, photo-signal in DN
    /// above bias out.
    pub run: Box<Denoise<'a>>,
    /// It estimates from a stack (photon counting): a still pair's every noisy frame goes in,
    /// and its first output frame is scored against the one truth.
    pub whole_stack: bool,
}

/// What [`evaluate`] measured: every pair's scores and their summary table.
#[derive(Clone, Debug)]
pub struct Evaluation {
    /// Per method, pair and camera.
    pub scores: Vec<Score>,
    /// Per method: overall, per light level and per camera.
    pub table: Summaries,
}

impl Evaluation {
    /// The results document (`results.json`, `evaluate --json`): conventions, the summary
    /// table and every pair's scores.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "psnr_data_range": "ground-truth peak per pair; psnr_paper_db: images / 65535, range 1 (the paper's convention)",
            "lpips": "not computed: its network weights cannot be obtained offline",
            "level_unit": self.table.unit.describe(),
            "summary": self.table.rows,
            "pairs": self.scores,
        })
    }
}

/// Runs every method on every pair of `cameras` and scores it against the ground truth (which
/// is used only to score). `out`: also write there (made if missing) a panel per pair, and
/// `results.json` ([`Evaluation::json`]) and `results.csv` (every pair's scores) at the end.
/// `tick` is called after each method on each pair (progress).
pub fn evaluate(
    cameras: &[PairsDir],
    methods: &[Contender],
    out: Option<&Path>,
    tick: &dyn Fn(),
) -> crate::Result<Evaluation> {
    // Every pair's files first, from their headers: a pair at fault stops the run before any
    // work and before anything is written.
    for cam in cameras {
        for p in &cam.manifest.pair {
            p.check(&cam.dir)?;
        }
    }
    let made = out.filter(|d| !d.exists());
    if let Some(dir) = out {
        std::fs::create_dir_all(dir).map_err(|e| format!("creating {}: {e}", dir.display()))?;
    }
    let r = evaluate_into(cameras, methods, out, tick);
    if r.is_err() {
        if let Some(d) = made {
            let _ = std::fs::remove_dir(d);
        }
    }
    r
}

/// [`evaluate`] once its inputs are checked and `out` exists: its files are staged beside their
/// targets and placed together at the end, so a failure part way leaves `out` as it was.
fn evaluate_into(
    cameras: &[PairsDir],
    methods: &[Contender],
    out: Option<&Path>,
    tick: &dyn Fn(),
) -> crate::Result<Evaluation> {
    let mut staged: Vec<emccd_io::Staged> = Vec::new();
    let mut scores = Vec::new();
    for cam in cameras {
        for p in &cam.manifest.pair {
            let frames = p.read(&cam.dir)?;
            let PairFrames {
                width: w,
                height: h,
                noisy: raw,
                ..
            } = &frames;
            let prof = cam
                .profile
                .top_left(*w, *h)
                .map_err(|e| format!("{}: {e}", p.noisy))?;
            // A still pair's whole noisy stack, for the methods that estimate from one.
            let stack = if frames.frames == 1 && methods.iter().any(|m| m.whole_stack) {
                Some(p.read_noisy_stack(&cam.dir)?)
            } else {
                None
            };
            let mut outputs: Vec<Vec<f32>> = Vec::with_capacity(methods.len());
            for m in methods {
                let t = std::time::Instant::now();
                let input = match (&stack, m.whole_stack) {
                    (Some(s), true) => s.as_slice(),
                    _ => raw.as_slice(),
                };
                let mut denoised = (m.run)(&prof, input, p.exposure_s)
                    .map_err(|e| format!("{} on {}: {e}", m.name, p.noisy))?;
                if input.len() != raw.len() && denoised.len() == input.len() {
                    denoised.truncate(raw.len());
                }
                if denoised.len() != raw.len() {
                    return Err(crate::Error(format!(
                        "{} on {}: {} values out for {} in",
                        m.name,
                        p.noisy,
                        denoised.len(),
                        raw.len()
                    )));
                }
                let seconds = t.elapsed().as_secs_f64();
                scores.push(Score::measure(
                    m.name, &cam.name, p, &frames, &denoised, seconds,
                ));
                outputs.push(denoised);
                tick();
            }
            if let Some(dir) = out {
                let prefix = if cameras.len() > 1 {
                    cam.panel_prefix()
                } else {
                    String::new()
                };
                staged.push(write_panel(dir, &prefix, p, &frames, &outputs)?);
            }
        }
    }
    let names: Vec<String> = methods.iter().map(|m| m.name.to_string()).collect();
    let cams: Vec<String> = cameras.iter().map(|c| c.name.clone()).collect();
    let ev = Evaluation {
        table: crate::scores::summarize(&scores, &names, &cams),
        scores,
    };
    if let Some(dir) = out {
        let io = |e: emccd_io::Error| crate::Error(emccd_io::error_lines(&e).join(": "));
        let json = serde_json::to_string_pretty(&ev.json()).map_err(|e| e.to_string())?;
        staged.push(emccd_io::stage_bytes(&dir.join("results.json"), json.as_bytes()).map_err(io)?);
        let csv = crate::scores::csv(&ev.scores);
        staged.push(emccd_io::stage_bytes(&dir.join("results.csv"), csv.as_bytes()).map_err(io)?);
        for s in staged {
            s.place().map_err(io)?;
        }
    }
    Ok(ev)
}

/// A 256² crop (the frame's centre; a movie's middle frame) of input | each method | ground
/// truth, side by side, as
/// `DIR/PREFIX<noisy file stem>.png`, scaled from 0 to the truth's peak.
fn write_panel(
    dir: &Path,
    prefix: &str,
    p: &crate::Pair,
    frames: &PairFrames,
    outs: &[Vec<f32>],
) -> crate::Result<emccd_io::Staged> {
    // A movie's middle frame.
    let (w, h, k) = (frames.width, frames.height, frames.frames / 2);
    let truth = frames.clean_frame(k);
    let at = k * w * h..(k + 1) * w * h;
    let c = 256.min(w).min(h);
    let panels: Vec<&[f32]> = outs
        .iter()
        .map(|o| &o[at.clone()])
        .chain(std::iter::once(truth))
        .collect();
    let n = panels.len();
    let img = crate::scores::side_by_side(&panels, w, ((w - c) / 2, (h - c) / 2), (c, c));
    let stem = Path::new(&p.noisy)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let path = dir.join(format!("{prefix}{stem}.png"));
    emccd_io::stage_png_preview(
        &path,
        n * c,
        c,
        &img,
        0.0,
        crate::scores::truth_peak(truth) as f32,
    )
    .map_err(|e| emccd_io::error_lines(&e).join(": ").into())
}
