//! Readers and writers for the files EMCCD users have, one frame at a time.
//!
//! Every format is opened through [`open`], which sniffs the file's magic bytes and returns a
//! [`FrameReader`]: the stack's size, frame count, pixel type and camera metadata up front, then
//! frames decoded one by one into a caller-owned `f32` buffer, so a stack larger than memory can
//! be streamed. Writers ([`StackWriter`]) write to a temporary file beside the target and rename it
//! into place on [`StackWriter::finish`], so a failed run never leaves a half-written output.
//!
//! Formats: TIFF and BigTIFF (the `tiff` crate), Andor SIF (hand-written: no maintained crate
//! reads it), FITS (headers parsed with `fitsrs`; frames streamed by offset; writing is
//! hand-written, since `fitsrs` only reads), PNG for clean scenes (the `png` crate; colour is
//! converted to luminance), and Zarr stores — a folder, opened by [`open`] too — through the
//! `zarrs` crate, with an OME-Zarr writer that many processes fill at once ([`zarr`]).
//!
//! A stack written and streamed back, one frame at a time:
//!
//! ```
//! # fn main() -> emccd_io::Result<()> {
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("stack.tif");
//! let mut w = emccd_io::StackWriter::create(&path, 4, 2, emccd_io::SampleFormat::U16, Some(3))?;
//! for k in 0..3 {
//!     w.write_frame(&[100.0 + k as f32; 8])?;
//! }
//! w.finish()?; // renamed into place only now
//! let mut r = emccd_io::open(&path)?;
//! let info = r.info().clone();
//! assert_eq!((info.width, info.height, info.frames), (4, 2, 3));
//! let mut frame = vec![0f32; info.frame_len()];
//! let mut k = 0;
//! while r.read_frame(&mut frame)? {
//!     assert_eq!(frame[0], 100.0 + k as f32);
//!     k += 1;
//! }
//! # Ok(())
//! # }
//! ```

#![deny(missing_docs)]

mod error;
mod files;
pub mod fits;
mod image;
pub mod png_io;
pub mod sif;
pub mod tiff_io;
pub mod zarr;

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

pub use error::{Error, Result};
pub use files::{
    bytes_hash, check_room, content_hash, input_among, not_a_file, output_paths, read_regular,
    read_regular_text, refuse_overwrite, safetensors_sorted, FileId, FileStamp,
};
pub use image::{image_files, Image};

/// The sample type stored in a file (what `emccd info` reports).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PixelType {
    /// Unsigned 8-bit.
    U8,
    /// Unsigned 16-bit (raw camera frames).
    U16,
    /// Signed 16-bit.
    I16,
    /// Unsigned 32-bit.
    U32,
    /// Signed 32-bit.
    I32,
    /// 32-bit IEEE float (SIF data, processed frames).
    F32,
    /// 64-bit IEEE float.
    F64,
}

impl PixelType {
    /// Bytes per sample on disk.
    pub fn bytes(self) -> usize {
        match self {
            PixelType::U8 => 1,
            PixelType::U16 | PixelType::I16 => 2,
            PixelType::U32 | PixelType::I32 | PixelType::F32 => 4,
            PixelType::F64 => 8,
        }
    }
}

/// The container format of a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Classic TIFF (32-bit offsets).
    Tiff,
    /// BigTIFF (64-bit offsets).
    BigTiff,
    /// Andor Technology Multi-Channel File.
    Sif,
    /// Flexible Image Transport System.
    Fits,
    /// Portable Network Graphics.
    Png,
    /// A Zarr store (a folder): OME-Zarr, Zarr v3 or v2.
    Zarr,
}

impl Format {
    /// Guesses the output format from a file name's extension.
    pub fn from_extension(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "tif" | "tiff" => Some(Format::Tiff),
            "btf" | "tf8" => Some(Format::BigTiff),
            "fits" | "fit" | "fts" => Some(Format::Fits),
            "png" => Some(Format::Png),
            "sif" => Some(Format::Sif),
            "zarr" => Some(Format::Zarr),
            _ => None,
        }
    }
}

/// Camera metadata found in a file's header; `None` where the file does not say.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Metadata {
    /// Exposure time in seconds.
    pub exposure_s: Option<f64>,
    /// EM gain setting as recorded by the camera software.
    pub em_gain: Option<f64>,
    /// Detector temperature in °C.
    pub temperature_c: Option<f64>,
    /// Camera model as recorded (e.g. `DU897_BV`).
    pub camera_model: Option<String>,
    /// On-chip binning (horizontal, vertical).
    pub binning: Option<(u32, u32)>,
    /// Number of accumulations summed into each frame.
    pub accumulations: Option<u32>,
    /// Warnings about the file that did not stop reading (e.g. a truncated stack).
    pub warnings: Vec<String>,
}

/// What a stack holds, known before any frame is decoded.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct StackInfo {
    /// Frame width in pixels.
    pub width: usize,
    /// Frame height in pixels.
    pub height: usize,
    /// Number of whole frames that can be read.
    pub frames: usize,
    /// Sample type on disk.
    pub pixel_type: PixelType,
    /// Container format.
    pub format: Format,
    /// Camera metadata from the header.
    pub metadata: Metadata,
}

impl StackInfo {
    /// Pixels per frame.
    pub fn frame_len(&self) -> usize {
        self.width * self.height
    }

