//! Andor SIF ("Andor Technology Multi-Channel File") reader, written here because no maintained
//! Rust crate reads the format and Andor publishes no specification.
//!
//! Layout, as seen in files from Solis and the Andor SDK (versions 65559–65567): a text header of
//! space-separated fields with a few binary bytes, a length-prefixed user text, version-dependent
//! calibration lines, then the image-structure line
//! `65538|65541 x0 y1 x1 y0 frames subimages total_len image_len`, one line per sub-image
//! `65538 x0 y1 x1 y0 ybin xbin 0`, one timestamp line per frame, an optional flag line, and the
//! pixel data: little-endian `f32`, frame after frame. Rather than skip a version-specific number
//! of lines, the reader finds the structure line by its arithmetic (`total = frames·image_len`,
//! sub-image areas summing to `image_len`), which also rejects a damaged header.

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use crate::{Error, Format, FrameReader, Limits, Metadata, PixelType, Result, StackInfo};

/// The first bytes of every SIF file.
pub const MAGIC: &[u8] = b"Andor Technology Multi-Channel File\n";

/// Header fields of a SIF file.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SifHeader {
    /// File-format version (e.g. 65567).
    pub version: u32,
    /// Exposure time in seconds.
    pub exposure_s: f64,
    /// Kinetic cycle time in seconds.
    pub cycle_time_s: f64,
    /// Accumulations per frame.
    pub accumulations: u32,
    /// EM gain setting (0 means the EM register was off).
    pub em_gain: f64,
    /// Detector temperature in °C, where recorded.
    pub temperature_c: Option<f64>,
    /// Detector model string (e.g. `DU897_BV`).
    pub detector: String,
    /// Full sensor size (columns, rows).
    pub sensor: (u32, u32),
    /// Frame width after binning.
    pub width: usize,
    /// Frame height after binning (sub-images stacked).
    pub height: usize,
    /// Horizontal and vertical binning.
    pub binning: (u32, u32),
    /// Frames the header declares.
    pub frames_declared: usize,
    /// Byte offset of the first frame.
    pub data_offset: u64,
}

/// Streams the frames of a SIF file (or any seekable source).
pub struct SifReader<R = File> {
    file: BufReader<R>,
    header: SifHeader,
    info: StackInfo,
    next: usize,
    bytes: Vec<u8>,
}

impl SifReader {
    /// Opens a file with the process's [`Limits`].
    pub fn open(path: &Path) -> Result<SifReader> {
        SifReader::new(File::open(path)?, Limits::process())
    }
}

impl<R: Read + Seek> SifReader<R> {
    /// Parses the header. A file cut short yields its whole frames, with a warning saying how
    /// many of the declared frames are missing.
    pub fn new(source: R, limits: Limits) -> Result<SifReader<R>> {
        let mut file = BufReader::new(source);
        let file_len = crate::stream_len(&mut file)?;
        let header = parse_header(&mut file, file_len)?;
        let frame_bytes = limits.frame_bytes(header.width, header.height, 4)?;
        let available = file_len.saturating_sub(header.data_offset) / frame_bytes;
        let frames = (available as usize).min(header.frames_declared);
        limits.stack(frames as u64)?;
        let mut metadata = Metadata {
            exposure_s: Some(header.exposure_s),
            em_gain: Some(header.em_gain),
            temperature_c: header.temperature_c,
            camera_model: Some(header.detector.clone()),
            binning: Some(header.binning),
            accumulations: Some(header.accumulations),
            warnings: Vec::new(),
        };
        if frames < header.frames_declared {
            let have = file_len - header.data_offset;
            metadata.warnings.push(format!(
                "truncated: the header declares {} frames ({} bytes of pixel data) but the file holds \
                 {} bytes after the header, so only frames 1–{} are whole; frames {}–{} are missing",
                header.frames_declared,
                frame_bytes.saturating_mul(header.frames_declared as u64),
                have,
                frames,
                frames + 1,
                header.frames_declared
            ));
        }
        if frames == 0 {
            return Err(Error::Format(format!(
                "truncated: the header declares {} frames of {}×{} but not one whole frame is present",
                header.frames_declared, header.width, header.height
            )));
        }
        file.seek(SeekFrom::Start(header.data_offset))?;
        let info = StackInfo {
            width: header.width,
            height: header.height,
            frames,
            pixel_type: PixelType::F32,
            format: Format::Sif,
            metadata,
        };
        Ok(SifReader {
            file,
            header,
            info,
            next: 0,
            bytes: vec![0; frame_bytes as usize],
        })
    }

