//! `emccd denoise`: raw EMCCD recordings → denoised photo-signal.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use emccd_denoise::stack::{denoise_to_zarr, ZarrOutput};
use emccd_denoise::{Method, Resolved, Units};
use emccd_io::zarr::Shard;
use emccd_nn::tile::Tiling;

use crate::common::{progress, ChosenProfile, RecordingArgs};

/// Denoise raw EMCCD frames: remove blooming and the fixed pattern with the camera profile (paper
/// eq. 4; without --profile the camera is characterized from the inputs themselves), then denoise. By default a recording of several frames (a movie) runs `temporal`: each
/// frame estimated from the 12 before and after it too (blocks tracked along the motion, averaged,
/// denoised at the mean's noise), or from the 3 nearest each side where the frame's own data, held
/// out of both, finds them clearly better (a deforming scene); above `blend` on every kind of
/// motion of the movie suite, docs/results.md. A single frame runs `blend`: BM3D with iterative
/// variance stabilization (`ivst`) and the bundled `lowlight` network, averaged, the most accurate
/// method this build ships at low light (measured on the low-light suite, docs/results.md: +0.48 dB
/// over plain BM3D + GAT, above it and above `ivst` at every light level); `--method ivst` is the
/// classical half alone, `--method bm3d` one plain BM3D + GAT pass, `--method hybrid` refines
/// BM3D's estimate with the bundled `hybrid` network, `--method net` runs a network alone (the
/// `lowlight` network unless --model names another; fastest), `--method temporal` estimates each
/// frame of a stack from its neighbours too (`--window`; blocks tracked along the motion, averaged,
/// denoised by `ivst` at the mean's noise), `--method temporal-net` by the bundled temporal network
/// (`movie`: each frame and the 2 before and after it; shown only the frame's scene, at its
/// brightness; a fifth to a seventh of `temporal`'s time, 2.3–2.5 dB behind it on the 256² movie
/// suite), `--method none` only preprocesses. TIFF/BigTIFF, SIF, FITS and Zarr in (stacks are
/// streamed frame by frame); float32 TIFF, FITS or OME-Zarr out (by the output's extension), in DN
/// above bias by default. The exposure comes from the file header (SIF, emccd TIFF) or
/// --exposure-s.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Raw frames or stacks.
    #[arg(required = true, num_args = 1..)]
    pub inputs: Vec<PathBuf>,
    /// Output file (one input) or directory (several; each written as NAME_denoised.tif), or an
    /// OME-Zarr store `OUT.zarr` (all inputs as one stack of float32 frames, one chunk per
    /// frame, with what made it in the attributes; an existing store made by the same command
    /// is resumed, one made by another is refused).
    #[arg(short, long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub recording: RecordingArgs,
    /// Model file, or a bundled model: `hybrid` (BM3D-refining), `default` (a network trained on
    /// natural images), `microscopy` (fine-tuned on fluorescence microscopy) or `lowlight`
    /// (trained for 0.3–30 mean photoelectrons per pixel on many cameras: the best network at
    /// low light, docs/results.md), or `movie` (the temporal network of --method temporal-net).
    /// All are built into the binary. Default: `hybrid` for --method hybrid, `movie` for
    /// --method temporal-net, `lowlight` for --method net and blend.
    #[arg(long)]
    pub model: Option<String>,
    /// Denoiser. Default: temporal on a movie, blend on a single frame, or the method --model was
    /// trained for when one is given.
    #[arg(long, value_enum)]
    pub method: Option<Method>,
    /// Output units.
    #[arg(long, value_enum, default_value = "dn")]
    pub units: Units,
    #[command(flatten)]
    pub tiling: Tiling,
    /// Average the network over this many flips/transposes of each frame (1, 2, 4 or 8):
    /// a geometric self-ensemble, slightly higher PSNR for proportionally more time.
    #[arg(long, default_value_t = 1, value_parser = parse_ensemble)]
    pub ensemble: usize,
    /// --method temporal, and the default on a movie: the frames before and after each frame it
    /// uses (default 12: twenty-five frames, or the 3 nearest each side where a held-out test
    /// prefers them; 0: each frame alone — with --method temporal its own estimate, ivst below one
    /// count per pixel and one BM3D pass from there; with no --method the default's on a single
    /// frame, blend, to the bit). A frame's window stays within its recording and is clipped at the
    /// recording's ends; at most 2·K + 1 frames are held. --method temporal-net takes 2 (its
    /// network's window) or nothing.
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u16).range(0..=emccd_denoise::MAX_WINDOW as i64))]
    pub window: Option<u16>,
    /// Denoise only share I of N of the frames (I from 0; contiguous, one chunk per frame) into
    /// a `.zarr` output that N processes write at once — a SLURM array task passes
    /// `--shard $SLURM_ARRAY_TASK_ID/N` with N written out (a task resubmitted alone has an
    /// array of one; tools/slurm/denoise-array.sbatch does this). Frames already complete in
    /// the store are skipped, so a killed shard is resumed by running it again. Several inputs
    /// are one stack in the order given.
    #[arg(long, allow_hyphen_values = true)]
    pub shard: Option<Shard>,
}