    /// What `emccd info --json` prints and Python's `emccd.info` returns for the stack at
    /// `path`: size, frames, sample type and format beside the header's fields (`null` where
    /// the file does not say).
    pub fn summary_json(&self, path: &Path) -> serde_json::Value {
        let m = &self.metadata;
        serde_json::json!({
            "file": path,
            "format": self.format,
            "width": self.width,
            "height": self.height,
            "frames": self.frames,
            "pixel_type": self.pixel_type,
            "exposure_s": m.exposure_s,
            "em_gain": m.em_gain,
            "temperature_c": m.temperature_c,
            "camera_model": m.camera_model,
            "binning": m.binning,
            "accumulations": m.accumulations,
            "warnings": m.warnings,
        })
    }

    /// What `emccd info` prints for the stack at `path`: one line per field, `unknown` where the
    /// header does not say; an exposure `denoise` would refuse is marked, and the reader's
    /// warnings follow.
    pub fn summary_text(&self, path: &Path) -> String {
        use std::fmt::Write;
        let m = &self.metadata;
        let opt = |v: Option<f64>, unit: &str| {
            v.map(|x| format!("{x}{unit}"))
                .unwrap_or_else(|| "unknown".into())
        };
        // A header's exposure is shown as recorded; one that `denoise` would refuse is marked.
        let bad = m.exposure_s.is_some_and(|t| !(t.is_finite() && t > 0.0));
        let gain = match m.em_gain {
            Some(g) if g == 0.0 => "0 (EM register off)".to_string(),
            g => opt(g, ""),
        };
        let mut s = String::new();
        // Writing to a String cannot fail.
        let _ = writeln!(s, "{}", path.display());
        let _ = writeln!(s, "  format       {:?}", self.format);
        let _ = writeln!(s, "  size         {} × {} pixels", self.width, self.height);
        let _ = writeln!(s, "  frames       {}", self.frames);
        let _ = writeln!(s, "  pixel type   {:?}", self.pixel_type);
        let _ = writeln!(
            s,
            "  exposure     {}{}",
            opt(m.exposure_s, " s"),
            if bad {
                "  (not a positive number of seconds: give --exposure-s to denoise)"
            } else {
                ""
            }
        );
        let _ = writeln!(s, "  EM gain      {gain}");
        let _ = writeln!(s, "  temperature  {}", opt(m.temperature_c, " °C"));
        let _ = writeln!(
            s,
            "  camera       {}",
            m.camera_model.as_deref().unwrap_or("unknown")
        );
        if let Some((bx, by)) = m.binning {
            let _ = writeln!(s, "  binning      {bx} × {by}");
        }
        if let Some(acc) = m.accumulations {
            let _ = writeln!(s, "  accumulations {acc}");
        }
        for w in &m.warnings {
            let _ = writeln!(s, "  warning: {w}");
        }
        s
    }
}

/// An error and its causes as lines to show a person: the error, then each cause its wrapper
/// does not already spell out (an error with its file attached prints the error itself too, so
/// it is said once). What the CLI prints after `error:` and the Python package raises.
pub fn error_lines(e: &(dyn std::error::Error + 'static)) -> Vec<String> {
    let mut last = e.to_string();
    let mut lines = vec![last.clone()];
    let mut cause = e.source();
    while let Some(c) = cause {
        let text = c.to_string();
        if !last.contains(&text) {
            lines.push(text.clone());
        }
        last = text;
        cause = c.source();
    }
    lines
}

/// A stack opened for reading, decoded one frame at a time in row-major order.
pub trait FrameReader: Send {
    /// Size, count, type and metadata of the stack.
    fn info(&self) -> &StackInfo;
    /// Decodes the next frame into `buf` (length `width·height`); `Ok(false)` after the last.
    fn read_frame(&mut self, buf: &mut [f32]) -> Result<bool>;
    /// Moves past the next frame without converting it, where the format allows (a shard of a
    /// stack starts mid-way); `Ok(false)` after the last.
    fn skip_frame(&mut self) -> Result<bool> {
        let mut scratch = vec![0f32; self.info().frame_len()];
        self.read_frame(&mut scratch)
    }
}

/// [`FrameReader::skip_frame`] for frames stored one after another, `len` bytes each: seeks past
/// frame `*next` of `frames`.
pub(crate) fn skip_stored<R: Read + Seek>(
    file: &mut std::io::BufReader<R>,
    next: &mut usize,
    frames: usize,
    len: usize,
) -> Result<bool> {
    if *next >= frames {
        return Ok(false);
    }
    file.seek_relative(len as i64)?;
    *next += 1;
    Ok(true)
}

/// The error every reader gives for a caller's buffer of the wrong size.
pub(crate) fn check_buffer(out: &[f32], info: &StackInfo) -> Result<()> {
    if out.len() != info.frame_len() {
        return Err(Error::Usage(format!(
            "buffer holds {} pixels, frame has {}",
            out.len(),
            info.frame_len()
        )));
    }
    Ok(())
}

/// Opens an image or stack, choosing the reader from the file's first bytes, with the process's
/// [`Limits`].
///
/// Errors name the file. A truncated SIF opens with the whole frames it holds and a warning in
/// [`Metadata::warnings`].
pub fn open(path: impl AsRef<Path>) -> Result<Box<dyn FrameReader>> {
    open_with(path, Limits::process())
}

/// [`open`] with the given limits.
pub fn open_with(path: impl AsRef<Path>, limits: Limits) -> Result<Box<dyn FrameReader>> {
    let path = path.as_ref();
    if path.is_dir() {
        if !zarr::is_zarr(path) {
            return Err(Error::Usage(
                "a folder, and not a Zarr store (no zarr.json, .zgroup or .zarray)".into(),
            )
            .with_path(path));
        }
        return zarr::ZarrReader::open(path, limits)
            .map(|r| Box::new(r) as Box<dyn FrameReader>)
            .map_err(|e| e.with_path(path));
    }
    // Opening a FIFO waits for a writer (forever, if none comes) and a device reads without
    // end; neither is an image file, so neither is opened.
    if let Some(what) = files::not_a_file(path) {
        return Err(Error::Usage(format!("{what}, not an image file")).with_path(path));
    }
    File::open(path)
        .map_err(Error::from)
        .and_then(|f| from_reader(f, limits))
        .map_err(|e| e.with_path(path))
}

thread_local!(static QUIET_HERE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) });
/// Callers of [`catch_quietly_everywhere`] in progress.
static QUIET_EVERYWHERE: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// The one panic hook of the process that can stay silent: it wraps whatever hook was set before
/// and passes a panic on unless this thread is in [`quietly`] or some thread is in
/// [`catch_quietly_everywhere`]. Installed once; every silencing in emccd goes through it, so no
/// caller swaps the process's hook under another.
fn install_quiet_hook() {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let silent = QUIET_HERE.with(std::cell::Cell::get)
                || QUIET_EVERYWHERE.load(std::sync::atomic::Ordering::SeqCst) > 0;
            if !silent {
                previous(info)
            }
        }));
    });
}

