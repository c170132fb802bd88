//! `emccd count`: photon counting.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use emccd_count::{Camera, Counter, Threshold};

use emccd_io::zarr::{Shard, ZarrStackSpec, ZarrStackWriter};
use serde_json::json;

use crate::common::{progress, ChosenProfile, RecordingArgs};

/// Count photons: below a few tenths of a photo-electron per pixel per frame (faint sources,
/// single molecules at high frame rates), read every preprocessed pixel of every frame as a
/// number of electrons rather than a signal, and turn N frames into photo-electrons per pixel
/// per frame. This removes the EM register's excess noise (√2 in SNR) where the light is
/// faintest. By default each value falls into one of 30 bins and each pixel's rate is the most
/// likely one under the camera's exact model — the register's output for 0, 1, 2, … electrons
/// plus read noise, coincidences, clock-induced charge and dark current (which `emccd calibrate`
/// measures); `--threshold auto|<k>sigma|<n>DN` counts events above one threshold instead and
/// inverts their probability, its small-sample bias removed. Either is unbiased, and its standard
/// error can be written beside it (--uncertainty). Frames are preprocessed as `denoise` does
/// (blooming and the fixed pattern at the exposure removed); bright and hot pixels take the
/// analog mean (--analog), which the command also writes on its own, to compare.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Raw stacks (TIFF/BigTIFF, SIF, FITS, Zarr).
    #[arg(required = true, num_args = 1..)]
    pub inputs: Vec<PathBuf>,
    /// Output file (one input; .tif, .btf, .fits, or an OME-Zarr store .zarr that several
    /// processes can fill at once: --shard) or directory (several inputs: NAME_count.tif each).
    #[arg(short, long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub recording: RecordingArgs,
    /// How each frame's pixel is read: `likelihood` (the default: no single threshold — each
    /// value falls into one of 30 bins, half a read-noise σ wide near the bias and half the
    /// register's gain above, and the rate is the one that makes each pixel's bins most likely
    /// under the camera's exact model; +0.1 to +0.9 dB over the best single threshold), `auto`
    /// (one threshold, k times each pixel's read noise, k chosen to make the rate's error
    /// smallest at the stack's own light level), `<k>sigma` (e.g. 3sigma) or `<n>DN` (the same
    /// DN above bias for every pixel).
    #[arg(long, default_value = "likelihood")]
    pub threshold: Threshold,
    /// One output frame per N input frames (the last one from what is left).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..), conflicts_with = "all")]
    pub per: Option<u32>,
    /// One output frame from the whole stack (the default).
    #[arg(long)]
    pub all: bool,
    /// Also write each output frame's standard error per pixel here (one input only; a .zarr
    /// store beside a .zarr output).
    #[arg(long, value_name = "FILE")]
    pub uncertainty: Option<PathBuf>,
    /// Count only share I of N of the output frames (I from 0) into a .zarr output that N
    /// processes write at once (a SLURM array task: --shard $SLURM_ARRAY_TASK_ID/N). Output
    /// frames already complete are skipped, so a killed shard is resumed by running it again;
    /// every shard chooses the same threshold (from the stack's first frames).
    #[arg(long, value_name = "I/N")]
    pub shard: Option<Shard>,
    /// Each pixel's read noise: `camera` (one for every pixel: the calibration's fit beneath the
    /// spurious charge, as an EMCCD reads every pixel through one amplifier), `pixel` (each
    /// pixel's std map at the exposure, which also holds the few spurious events its bias
    /// frames caught) or `auto`: `pixel` where the profile's maps at two exposures agree pixel
    /// by pixel (a sensor whose read noise has a texture of its own), else `camera`.
    #[arg(long, default_value = "auto", value_name = "auto|camera|pixel")]
    pub read_noise: emccd_count::ReadNoise,
    /// Write the analog estimate instead (each pixel's mean signal over the register's gain,
    /// less the spurious electrons), to compare with counting.
    #[arg(long)]
    pub analog: bool,
}

/// One input, checked and ready: its camera at its exposure and its light level.
struct Job {
    input: PathBuf,
    out: PathBuf,
    frames: usize,
    exposure: f64,
    camera: Camera,
    /// Photo-electrons per pixel per frame over the first frames (the analog mean, less the
    /// spurious electrons): what `auto` chooses its threshold at.
    level: f64,
}

