//! FITS images and cubes: headers parsed with `fitsrs`, pixel data streamed frame by frame by
//! offset (so cubes larger than memory work), writing by hand (`fitsrs` only reads).
//!
//! Axes: `NAXIS1` is the width, `NAXIS2` the height, and all higher axes together count frames.
//! Pixels are returned in file order (first stored row first) with `BZERO`/`BSCALE` applied.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom, Write};
use std::path::Path;

use fitsrs::card::Value;
use fitsrs::hdu::header::Bitpix;
use fitsrs::{Fits, HDU};

use crate::{
    Error, Format, FrameReader, Limits, Metadata, PixelType, Result, SampleFormat, StackInfo,
};

const BLOCK: usize = 2880;

/// Streams the frames of the first image HDU that has at least two axes (from a file or any
/// seekable source).
pub struct FitsReader<R = File> {
    file: BufReader<R>,
    info: StackInfo,
    bitpix: i32,
    bzero: f64,
    bscale: f64,
    next: usize,
    bytes: Vec<u8>,
}

fn card_f64(v: Option<&Value>) -> Option<f64> {
    match v? {
        Value::Integer { value, .. } => Some(*value as f64),
        Value::Float { value, .. } => Some(*value),
        _ => None,
    }
}

fn card_string(v: Option<&Value>) -> Option<String> {
    match v? {
        Value::String { value, .. } => Some(value.trim().to_string()),
        _ => None,
    }
}

/// Reads the primary header's `NAXISn` cards (from the start of `f`) before `fitsrs` multiplies
/// them (it does so unchecked, and a damaged header can hold any 64-bit values): their product
/// must stay below 2⁵² pixels, so the arithmetic cannot overflow; the frame size itself is then
/// checked against the reader's limits and the file's length.
fn check_primary_axes(f: &mut impl Read) -> Result<()> {
    let mut card = [0u8; 80];
    let mut total: u64 = 1;
    // At most 36 header blocks of 36 cards: far more than any camera writes.
    for _ in 0..36 * 36 {
        if f.read_exact(&mut card).is_err() {
            return Ok(()); // a short file: fitsrs reports it
        }
        let key = std::str::from_utf8(&card[..8]).unwrap_or("").trim_end();
        if key == "END" {
            break;
        }
        if key
            .strip_prefix("NAXIS")
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
        {
            let v = std::str::from_utf8(&card[10..])
                .unwrap_or("")
                .split('/')
                .next()
                .unwrap_or("")
                .trim();
            let v: u64 = v
                .parse()
                .map_err(|_| Error::Format(format!("FITS header: {key} = {v:?} is not a size")))?;
            total = total
                .checked_mul(v)
                .filter(|&t| t <= 1 << 52)
                .ok_or_else(|| Error::Format(format!("FITS header: the axes multiply to more pixels than any file holds ({key} = {v}; a damaged header?)")))?;
        }
    }
    Ok(())
}

/// What the first image HDU with two or more axes holds: axes, BITPIX, BZERO, BSCALE, data
/// offset and metadata.
type Found = (Vec<u64>, i32, f64, f64, u64, Metadata);

/// `fitsrs` wants a `Debug` source; this one prints as its type, so readers need not be `Debug`.
struct Src<'a, R>(&'a mut BufReader<R>);

impl<R> std::fmt::Debug for Src<'_, R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("FITS source")
    }
}

impl<R: Read> Read for Src<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.0.read(buf)
    }
}

impl<R: Seek> Seek for Src<'_, R> {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.0.seek(pos)
    }
}

