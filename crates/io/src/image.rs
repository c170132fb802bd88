//! Clean scenes: the images pairs and training data are made from.

use std::path::{Path, PathBuf};

use crate::{Error, Format, PixelType, Result};

/// A single-channel image, values in [0, 1] for a clean scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Row-major pixels.
    pub data: Vec<f32>,
}

impl Image {
    /// Reads the first frame of a PNG, TIFF or FITS file as a clean scene: luminance normalized
    /// to [0, 1] by the pixel type's full scale (8- and 16-bit), or by the image's maximum (float
    /// and other types, which have no full scale).
    pub fn read_scene(path: impl AsRef<Path>) -> Result<Image> {
        let (info, mut data) = crate::read_first(path)?;
        let scale = match info.pixel_type {
            PixelType::U8 => 255.0,
            PixelType::U16 => 65535.0,
            _ => data
                .iter()
                .copied()
                .fold(0f32, f32::max)
                .max(f32::MIN_POSITIVE),
        };
        for v in &mut data {
            *v = (*v / scale).clamp(0.0, 1.0);
        }
        Ok(Image {
            width: info.width,
            height: info.height,
            data,
        })
    }

    /// Its centre `width × height` (at most its own size).
    pub fn center_crop(&self, width: usize, height: usize) -> Image {
        let (cw, ch) = (width.min(self.width), height.min(self.height));
        let (x0, y0) = ((self.width - cw) / 2, (self.height - ch) / 2);
        let mut data = Vec::with_capacity(cw * ch);
        for y in y0..y0 + ch {
            data.extend_from_slice(&self.data[y * self.width + x0..y * self.width + x0 + cw]);
        }
        Image {
            width: cw,
            height: ch,
            data,
        }
    }
}

/// The image files of `inputs`: files as given, folders expanded into the PNG, TIFF and FITS
/// files they hold (sorted). A folder without images or a path that does not exist is an error.
pub fn image_files(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let mut v: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| Error::from(e).with_path(p))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|q| matches!(Format::from_extension(q), Some(f) if f != Format::Sif))
                .collect();
            v.sort();
            if v.is_empty() {
                return Err(Error::Usage("no PNG, TIFF or FITS images inside".into()).with_path(p));
            }
            out.extend(v);
        } else if p.exists() {
            out.push(p.clone());
        } else {
            return Err(Error::Usage("no such file or directory".into()).with_path(p));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scenes_are_normalized_and_cropped_about_the_centre() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.tif");
        let mut w =
            crate::StackWriter::create(&path, 4, 3, crate::SampleFormat::U16, Some(1)).unwrap();
        let px: Vec<f32> = (0..12).map(|i| (i * 5000) as f32).collect();
        w.write_frame(&px).unwrap();
        w.finish().unwrap();
        let img = Image::read_scene(&path).unwrap();
        assert_eq!((img.width, img.height), (4, 3));
        assert_eq!(img.data[11], 55000.0 / 65535.0);
        let c = img.center_crop(2, 1);
        assert_eq!((c.width, c.height), (2, 1));
        assert_eq!(c.data, vec![img.data[5], img.data[6]]);
        assert_eq!(
            image_files(&[dir.path().to_path_buf()]).unwrap(),
            vec![path.clone()]
        );
        let e = image_files(&[dir.path().join("nothing")])
            .unwrap_err()
            .to_string();
        assert!(e.contains("nothing") && e.contains("no such file"), "{e}");
    }
}