pub fn run(a: Args) -> Result<()> {
    let several = a.inputs.len() > 1;
    if several && a.uncertainty.is_some() {
        bail!("--uncertainty names one file: give one input");
    }
    let is_zarr = |p: &Path| emccd_io::Format::from_extension(p) == Some(emccd_io::Format::Zarr);
    let zarr = is_zarr(&a.out);
    if a.shard.is_some() && !zarr {
        bail!("--shard needs a .zarr output (-o OUT.zarr): only a Zarr store is written by several processes at once");
    }
    if zarr && several {
        bail!(
            "{}: a .zarr output holds one counted stack: give one input (or a folder, -o DIR, for NAME_count.tif each)",
            a.out.display()
        );
    }
    if let Some(u) = &a.uncertainty {
        if is_zarr(u) != zarr {
            bail!(
                "--uncertainty {}: {}",
                u.display(),
                if zarr {
                    "beside a .zarr output it is a .zarr store too (each shard writes its share of both)"
                } else {
                    "a .zarr store goes beside a .zarr output (-o OUT.zarr); here give .tif, .btf or .fits"
                }
            );
        }
    }
    if several && a.out.exists() && !a.out.is_dir() {
        bail!(
            "{}: is a file; several inputs are written into a folder (-o FOLDER), one NAME_count.tif each",
            a.out.display()
        );
    }
    let outs = if zarr {
        // A store is a folder, resumed or shared by design; it is never its input.
        for i in &a.inputs {
            emccd_io::refuse_overwrite(&a.out, i, "the input")?;
        }
        vec![a.out.clone()]
    } else {
        emccd_io::output_paths(&a.inputs, &a.out, several.then_some("_count.tif"))?
    };
    if let Some(u) = &a.uncertainty {
        for p in a.inputs.iter().chain([&a.out]) {
            emccd_io::refuse_overwrite(u, p, "an input or the output")?;
        }
    }
    let given = a.recording.spurious();
    if let Some((cic, dark)) = given {
        emccd_profile::check_spurious(cic, dark)?;
    }
    let mut chosen = a.recording.choose_profile(&a.inputs, false)?;
    let profile = &chosen.profile;
    // A recording cannot tell spurious electrons from light: without the data sheet's numbers
    // they stay in the rates, and the output says so.
    let spurious = given.or_else(|| {
        (profile.from_recording() && profile.pgn.is_none()).then(|| {
            eprintln!("note: the clock-induced charge and dark current cannot be told from light in a recording: the rates include them (pass --cic and --dark from the camera's data sheet to remove them)");
            (0.0, 0.0)
        })
    });
    // Every input checked before anything is written: its header, size, exposure, the
    // profile's numbers at that exposure, --per against its length, and its first frames (read
    // for the light level).
    let mut jobs = Vec::with_capacity(a.inputs.len());
    for (input, out) in a.inputs.iter().zip(outs) {
        let mut rec = a.recording.open(input, profile)?;
        let camera = Camera::from_profile(profile, rec.exposure, spurious, a.read_noise)
            .map_err(|e| anyhow::anyhow!("profile {}: {e}", chosen.name))?;
        if let Some(n) = a.per {
            if n as usize > rec.info.frames {
                bail!(
                    "{}: --per {n} is more than the stack's {} frames",
                    input.display(),
                    rec.info.frames
                );
            }
        }
        let level = emccd_count::light_level(profile, &mut rec, emccd_count::LEVEL_FRAMES)?
            - camera.unremoved();
        emccd_count::check_level(level, &camera)
            .map_err(|e| anyhow::anyhow!("{}: {e}", input.display()))?;
        jobs.push(Job {
            input: input.clone(),
            out,
            frames: rec.info.frames,
            exposure: rec.exposure,
            camera,
            level,
        });
    }
    a.recording.check_fit(&mut chosen, &a.inputs, false)?;
    if zarr {
        return count_zarr(&a, &chosen, &jobs[0]);
    }
    let made = several && !a.out.exists();
    if several {
        std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    }
    let done = count_all(&a, &chosen, &jobs);
    if done.is_err() && made {
        let _ = std::fs::remove_dir(&a.out); // only if empty: it was made for this run
    }
    done
}

/// Counts every job into staged files; places them all once every one is done.
fn count_all(a: &Args, chosen: &ChosenProfile, jobs: &[Job]) -> Result<()> {
    let mut staged = Vec::new();
    let mut summaries = Vec::new();
    for job in jobs {
        let (files, summary) = count_one(a, chosen, job)?;
        staged.extend(files);
        summaries.push(summary);
    }
    for file in staged {
        file.place()?;
    }
    for s in summaries {
        eprintln!("{s}");
    }
    Ok(())
}