    /// The parsed header.
    pub fn header(&self) -> &SifHeader {
        &self.header
    }
}

impl<R: Read + Seek + Send> FrameReader for SifReader<R> {
    fn info(&self) -> &StackInfo {
        &self.info
    }

    fn skip_frame(&mut self) -> Result<bool> {
        crate::skip_stored(
            &mut self.file,
            &mut self.next,
            self.info.frames,
            self.bytes.len(),
        )
    }

    fn read_frame(&mut self, out: &mut [f32]) -> Result<bool> {
        if self.next >= self.info.frames {
            return Ok(false);
        }
        crate::check_buffer(out, &self.info)?;
        self.file.read_exact(&mut self.bytes).map_err(|e| {
            Error::Format(format!(
                "frame {}: {e} (file changed while reading?)",
                self.next + 1
            ))
        })?;
        for (o, c) in out.iter_mut().zip(self.bytes.chunks_exact(4)) {
            *o = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
        self.next += 1;
        Ok(true)
    }
}

fn fmt_err(what: impl std::fmt::Display) -> Error {
    Error::Format(format!("SIF header: {what}"))
}

fn read_line(r: &mut impl BufRead, limit: usize) -> Result<Vec<u8>> {
    let mut line = Vec::new();
    let n = r.by_ref().take(limit as u64).read_until(b'\n', &mut line)?;
    if n == 0 {
        return Err(fmt_err("the file ends inside the header"));
    }
    Ok(line)
}

fn parse_header(r: &mut (impl BufRead + Seek), file_len: u64) -> Result<SifHeader> {
    let mut magic = vec![0u8; MAGIC.len()];
    r.read_exact(&mut magic)
        .map_err(|_| fmt_err("shorter than the SIF magic"))?;
    if magic != MAGIC {
        return Err(fmt_err(
            "missing the 'Andor Technology Multi-Channel File' magic",
        ));
    }
    read_line(r, 64)?; // "65538 1"
    let acq = acquisition(&read_line(r, 4096)?)?;
    let detector = String::from_utf8_lossy(&read_line(r, 256)?)
        .trim()
        .to_string();
    let dims = read_line(r, 256)?;
    let dims: Vec<u32> = String::from_utf8_lossy(&dims)
        .split_whitespace()
        .filter_map(|s| s.parse().ok())
        .collect();
    let sensor = (
        dims.first().copied().unwrap_or(0),
        dims.get(1).copied().unwrap_or(0),
    );

    // Find the image-structure line in the next 64 KiB by its arithmetic.
    let search_start = r.stream_position()?;
    let mut window = Vec::new();
    r.by_ref().take(64 * 1024).read_to_end(&mut window)?;
    let st = find_structure(&window).ok_or_else(|| {
        fmt_err("no consistent image-structure line (damaged or unknown version)")
    })?;
    r.seek(SeekFrom::Start(search_start + st.end as u64))?;
    let area = sub_images(r, st.sub_images, st.image_len)?;
    let data_offset = skip_frame_lines(r, st.frames, acq.version)?;
    if data_offset > file_len {
        return Err(fmt_err("the header runs past the end of the file"));
    }
    Ok(SifHeader {
        version: acq.version,
        exposure_s: acq.exposure_s,
        cycle_time_s: acq.cycle_time_s,
        accumulations: acq.accumulations,
        em_gain: acq.em_gain,
        temperature_c: acq.temperature_c,
        detector,
        sensor,
        width: area.width,
        height: area.height,
        binning: area.binning,
        frames_declared: st.frames,
        data_offset,
    })
}

/// What the acquisition line (the header's third) says, checked field by field.
struct Acquisition {
    version: u32,
    exposure_s: f64,
    cycle_time_s: f64,
    accumulations: u32,
    em_gain: f64,
    temperature_c: Option<f64>,
}

/// Reads the acquisition line; an error where a field is not what its place says.
fn acquisition(line: &[u8]) -> Result<Acquisition> {
    let tokens: Vec<&[u8]> = line
        .split(|&b| b == b' ' || b == b'\n')
        .filter(|t| !t.is_empty())
        .collect();
    let num = |t: &[u8]| {
        std::str::from_utf8(t)
            .ok()
            .and_then(|s| s.trim().parse::<f64>().ok())
    };
    if tokens.len() < 6 {
        return Err(fmt_err("the acquisition line has too few fields"));
    }
    let version = num(tokens[0]).ok_or_else(|| fmt_err("unreadable version"))? as u32;
    let temp_head = num(tokens[5]);
    // After the temperature come single binary bytes, at fixed places, between numeric fields:
    // 0, exposure, cycle time, accumulated cycle time, accumulations, stack cycle time, pixel
    // readout time, 0, 1, EM gain, … and (index 33) a second temperature field. Every field
    // must be what its place says: a damaged byte that joins, splits or turns a field would
    // otherwise shift every later one (a wrong exposure, EM gain or temperature read without
    // complaint). The places and counts are those of Solis/SDK files of versions 65559, 65564
    // and 65567 (`tests/data/emccd-real/andor-sif`).
    const BINARY: [usize; 8] = [6, 7, 8, 9, 10, 16, 27, 28];
    let binary = |t: &[u8]| t.len() == 1 && !t[0].is_ascii_graphic();
    let mut n = Vec::with_capacity(tokens.len());
    for (i, t) in tokens.iter().enumerate().skip(6) {
        let want_binary = BINARY.contains(&i);
        match (want_binary, num(t)) {
            (false, Some(v)) => n.push(v),
            (true, None) if binary(t) => {}
            (true, _) => {
                return Err(fmt_err(format!(
                    "damaged acquisition line: field {} ({:?}) should be a single binary byte",
                    i + 1,
                    String::from_utf8_lossy(t)
                )))
            }
            (false, None) => {
                return Err(fmt_err(format!(
                    "damaged acquisition line: field {} ({:?}) is not a number",
                    i + 1,
                    String::from_utf8_lossy(t)
                )))
            }
        }
    }
    let expected = match version {
        65559 => Some(61),
        65564 | 65567 => Some(77),
        _ => None,
    };
    if let Some(e) = expected.filter(|&e| e != tokens.len()) {
        return Err(fmt_err(format!(
            "damaged acquisition line: {} fields where version {version} has {e}",
            tokens.len()
        )));
    }
    if n.len() < 34 {
        return Err(fmt_err("the acquisition line has too few numeric fields"));
    }
    // What the fields must hold in any real recording.
    let temp_ok = |t: f64| t == -999.0 || (-150.0..=100.0).contains(&t);
    if !temp_head.is_some_and(temp_ok) || !temp_ok(n[33]) {
        return Err(fmt_err(format!(
            "damaged acquisition line: temperature {:?} / {} °C is not a detector temperature",
            temp_head, n[33]
        )));
    }
    // n[1] exposure, n[2] cycle time: a frame's exposure fits in its cycle (where one is set).
    if !(n[1].is_finite() && n[1] >= 0.0) || (n[2] > 0.0 && n[1] > n[2] * 1.001) {
        return Err(fmt_err(format!(
            "damaged acquisition line: exposure {} s with a cycle time of {} s",
            n[1], n[2]
        )));
    }
    if !(n[9] >= 0.0 && n[9] <= 10000.0 && n[9].fract() == 0.0) {
        return Err(fmt_err(format!(
            "damaged acquisition line: EM gain {} is not a gain setting",
            n[9]
        )));
    }
    let temperature_c = [temp_head, n.get(33).copied()]
        .into_iter()
        .flatten()
        .find(|&t| t != -999.0 && t.is_finite());
    Ok(Acquisition {
        version,
        exposure_s: n[1],
        cycle_time_s: n[2],
        accumulations: n[4].max(0.0) as u32,
        em_gain: n[9],
        temperature_c,
    })
}

/// The frame's area: the sub-images' common width, their summed height, the first's binning.
struct Area {
    width: usize,
    height: usize,
    binning: (u32, u32),
}

/// Reads the `subs` sub-image lines; an error unless they cover `image_len` pixels.
fn sub_images(r: &mut impl BufRead, subs: usize, image_len: usize) -> Result<Area> {
    let mut width = 0usize;
    let mut height = 0usize;
    let mut binning = (1, 1);
    for i in 0..subs {
        let line = read_line(r, 256)?;
        let v: Vec<i64> = String::from_utf8_lossy(&line)
            .split_whitespace()
            .filter_map(|s| s.parse().ok())
            .collect();
        if v.len() < 7 {
            return Err(fmt_err(format!("sub-image {} line is incomplete", i + 1)));
        }
        let (x0, y1, x1, y0, ybin, xbin) = (v[1], v[2], v[3], v[4], v[5], v[6]);
        if xbin <= 0 || ybin <= 0 || x1 < x0 || y1 < y0 {
            return Err(fmt_err(format!(
                "sub-image {} has an impossible area",
                i + 1
            )));
        }
        // Differences and sums in i128: a damaged header can hold any 64-bit values.
        let w = ((x1 as i128 - x0 as i128 + 1) / xbin as i128) as usize;
        let h = ((y1 as i128 - y0 as i128 + 1) / ybin as i128) as usize;
        if i == 0 {
            width = w;
            binning = (xbin as u32, ybin as u32);
        } else if w != width {
            return Err(Error::Unsupported(
                "SIF sub-images of different widths".into(),
            ));
        }
        height = height.saturating_add(h);
    }
    if width.checked_mul(height) != Some(image_len) {
        return Err(fmt_err(format!(
            "sub-images cover {}×{} pixels but the image length is {image_len}",
            width, height
        )));
    }
    Ok(Area {
        width,
        height,
        binning,
    })
}

/// Reads past the per-frame lines (timestamps, then the optional flag line and what it
/// announces); returns the offset of the pixel data.
fn skip_frame_lines(r: &mut (impl BufRead + Seek), frames: usize, version: u32) -> Result<u64> {
    // One timestamp line per frame (leading spaces allowed).
    for f in 0..frames {
        let line = read_line(r, 64)?;
        if String::from_utf8_lossy(&line)
            .trim()
            .parse::<i64>()
            .is_err()
        {
            return Err(fmt_err(format!(
                "timestamp of frame {} is not a number",
                f + 1
            )));
        }
    }
    // Optional flag line: "0", or (version 65567) "1" followed by one line per frame.
    let mut offset = r.stream_position()?;
    let peek = r.fill_buf()?.to_vec();
    if let Some(nl) = peek.iter().take(24).position(|&b| b == b'\n') {
        match std::str::from_utf8(&peek[..nl]).map(str::trim) {
            Ok("0") => offset += nl as u64 + 1,
            Ok("1") if version >= 65567 => {
                read_line(r, 24)?;
                for _ in 0..frames {
                    read_line(r, 64)?;
                }
                offset = r.stream_position()?;
            }
            _ => {}
        }
    }
    Ok(offset)
}

/// The image-structure line: where it ends (the offset after its newline) and what it says.
#[derive(Debug, PartialEq)]
struct Structure {
    end: usize,
    frames: usize,
    image_len: usize,
    sub_images: usize,
}

/// Finds the image-structure line by its arithmetic (frames × image length = total).
fn find_structure(w: &[u8]) -> Option<Structure> {
    let mut i = 0;
    while i + 6 < w.len() {
        if (w[i..].starts_with(b"65538 ") || w[i..].starts_with(b"65541 "))
            && (i == 0 || !w[i - 1].is_ascii_digit())
        {
            let end = w[i..].iter().position(|&b| b == b'\n').map(|p| i + p);
            if let Some(end) = end {
                let text = std::str::from_utf8(&w[i..end]).ok();
                let v: Option<Vec<u64>> =
                    text.and_then(|t| t.split(' ').map(|s| s.parse().ok()).collect());
                if let Some(v) = v {
                    if v.len() == 9 {
                        let (frames, subs, total, len) = (v[5], v[6], v[7], v[8]);
                        if frames > 0
                            && subs > 0
                            && len > 0
                            && frames.checked_mul(len) == Some(total)
                        {
                            return Some(Structure {
                                end: end + 1,
                                frames: frames as usize,
                                image_len: len as usize,
                                sub_images: subs as usize,
                            });
                        }
                    }
                }
            }
        }
        i += 1;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn structure_line_needs_consistent_arithmetic() {
        assert_eq!(
            find_structure(b"xx65538 1 512 512 1 4 1 1048576 262144\n"),
            Some(Structure {
                end: 39,
                frames: 4,
                image_len: 262144,
                sub_images: 1
            })
        );
        assert_eq!(
            find_structure(b"65538 1 512 512 1 4 1 1048575 262144\n"),
            None
        );
        assert_eq!(find_structure(b"65538 2048\n"), None);
    }
}
