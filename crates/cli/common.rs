//! Helpers shared by subcommands: loading profiles and recordings, progress bars.

use std::path::Path;

use anyhow::{Context, Result};
use emccd_profile::{CameraProfile, Recording};
use indicatif::{ProgressBar, ProgressStyle};

/// The device networks run on: `BURN_DEVICE` (`flex`, `vulkan`, `wgpu`) if set, else the GPU
/// of a GPU build when one answers, else the CPU (the libraries take the device they are given).
pub fn device() -> burn::prelude::Device {
    emccd_nn::device(std::env::var("BURN_DEVICE").ok().as_deref())
}

/// Loads a model argument (a bundled name or a file) onto [`device`].
pub fn load_model(arg: &str) -> emccd_nn::Result<emccd_nn::Model> {
    emccd_denoise::bundled::load(arg, &device())
}

/// Loads `--profile`: a directory, or `default` for the bundled profile.
pub fn load_profile(arg: &str) -> Result<CameraProfile> {
    CameraProfile::load_arg(arg).with_context(|| {
        if arg == "default" {
            "loading the bundled default profile".to_string()
        } else {
            format!("loading profile {arg}")
        }
    })
}

/// A progress bar for `len` items of `what`; hidden when stderr is not a terminal.
pub fn progress(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} {per_sec} ETA {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// The progress bar of a training run and the step callback that feeds it: the smoothed loss
/// and the latest validation PSNR. Without a terminal the bar is hidden and a line is logged at
/// every `every`-th step instead, with the seconds since the run started (learning curves
/// against wall-clock).
pub fn step_progress(
    steps: u64,
    every: u64,
) -> (ProgressBar, impl FnMut(&emccd_train::StepReport) -> bool) {
    let pb = ProgressBar::new(steps);
    pb.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} steps {msg} ETA {eta}")
            .expect("template")
            .progress_chars("=> "),
    );
    let every = every.max(1);
    let t0 = std::time::Instant::now();
    let bar = pb.clone();
    let report = move |r: &emccd_train::StepReport| {
        bar.set_position(r.step);
        let v = r.val_psnr.map_or(String::new(), |p| {
            format!(
                " val PSNR {:.2} dB (input {:.2})",
                p.denoised_db, p.noisy_db
            )
        });
        bar.set_message(format!("loss {:.5}{v}", r.loss));
        if bar.is_hidden() && (r.step % every == 0 || r.step == r.steps) {
            let t = t0.elapsed().as_secs_f64();
            eprintln!(
                "step {}/{}: loss {:.5}{v} at {t:.0} s",
                r.step, r.steps, r.loss
            );
        }
        true
    };
    (pb, report)
}

/// Opens a recording and checks it against the profile ([`Recording::open`]: `exposure_arg`
/// overrides the header's; outside the calibrated range only with `extrapolate`); its warnings
/// go to stderr.
pub fn open_recording(
    input: &Path,
    profile: &CameraProfile,
    exposure_arg: Option<f64>,
    extrapolate: bool,
) -> Result<Recording> {
    let r = Recording::open(input, profile, exposure_arg, "--exposure-s", extrapolate)?;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    Ok(r)
}

/// [`open_recording`] again, for a recording already opened (and its warnings printed) once.
pub fn reopen_recording(
    input: &Path,
    profile: &CameraProfile,
    exposure_arg: Option<f64>,
    extrapolate: bool,
) -> Result<Recording> {
    Ok(Recording::open(
        input,
        profile,
        exposure_arg,
        "--exposure-s",
        extrapolate,
    )?)
}

/// Refuses to write over an earlier result of `kind` in `dir` (known by its `marker` file)
/// unless `force`: a calibrated profile, an acquisition or a set of pairs is a person's work,
/// and a command run twice by mistake must not replace it.
pub fn refuse_replacing(dir: &Path, marker: &str, kind: &str, force: bool) -> Result<()> {
    if !force && dir.join(marker).exists() {
        anyhow::bail!(
            "{}: already holds {kind} ({marker}); pass --force to replace it",
            dir.display()
        );
    }
    Ok(())
}

/// Below this many photo-electrons per pixel per frame a stack is in the photon-counting
/// regime: `emccd count` removes the EM register's excess noise there.
pub const COUNTING_LEVEL: f64 = 0.2;

/// The note for a recording at `level` photo-electrons per pixel per frame, if it is in the
/// counting regime.
pub fn counting_note(level: f64) -> Option<String> {
    (level < COUNTING_LEVEL).then(|| {
        format!(
            "about {:.3} photo-electrons per pixel per frame: the photon-counting regime, where `emccd count` removes the EM register's excess noise (√2 in SNR)",
            level
        )
    })
}