/// What a run tells: the output's notes (units, threshold, predictions) and, for the summary,
/// the threshold and the predicted false-event and missed-electron rates.
struct Described {
    notes: Vec<String>,
    threshold: String,
    /// What the threshold predicts (false events, missed electrons), in words.
    prediction: String,
    per: usize,
    outputs: usize,
}

/// Input frames per output frame: `--per`, else the whole stack.
fn per(a: &Args, job: &Job) -> usize {
    a.per.map_or(job.frames, |n| n as usize)
}

/// Describes `counter`'s plan for `job`, warning of a fixed threshold below 3σ.
fn describe(a: &Args, job: &Job, counter: &Counter) -> Described {
    let cam = &job.camera;
    let per = per(a, job);
    let plan = counter.plan();
    let (false_events, missed) = plan.predicted();
    let sigma = cam.median_sigma();
    let threshold = match plan.k_sigma {
        Some(k) => Threshold::Sigma(k),
        None => a.threshold,
    };
    let below_3 = match threshold {
        Threshold::Sigma(k) => k < 3.0,
        Threshold::Dn(d) => d < 3.0 * sigma,
        Threshold::Auto | Threshold::Likelihood => false,
    };
    if below_3 && a.threshold != Threshold::Auto {
        eprintln!(
            "warning: {}: a threshold below 3 read-noise σ ({sigma:.2} DN) counts read noise: a predicted {} false events per pixel per frame (the events it subtracts as background)",
            job.input.display(),
            number(false_events)
        );
    }
    let (described, ascii) = match (threshold, plan.k_sigma) {
        (Threshold::Likelihood, _) => (
            format!(
                "none (each pixel's values in {} bins, the most likely rate)",
                emccd_count::likelihood::BINS
            ),
            "none (likelihood)".to_string(),
        ),
        (Threshold::Dn(d), _) => (format!("{} DN", number(d)), format!("{} DN", number(d))),
        (_, Some(k)) => (
            format!("{k:.2} σ (median {:.2} DN)", k * sigma),
            format!("{k:.2} sigma (median {:.2} DN)", k * sigma),
        ),
        _ => unreachable!("a threshold is in σ or in DN"),
    };
    let mut notes = vec![
        format!(
            "units=photo-electrons per pixel per frame ({})",
            if a.analog {
                "analog mean"
            } else {
                "photon counting"
            }
        ),
        format!("threshold={ascii}"),
        format!("frames_per_output={per}"),
    ];
    // What one threshold predicts; the likelihood has none.
    if threshold != Threshold::Likelihood {
        notes.push(format!("false_events_per_frame={}", number(false_events)));
        notes.push(format!("single_electron_missed={:.4}", missed));
    }
    notes.extend([
        format!("em_dn_per_electron={}", number(cam.g)),
        format!("spurious_electrons_per_frame={}", number(cam.spurious)),
        format!("read_noise={:?}", cam.read_noise).to_lowercase(),
        format!("hot_pixels={}", cam.hot.len()),
    ]);
    let prediction = if threshold == Threshold::Likelihood {
        "every value weighed by the camera's model".to_string()
    } else {
        format!(
            "predicted {} false events per pixel per frame, one photo-electron missed {:.0} % of the time",
            number(false_events),
            100.0 * missed
        )
    };
    Described {
        notes,
        threshold: described,
        prediction,
        per,
        outputs: job.frames.div_ceil(per),
    }
}

/// A counter for `job` as the arguments ask.
fn counter(a: &Args, job: &Job) -> Result<Counter> {
    Ok(Counter::new(
        job.camera.clone(),
        a.threshold,
        job.level,
        per(a, job),
        job.frames,
        a.analog,
    )?)
}

/// A standard error for a file: a pixel with an event in every frame has no finite error and
/// is written as the largest float, so readers see a number.
fn finite(se: &[f32]) -> Vec<f32> {
    se.iter()
        .map(|&v| if v.is_finite() { v } else { f32::MAX })
        .collect()
}