/// Runs `f`, turning a panic inside it — a third-party parser meeting input it was not written
/// for — into an error about `what`, with the panic's message kept off the terminal (the error
/// carries it).
pub(crate) fn quietly<T>(what: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
    install_quiet_hook();
    QUIET_HERE.with(|q| q.set(true));
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    QUIET_HERE.with(|q| q.set(false));
    r.unwrap_or_else(|p| {
        let msg = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        Err(Error::Format(format!(
            "{what}: damaged beyond what the parser handles ({msg})"
        )))
    })
}

/// Runs `f` and catches a panic from it, with every thread's panic messages kept off the
/// terminal meanwhile: for probing a runtime that reports failure by panicking in threads of its
/// own (a GPU backend without an adapter), where the caller says in one line what it does next.
pub fn catch_quietly_everywhere<T>(f: impl FnOnce() -> T) -> std::thread::Result<T> {
    use std::sync::atomic::Ordering::SeqCst;
    install_quiet_hook();
    QUIET_EVERYWHERE.fetch_add(1, SeqCst);
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    QUIET_EVERYWHERE.fetch_sub(1, SeqCst);
    r
}

/// How much a file's header may claim before a reader allocates for the claim.
///
/// Every caller sizes a frame buffer from the header before decoding a pixel, so a damaged or
/// hostile header (65535² pixels in a 1 kB file) must be refused by the reader, not discovered
/// by the allocator. Independently of these limits, a reader never believes a header that claims
/// more uncompressed data than the file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Pixels in one frame.
    pub frame_pixels: usize,
    /// Frames in one stack.
    pub frames: usize,
    /// Bytes of one allocation sized from a header (a frame's samples as stored, or decoded).
    pub bytes: u64,
}

impl Limits {
    /// The default: frames up to 2²⁸ pixels (16384², 1 GiB as `f32`), 2²⁴ frames, 4 GiB in one
    /// allocation. EMCCD sensors are at most 1024²; mosaics and processed images far below this.
    pub const GENEROUS: Limits = Limits {
        frame_pixels: 1 << 28,
        frames: 1 << 24,
        bytes: 1 << 32,
    };

    /// No limits (`emccd --no-limits`), for good files beyond the defaults; what the file's own
    /// length bounds is still checked.
    pub const NONE: Limits = Limits {
        frame_pixels: usize::MAX,
        frames: usize::MAX,
        bytes: u64::MAX,
    };

    /// The limits [`open`] applies: [`Limits::GENEROUS`] unless [`Limits::set_process`] said
    /// otherwise.
    pub fn process() -> Limits {
        *PROCESS_LIMITS.read().unwrap_or_else(|e| e.into_inner())
    }

    /// Sets the limits of every later [`open`] in this process (the CLI's `--no-limits`).
    pub fn set_process(limits: Limits) {
        *PROCESS_LIMITS.write().unwrap_or_else(|e| e.into_inner()) = limits;
    }