/// Walks the HDUs (from the start of `f`) to the first image with two or more axes.
fn find_image<R: Read + Seek>(f: &mut BufReader<R>) -> Result<Option<Found>> {
    let mut hdus = Fits::from_reader(Src(f));
    let mut found = None;
    for hdu in &mut hdus {
        let hdu = hdu.map_err(|e| {
            // The parser reports a header cut off before its END card as a bare I/O error.
            let what = format!("{e}");
            Error::Format(if what.contains("UnexpectedEof") {
                "FITS header: the file ends inside a header (no END card)".into()
            } else {
                format!("FITS header: {what}")
            })
        })?;
        let image = match hdu {
            HDU::Primary(h) | HDU::XImage(h) => h,
            _ => continue,
        };
        let x = image.get_header().get_xtension();
        let naxis = x.get_naxis().to_vec();
        if naxis.len() >= 2 && naxis.iter().all(|&n| n > 0) {
            let bitpix: i32 = match x.get_bitpix() {
                Bitpix::U8 => 8,
                Bitpix::I16 => 16,
                Bitpix::I32 => 32,
                Bitpix::I64 => 64,
                Bitpix::F32 => -32,
                Bitpix::F64 => -64,
            };
            let h = image.get_header();
            let meta = Metadata {
                exposure_s: card_f64(h.get("EXPTIME")).or_else(|| card_f64(h.get("EXPOSURE"))),
                em_gain: card_f64(h.get("EMGAIN")).or_else(|| card_f64(h.get("EM_GAIN"))),
                temperature_c: card_f64(h.get("CCD-TEMP")).or_else(|| card_f64(h.get("TEMPERAT"))),
                camera_model: card_string(h.get("INSTRUME"))
                    .or_else(|| card_string(h.get("DETECTOR"))),
                ..Default::default()
            };
            found = Some((
                naxis,
                bitpix,
                card_f64(h.get("BZERO")).unwrap_or(0.0),
                card_f64(h.get("BSCALE")).unwrap_or(1.0),
                image.get_data_unit_byte_offset(),
                meta,
            ));
            break;
        }
    }
    Ok(found)
}

impl FitsReader {
    /// Opens a file with the process's [`Limits`].
    pub fn open(path: &Path) -> Result<FitsReader> {
        FitsReader::new(File::open(path)?, Limits::process())
    }
}

impl<R: Read + Seek> FitsReader<R> {
    /// Reads the headers and locates the image data.
    pub fn new(source: R, limits: Limits) -> Result<FitsReader<R>> {
        let mut file = BufReader::new(source);
        let file_len = crate::stream_len(&mut file)?;
        check_primary_axes(&mut file)?;
        file.seek(SeekFrom::Start(0))?;
        // fitsrs 0.4.1 panics on some malformed cards (a value of a lone quote slices
        // s[1..0]; found by fuzzing): such a header is an error like any other damage.
        let found = crate::quietly("FITS header", || find_image(&mut file))?;
        let (naxis, bitpix, bzero, bscale, offset, mut metadata) = found
            .ok_or_else(|| Error::Format("FITS: no image HDU with two or more axes".into()))?;
        let (width, height) = (naxis[0] as usize, naxis[1] as usize);
        let frames_declared = naxis[2..]
            .iter()
            .try_fold(1u64, |a, &n| a.checked_mul(n))
            .unwrap_or(u64::MAX);
        let frames_declared = usize::try_from(frames_declared).unwrap_or(usize::MAX);
        let bpp = (bitpix.unsigned_abs() / 8) as usize;
        let frame_bytes = limits.frame_bytes(width, height, bpp)?;
        let whole = (file_len.saturating_sub(offset) / frame_bytes) as usize;
        let frames = whole.min(frames_declared);
        limits.stack(frames as u64)?;
        if frames == 0 {
            return Err(Error::Format(format!(
                "FITS data ends early: {width}×{height} frame of {frame_bytes} bytes at offset {offset}, file is {file_len} bytes"
            )));
        }
        if frames < frames_declared {
            metadata.warnings.push(format!(
                "truncated: {frames_declared} frames declared, only {frames} whole frames present"
            ));
        }
        let pixel_type = match (bitpix, bzero, bscale) {
            (8, _, _) => PixelType::U8,
            (16, z, s) if z == 32768.0 && s == 1.0 => PixelType::U16,
            (16, _, _) => PixelType::I16,
            (32, _, _) => PixelType::I32,
            (64, _, _) | (-64, _, _) => PixelType::F64,
            _ => PixelType::F32,
        };
        file.seek(SeekFrom::Start(offset))?;
        Ok(FitsReader {
            file,
            info: StackInfo {
                width,
                height,
                frames,
                pixel_type,
                format: Format::Fits,
                metadata,
            },
            bitpix,
            bzero,
            bscale,
            next: 0,
            bytes: vec![0; frame_bytes as usize],
        })
    }
}