fn count_one(
    a: &Args,
    chosen: &ChosenProfile,
    job: &Job,
) -> Result<(Vec<emccd_io::Staged>, String)> {
    let profile = &chosen.profile;
    let (cam, level) = (&job.camera, job.level);
    let mut counter = counter(a, job)?;
    let d = describe(a, job, &counter);
    let (per, outputs) = (d.per, d.outputs);
    let create = |path: &Path| -> Result<emccd_io::StackWriter> {
        let mut w = emccd_io::StackWriter::create(
            path,
            cam.width,
            cam.height,
            emccd_io::SampleFormat::F32,
            Some(outputs),
        )?;
        w.set_metadata(&emccd_io::Metadata {
            exposure_s: Some(job.exposure),
            ..Default::default()
        });
        w.set_notes(&[d.notes.clone(), chosen.notes()].concat());
        Ok(w)
    };
    let mut rate_w = create(&job.out)?;
    let mut se_w = a.uncertainty.as_deref().map(create).transpose()?;
    let mut rec = a.recording.reopen(&job.input, profile)?;
    let pb = progress(job.frames as u64, "frames");
    let mut mean_rate = 0.0;
    let io = |e: emccd_io::Error| emccd_count::Error(e.to_string());
    let r = emccd_count::count_outputs(
        profile,
        &mut rec,
        &mut counter,
        0..outputs,
        |_| false,
        |_, rate, se| {
            mean_rate += rate.iter().map(|&v| v as f64).sum::<f64>() / rate.len() as f64;
            rate_w.write_frame(rate).map_err(io)?;
            if let Some(w) = &mut se_w {
                w.write_frame(&finite(se)).map_err(io)?;
            }
            Ok(())
        },
        || pb.inc(1),
    );
    pb.finish_and_clear();
    r?;
    let mut files = vec![rate_w.finish_staged()?];
    if let Some(w) = se_w {
        files.push(w.finish_staged()?);
    }
    let mean_rate = mean_rate / outputs as f64;
    let share = counter.analog_share();
    let mixed = if share > 0.0 && !a.analog {
        format!(
            "; {:.1} % of the pixels (of the last output frame: bright or hot ones) took their analog mean, the better estimate there",
            100.0 * share
        )
    } else {
        String::new()
    };
    let summary = format!(
        "{} → {}: {} frames into {outputs} output frame{} of {per}; threshold {}; {}{mixed}; mean rate {} photo-electrons per pixel per frame ({}).{}",
        job.input.display(),
        job.out.display(),
        job.frames,
        if outputs == 1 { "" } else { "s" },
        d.threshold,
        d.prediction,
        number(mean_rate),
        if a.analog { "analog" } else { "counted" },
        regime(level, a.threshold),
    );
    Ok((files, summary))
}

/// A note where the light is bright enough that counting may not pay: above 0.5 e⁻ per pixel
/// per frame for one threshold, above 1 for the likelihood (measured ahead of the analog mean up
/// to 1 on both cameras of the suite, and not beyond).
fn regime(level: f64, threshold: Threshold) -> String {
    let (pays, measured) = match threshold {
        Threshold::Likelihood => (1.0, "was measured ahead of it up to 1"),
        _ => (0.5, "pays below about 0.5"),
    };
    if level > pays {
        format!(" At {} e⁻ per pixel per frame the analog mean (--analog) is likely as good: counting {measured}.", number(level))
    } else {
        String::new()
    }
}

