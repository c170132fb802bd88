//! TIFF and BigTIFF stacks through the `tiff` crate: one page per frame.
//!
//! Stacks written here carry no ImageJ description: an `ImageJ=` description with `images=N`
//! tells readers (tifffile, Fiji) that the frames lie contiguously after the first page's data,
//! but the `tiff` crate writes each page's directory between frames, so those readers would
//! read every frame after the first from the wrong offset. Without it they walk the page chain,
//! which is correct, and still open a multi-page file as a stack. Camera metadata goes in plain
//! `exposure_s=`/`em_gain=` lines on the first page, which this reader reads back.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use tiff::decoder::{Decoder, DecodingResult};
use tiff::encoder::{colortype, TiffEncoder, TiffKindBig, TiffKindStandard};
use tiff::tags::Tag;
use tiff::ColorType;

use crate::{
    Error, Format, FrameReader, Limits, Metadata, PixelType, Result, SampleFormat, StackInfo,
};

/// Streams the pages of a TIFF or BigTIFF file (or any seekable source).
pub struct TiffReader<R: Read + Seek = File> {
    decoder: Decoder<BufReader<R>>,
    info: StackInfo,
    next: usize,
    buf: DecodingResult,
    /// Samples per pixel: 1 (grayscale) or 3 (RGB, read as BT.601 luminance like PNG).
    channels: usize,
    /// RGB stored as three separate planes (PlanarConfiguration 2), not interleaved.
    planar: bool,
}

impl TiffReader {
    /// Opens a file with the process's [`Limits`].
    pub fn open(path: &Path) -> Result<TiffReader> {
        TiffReader::new(File::open(path)?, Limits::process())
    }
}

impl<R: Read + Seek> TiffReader<R> {
    /// Reads the header, counts the pages and reads the first page's metadata.
    pub fn new(source: R, limits: Limits) -> Result<TiffReader<R>> {
        let mut source = BufReader::new(source);
        let mut head = [0u8; 4];
        source.read_exact(&mut head)?;
        let len = crate::stream_len(&mut source)?;
        source.seek(SeekFrom::Start(0))?;
        let big = head[2] == 43 || head[3] == 43;
        let mut tl = tiff::decoder::Limits::default();
        let cap = usize::try_from(limits.bytes).unwrap_or(usize::MAX);
        tl.decoding_buffer_size = cap;
        tl.intermediate_buffer_size = tl.intermediate_buffer_size.min(cap);
        tl.ifd_value_size = tl.ifd_value_size.min(cap);
        let mut decoder = Decoder::new(source)?.with_limits(tl);
        let (w, h) = decoder.dimensions()?;
        let ct = decoder.colortype()?;
        let description = match decoder.find_tag(Tag::ImageDescription)? {
            Some(v) => v.into_string().ok(),
            None => None,
        };
        let (pixel_type, channels) = page_pixel_type(&mut decoder, ct)?;
        // PlanarConfiguration 2: the page's samples come plane after plane (all red, then all
        // green, then all blue).
        let planar = channels > 1
            && decoder
                .find_tag_unsigned::<u16>(Tag::PlanarConfiguration)?
                .unwrap_or(1)
                == 2;
        let compression = decoder
            .find_tag_unsigned::<u16>(Tag::Compression)?
            .unwrap_or(1);
        // A page cannot unpack to more than its compression's best ratio times the file: an
        // uncompressed page must fit in it, PackBits codes at most 128 bytes in 2, Deflate about
        // 1032:1, and an LZW code (9 bits or more) stands for at most 4096 bytes. A claim past
        // that is damage whatever the limits, and would otherwise have callers allocate it
        // before the first read fails (found by review: 289 bytes claiming a 1 GiB frame).
        let ratio: Option<u128> = match compression {
            1 => Some(1),
            32773 => Some(64),
            8 | 32946 => Some(1100),
            5 => Some(4096),
            _ => None,
        };
        let bytes = (w as u128) * (h as u128) * channels as u128 * pixel_type.bytes() as u128;
        if let Some(r) = ratio.filter(|&r| bytes > r * len as u128) {
            return Err(Error::Format(if r == 1 {
                format!("page 0 claims {w}×{h} uncompressed pixels ({bytes} bytes), but the file holds {len} bytes")
            } else {
                format!("page 0 claims {w}×{h} pixels ({bytes} bytes), more than compression {compression} can unpack from a file of {len} bytes")
            }));
        }
        // The limits every reader applies before a caller sizes a frame buffer from the header
        // (a compressed page's claim is not bounded by the file's length; found by fuzzing:
        // 1.7·10⁹×8 pixels in a few hundred bytes).
        limits.frame(w as usize, h as usize, channels * pixel_type.bytes())?;
        // Walk the IFD chain to count pages; every page must match the first.
        let mut frames = 1;
        while decoder.more_images() {
            decoder.next_image()?;
            let (pw, ph) = decoder.dimensions()?;
            if (pw, ph) != (w, h) {
                return Err(Error::Format(format!(
                    "page {frames} is {pw}×{ph}, but page 0 is {w}×{h}; a stack needs one frame size"
                )));
            }
            frames += 1;
            limits.stack(frames as u64)?;
        }
        decoder.seek_to_image(0)?;
        let mut metadata = description
            .as_deref()
            .map(parse_description)
            .unwrap_or_default();
        if planar {
            metadata.warnings.push(
                "an RGB image with separate planes, read as its luminance (one frame); a stack \
                 of 3 frames written by tifffile without photometric='minisblack' looks like \
                 this: write it again with that option to read it as 3 frames"
                    .into(),
            );
        }
        let info = StackInfo {
            width: w as usize,
            height: h as usize,
            frames,
            pixel_type,
            format: if big { Format::BigTiff } else { Format::Tiff },
            metadata,
        };
        Ok(TiffReader {
            decoder,
            info,
            next: 0,
            buf: DecodingResult::U16(Vec::new()),
            channels,
            planar,
        })
    }
}