fn parse_ensemble(s: &str) -> std::result::Result<usize, String> {
    emccd_denoise::ensemble_size(s).map_err(|e| e.to_string())
}

pub fn run(a: Args) -> Result<()> {
    let r = emccd_denoise::resolve(a.method, a.model.as_deref(), crate::common::load_model)?;
    let window = r.window(a.window.map(usize::from))?;
    let zarr = emccd_io::Format::from_extension(&a.out) == Some(emccd_io::Format::Zarr);
    if a.shard.is_some() && !zarr {
        bail!("--shard needs a .zarr output (-o OUT.zarr): only a Zarr store is written by several processes at once");
    }
    let several = a.inputs.len() > 1;
    if !zarr && several && a.out.exists() && !a.out.is_dir() {
        bail!(
            "{}: is a file; several inputs are written into a folder (-o FOLDER), one NAME_denoised.tif each",
            a.out.display()
        );
    }
    let outs = if zarr {
        Vec::new()
    } else {
        emccd_io::output_paths(&a.inputs, &a.out, several.then_some("_denoised.tif"))?
    };
    let mut chosen = a.recording.choose_profile(&a.inputs, true)?;
    let profile = &chosen.profile;
    // The profile's fitness for denoising, checked before anything is opened or written.
    r.denoiser(profile, 1, a.tiling, a.ensemble, a.units, window)
        .map_err(|e| anyhow::anyhow!("profile {}: {e}", chosen.name))?;
    if zarr {
        return run_zarr(&a, &r, &mut chosen, window);
    }
    // All or nothing: every input is opened and checked (its header, size and exposure) before
    // anything is written, and the outputs are placed only once every input is denoised, so an
    // input that fails halfway (truncated, a non-finite value) leaves every output as it was.
    // A light level in the counting regime is noted (only: a profile that cannot say the level,
    // without a slope, denoises as before).
    let mut notes = Vec::with_capacity(a.inputs.len());
    for input in &a.inputs {
        let mut rec = a.recording.open(input, profile)?;
        let level = emccd_count::light_level(profile, &mut rec, 4).ok();
        notes.push(level.and_then(crate::common::counting_note));
    }
    a.recording.check_fit(&mut chosen, &a.inputs, true)?;
    let made = several && !a.out.exists();
    if several {
        std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    }
    let done = denoise_files(&a, &r, &chosen, window, &outs, &notes);
    if done.is_err() && made {
        let _ = std::fs::remove_dir(&a.out); // only if empty: it was made for this run
    }
    done
}