/// Counts this process's share of the output frames into the OME-Zarr store `-o` (and the
/// standard errors into `--uncertainty`'s), skipping output frames already complete there.
/// A store this run made alone and could not finish because of the data is removed; one
/// stopped while writing (a full disk) stays to be resumed, as a shard's does.
fn count_zarr(a: &Args, chosen: &ChosenProfile, job: &Job) -> Result<()> {
    let profile = &chosen.profile;
    let shard = a.shard.unwrap_or(Shard::ALL);
    let mut counter = counter(a, job)?;
    let d = describe(a, job, &counter);
    let mut input = serde_json::to_value(emccd_io::FileStamp::of(&job.input)?)?;
    input["frames"] = job.frames.into();
    input["exposure_s"] = job.exposure.into();
    let made_of = |what: &str| {
        json!({
            "software": format!("emccd {}", env!("CARGO_PKG_VERSION")),
            "command": "count",
            "values": what,
            "input": input,
            "profile_fingerprint": profile.fingerprint_hex(),
            "threshold": format!("{:?}", a.threshold),
            "frames_per_output": d.per,
            "analog": a.analog,
            "read_noise": format!("{:?}", a.read_noise),
            "cic_e": a.recording.cic,
            "dark_e_per_s": a.recording.dark,
        })
    };
    let spec = |path: &Path, what: &str| ZarrStackSpec {
        width: job.camera.width,
        height: job.camera.height,
        frames: d.outputs,
        name: path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        provenance: made_of(what),
        notes: json!({
            "input": job.input.display().to_string(),
            "profile": chosen.name,
            "characterization": chosen.summary,
            "notes": d.notes,
        }),
    };
    let open = |path: &Path, what: &str| -> Result<(ZarrStackWriter, bool)> {
        if !path.exists() {
            let bytes = (d.outputs as u64) * (job.camera.width * job.camera.height) as u64 * 4;
            emccd_io::check_room(path, bytes + (1 << 16))?;
        }
        Ok(ZarrStackWriter::create_or_open(path, &spec(path, what))?)
    };
    // What this run made alone goes again if it cannot start or cannot finish because of the
    // data; a store stopped while writing (a full disk) stays to be resumed, as a shard's does.
    let discard = |made_rate: bool, made_se: bool| {
        if shard != Shard::ALL {
            return;
        }
        if made_rate {
            let _ = std::fs::remove_dir_all(&a.out);
        }
        if let (true, Some(u)) = (made_se, &a.uncertainty) {
            let _ = std::fs::remove_dir_all(u);
        }
    };
    let (rate_store, made_rate) = open(&a.out, "photo-electrons per pixel per frame")?;
    let se_store = match &a.uncertainty {
        Some(u) => match open(u, "standard error, photo-electrons per pixel per frame") {
            Ok(s) => Some(s),
            Err(e) => {
                discard(made_rate, false);
                return Err(e);
            }
        },
        None => None,
    };
    let made_se = se_store.as_ref().is_some_and(|s| s.1);
    let range = shard.range(d.outputs);
    let mut rec = match a.recording.reopen(&job.input, profile) {
        Ok(r) => r,
        Err(e) => {
            discard(made_rate, made_se);
            return Err(e);
        }
    };
    let pb = progress(
        (range.end.min(d.outputs) * d.per).min(job.frames) as u64
            - (range.start * d.per).min(job.frames) as u64,
        "frames",
    );
    let mut wrote_failed = false;
    let r = emccd_count::count_outputs(
        profile,
        &mut rec,
        &mut counter,
        range.clone(),
        |k| rate_store.is_done(k) && se_store.as_ref().is_none_or(|s| s.0.is_done(k)),
        |k, rate, se| {
            let w = (|| {
                if !rate_store.is_done(k) {
                    rate_store.write_frame(k, rate)?;
                }
                if let Some((s, _)) = &se_store {
                    if !s.is_done(k) {
                        s.write_frame(k, &finite(se))?;
                    }
                }
                Ok::<_, emccd_io::Error>(())
            })();
            wrote_failed |= w.is_err();
            w.map_err(|e| emccd_count::Error(e.to_string()))
        },
        || pb.inc(1),
    );
    pb.finish_and_clear();
    let written = match r {
        Ok(n) => n,
        Err(e) => {
            if !wrote_failed {
                drop(se_store);
                drop(rate_store);
                discard(made_rate, made_se);
            }
            return Err(e.into());
        }
    };
    let share = if shard.count > 1 {
        format!("shard {}/{}: ", shard.index, shard.count)
    } else {
        String::new()
    };
    if range.is_empty() {
        eprintln!(
            "{share}no output frames: {} shards for {} output frames leave this one empty",
            shard.count, d.outputs
        );
        return Ok(());
    }
    let done = rate_store.done_count();
    eprintln!(
        "{share}{} → {}: output frames {}–{} of {} input frames each ({written} counted now, {} were already done); {done} of {} complete{}; threshold {}; {}.{}",
        job.input.display(),
        a.out.display(),
        range.start + 1,
        range.end,
        d.per,
        range.len() - written,
        d.outputs,
        if done < d.outputs { " (the other shards write the rest)" } else { "" },
        d.threshold,
        d.prediction,
        regime(job.level, a.threshold),
    );
    Ok(())
}

/// A rate or probability for a person: three significant digits.
fn number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        format!("{v}")
    } else if v.abs() >= 0.01 && v.abs() < 1e4 {
        format!("{}", (v * 1e3).round() / 1e3)
    } else {
        format!("{v:.2e}")
    }
}