    /// Pixels of one `width`×`height` frame of `bytes_per_sample`-byte samples, or an error if
    /// the frame is empty or passes a limit (pixels; bytes as stored or as `f32`).
    pub fn frame(&self, width: usize, height: usize, bytes_per_sample: usize) -> Result<usize> {
        let n = width
            .checked_mul(height)
            .filter(|&n| n <= self.frame_pixels)
            .ok_or_else(|| {
                Error::Format(format!(
                    "the header claims {width}×{height} pixels per frame, beyond the limit of {} pixels (a damaged header? `--no-limits` lifts it)",
                    self.frame_pixels
                ))
            })?;
        if n == 0 || bytes_per_sample == 0 {
            return Err(Error::Format(format!(
                "the header claims an empty frame ({width}×{height} pixels of {bytes_per_sample}-byte samples)"
            )));
        }
        let bytes = (n as u128) * (bytes_per_sample.max(4) as u128);
        if bytes > self.bytes as u128 {
            return Err(Error::Format(format!(
                "a {width}×{height} frame takes {bytes} bytes, beyond the limit of {} bytes (a damaged header? `--no-limits` lifts it)",
                self.bytes
            )));
        }
        Ok(n)
    }

    /// Bytes of one stored frame of `bytes_per_sample`-byte samples, after [`Limits::frame`]'s
    /// checks: what a reader divides the file by and allocates to read a frame.
    pub fn frame_bytes(&self, width: usize, height: usize, bytes_per_sample: usize) -> Result<u64> {
        Ok(self.frame(width, height, bytes_per_sample)? as u64 * bytes_per_sample as u64)
    }

    /// An error if a stack of `frames` passes the frame limit.
    pub fn stack(&self, frames: u64) -> Result<()> {
        if frames > self.frames as u64 {
            return Err(Error::Format(format!(
                "the file claims {frames} frames, beyond the limit of {} (a damaged header? `--no-limits` lifts it)",
                self.frames
            )));
        }
        Ok(())
    }
}

impl Default for Limits {
    fn default() -> Limits {
        Limits::GENEROUS
    }
}

static PROCESS_LIMITS: std::sync::RwLock<Limits> = std::sync::RwLock::new(Limits::GENEROUS);

/// The length of a stream, its position kept.
pub(crate) fn stream_len(r: &mut impl Seek) -> std::io::Result<u64> {
    let pos = r.stream_position()?;
    let end = r.seek(SeekFrom::End(0))?;
    r.seek(SeekFrom::Start(pos))?;
    Ok(end)
}

/// Opens an image or stack from any seekable source (a file, bytes in memory), choosing the
/// reader from its first bytes; the source is read through a buffer.
pub fn from_reader<R: Read + Seek + Send + 'static>(
    mut source: R,
    limits: Limits,
) -> Result<Box<dyn FrameReader>> {
    let mut magic = [0u8; 36];
    let n = read_up_to(&mut source, &mut magic)?;
    source.seek(SeekFrom::Start(0))?;
    let magic = &magic[..n];
    let r: Box<dyn FrameReader> = if magic.starts_with(b"II*\0")
        || magic.starts_with(b"MM\0*")
        || magic.starts_with(b"II+\0")
        || magic.starts_with(b"MM\0+")
    {
        Box::new(tiff_io::TiffReader::new(source, limits)?)
    } else if magic.starts_with(sif::MAGIC) {
        Box::new(sif::SifReader::new(source, limits)?)
    } else if magic.starts_with(b"SIMPLE  =") {
        Box::new(fits::FitsReader::new(source, limits)?)
    } else if magic.starts_with(b"\x89PNG\r\n\x1a\n") {
        Box::new(png_io::PngReader::new(source, limits)?)
    } else if n == 0 {
        return Err(Error::Format("the file is empty".into()));
    } else {
        return Err(Error::Unsupported(
            "not a TIFF, BigTIFF, Andor SIF, FITS or PNG file (unrecognized first bytes)".into(),
        ));
    };
    // Whatever the format said, the caller's frame buffer is sized from this.
    limits.frame(r.info().width, r.info().height, r.info().pixel_type.bytes())?;
    Ok(r)
}

fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

/// Reads every frame of a file into memory (for small inputs: clean scenes, maps, tests).
pub fn read_all(path: impl AsRef<Path>) -> Result<(StackInfo, Vec<Vec<f32>>)> {
    let path = path.as_ref();
    let mut r = open(path)?;
    let info = r.info().clone();
    let mut frames = Vec::with_capacity(info.frames);
    loop {
        let mut buf = vec![0f32; info.frame_len()];
        if !r.read_frame(&mut buf).map_err(|e| e.with_path(path))? {
            break;
        }
        frames.push(buf);
    }
    Ok((info, frames))
}

/// Reads only the first frame of a file (a map, a scene, the first frame of a stack).
pub fn read_first(path: impl AsRef<Path>) -> Result<(StackInfo, Vec<f32>)> {
    let path = path.as_ref();
    let mut r = open(path)?;
    let info = r.info().clone();
    let mut buf = vec![0f32; info.frame_len()];
    if !r.read_frame(&mut buf).map_err(|e| e.with_path(path))? {
        return Err(Error::Format("the file holds no frame".into()).with_path(path));
    }
    Ok((info, buf))
}

/// Sample type written by a [`StackWriter`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleFormat {
    /// Unsigned 8-bit: values are rounded and clipped to 0..=255.
    U8,
    /// Unsigned 16-bit: values are rounded and clipped to 0..=65535 (raw camera frames).
    U16,
    /// 32-bit float (processed frames, ground truth).
    F32,
}

