//! Recordings denoised frame by frame in bounded memory: one recording into a float32 stack
//! in the format its file name says (TIFF, BigTIFF or FITS; [`denoise_file`]), or several into one OME-Zarr stack that several processes (a SLURM
//! array) fill at once, each its own share of the frames, resumable frame by frame.

use std::ops::Range;
use std::path::Path;

use emccd_io::zarr::ZarrStackWriter;
use emccd_profile::Recording;
use serde_json::{json, Value};

use crate::denoiser::Denoiser;
use emccd_nn::{Error, Result};

/// What a denoised stack's frames are a function of, compared by every process that writes
/// the store: each input by its real path, size and modification time (a file rewritten
/// between two shards is another input) with its frame count and exposure, the profile, the
/// method, the model by its bytes (not by how it was named: `model_name` is the argument it
/// was loaded from) and the output's units and network settings; `software` names the program
/// and its version.
pub fn provenance(
    fd: &Denoiser,
    model_name: Option<&str>,
    inputs: &[Recording],
    software: &str,
) -> Result<Value> {
    let mut ids = Vec::with_capacity(inputs.len());
    for i in inputs {
        let mut stamp = serde_json::to_value(emccd_io::FileStamp::of(&i.path)?)
            .map_err(|e| Error::Data(e.to_string()))?;
        stamp["frames"] = i.info.frames.into();
        stamp["exposure_s"] = i.exposure.into();
        ids.push(stamp);
    }
    let model_hash = match model_name.filter(|_| fd.model.is_some()) {
        Some(n) => Some(format!(
            "{:016x}",
            emccd_io::bytes_hash(&crate::bundled::source(n)?.bytes()?)
        )),
        None => None,
    };
    let net = fd.model.is_some();
    let mut p = json!({
        "software": software,
        "inputs": ids,
        "profile_fingerprint": fd.profile.fingerprint_hex(),
        "method": fd.method.name(),
        "model_hash": model_hash,
        "units": fd.units.describe(),
        "tile": net.then_some(fd.tiling.tile),
        "overlap": net.then_some(fd.tiling.overlap),
        "ensemble": net.then_some(fd.ensemble),
    });
    if fd.method.temporal() {
        p["window"] = fd.window.into();
    }
    Ok(p)
}

/// The recording's next frame into `buf`; `at` names it in errors (a read error, or a file
/// that ends before its header's frame count), made only when there is one.
fn read_frame(rec: &mut Recording, buf: &mut [f32], at: impl Fn() -> String) -> Result<()> {
    match rec.reader.read_frame(buf) {
        Ok(true) => Ok(()),
        Ok(false) => Err(Error::Data(format!(
            "the file ended before it (its header says {} frames)",
            rec.info.frames
        ))
        .at(at())),
        Err(source) => Err(Error::Frame { at: at(), source }),
    }
}

/// Passes over the recording's next frame unread; `at` names it in errors. A file shorter than
/// its header fails only where the missing frames are read, so skipping past its end is not one.
fn skip_frame(rec: &mut Recording, at: impl Fn() -> String) -> Result<()> {
    rec.reader
        .skip_frame()
        .map(|_| ())
        .map_err(|source| Error::Frame { at: at(), source })
}

/// The description of the OME-Zarr store that `inputs` (one stack, in this order) denoised by
/// `fd` make at `out.path`: its size, its name (the file stem), the [`provenance`] every
/// writing process compares, and what a person reads (the inputs and profile as typed, the
/// model's name). An error if the inputs hold no frame.
pub fn zarr_spec(
    fd: &Denoiser,
    inputs: &[Recording],
    out: &ZarrOutput,
) -> Result<emccd_io::zarr::ZarrStackSpec> {
    let frames: usize = inputs.iter().map(|i| i.info.frames).sum();
    if frames == 0 {
        return Err(Error::Data("the inputs hold no frame".into()));
    }
    Ok(emccd_io::zarr::ZarrStackSpec {
        width: fd.profile.width,
        height: fd.profile.height,
        frames,
        name: out
            .path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        provenance: provenance(fd, out.model_name, inputs, out.software)?,
        notes: json!({
            "inputs": inputs.iter().map(|i| i.path.display().to_string()).collect::<Vec<_>>(),
            "profile": out.profile_arg,
            "characterization": out.characterization,
            "model": out.model_name.filter(|_| fd.model.is_some()),
        }),
    })
}