fn page_pixel_type<R: Read + Seek>(
    decoder: &mut Decoder<R>,
    ct: ColorType,
) -> Result<(PixelType, usize)> {
    // Colour images (clean training scenes such as McMaster) are read as luminance.
    let (bits, channels) = match ct {
        ColorType::Gray(b) => (b, 1),
        ColorType::RGB(b) => (b, 3),
        other => {
            return Err(Error::Unsupported(format!(
                "TIFF colour type {other:?}; EMCCD stacks are single-channel grayscale (RGB is read as luminance)"
            )))
        }
    };
    // SampleFormat: 1 = unsigned, 2 = signed, 3 = IEEE float; one value per channel (an RGB
    // image has three, which must agree).
    let fmts = decoder
        .find_tag_unsigned_vec::<u16>(Tag::SampleFormat)?
        .unwrap_or_default();
    let fmt = fmts.first().copied().unwrap_or(1);
    if fmts.iter().any(|&f| f != fmt) {
        return Err(Error::Unsupported(format!(
            "TIFF channels of different sample formats ({fmts:?})"
        )));
    }
    Ok((
        match (fmt, bits) {
            (1, 8) => PixelType::U8,
            (1, 16) => PixelType::U16,
            (2, 16) => PixelType::I16,
            (1, 32) => PixelType::U32,
            (2, 32) => PixelType::I32,
            (3, 32) => PixelType::F32,
            (3, 64) => PixelType::F64,
            _ => {
                return Err(Error::Unsupported(format!(
                    "TIFF samples of {bits} bits with SampleFormat {fmt}"
                )))
            }
        },
        channels,
    ))
}

/// Reads `key=value` lines of an ImageJ-style description.
fn parse_description(desc: &str) -> Metadata {
    let mut m = Metadata::default();
    for line in desc.lines() {
        let Some((k, v)) = line.split_once('=') else {
            continue;
        };
        let v = v.trim();
        match k.trim() {
            "exposure_s" => m.exposure_s = v.parse().ok(),
            "em_gain" => m.em_gain = v.parse().ok(),
            "temperature_c" => m.temperature_c = v.parse().ok(),
            "camera" => m.camera_model = Some(v.to_string()),
            _ => {}
        }
    }
    m
}