/// How a recording is read through a camera profile: the flags `denoise`, `count` and `adapt`
/// share.
#[derive(clap::Args, Debug)]
pub struct RecordingArgs {
    /// Camera profile: a folder made by `emccd calibrate`, or `default` for the bundled iXon 897
    /// model. Without it the camera is characterized from the inputs themselves (their dark
    /// pixels' zero-electron peak and EM tail, a movie's mean–variance; all inputs together, so
    /// they must come from one camera at one setting) and the numbers are printed and recorded
    /// with the output. A profile given is checked against the inputs first.
    #[arg(long)]
    pub profile: Option<String>,
    /// Use --profile even where the inputs disagree with it (another bias, gain, read noise or EM
    /// gain than the profile's; refused otherwise).
    #[arg(long)]
    pub force: bool,
    /// Exposure in seconds, where the file header does not record it (overrides the header).
    #[arg(long, allow_negative_numbers = true)]
    pub exposure_s: Option<f64>,
    /// Accept exposures more than 2× outside the profile's calibrated range, with the fixed
    /// pattern extrapolated from the calibration's model (otherwise an error: the pattern there
    /// is a guess, and so is the output).
    #[arg(long)]
    pub extrapolate: bool,
    /// Clock-induced charge, e⁻ per pixel per frame, from the camera's data sheet (given with
    /// --dark). A recording cannot tell it, or the dark current, from light: without --profile
    /// they stay in the output unless given, and `denoise` and `adapt` then subtract them from
    /// the characterized bias. `count` takes them in place of a profile's own.
    #[arg(long, requires = "dark")]
    pub cic: Option<f64>,
    /// Dark current, e⁻ per pixel per second, with --cic.
    #[arg(long, requires = "cic")]
    pub dark: Option<f64>,
}

/// The camera profile a command reads its recordings through, and how it came about.
pub struct ChosenProfile {
    /// The profile.
    pub profile: CameraProfile,
    /// How messages and the outputs' provenance name it: the `--profile` argument, or
    /// [`CHARACTERIZED`].
    pub name: String,
    /// The characterization's one-line summary, where the camera was characterized from the
    /// inputs.
    pub summary: Option<String>,
    /// The spurious charge subtracted from its bias (`--cic`, `--dark`), in words.
    pub spurious: Option<String>,
    /// Frame-transfer smear measured on the inputs and put into a profile that had no blooming
    /// calibration ([`RecordingArgs::check_fit`]), in words.
    pub smear: Option<String>,
}

/// `text` in ASCII, as TIFF descriptions and FITS headers hold it: the units' and errors'
/// signs spelled out.
fn ascii(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '⁻' | '–' | '−' => out.push('-'),
            '±' => out.push_str("+/-"),
            '×' => out.push('x'),
            '²' => out.push_str("^2"),
            c if c.is_ascii() => out.push(c),
            _ => out.push('?'),
        }
    }
    out
}

/// The name of a profile characterized from a command's own inputs.
pub const CHARACTERIZED: &str = "characterized from the recording";

impl ChosenProfile {
    /// The lines the outputs record about it (a TIFF's description, a FITS header, a store's
    /// attributes).
    pub fn notes(&self) -> Vec<String> {
        let mut n = vec![format!("profile={}", self.name)];
        n.extend(
            self.summary
                .iter()
                .map(|s| format!("characterization={}", ascii(s))),
        );
        n.extend(
            self.spurious
                .iter()
                .map(|s| format!("spurious={}", ascii(s))),
        );
        n.extend(self.smear.iter().map(|s| format!("smear={}", ascii(s))));
        n
    }
}

impl RecordingArgs {
    /// The spurious electrons' sources given (`--cic`, `--dark`); the library that takes them
    /// checks them.
    pub fn spurious(&self) -> Option<(f64, f64)> {
        self.cic.zip(self.dark)
    }