impl<R: Read + Seek + Send> FrameReader for FitsReader<R> {
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
        self.file
            .read_exact(&mut self.bytes)
            .map_err(|e| Error::Format(format!("frame {}: {e}", self.next)))?;
        let (z, s) = (self.bzero, self.bscale);
        macro_rules! conv {
            ($t:ty, $n:expr) => {
                for (o, c) in out.iter_mut().zip(self.bytes.chunks_exact($n)) {
                    let raw = <$t>::from_be_bytes(c.try_into().unwrap());
                    *o = (z + s * raw as f64) as f32;
                }
            };
        }
        match self.bitpix {
            8 => conv!(u8, 1),
            16 => conv!(i16, 2),
            32 => conv!(i32, 4),
            64 => conv!(i64, 8),
            -32 => conv!(f32, 4),
            _ => conv!(f64, 8),
        }
        self.next += 1;
        Ok(true)
    }
}

fn card(key: &str, value: &str, comment: &str) -> [u8; 80] {
    let mut c = [b' '; 80];
    let text = if value.is_empty() {
        format!("{key:<8}")
    } else if comment.is_empty() {
        format!("{key:<8}= {value:>20}")
    } else {
        format!("{key:<8}= {value:>20} / {comment}")
    };
    let b = text.as_bytes();
    let n = b.len().min(80);
    c[..n].copy_from_slice(&b[..n]);
    c
}

fn quoted(s: &str) -> String {
    let clean: String = s
        .chars()
        .filter(|c| c.is_ascii() && !c.is_ascii_control())
        .collect();
    format!("'{:<8}'", clean.replace('\'', "''"))
}

/// Writes a FITS cube to a temporary file; see [`crate::StackWriter`].
pub(crate) struct FitsStackWriter {
    tmp: tempfile::NamedTempFile,
    file: std::io::BufWriter<File>,
    sample: SampleFormat,
    width: usize,
    height: usize,
    meta: Metadata,
    notes: Vec<String>,
    header_written: bool,
    naxis_card: u64,
    bytes: Vec<u8>,
    data_len: u64,
}

impl FitsStackWriter {
    pub(crate) fn new(
        tmp: tempfile::NamedTempFile,
        width: usize,
        height: usize,
        sample: SampleFormat,
        _frames_hint: Option<usize>,
    ) -> Result<Self> {
        let file = std::io::BufWriter::new(tmp.as_file().try_clone()?);
        Ok(FitsStackWriter {
            tmp,
            file,
            sample,
            width,
            height,
            meta: Metadata::default(),
            notes: Vec::new(),
            header_written: false,
            naxis_card: 2,
            bytes: Vec::new(),
            data_len: 0,
        })
    }

    pub(crate) fn set_metadata(&mut self, meta: &Metadata) {
        self.meta = meta.clone();
    }

    pub(crate) fn set_notes(&mut self, notes: &[String]) {
        self.notes = notes.to_vec();
    }

    fn write_header(&mut self) -> Result<()> {
        let mut cards: Vec<[u8; 80]> = vec![
            card("SIMPLE", "T", "conforms to FITS standard"),
            card(
                "BITPIX",
                match self.sample {
                    SampleFormat::U8 => "8",
                    SampleFormat::U16 => "16",
                    SampleFormat::F32 => "-32",
                },
                "array data type",
            ),
            card("NAXIS", "3", "width, height, frames"),
            card("NAXIS1", &self.width.to_string(), ""),
            card("NAXIS2", &self.height.to_string(), ""),
            card("NAXIS3", &format!("{:>10}", 0), "frames"),
        ];
        if self.sample == SampleFormat::U16 {
            cards.push(card("BZERO", "32768", "unsigned 16-bit data"));
            cards.push(card("BSCALE", "1", ""));
        }
        if let Some(e) = self.meta.exposure_s {
            cards.push(card("EXPTIME", &format!("{e:E}"), "exposure time [s]"));
        }
        if let Some(g) = self.meta.em_gain {
            cards.push(card("EMGAIN", &format!("{g:E}"), "EM gain setting"));
        }
        if let Some(c) = &self.meta.camera_model {
            cards.push(card("INSTRUME", &quoted(c), "camera"));
        }
        cards.push(card("ORIGIN", &quoted("emccd"), ""));
        // Free text as HISTORY cards, 72 characters each (FITS headers are ASCII).
        for note in &self.notes {
            let ascii: String = note
                .chars()
                .map(|c| {
                    if c.is_ascii() && !c.is_ascii_control() {
                        c
                    } else {
                        '?'
                    }
                })
                .collect();
            for part in ascii.as_bytes().chunks(72) {
                let mut c = [b' '; 80];
                c[..8].copy_from_slice(b"HISTORY ");
                c[8..8 + part.len()].copy_from_slice(part);
                cards.push(c);
            }
        }
        cards.push(card("END", "", ""));
        let mut block = Vec::with_capacity(BLOCK);
        for c in &cards {
            block.extend_from_slice(c);
        }
        block.resize(block.len().div_ceil(BLOCK) * BLOCK, b' ');
        self.file.write_all(&block)?;
        self.naxis_card = 2;
        self.header_written = true;
        Ok(())
    }