impl<R: Read + Seek + Send> FrameReader for TiffReader<R> {
    fn info(&self) -> &StackInfo {
        &self.info
    }

    fn skip_frame(&mut self) -> Result<bool> {
        if self.next >= self.info.frames {
            return Ok(false);
        }
        // Pages are reached through the IFD chain: follow it without decoding this page.
        if self.next > 0 {
            self.decoder.next_image()?;
        }
        self.next += 1;
        Ok(true)
    }

    fn read_frame(&mut self, out: &mut [f32]) -> Result<bool> {
        if self.next >= self.info.frames {
            return Ok(false);
        }
        crate::check_buffer(out, &self.info)?;
        if self.next > 0 {
            self.decoder.next_image()?;
        }
        let page = self.next;
        self.decoder
            .read_image_to_buffer(&mut self.buf)
            .map_err(Error::from)
            .map_err(|e| Error::Format(format!("page {page}: {e}")))?;
        let n = out.len();
        let ch = self.channels;
        macro_rules! conv {
            ($v:expr) => {{
                if $v.len() < n * ch {
                    return Err(Error::Format(format!(
                        "page {page} holds {} samples, expected {}",
                        $v.len(),
                        n * ch
                    )));
                }
                if ch == 3 && self.planar {
                    let (r, rest) = $v.split_at(n);
                    let (g, b) = rest.split_at(n);
                    for (i, o) in out.iter_mut().enumerate() {
                        *o = 0.299 * r[i] as f32 + 0.587 * g[i] as f32 + 0.114 * b[i] as f32;
                    }
                } else if ch == 3 {
                    for (o, p) in out.iter_mut().zip($v.chunks_exact(3)) {
                        *o = 0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32;
                    }
                } else {
                    for (o, &x) in out.iter_mut().zip($v.iter()) {
                        *o = x as f32;
                    }
                }
            }};
        }
        match &self.buf {
            DecodingResult::U8(v) => conv!(v),
            DecodingResult::U16(v) => conv!(v),
            DecodingResult::I16(v) => conv!(v),
            DecodingResult::U32(v) => conv!(v),
            DecodingResult::I32(v) => conv!(v),
            DecodingResult::F32(v) => conv!(v),
            DecodingResult::F64(v) => conv!(v),
            _ => return Err(Error::Unsupported(format!("page {page}: sample type"))),
        }
        self.next += 1;
        Ok(true)
    }
}

enum Enc {
    Standard(TiffEncoder<File, TiffKindStandard>),
    Big(TiffEncoder<File, TiffKindBig>),
}

/// Writes pages to a temporary file; see [`crate::StackWriter`].
pub(crate) struct TiffStackWriter {
    tmp: tempfile::NamedTempFile,
    enc: Enc,
    width: u32,
    height: u32,
    sample: SampleFormat,
    description: Option<String>,
    u16buf: Vec<u16>,
    u8buf: Vec<u8>,
    pages: usize,
}

impl TiffStackWriter {
    pub(crate) fn new(
        tmp: tempfile::NamedTempFile,
        big: bool,
        width: usize,
        height: usize,
        sample: SampleFormat,
        frames_hint: Option<usize>,
    ) -> Result<Self> {
        let file = tmp.as_file().try_clone()?;
        let enc = if big {
            Enc::Big(TiffEncoder::new_big(file)?)
        } else {
            Enc::Standard(TiffEncoder::new(file)?)
        };
        // The frame count is not recorded: see the module documentation.
        let _ = frames_hint;
        let description = None;
        Ok(TiffStackWriter {
            tmp,
            enc,
            width: width as u32,
            height: height as u32,
            sample,
            description,
            u16buf: Vec::new(),
            u8buf: Vec::new(),
            pages: 0,
        })
    }

