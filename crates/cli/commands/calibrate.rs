//! `emccd calibrate`: a camera's acquisitions → a camera profile and a report.

use std::path::PathBuf;

use anyhow::Result;
use emccd_calib::{Manifest, Options, Progress};

use crate::common::progress;

/// Calibrate a camera from its bias, flat-field, blooming and gain-series stacks.
///
/// MANIFEST is a TOML file naming the stacks (paths relative to it), in the form
/// `emccd simulate calibration` writes:
///
///   camera = "iXon Ultra 897"
///   em_gain = 300
///   [[bias]]      file = "bias_10ms.tif", exposure_s = 0.01   (one per exposure)
///   [[flat]]      file = "flat_01.tif",   exposure_s = 0.01   (one per light level)
///   [[blooming]]  file = "bloom_1ms.tif", exposure_s = 0.001  (bright source in one quadrant)
///   [gain_series] with [[gain_series.settings]] em_gain, file, offset_map + sigma_map or no_signal
///
/// exposure_s may be left out where the file's header records it (SIF). Any subset works:
/// flats alone give the photon-transfer slope, bias alone the FPN and read noise; what is missing
/// is reported and left out of the profile. Nothing is written unless every input is good.
///
/// Without a calibration acquisition, --from-recording FILE... characterizes the camera from
/// plain recordings (movies or single frames at EMCCD light levels, with some dark background):
/// the bias and read noise from the dark pixels' zero-electron peak and their differences, the
/// DN per photoelectron from a movie's temporal mean–variance (or, from one frame, from the EM
/// register's tail). Several files are one camera and readout, pooled.
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The calibration manifest (TOML).
    #[arg(
        required_unless_present = "from_recording",
        conflicts_with = "from_recording"
    )]
    pub manifest: Option<PathBuf>,
    /// Characterize the camera from these recordings instead of a calibration acquisition.
    #[arg(long, num_args = 1.., value_name = "FILE")]
    pub from_recording: Vec<PathBuf>,
    /// Output profile directory (profile.toml + maps.safetensors).
    #[arg(short, long)]
    pub out: PathBuf,
    /// Replace a profile already in the output directory.
    #[arg(long)]
    pub force: bool,
    /// Also write an HTML report (index.html, self-contained) and results.json here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    #[command(flatten)]
    pub options: Options,
}

struct Bar(indicatif::ProgressBar);
impl Progress for Bar {
    fn advance(&self, frames: u64) {
        self.0.inc(frames);
    }
}

pub fn run(a: Args) -> Result<()> {
    crate::common::refuse_replacing(&a.out, "profile.toml", "a camera profile", a.force)?;
    let Some(manifest) = &a.manifest else {
        return from_recording(&a);
    };
    let m = Manifest::load(manifest)?;
    let bar = Bar(progress(emccd_calib::total_frames(&m), "frames"));
    let cal = emccd_calib::calibrate(&m, &a.options, &bar);
    bar.0.finish_and_clear();
    let cal = cal?;
    for w in &cal.warnings {
        eprintln!("warning: {w}");
    }
    cal.save(&a.out, a.report.as_deref(), a.force)?;
    print!("{}", cal.summary());
    eprintln!("profile written to {}", a.out.display());
    if let Some(dir) = &a.report {
        eprintln!("report written to {}", dir.join("index.html").display());
    }
    Ok(())
}

/// `--from-recording`: the camera characterized from the recordings, written as a profile (and
/// a report).
fn from_recording(a: &Args) -> Result<()> {
    let paths: Vec<&std::path::Path> = a.from_recording.iter().map(PathBuf::as_path).collect();
    // The profile and the report are folders, replaced as a whole: no input may be one or lie
    // inside one, however the paths are spelled.
    let absolute = |p: &std::path::Path| -> PathBuf {
        std::fs::canonicalize(p)
            .or_else(|_| {
                let name = p.file_name().unwrap_or_default();
                let parent = p.parent().filter(|d| !d.as_os_str().is_empty());
                std::fs::canonicalize(parent.unwrap_or(std::path::Path::new(".")))
                    .map(|d| d.join(name))
            })
            .unwrap_or_else(|_| p.to_path_buf())
    };
    for out in std::iter::once(&a.out).chain(a.report.as_ref()) {
        let dir = absolute(out);
        if let Some(p) = paths.iter().find(|p| absolute(p).starts_with(&dir)) {
            anyhow::bail!(
                "{}: is an input (or inside one of the outputs); write the profile and report elsewhere",
                p.display()
            );
        }
    }
    let frames = emccd_calib::recording::read(&paths)?;
    let c = frames.characterize()?;
    let profile = frames.profile(&c)?;
    c.save(
        &profile,
        &frames.source,
        &a.out,
        a.report.as_deref(),
        a.force,
    )?;
    println!("{}: {}", frames.source, c.summary_line());
    for n in &c.notes {
        println!("  note: {n}");
    }
    eprintln!("profile written to {}", a.out.display());
    if let Some(dir) = &a.report {
        eprintln!("report written to {}", dir.join("index.html").display());
    }
    Ok(())
}