/// What one process did to its share of a stack ([`denoise_shard`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShardRun {
    /// Frames denoised and stored now.
    pub written: usize,
    /// Frames of the share that were already complete (an earlier run, or another process).
    pub skipped: usize,
}

/// Where and how [`denoise_to_zarr`] writes: the store, this process's share, and what the
/// store records about how it was made.
#[derive(Clone, Copy, Debug)]
pub struct ZarrOutput<'a> {
    /// The `.zarr` store.
    pub path: &'a Path,
    /// This process's share of the frames.
    pub shard: emccd_io::zarr::Shard,
    /// The profile as the user named it.
    pub profile_arg: &'a str,
    /// What the camera was characterized as, where the profile was made from the inputs.
    pub characterization: Option<&'a str>,
    /// The model as the user named it, where one runs.
    pub model_name: Option<&'a str>,
    /// The program and its version ([`provenance`]).
    pub software: &'a str,
}

impl ZarrOutput<'_> {
    /// An error if the store is one of `inputs` (it would be overwritten while read).
    pub fn check_inputs<'p>(&self, inputs: impl IntoIterator<Item = &'p Path>) -> Result<()> {
        for i in inputs {
            emccd_io::refuse_overwrite(self.path, i, &format!("the input {}", i.display()))?;
        }
        Ok(())
    }
}

/// What [`denoise_to_zarr`] did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ZarrRun {
    /// Frames of the whole stack.
    pub frames: usize,
    /// This share's frames (from 0); empty where there are more shards than frames.
    pub range: Range<usize>,
    /// Frames denoised now and frames found complete.
    pub run: ShardRun,
    /// Frames of the store complete after this run, every share's.
    pub done: usize,
    /// What a person should know about the frames read ([`crate::movie::Irregular`]).
    pub warnings: Vec<String>,
}

/// Denoises this process's share of the stack that `inputs` make (in the order given) into the
/// OME-Zarr store `out.path`: created ([`zarr_spec`]) or, made by the same command before,
/// resumed, skipping frames already complete; a store made otherwise is refused. `pending`
/// gets the number of frames about to be denoised, `on_frame` is called after each.
pub fn denoise_to_zarr(
    fd: &Denoiser,
    inputs: Vec<Recording>,
    out: &ZarrOutput,
    pending: &mut dyn FnMut(usize),
    on_frame: &mut dyn FnMut(),
) -> Result<ZarrRun> {
    out.check_inputs(inputs.iter().map(|i| i.path.as_path()))?;
    let spec = zarr_spec(fd, &inputs, out)?;
    let frames = spec.frames;
    if !out.path.exists() {
        // Float32 frames, one chunk each; the metadata is a few kB.
        let bytes = (frames as u64).saturating_mul(fd.profile.len() as u64 * 4) + (1 << 16);
        emccd_io::check_room(out.path, bytes)?;
    }
    let (store, created) = ZarrStackWriter::create_or_open(out.path, &spec)?;
    let r = denoise_share(fd, inputs, out, &store, frames, pending, on_frame);
    // A store this run began alone and could not finish because of what it read (a frame at
    // fault) goes: rerunning would stop at the same place. One stopped by the system (a full
    // disk, a failing filesystem) stays to be resumed once that is put right, as a killed
    // run's does; a shard's store holds other processes' work.
    if let Err(e) = &r {
        if created && out.shard == emccd_io::zarr::Shard::ALL && !is_io(e) {
            drop(store);
            let _ = std::fs::remove_dir_all(out.path);
        }
    }
    r
}