/// Denoises each input to its output, staged beside it (after its counting-regime note, if
/// any); places them all once every one is done.
fn denoise_files(
    a: &Args,
    r: &Resolved,
    chosen: &ChosenProfile,
    window: usize,
    outs: &[PathBuf],
    notes: &[Option<String>],
) -> Result<()> {
    let profile = &chosen.profile;
    let mut lines = vec![format!("software=emccd {}", env!("CARGO_PKG_VERSION"))];
    lines.extend(
        r.model_name
            .iter()
            .filter(|_| r.model.is_some())
            .map(|m| format!("model={m}")),
    );
    lines.extend(chosen.notes());
    let mut staged = Vec::with_capacity(outs.len());
    for ((input, out), note) in a.inputs.iter().zip(outs).zip(notes) {
        if let Some(n) = note {
            eprintln!("note: {}: {n}", input.display());
        }
        let rec = a.recording.reopen(input, profile)?;
        let frames = rec.info.frames;
        let asked = a.window.map(usize::from);
        for n in [
            r.movie_note(frames, window),
            r.lone_frame_note(frames, asked),
        ]
        .into_iter()
        .flatten()
        {
            eprintln!("{}: {n}", input.display());
        }
        let fd = r.denoiser(profile, frames, a.tiling, a.ensemble, a.units, window)?;
        warn_profile(r, &fd);
        let pb = progress(rec.info.frames as u64, "frames");
        let done =
            emccd_denoise::stack::denoise_file_staged(&fd, rec, out, &lines, &mut || pb.inc(1));
        pb.finish_and_clear();
        let (frames, file, warnings) = done?;
        for w in warnings {
            eprintln!("warning: {w}");
        }
        staged.push((input, frames, file));
    }
    for (input, frames, file) in staged {
        let out = file.target().to_path_buf();
        file.place()?;
        eprintln!("{} → {} ({frames} frames)", input.display(), out.display());
    }
    Ok(())
}

/// Warns, once a run, when the network that runs was trained for another camera profile.
fn warn_profile(r: &Resolved, fd: &emccd_denoise::Denoiser) {
    static WARNED: std::sync::Once = std::sync::Once::new();
    if fd.model.is_some() {
        if let Some(w) = r.profile_warning(fd.profile) {
            WARNED.call_once(|| eprintln!("warning: {w}"));
        }
    }
}

/// Denoises the inputs, one logical stack in the order given, into one OME-Zarr store: this
/// process's shard of the frames, skipping frames already complete.
fn run_zarr(a: &Args, r: &Resolved, chosen: &mut ChosenProfile, window: usize) -> Result<()> {
    let shard = a.shard.unwrap_or(Shard::ALL);
    let (name, summary) = (chosen.name.clone(), chosen.summary.clone());
    let out = ZarrOutput {
        path: &a.out,
        shard,
        profile_arg: &name,
        characterization: summary.as_deref(),
        model_name: r.model_name.as_deref(),
        software: &format!("emccd {}", env!("CARGO_PKG_VERSION")),
    };
    // Before any input is opened: the store is never one of them.
    out.check_inputs(a.inputs.iter().map(PathBuf::as_path))?;
    let inputs = a
        .inputs
        .iter()
        .map(|p| a.recording.open(p, &chosen.profile))
        .collect::<Result<Vec<_>>>()?;
    a.recording.check_fit(chosen, &a.inputs, true)?;
    let profile = &chosen.profile;
    // The store is one stack: the default runs temporally when any of its recordings is a
    // movie (each frame's window stays within its own recording).
    let longest = inputs.iter().map(|i| i.info.frames).max().unwrap_or(1);
    for n in [
        r.movie_note(longest, window),
        r.lone_frame_note(longest, a.window.map(usize::from)),
    ]
    .into_iter()
    .flatten()
    {
        eprintln!("{n}");
    }
    let fd = &r.denoiser(profile, longest, a.tiling, a.ensemble, a.units, window)?;
    warn_profile(r, fd);
    let pb = progress(0, "frames");
    let r = denoise_to_zarr(
        fd,
        inputs,
        &out,
        &mut |n| pb.set_length(n as u64),
        &mut || pb.inc(1),
    );
    // Cleared whatever happened: a failed run leaves no bar on the screen.
    pb.finish_and_clear();
    let r = r?;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    let (frames, done) = (r.frames, r.done);
    let share = if shard.count > 1 {
        format!("shard {}/{}: ", shard.index, shard.count)
    } else {
        String::new()
    };
    if r.range.is_empty() {
        eprintln!(
            "{share}no frames: {} shards for {frames} frames leave this one empty",
            shard.count
        );
        return Ok(());
    }
    eprintln!(
        "{share}{} → {}: frames {}–{} ({} denoised now, {} were already done); {done} of {frames} frames of the store complete{}",
        if a.inputs.len() == 1 { a.inputs[0].display().to_string() } else { format!("{} inputs", a.inputs.len()) },
        a.out.display(),
        r.range.start + 1,
        r.range.end,
        r.run.written,
        r.run.skipped,
        if done < frames { " (the other shards write the rest)" } else { "" }
    );
    Ok(())
}