/// Whether a classic TIFF of `frames` such frames would pass its 4 GiB limit (with room for
/// the page headers).
pub fn needs_bigtiff(width: usize, height: usize, sample: SampleFormat, frames: usize) -> bool {
    let bytes = match sample {
        SampleFormat::U8 => 1u128,
        SampleFormat::U16 => 2,
        SampleFormat::F32 => 4,
    };
    let data = width as u128 * height as u128 * bytes * frames as u128;
    data + 1024 * frames as u128 + (1 << 20) > u32::MAX as u128
}

/// The outputs a stack is written as, for messages.
const OUTPUT_FORMATS: &str =
    "output must end in .tif, .tiff, .btf (BigTIFF) or .fits (or .zarr, for `denoise` and `count`)";

/// Writes a stack frame by frame to a temporary file that is renamed into place by
/// [`StackWriter::finish`]; dropped unfinished, it removes the temporary file and leaves any
/// existing target untouched.
pub struct StackWriter {
    inner: WriterKind,
    target: PathBuf,
    width: usize,
    height: usize,
    frames: usize,
}

enum WriterKind {
    Tiff(tiff_io::TiffStackWriter),
    Fits(fits::FitsStackWriter),
}

impl StackWriter {
    /// Creates a writer for `path`; the format comes from the extension (`.tif`/`.tiff`, `.btf`
    /// for BigTIFF, `.fits`). `frames_hint` (the number of frames, if known) is required for
    /// FITS, whose header states it; TIFF pages need none.
    pub fn create(
        path: impl AsRef<Path>,
        width: usize,
        height: usize,
        sample: SampleFormat,
        frames_hint: Option<usize>,
    ) -> Result<StackWriter> {
        let path = path.as_ref();
        let fmt = Format::from_extension(path)
            .ok_or_else(|| Error::Usage(OUTPUT_FORMATS.into()).with_path(path))?;
        Self::create_as(path, fmt, width, height, sample, frames_hint)
    }

    /// Like [`StackWriter::create`] with an explicit format.
    pub fn create_as(
        path: &Path,
        fmt: Format,
        width: usize,
        height: usize,
        sample: SampleFormat,
        frames_hint: Option<usize>,
    ) -> Result<StackWriter> {
        if width == 0 || height == 0 {
            return Err(
                Error::Usage(format!("cannot write a {width}×{height} frame")).with_path(path),
            );
        }
        if fmt == Format::Sif {
            return Err(Error::Usage(
                "SIF is Andor's acquisition format and emccd reads it only; write .tif, .btf or .fits"
                    .into(),
            )
            .with_path(path));
        }
        // Classic TIFF addresses its file with 32-bit offsets: a stack known to outgrow them is
        // written as BigTIFF, which Fiji and tifffile read under a .tif name just the same.
        let fmt = match frames_hint {
            Some(n) if fmt == Format::Tiff && needs_bigtiff(width, height, sample, n) => {
                Format::BigTiff
            }
            _ => fmt,
        };
        let tmp = temp_beside(path).map_err(|e| Error::from(e).with_path(path))?;
        let inner = match fmt {
            Format::Tiff | Format::BigTiff => WriterKind::Tiff(
                tiff_io::TiffStackWriter::new(
                    tmp,
                    fmt == Format::BigTiff,
                    width,
                    height,
                    sample,
                    frames_hint,
                )
                .map_err(|e| e.with_path(path))?,
            ),
            Format::Fits => WriterKind::Fits(
                fits::FitsStackWriter::new(tmp, width, height, sample, frames_hint)
                    .map_err(|e| e.with_path(path))?,
            ),
            other => {
                return Err(Error::Usage(format!(
                    "{} files hold no stack written here: {OUTPUT_FORMATS}",
                    format!("{other:?}").to_uppercase()
                ))
                .with_path(path))
            }
        };
        Ok(StackWriter {
            inner,
            target: path.to_path_buf(),
            width,
            height,
            frames: 0,
        })
    }

    /// Appends one frame (row-major, `width·height` values).
    pub fn write_frame(&mut self, frame: &[f32]) -> Result<()> {
        if frame.len() != self.width * self.height {
            return Err(Error::Usage(format!(
                "frame {} has {} pixels; this stack is {}×{} = {}",
                self.frames + 1,
                frame.len(),
                self.width,
                self.height,
                self.width * self.height
            ))
            .with_path(&self.target));
        }
        // A non-finite value would be written as garbage (NaN, ±inf, or 0 after rounding to an
        // integer type) and look like data: refuse it, saying where it is (frames counted from
        // 1, pixels as (x, y) from 0, as every emccd message counts them).
        if let Some(i) = frame.iter().position(|v| !v.is_finite()) {
            return Err(Error::Usage(format!(
                "frame {} has a non-finite value ({}) at pixel ({}, {}); nothing was written",
                self.frames + 1,
                frame[i],
                i % self.width,
                i / self.width
            ))
            .with_path(&self.target));
        }
        let r = match &mut self.inner {
            WriterKind::Tiff(w) => w.write_frame(frame),
            WriterKind::Fits(w) => w.write_frame(frame),
        };
        r.map_err(|e| e.with_path(&self.target))?;
        self.frames += 1;
        Ok(())
    }

    /// Number of frames written so far.
    pub fn frames_written(&self) -> usize {
        self.frames
    }

    /// Completes the file and renames it into place.
    pub fn finish(self) -> Result<()> {
        self.finish_staged()?.place()
    }