    pub(crate) fn write_frame(&mut self, frame: &[f32]) -> Result<()> {
        if !self.header_written {
            self.write_header()?;
        }
        self.bytes.clear();
        match self.sample {
            SampleFormat::U8 => {
                for &x in frame {
                    self.bytes.push(if x.is_nan() {
                        0
                    } else {
                        x.round().clamp(0.0, 255.0) as u8
                    });
                }
            }
            SampleFormat::U16 => {
                for &x in frame {
                    let v = if x.is_nan() {
                        0.0
                    } else {
                        x.round().clamp(0.0, 65535.0)
                    };
                    let raw = (v as i32 - 32768) as i16;
                    self.bytes.extend_from_slice(&raw.to_be_bytes());
                }
            }
            SampleFormat::F32 => {
                for &x in frame {
                    self.bytes.extend_from_slice(&x.to_be_bytes());
                }
            }
        }
        self.file.write_all(&self.bytes)?;
        self.data_len += self.bytes.len() as u64;
        Ok(())
    }

    pub(crate) fn finish(mut self, frames: usize) -> Result<tempfile::NamedTempFile> {
        if frames == 0 {
            return Err(Error::Usage("no frames were written".into()));
        }
        let pad = (BLOCK as u64 - self.data_len % BLOCK as u64) % BLOCK as u64;
        self.file.write_all(&vec![0u8; pad as usize])?;
        // Patch the axis cards now that the frame count is known.
        let (naxis, naxis3) = if frames == 1 {
            (card("NAXIS", "2", "width, height"), [b' '; 80])
        } else {
            (
                card("NAXIS", "3", "width, height, frames"),
                card("NAXIS3", &frames.to_string(), "frames"),
            )
        };
        self.file.seek(SeekFrom::Start(self.naxis_card * 80))?;
        self.file.write_all(&naxis)?;
        self.file.seek(SeekFrom::Start(5 * 80))?;
        self.file.write_all(&naxis3)?;
        self.file.flush()?;
        drop(self.file);
        Ok(self.tmp)
    }
}

#[cfg(test)]
mod tests {
    use crate::{open, read_all, Metadata, SampleFormat, StackWriter};

    #[test]
    fn fits_roundtrip_u16_and_f32() {
        let dir = tempfile::tempdir().unwrap();
        for (sample, frames) in [
            (SampleFormat::U16, 3usize),
            (SampleFormat::F32, 1),
            (SampleFormat::U8, 2),
        ] {
            let p = dir.path().join(format!("x{frames}.fits"));
            let (w, h) = (9, 4);
            let data: Vec<Vec<f32>> = (0..frames)
                .map(|k| {
                    (0..w * h)
                        .map(|i| (i as f32) * 1000.0 + k as f32 + 0.5)
                        .collect()
                })
                .collect();
            let mut wr = StackWriter::create(&p, w, h, sample, None).unwrap();
            wr.set_metadata(&Metadata {
                exposure_s: Some(0.05),
                em_gain: Some(300.0),
                ..Default::default()
            });
            for f in &data {
                wr.write_frame(f).unwrap();
            }
            wr.finish().unwrap();
            assert_eq!(std::fs::metadata(&p).unwrap().len() % 2880, 0);
            let (info, got) = read_all(&p).unwrap();
            assert_eq!((info.width, info.height, info.frames), (w, h, frames));
            assert_eq!(info.metadata.exposure_s, Some(0.05));
            assert_eq!(info.metadata.em_gain, Some(300.0));
            for (a, b) in got.iter().zip(&data) {
                for (x, y) in a.iter().zip(b) {
                    let want = match sample {
                        SampleFormat::U16 => y.round().min(65535.0),
                        SampleFormat::U8 => y.round().min(255.0),
                        SampleFormat::F32 => *y,
                    };
                    assert_eq!(*x, want);
                }
            }
            let _ = open(&p).unwrap();
        }
    }
}