    /// Adds `key=value` lines (e.g. `exposure_s`) to the first page's description.
    pub(crate) fn set_extra(&mut self, extra: &str) {
        let d = self.description.get_or_insert_with(String::new);
        d.push_str(extra);
    }

    pub(crate) fn write_frame(&mut self, frame: &[f32]) -> Result<()> {
        let desc = if self.pages == 0 {
            self.description.clone()
        } else {
            None
        };
        let (w, h) = (self.width, self.height);
        macro_rules! page {
            ($enc:expr) => {{
                match self.sample {
                    SampleFormat::U8 => {
                        self.u8buf.clear();
                        // Finite: the stack writer refuses NaN and infinities.
                        self.u8buf
                            .extend(frame.iter().map(|&x| x.round().clamp(0.0, 255.0) as u8));
                        let mut img = $enc.new_image::<colortype::Gray8>(w, h)?;
                        if let Some(d) = &desc {
                            img.encoder().write_tag(Tag::ImageDescription, d.as_str())?;
                        }
                        img.write_data(&self.u8buf)?;
                    }
                    SampleFormat::U16 => {
                        self.u16buf.clear();
                        // Finite: the stack writer refuses NaN and infinities.
                        self.u16buf
                            .extend(frame.iter().map(|&x| x.round().clamp(0.0, 65535.0) as u16));
                        let mut img = $enc.new_image::<colortype::Gray16>(w, h)?;
                        if let Some(d) = &desc {
                            img.encoder().write_tag(Tag::ImageDescription, d.as_str())?;
                        }
                        img.write_data(&self.u16buf)?;
                    }
                    SampleFormat::F32 => {
                        let mut img = $enc.new_image::<colortype::Gray32Float>(w, h)?;
                        if let Some(d) = &desc {
                            img.encoder().write_tag(Tag::ImageDescription, d.as_str())?;
                        }
                        img.write_data(frame)?;
                    }
                }
            }};
        }
        match &mut self.enc {
            Enc::Standard(e) => page!(e),
            Enc::Big(e) => page!(e),
        }
        self.pages += 1;
        Ok(())
    }

    pub(crate) fn finish(self) -> Result<tempfile::NamedTempFile> {
        if self.pages == 0 {
            return Err(Error::Usage("no frames were written".into()));
        }
        drop(self.enc);
        Ok(self.tmp)
    }
}

impl crate::StackWriter {
    /// Records camera metadata (`exposure_s=…` lines) in a TIFF stack's description; call before
    /// the first frame. No effect on FITS (use its header) — see [`crate::fits`].
    pub fn set_metadata(&mut self, meta: &Metadata) {
        let mut extra = String::new();
        if let Some(e) = meta.exposure_s {
            extra.push_str(&format!("exposure_s={e}\n"));
        }
        if let Some(g) = meta.em_gain {
            extra.push_str(&format!("em_gain={g}\n"));
        }
        if let Some(c) = &meta.camera_model {
            extra.push_str(&format!("camera={c}\n"));
        }
        match &mut self.inner {
            crate::WriterKind::Tiff(w) => w.set_extra(&extra),
            crate::WriterKind::Fits(w) => w.set_metadata(meta),
        }
    }