/// Whether `e` is the operating system's (a full disk, a failing filesystem) rather than about
/// the data.
fn is_io(e: &Error) -> bool {
    fn io(e: &emccd_io::Error) -> bool {
        match e {
            emccd_io::Error::Io(_) => true,
            emccd_io::Error::WithPath { source, .. } => io(source),
            _ => false,
        }
    }
    match e {
        Error::Io { .. } => true,
        Error::File(f) | Error::Frame { source: f, .. } => io(f),
        Error::At { source, .. } => is_io(source),
        _ => false,
    }
}

/// [`denoise_to_zarr`]'s work once `store` is open.
fn denoise_share(
    fd: &Denoiser,
    inputs: Vec<Recording>,
    out: &ZarrOutput,
    store: &ZarrStackWriter,
    frames: usize,
    pending: &mut dyn FnMut(usize),
    on_frame: &mut dyn FnMut(),
) -> Result<ZarrRun> {
    let range = out.shard.range(frames);
    if range.is_empty() {
        return Ok(ZarrRun {
            frames,
            range,
            run: ShardRun {
                written: 0,
                skipped: 0,
            },
            done: store.done_count(),
            warnings: Vec::new(),
        });
    }
    pending(range.clone().filter(|&k| !store.is_done(k)).count());
    let (run, warnings) = shard(fd, inputs, store, range.clone(), on_frame)?;
    Ok(ZarrRun {
        frames,
        range,
        run,
        done: store.done_count(),
        warnings,
    })
}

/// Denoises frames `range` (from 0) of the stack that `inputs` make in the order given into
/// `store`, skipping frames already complete there, so that a killed run is resumed by running
/// it again; the other frames are skipped over unread. `on_frame` is called after every frame
/// stored. An error if the store was made for another number of frames or another frame size,
/// or `range` reaches past the inputs' frames; errors about a frame name its input and its
/// number there (from 1), and an input that ends before its header's frame count is one.
pub fn denoise_shard(
    fd: &Denoiser,
    inputs: Vec<Recording>,
    store: &ZarrStackWriter,
    range: Range<usize>,
    on_frame: &mut dyn FnMut(),
) -> Result<ShardRun> {
    shard(fd, inputs, store, range, on_frame).map(|(run, _)| run)
}

/// [`denoise_shard`], with the warnings about the frames read.
fn shard(
    fd: &Denoiser,
    inputs: Vec<Recording>,
    store: &ZarrStackWriter,
    range: Range<usize>,
    on_frame: &mut dyn FnMut(),
) -> Result<(ShardRun, Vec<String>)> {
    let mut warnings = Vec::new();
    let frames: usize = inputs.iter().map(|i| i.info.frames).sum();
    let spec = store.spec();
    let size = (fd.profile.width, fd.profile.height);
    if spec.frames != frames || (spec.width, spec.height) != size {
        return Err(Error::Data(format!(
            "the store holds {} frames of {}×{}, the inputs {frames} of {}×{}",
            spec.frames, spec.width, spec.height, size.0, size.1
        )));
    }
    if range.end > frames {
        return Err(Error::Data(format!(
            "frames {}–{} asked of a stack of {frames}",
            range.start + 1,
            range.end
        )));
    }
    let mut buf = vec![0f32; fd.profile.len()];
    let mut run = ShardRun {
        written: 0,
        skipped: 0,
    };
    // k counts the stack's frames, j each input's (what messages name).
    let mut k = 0usize;
    for mut i in inputs {
        if k >= range.end {
            break;
        }
        let name = i.path.display().to_string();
        let count = i.info.frames;
        let at = |j: usize| format!("{name}: frame {}", j + 1);
        if fd.method.temporal() {
            // This input's frames of the share, with their windows' frames around them.
            // (The loop ends before an input that starts at or after the share's end.)
            let first = k;
            let want = range.start.saturating_sub(first)..(range.end - first).min(count);
            let exposure = i.exposure;
            let irregular = crate::movie::denoise_frames(
                fd,
                exposure,
                count,
                want,
                &at,
                &mut |j, buf| match buf {
                    Some(buf) => read_frame(&mut i, buf, || at(j)),
                    None => skip_frame(&mut i, || at(j)),
                },
                &mut |j, out| {
                    if store.is_done(first + j) {
                        run.skipped += 1;
                    } else {
                        store.write_frame(first + j, &out)?;
                        run.written += 1;
                        on_frame();
                    }
                    Ok(())
                },
            )?;
            warnings.extend(irregular.warnings(&name));
            k += count;
            continue;
        }
        for j in 0..count {
            if k >= range.end {
                break;
            }
            if range.contains(&k) && !store.is_done(k) {
                read_frame(&mut i, &mut buf, || at(j))?;
                let out = fd.run(&buf, i.exposure).map_err(|e| e.at(at(j)))?;
                store.write_frame(k, &out)?;
                run.written += 1;
                on_frame();
            } else {
                run.skipped += range.contains(&k) as usize;
                skip_frame(&mut i, || at(j))?;
            }
            k += 1;
        }
    }
    Ok((run, warnings))
}

