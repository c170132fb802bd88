//! PNG through the `png` crate: clean scenes in (8/16-bit, any colour type, converted to
//! luminance with the ITU-R BT.601 weights that PIL's `convert("L")` uses), previews out.

use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::Path;

use png::{BitDepth, ColorType, Transformations};

use crate::{Error, Format, FrameReader, Limits, Metadata, PixelType, Result, StackInfo};

/// A single-image PNG, decoded to luminance in the file's own scale (0–255 or 0–65535).
pub struct PngReader {
    data: Option<Vec<f32>>,
    info: StackInfo,
}

fn png_err(e: png::DecodingError) -> Error {
    match e {
        png::DecodingError::IoError(io) => Error::Format(format!("PNG: {io} (truncated file?)")),
        other => Error::Format(format!("PNG: {other}")),
    }
}

impl PngReader {
    /// Decodes a whole file (PNGs are single frames) with the process's [`Limits`].
    pub fn open(path: &Path) -> Result<PngReader> {
        PngReader::new(File::open(path)?, Limits::process())
    }

    /// Decodes the whole image from any seekable source.
    pub fn new(source: impl Read + Seek, limits: Limits) -> Result<PngReader> {
        let source = BufReader::new(source);
        let bytes = usize::try_from(limits.bytes).unwrap_or(usize::MAX);
        let mut dec = png::Decoder::new_with_limits(source, png::Limits { bytes });
        // Expand palettes and sub-byte gray to 8 bits; keep 16-bit samples.
        dec.set_transformations(Transformations::EXPAND);
        let mut reader = dec.read_info().map_err(png_err)?;
        let size = reader
            .output_buffer_size()
            .ok_or_else(|| Error::Format("PNG: image too large".into()))?;
        let (w, h) = (reader.info().width as usize, reader.info().height as usize);
        limits.frame(w, h, 4)?;
        let mut buf = vec![0u8; size];
        let out = reader.next_frame(&mut buf).map_err(png_err)?;
        let (w, h) = (out.width as usize, out.height as usize);
        let channels = match out.color_type {
            ColorType::Grayscale => 1,
            ColorType::GrayscaleAlpha => 2,
            ColorType::Rgb => 3,
            ColorType::Rgba => 4,
            ColorType::Indexed => {
                return Err(Error::Unsupported("PNG palette left unexpanded".into()))
            }
        };
        let sixteen = out.bit_depth == BitDepth::Sixteen;
        let sample = |row: &[u8], i: usize| -> f32 {
            if sixteen {
                u16::from_be_bytes([row[2 * i], row[2 * i + 1]]) as f32
            } else {
                row[i] as f32
            }
        };
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            let row = &buf[y * out.line_size..(y + 1) * out.line_size];
            for x in 0..w {
                let b = x * channels;
                let v = if channels >= 3 {
                    0.299 * sample(row, b) + 0.587 * sample(row, b + 1) + 0.114 * sample(row, b + 2)
                } else {
                    sample(row, b)
                };
                data.push(v);
            }
        }
        let info = StackInfo {
            width: w,
            height: h,
            frames: 1,
            pixel_type: if sixteen {
                PixelType::U16
            } else {
                PixelType::U8
            },
            format: Format::Png,
            metadata: Metadata::default(),
        };
        Ok(PngReader {
            data: Some(data),
            info,
        })
    }
}

impl FrameReader for PngReader {
    fn info(&self) -> &StackInfo {
        &self.info
    }

    fn read_frame(&mut self, out: &mut [f32]) -> Result<bool> {
        match self.data.take() {
            Some(d) => {
                if out.len() != d.len() {
                    return Err(Error::Usage(format!(
                        "buffer holds {} pixels, image has {}",
                        out.len(),
                        d.len()
                    )));
                }
                out.copy_from_slice(&d);
                Ok(true)
            }
            None => Ok(false),
        }
    }
}

/// Writes an 8-bit grayscale PNG (atomically), mapping `lo..=hi` linearly onto 0..=255.
pub fn write_gray8(
    path: &Path,
    width: usize,
    height: usize,
    data: &[f32],
    lo: f32,
    hi: f32,
) -> Result<crate::Staged> {
    write_gray8_inner(path, width, height, data, lo, hi).map_err(|e| e.with_path(path))
}

fn write_gray8_inner(
    path: &Path,
    width: usize,
    height: usize,
    data: &[f32],
    lo: f32,
    hi: f32,
) -> Result<crate::Staged> {
    if data.len() != width * height {
        return Err(Error::Usage(format!(
            "{} values for a {width}×{height} image",
            data.len()
        )));
    }
    let span = if hi > lo { hi - lo } else { 1.0 };
    let bytes: Vec<u8> = data
        .iter()
        .map(|&v| (((v - lo) / span) * 255.0).round().clamp(0.0, 255.0) as u8)
        .collect();
    let tmp = crate::temp_beside(path)?;
    {
        let w = std::io::BufWriter::new(tmp.as_file().try_clone()?);
        let mut enc = png::Encoder::new(w, width as u32, height as u32);
        enc.set_color(ColorType::Grayscale);
        enc.set_depth(BitDepth::Eight);
        let mut wr = enc
            .write_header()
            .map_err(|e| Error::Format(format!("PNG: {e}")))?;
        wr.write_image_data(&bytes)
            .map_err(|e| Error::Format(format!("PNG: {e}")))?;
        wr.finish()
            .map_err(|e| Error::Format(format!("PNG: {e}")))?;
    }
    Ok(crate::Staged {
        tmp,
        target: path.to_path_buf(),
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn preview_roundtrip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.png");
        let data = [0.0, 50.0, 100.0, 200.0];
        super::write_gray8(&p, 2, 2, &data, 0.0, 100.0)
            .unwrap()
            .place()
            .unwrap();
        let (info, f) = crate::read_all(&p).unwrap();
        assert_eq!(
            (info.width, info.height, info.pixel_type),
            (2, 2, crate::PixelType::U8)
        );
        assert_eq!(f[0], vec![0.0, 128.0, 255.0, 255.0]);
    }
}