    /// Completes the file but leaves it beside its target ([`Staged`]): a command writing
    /// several files places them only once every one is complete.
    pub fn finish_staged(self) -> Result<Staged> {
        let target = self.target;
        let tmp = match self.inner {
            WriterKind::Tiff(w) => w.finish(),
            WriterKind::Fits(w) => w.finish(self.frames),
        }
        .map_err(|e| e.with_path(&target))?;
        Ok(Staged { tmp, target })
    }
}

/// A complete output file not yet at its target: [`Staged::place`] renames it there; dropped
/// instead, it is removed and the target stays as it was.
pub struct Staged {
    tmp: tempfile::NamedTempFile,
    target: PathBuf,
}

impl Staged {
    /// Renames the file to its target (replacing what was there).
    pub fn place(self) -> Result<()> {
        persist(self.tmp, &self.target)
    }

    /// Moves the file to its target only where none is there at that moment (a link, which the
    /// filesystem refuses over an existing name): of two runs placing the same file at once,
    /// the second is refused instead of replacing the first's. `Ok(false)` where the target
    /// exists; the staged file is then removed.
    pub fn place_new(self) -> Result<bool> {
        let was = self.tmp.path().to_path_buf();
        let placed = readable(&was)
            .and_then(|()| flush(&was))
            .map_err(|e| Error::from(e).with_path(&self.target));
        let placed = placed.and_then(|()| match self.tmp.persist_noclobber(&self.target) {
            Ok(_) => Ok(true),
            Err(e) if e.error.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
            Err(e) => Err(Error::from(e.error).with_path(&self.target)),
        });
        live_temps().remove(&was);
        if placed? {
            sync_parent(&self.target);
            return Ok(true);
        }
        Ok(false)
    }

    /// Where it goes.
    pub fn target(&self) -> &Path {
        &self.target
    }
}

/// A folder of outputs (an acquisition, a set of pairs) written in full in a temporary folder
/// beside its target and moved there only when complete ([`StagedDir::place`]): a run that
/// fails or is stopped part way leaves the target as it was, even when it replaces an earlier
/// folder of the same kind (`--force`). Dropped unplaced, the temporary folder is removed.
pub struct StagedDir {
    tmp: tempfile::TempDir,
    target: PathBuf,
}

impl StagedDir {
    /// A new empty staging folder for `target` (on its filesystem, so placing it only renames).
    pub fn beside(target: &Path) -> Result<StagedDir> {
        // Its folder is made if missing, as the target's would be.
        let parent = folder_of(target);
        std::fs::create_dir_all(parent).map_err(|e| Error::from(e).with_path(parent))?;
        let tmp = make_beside(target, |b, dir| b.tempdir_in(dir))
            .map_err(|e| Error::from(e).with_path(target))?;
        // Stopped by Ctrl-C or SIGTERM, the destructor does not run: removed by the handler.
        live_temps().insert(tmp.path().to_path_buf());
        Ok(StagedDir {
            tmp,
            target: target.to_path_buf(),
        })
    }

    /// Where to write.
    pub fn path(&self) -> &Path {
        self.tmp.path()
    }

    /// Moves everything written into the target: the whole folder where there is none yet,
    /// else entry by entry into it, files replacing same-named ones (subfolders first and the
    /// top level's files last, so a manifest arrives after what it names). Renames only, so a
    /// full disk cannot stop it part way.
    pub fn place(self) -> Result<()> {
        let at = |e: std::io::Error| Error::from(e).with_path(&self.target);
        let src = self.tmp.path().to_path_buf();
        // From here on a signal must not remove what is not yet moved: that would leave a mix
        // of this run's entries and the target's earlier ones.
        live_temps().remove(&src);
        if !self.target.exists() {
            readable_dir(&src).map_err(at)?;
            std::fs::rename(&src, &self.target).map_err(at)?;
            let _ = self.tmp.keep();
        } else {
            // Every entry's place is checked first, so a clash moves nothing.
            if let Some((dest, what)) = clash(&src, &self.target) {
                return Err(Error::Usage(format!(
                    "{what} is in the way of what this run writes there; nothing was placed"
                ))
                .with_path(&dest));
            }
            merge_into(&src, &self.target).map_err(at)?;
        }
        sync_parent(&self.target);
        Ok(())
    }
}

/// The first place in folder `to` where an entry of folder `from` cannot go (a folder where a
/// file goes or the reverse), with what is there.
fn clash(from: &Path, to: &Path) -> Option<(PathBuf, &'static str)> {
    for e in std::fs::read_dir(from).ok()?.flatten() {
        let (p, dest) = (e.path(), to.join(e.file_name()));
        match (p.is_dir(), std::fs::symlink_metadata(&dest)) {
            (true, Ok(m)) if m.is_dir() => {
                if let Some(c) = clash(&p, &dest) {
                    return Some(c);
                }
            }
            (true, Ok(_)) => return Some((dest, "a file")),
            (false, Ok(m)) if m.is_dir() => return Some((dest, "a folder")),
            _ => {}
        }
    }
    None
}