    /// Records `key=value` lines about how the stack was made (a TIFF's description lines, a
    /// FITS header's HISTORY cards); call before the first frame.
    pub fn set_notes(&mut self, notes: &[String]) {
        match &mut self.inner {
            crate::WriterKind::Tiff(w) => {
                // The description is an ASCII tag: other characters would make the file
                // unreadable.
                let text: String = notes
                    .iter()
                    .map(|n| {
                        n.chars()
                            .map(|c| if c.is_ascii() { c } else { '?' })
                            .collect::<String>()
                            + "\n"
                    })
                    .collect();
                w.set_extra(&text)
            }
            crate::WriterKind::Fits(w) => w.set_notes(notes),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{open, StackWriter};

    fn roundtrip(ext: &str, sample: SampleFormat) {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(format!("s.{ext}"));
        let (w, h) = (7, 5);
        let frames: Vec<Vec<f32>> = (0..3)
            .map(|k| {
                (0..w * h)
                    .map(|i| (i * 100 + k * 7) as f32 + 0.25)
                    .collect()
            })
            .collect();
        let mut wr = StackWriter::create(&p, w, h, sample, Some(3)).unwrap();
        wr.set_metadata(&Metadata {
            exposure_s: Some(0.01),
            em_gain: Some(300.0),
            ..Default::default()
        });
        for f in &frames {
            wr.write_frame(f).unwrap();
        }
        wr.finish().unwrap();
        let mut r = open(&p).unwrap();
        let info = r.info().clone();
        assert_eq!((info.width, info.height, info.frames), (w, h, 3));
        assert_eq!(info.metadata.exposure_s, Some(0.01));
        assert_eq!(info.metadata.em_gain, Some(300.0));
        let mut buf = vec![0f32; w * h];
        for f in &frames {
            assert!(r.read_frame(&mut buf).unwrap());
            for (a, b) in buf.iter().zip(f) {
                let want = if sample == SampleFormat::U16 {
                    b.round()
                } else {
                    *b
                };
                assert_eq!(*a, want);
            }
        }
        assert!(!r.read_frame(&mut buf).unwrap());
        // Only the final file remains: no temporary left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn tiff_u16_roundtrip() {
        roundtrip("tif", SampleFormat::U16);
    }

    #[test]
    fn tiff_f32_roundtrip() {
        roundtrip("tif", SampleFormat::F32);
    }

    #[test]
    fn tiff_u8_roundtrip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("b.tif");
        let mut wr = StackWriter::create(&p, 3, 1, SampleFormat::U8, Some(2)).unwrap();
        wr.write_frame(&[0.0, 127.6, 300.0]).unwrap();
        wr.write_frame(&[1.0, 2.0, 3.0]).unwrap();
        wr.finish().unwrap();
        let (info, f) = crate::read_all(&p).unwrap();
        assert_eq!((info.pixel_type, info.frames), (PixelType::U8, 2));
        assert_eq!(f, vec![vec![0.0, 128.0, 255.0], vec![1.0, 2.0, 3.0]]);
    }

    #[test]
    fn bigtiff_roundtrip() {
        roundtrip("btf", SampleFormat::U16);
        roundtrip("btf", SampleFormat::F32);
    }

    #[test]
    fn u16_clips_and_rounds() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.tif");
        let mut wr = StackWriter::create(&p, 4, 1, SampleFormat::U16, None).unwrap();
        wr.write_frame(&[-5.0, 1.6, 70000.0, 0.4]).unwrap();
        wr.finish().unwrap();
        let (_, f) = crate::read_all(&p).unwrap();
        assert_eq!(f[0], vec![0.0, 2.0, 65535.0, 0.0]);
    }

    #[test]
    fn truncated_tiff_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.tif");
        let mut wr = StackWriter::create(&p, 64, 64, SampleFormat::U16, Some(2)).unwrap();
        wr.write_frame(&vec![1.0; 64 * 64]).unwrap();
        wr.write_frame(&vec![2.0; 64 * 64]).unwrap();
        wr.finish().unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        let err = match open(&p) {
            Err(e) => e,
            Ok(mut r) => {
                let mut buf = vec![0f32; 64 * 64];
                let mut res = Ok(true);
                while let Ok(true) = res {
                    res = r.read_frame(&mut buf);
                }
                res.expect_err("truncated stack must not read cleanly")
                    .with_path(&p)
            }
        };
        assert!(err.to_string().contains("t.tif"), "{err}");
    }

    #[test]
    fn unfinished_writer_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("u.tif");
        let mut wr = StackWriter::create(&p, 4, 4, SampleFormat::F32, None).unwrap();
        wr.write_frame(&[0.0; 16]).unwrap();
        drop(wr);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