    /// The profile for `inputs`: `--profile`'s, or, without one, the camera characterized from
    /// them (its summary printed). A given profile is checked against the inputs by
    /// [`RecordingArgs::check_fit`] once they have been opened through it.
    /// `subtract_spurious` (`denoise`, `adapt`): the spurious charge given (`--cic`, `--dark`)
    /// is subtracted from the bias of a camera characterized from a recording (these inputs, or
    /// a profile `calibrate --from-recording` made; [`emccd_calib::recording::remove_spurious`])
    /// and refused with a calibrated or modeled profile, which holds or models its own; without
    /// it, a note says that the output keeps it.
    pub fn choose_profile(
        &self,
        inputs: &[std::path::PathBuf],
        subtract_spurious: bool,
    ) -> Result<ChosenProfile> {
        use emccd_calib::recording::{remove_spurious, spurious_electrons};
        let paths: Vec<&Path> = inputs.iter().map(|p| p.as_path()).collect();
        let spurious = self.spurious().filter(|_| subtract_spurious);
        const KEPT: &str = "the clock-induced charge and dark current cannot be told from light in a recording: the output keeps them (pass --cic and --dark from the camera's data sheet to remove them)";
        let Some(arg) = &self.profile else {
            let mut frames = emccd_calib::recording::read(&paths)?;
            frames.exposure_s = self.exposure_s.or(frames.exposure_s);
            if let Some((cic, dark)) = spurious {
                spurious_electrons(cic, dark, frames.exposure_s)?;
            }
            let c = frames
                .characterize()
                .context("no --profile given, so the camera is characterized from the inputs")?;
            let mut profile = frames.profile(&c)?;
            let summary = c.summary_line();
            eprintln!(
                "{}: camera characterized from the recording (no --profile): {summary}",
                frames.source
            );
            for n in &c.notes {
                eprintln!("  note: {n}");
            }
            let removed = match spurious {
                Some((cic, dark)) => {
                    let said = remove_spurious(&mut profile, cic, dark, frames.exposure_s)?;
                    eprintln!("  {said}");
                    Some(said)
                }
                None => {
                    if subtract_spurious {
                        eprintln!("  note: {KEPT}");
                    }
                    None
                }
            };
            return Ok(ChosenProfile {
                profile,
                name: CHARACTERIZED.into(),
                summary: Some(summary),
                spurious: removed,
                smear: None,
            });
        };
        let mut profile = load_profile(arg)?;
        let mut removed = None;
        match spurious {
            Some(_) if !profile.from_recording() => anyhow::bail!(
                "--cic and --dark are for a camera characterized from a recording (no --profile, or one `calibrate --from-recording` made): profile {arg}'s bias holds or models its own spurious charge"
            ),
            Some((cic, dark)) => {
                // The profile's exposure is its recording's (or a nominal one where that
                // recorded none: then give --exposure-s for the dark current).
                let exposure = self.exposure_s.or(profile.exposures_s.first().copied());
                let said = remove_spurious(&mut profile, cic, dark, exposure)?;
                eprintln!("profile {arg}: {said}");
                removed = Some(said);
            }
            None if subtract_spurious && profile.from_recording() => eprintln!("note: {KEPT}"),
            None => {}
        }
        Ok(ChosenProfile {
            profile,
            name: arg.clone(),
            summary: None,
            spurious: removed,
            smear: None,
        })
    }

    /// Refuses `profile` where the inputs, characterized, disagree with it
    /// ([`emccd_calib::recording::Frames::misfit`]). Inputs that cannot be compared with it
    /// (bright everywhere, too small, another size) are let through with a note: opening them
    /// checks the rest. `add_smear` (`denoise`): a frame-transfer smear the inputs show goes
    /// into a profile without a blooming calibration
    /// ([`emccd_calib::recording::add_measured_smear`]), said and recorded.
    /// Call once the inputs have opened through the profile (their size and exposure checked),
    /// before anything is written; nothing to do for a profile characterized from them, or with
    /// `--force`.
    pub fn check_fit(
        &self,
        chosen: &mut ChosenProfile,
        inputs: &[std::path::PathBuf],
        add_smear: bool,
    ) -> Result<()> {
        if self.force || chosen.summary.is_some() {
            return Ok(());
        }
        let arg = chosen.name.clone();
        let paths: Vec<&Path> = inputs.iter().map(|p| p.as_path()).collect();
        let misfit = emccd_calib::recording::read(&paths).map(|mut f| {
            f.exposure_s = self.exposure_s.or(f.exposure_s);
            let exposure = f.checked_exposure(&chosen.profile);
            (f.misfit(&chosen.profile), f.source, exposure)
        });
        match misfit {
            Ok((Ok((off, _)), source, _)) if !off.is_empty() => anyhow::bail!(
                "{}",
                emccd_calib::recording::misfit_message(&source, &arg, &off, "--force")
            ),
            // Why, without its advice to pass a profile (one was given).
            Ok((Err(why), source, _)) => eprintln!(
                "note: {source}: not checked against profile {arg} ({})",
                why.split("; ").next().unwrap_or(&why)
            ),
            Err(e) => eprintln!("note: not checked against profile {arg} ({e})"),
            Ok((Ok((_, c)), source, Some(exposure))) if add_smear => {
                if let Some(said) =
                    emccd_calib::recording::add_measured_smear(&mut chosen.profile, &c, exposure)
                {
                    eprintln!("{source}: {said}");
                    chosen.smear = Some(said);
                }
            }
            Ok(_) => {}
        }
        Ok(())
    }

    /// Opens `input` through `profile` ([`open_recording`]: its warnings printed).
    pub fn open(&self, input: &Path, profile: &CameraProfile) -> Result<Recording> {
        open_recording(input, profile, self.exposure_s, self.extrapolate)
    }

    /// Opens `input` again, quietly ([`reopen_recording`]).
    pub fn reopen(&self, input: &Path, profile: &CameraProfile) -> Result<Recording> {
        reopen_recording(input, profile, self.exposure_s, self.extrapolate)
    }
}