/// Moves the entries of folder `from` into folder `to` (see [`StagedDir::place`]).
fn merge_into(from: &Path, to: &Path) -> std::io::Result<()> {
    let mut entries: Vec<(bool, PathBuf)> = std::fs::read_dir(from)?
        .map(|e| e.map(|e| (!e.path().is_dir(), e.path())))
        .collect::<std::io::Result<_>>()?;
    // Folders (false) before files (true), each in name order.
    entries.sort();
    for (is_file, p) in entries {
        let dest = to.join(p.file_name().unwrap_or_default());
        if !is_file && dest.is_dir() {
            merge_into(&p, &dest)?;
        } else {
            if !is_file {
                readable_dir(&p)?;
            }
            std::fs::rename(&p, &dest)?;
        }
    }
    Ok(())
}

/// Removes the files and folders in `dir` named `prefix`, six random letters or digits (as
/// `tempfile` names them), then `suffix`, that nothing has touched for `stale` (the newest
/// modification time of anything inside counts): what processes killed beyond any handler
/// (SIGKILL, a lost node) left. Each folder and name pattern is swept once per process: the
/// listing is not repeated for every file a run writes there.
pub(crate) fn remove_stale(dir: &Path, prefix: &str, suffix: &str, stale: std::time::Duration) {
    static SWEPT: std::sync::Mutex<Vec<(PathBuf, String)>> = std::sync::Mutex::new(Vec::new());
    {
        let mut swept = SWEPT.lock().unwrap_or_else(|e| e.into_inner());
        let key = (dir.to_path_buf(), format!("{prefix}\0{suffix}"));
        if swept.contains(&key) {
            return;
        }
        swept.push(key);
    }
    fn newest(p: &Path) -> Option<std::time::SystemTime> {
        let m = std::fs::symlink_metadata(p).ok()?;
        let mut t = m.modified().ok()?;
        if m.is_dir() {
            for e in std::fs::read_dir(p).ok()?.flatten() {
                t = t.max(newest(&e.path())?);
            }
        }
        Some(t)
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(name) = name.to_str() else { continue };
        let random = name
            .strip_prefix(prefix)
            .and_then(|r| r.strip_suffix(suffix))
            .is_some_and(|r| r.len() == 6 && r.bytes().all(|b| b.is_ascii_alphanumeric()));
        if !random {
            continue;
        }
        let p = e.path();
        let old = newest(&p)
            .and_then(|t| t.elapsed().ok())
            .is_some_and(|age| age > stale);
        if old {
            let _ = std::fs::remove_file(&p).or_else(|_| std::fs::remove_dir_all(&p));
        }
    }
}

/// A temporary output (a file, a staging folder, a Zarr writer's staging folder) untouched for
/// this long was left by a killed process, and the next run writing the same target removes it.
/// A live run touches what it writes more often: a frame or a file takes minutes at most. (A
/// finished output held back until the run's others are done is the exception: two runs that
/// write the same target an hour apart while the first still holds it would lose the first's.)
pub const STALE: std::time::Duration = std::time::Duration::from_secs(3600);

/// A temporary file in the target's directory, so the final rename stays on one filesystem.
/// Stale ones of the same target that killed processes left are removed ([`make_beside`]).
pub fn temp_beside(path: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    let tmp = make_beside(path, |b, dir| b.tempfile_in(dir))?;
    live_temps().insert(tmp.path().to_path_buf());
    Ok(tmp)
}

/// Makes a temporary file or folder (`make`) named `.NAME.…tmp` in `path`'s folder; its error
/// names that folder, not tempfile's random path.
pub(crate) fn make_beside<T>(
    path: &Path,
    make: impl FnOnce(&tempfile::Builder, &Path) -> std::io::Result<T>,
) -> std::io::Result<T> {
    let dir = folder_of(path);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let prefix = format!(".{name}.");
    // What killed processes left for this target, once stale ([`STALE`]).
    remove_stale(dir, &prefix, ".tmp", STALE);
    let mut b = tempfile::Builder::new();
    b.prefix(&prefix).suffix(".tmp");
    make(&b, dir).map_err(|e| {
        std::io::Error::new(
            e.kind(),
            match e.kind() {
                std::io::ErrorKind::NotFound => {
                    format!("the folder {} does not exist", dir.display())
                }
                k => format!("cannot write in the folder {}: {k}", dir.display()),
            },
        )
    })
}

/// Flushes a finished temporary file to disk and renames it to `target`. Works by the temporary
/// path, so it also covers a writer that replaced the file under that name (burn-store does).
pub fn persist(tmp: tempfile::NamedTempFile, target: &Path) -> Result<()> {
    let was = tmp.path().to_path_buf();
    let placed = readable(&was)
        .and_then(|()| flush(&was))
        .map_err(|e| Error::from(e).with_path(target))
        .and_then(|()| {
            tmp.persist(target)
                .map_err(|e| Error::from(e.error).with_path(target))
        });
    // Renamed, or removed with the guard on failure: either way no longer a live temporary.
    live_temps().remove(&was);
    placed?;
    sync_parent(target);
    Ok(())
}

/// Flushes the finished file `staged` to disk and renames it to `target` (on the same
/// filesystem, so a reader sees the old file or the new one whole, never part of one), then
/// flushes the folder entry: [`persist`]'s steps for a file another library wrote (a Zarr chunk
/// zarrs encoded in a staging folder).
pub(crate) fn move_into_place(staged: &Path, target: &Path) -> std::io::Result<()> {
    flush(staged)?;
    std::fs::rename(staged, target)?;
    sync_parent(target);
    Ok(())
}