/// Denoises every frame of `input` into a float32 stack at `out`, in the format its extension
/// names (TIFF, BigTIFF or FITS; written atomically:
/// nothing is left there if a frame fails). `on_frame` is called after every frame written.
/// Errors about a frame name the input and the frame's number (from 1); an input that ends
/// before its header's frame count is one. Returns the frames written.
pub fn denoise_file(
    fd: &Denoiser,
    input: Recording,
    out: &Path,
    on_frame: &mut dyn FnMut(),
) -> Result<usize> {
    let (frames, staged, _) = denoise_file_staged(fd, input, out, &[], on_frame)?;
    staged.place()?;
    Ok(frames)
}

/// [`denoise_file`], the finished stack left beside `out` for the caller to place: a run over
/// several inputs places its outputs only once every input has been denoised. `notes` are
/// `key=value` lines the stack records after its own (method, units, profile fingerprint): a
/// TIFF's description, a FITS header's HISTORY. Returns the frames written, the stack, and
/// what a person should know about the frames read ([`crate::movie::Irregular`]).
pub fn denoise_file_staged(
    fd: &Denoiser,
    mut input: Recording,
    out: &Path,
    notes: &[String],
    on_frame: &mut dyn FnMut(),
) -> Result<(usize, emccd_io::Staged, Vec<String>)> {
    let (width, height, frames) = (input.info.width, input.info.height, input.info.frames);
    let mut w = emccd_io::StackWriter::create(
        out,
        width,
        height,
        emccd_io::SampleFormat::F32,
        Some(frames),
    )?;
    let own = [
        format!("method={}", fd.method.name()),
        format!("units={}", fd.units.describe()),
        format!("profile_fingerprint={}", fd.profile.fingerprint_hex()),
    ];
    w.set_notes(
        &own.into_iter()
            .chain(notes.iter().cloned())
            .collect::<Vec<_>>(),
    );
    let name = input.path.display().to_string();
    let at = |j: usize| format!("{name}: frame {}", j + 1);
    if fd.method.temporal() {
        let exposure = input.exposure;
        let irregular = crate::movie::denoise_frames(
            fd,
            exposure,
            frames,
            0..frames,
            &at,
            &mut |j, buf| match buf {
                Some(buf) => read_frame(&mut input, buf, || at(j)),
                None => Ok(()),
            },
            &mut |_, out| {
                w.write_frame(&out)?;
                on_frame();
                Ok(())
            },
        )?;
        return Ok((frames, w.finish_staged()?, irregular.warnings(&name)));
    }
    let mut buf = vec![0f32; width * height];
    for j in 0..frames {
        read_frame(&mut input, &mut buf, || at(j))?;
        let den = fd.run(&buf, input.exposure).map_err(|e| e.at(at(j)))?;
        w.write_frame(&den)?;
        on_frame();
    }
    Ok((frames, w.finish_staged()?, Vec::new()))
}