/// Flushes a finished file's contents to disk, so that a rename never exposes a file whose
/// data is still only in memory.
fn flush(path: &Path) -> std::io::Result<()> {
    std::fs::File::open(path).and_then(|f| f.sync_all())
}

/// Flushes the entry of `path` in its folder (after a rename).
fn sync_parent(path: &Path) {
    sync_dir(folder_of(path));
}

/// The folder `path` is in (`.` for a bare file name).
pub(crate) fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Flushes a folder's entries (a rename or a new file in it) to disk; best effort, since not
/// every filesystem allows it.
pub(crate) fn sync_dir(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Temporary files made by [`temp_beside`] and not yet renamed into place, and staging folders
/// ([`StagedDir`], a Zarr writer's).
pub(crate) fn live_temps() -> std::sync::MutexGuard<'static, std::collections::BTreeSet<PathBuf>> {
    static LIVE: std::sync::Mutex<std::collections::BTreeSet<PathBuf>> =
        std::sync::Mutex::new(std::collections::BTreeSet::new());
    // A panic while the set was held leaves it usable: it only lists paths.
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

/// Removes every temporary output still being written (files, and [`StagedDir`]s with all they
/// hold), for a program that is being stopped (Ctrl-C, SIGTERM) and will not run the
/// destructors that normally remove them. Returns how many were removed.
pub fn remove_live_temps() -> usize {
    let mut live = live_temps();
    // Files, and staging folders ([`StagedDir`]) with all they hold. The run goes on writing
    // until the process exits, and may make a folder's subfolders again while it is removed:
    // a folder is removed until it stays gone.
    let n = live
        .iter()
        .filter(|p| {
            if std::fs::remove_file(p).is_ok() {
                return true;
            }
            let mut gone = false;
            for _ in 0..50 {
                let _ = std::fs::remove_dir_all(p);
                std::thread::sleep(std::time::Duration::from_millis(2));
                if !p.exists() {
                    if gone {
                        break;
                    }
                    gone = true;
                } else {
                    gone = false;
                }
            }
            gone
        })
        .count();
    live.clear();
    n
}

/// Writes `bytes` to `path` atomically (temporary file, then rename).
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<()> {
    stage_bytes(path.as_ref(), bytes)?.place()
}

/// `bytes` written in full beside `path` and flushed to disk, to be placed there with the other
/// outputs of the run ([`Staged`]): a full disk is met here, before any of them is placed.
pub fn stage_bytes(path: &Path, bytes: &[u8]) -> Result<Staged> {
    use std::io::Write;
    let mut tmp = temp_beside(path).map_err(|e| Error::from(e).with_path(path))?;
    tmp.write_all(bytes)
        .and_then(|()| tmp.as_file().sync_all())
        .map_err(|e| Error::from(e).with_path(path))?;
    Ok(Staged {
        tmp,
        target: path.to_path_buf(),
    })
}

/// Writes files that belong together (a profile's two files): every one in full beside its
/// target first, then each renamed into place. A failure while writing (a full disk) leaves
/// every earlier file as it was; only the renames, which need no space, come after it.
pub fn write_atomic_together(files: &[(&Path, &[u8])]) -> Result<()> {
    write_together(files, false).map(|_| ())
}

/// [`write_atomic_together`] where the last file marks the set (a profile's `profile.toml`):
/// it is placed only where none is there at that moment ([`Staged::place_new`]), and the
/// others after it. `Ok(false)`, with nothing placed, where one is.
pub fn write_new_together(files: &[(&Path, &[u8])]) -> Result<bool> {
    write_together(files, true)
}

fn write_together(files: &[(&Path, &[u8])], new: bool) -> Result<bool> {
    let mut staged = files
        .iter()
        .map(|&(path, bytes)| stage_bytes(path, bytes))
        .collect::<Result<Vec<_>>>()?;
    if new {
        let Some(marker) = staged.pop() else {
            return Ok(true);
        };
        if !marker.place_new()? {
            return Ok(false);
        }
    }
    staged.into_iter().try_for_each(Staged::place)?;
    Ok(true)
}

/// Writes one frame as an 8-bit grayscale PNG, mapping `lo..=hi` to 0..=255 (for previews).
pub fn write_png_preview(
    path: impl AsRef<Path>,
    width: usize,
    height: usize,
    data: &[f32],
    lo: f32,
    hi: f32,
) -> Result<()> {
    stage_png_preview(path.as_ref(), width, height, data, lo, hi)?.place()
}

/// [`write_png_preview`] written beside `path`, placed with the run's other outputs
/// ([`Staged`]).
pub fn stage_png_preview(
    path: &Path,
    width: usize,
    height: usize,
    data: &[f32],
    lo: f32,
    hi: f32,
) -> Result<Staged> {
    png_io::write_gray8(path, width, height, data, lo, hi)
}

/// Temporary folders are created owner-only; a finished store gets the usual 0755, so other
/// users (and other nodes' jobs) can read it.
pub(crate) fn readable_dir(path: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755))?;
    }
    #[cfg(not(unix))]
    let _ = path;
    Ok(())
}

/// Temporary files are created owner-only; finished outputs get the usual 0644.
pub fn readable(path: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o644))?;
    }
    #[cfg(not(unix))]
    let _ = path;
    Ok(())
}
