//! The readers against the real files in `tests/data` of the repository.
//! Expected values are what the files' own headers and names say, cross-checked with
//! sif_parser where it reads the file.

use std::path::PathBuf;

use emccd_io::{open, read_all, Format, PixelType};

fn data(rel: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(rel);
    assert!(p.exists(), "test data missing: {}", p.display());
    p
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
}

#[test]
fn sif_truncated_bias_gives_whole_frames_and_a_warning() {
    let p = data("emccd-real/andor-sif/ixon897_bias_truncated.sif");
    let mut r = open(&p).unwrap();
    let info = r.info().clone();
    assert_eq!(info.format, Format::Sif);
    assert_eq!((info.width, info.height), (512, 512));
    // The user text says "Image 1 to 4 in series of 4"; the file holds 2 whole frames.
    assert_eq!(info.frames, 2);
    let w = info.metadata.warnings.join(" ");
    assert!(
        w.contains("declares 4 frames") && w.contains("frames 3–4 are missing"),
        "{w}"
    );
    let m = &info.metadata;
    assert_eq!(m.exposure_s, Some(1e-6));
    assert_eq!(m.em_gain, Some(0.0));
    assert_eq!(m.temperature_c, Some(-49.2));
    assert_eq!(m.camera_model.as_deref(), Some("DU897_BB"));
    let mut buf = vec![0f32; 512 * 512];
    let mut n = 0;
    while r.read_frame(&mut buf).unwrap() {
        n += 1;
        // Bias frames of an iXon 897: a few hundred DN, integer-valued, no NaN.
        let mu = mean(&buf);
        assert!((300.0..800.0).contains(&mu), "frame {n} mean {mu}");
        assert!(buf.iter().all(|x| x.is_finite() && x.fract() == 0.0));
    }
    assert_eq!(n, 2);
}

#[test]
fn sif_binned_gain56() {
    let p = data("emccd-real/andor-sif/ixon897_binned_gain56.sif");
    let (info, frames) = read_all(&p).unwrap();
    assert_eq!((info.width, info.height, info.frames), (256, 256, 1));
    let m = &info.metadata;
    assert_eq!(m.binning, Some((2, 2)));
    assert_eq!(m.em_gain, Some(56.0));
    assert_eq!(m.exposure_s, Some(0.01457));
    assert_eq!(m.temperature_c, Some(-80.545));
    assert_eq!(m.camera_model.as_deref(), Some("DU897_BV"));
    assert!(m.warnings.is_empty());
    assert!(frames[0].iter().all(|x| x.is_finite()));
    // The pixels where the header puts them: the first and last values as sif_parser 0.3.6
    // (an independent reader, `sif_parser.np_open`) reads them; the file has 8 bytes after the
    // frame, so "the last 256 KiB" would be off by two pixels.
    let f = &frames[0];
    assert_eq!(f[..4], [851.0, 859.0, 699.0, 906.0]);
    assert_eq!(f[f.len() - 4..], [1427.0, 1465.0, 1330.0, 1208.0]);
}

#[test]
fn sif_avg20_and_other_cameras() {
    let (info, _) = read_all(data("emccd-real/andor-sif/ixon897_avg20.sif")).unwrap();
    assert_eq!((info.width, info.height, info.frames), (512, 512, 1));
    assert_eq!(info.metadata.exposure_s, Some(1.0));
    assert_eq!(info.metadata.temperature_c, Some(-100.0));
    assert_eq!(info.metadata.camera_model.as_deref(), Some("DU897_BV"));

    // Full-vertical-binning CCD spectrum: 1024×1 after 255-row binning.
    let (info, f) = read_all(data("emccd-real/andor-sif/ccd_cli0.sif")).unwrap();
    assert_eq!((info.width, info.height, info.frames), (1024, 1, 1));
    assert_eq!(info.metadata.binning, Some((1, 255)));
    assert_eq!(info.metadata.camera_model.as_deref(), Some("DU420_OE"));
    assert_eq!(info.metadata.exposure_s, Some(0.1));
    assert_eq!(f[0].len(), 1024);

    // iXon Ultra 888 Raman spectrum (version 65567 with the extra per-frame block).
    let (info, f) = read_all(data("emccd-real/andor-sif/ixon888_spectrum_raman.sif")).unwrap();
    assert_eq!((info.width, info.height, info.frames), (1024, 1, 1));
    assert_eq!(info.metadata.em_gain, Some(20.0));
    assert_eq!(info.metadata.accumulations, Some(500));
    assert_eq!(info.metadata.camera_model.as_deref(), Some("DU888_BV"));
    // Spectrum counts are large and positive: the offset did not land inside the header.
    assert!(
        f[0].iter().all(|&x| x > 1.0e5 && x < 1.0e7),
        "{:?}",
        &f[0][..4]
    );
}

#[test]
fn sif_corrupt_header_is_a_clear_error() {
    let src = std::fs::read(data("emccd-real/andor-sif/ixon897_binned_gain56.sif")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Cut inside the header: the structure line is gone.
    let p = dir.path().join("cut.sif");
    std::fs::write(&p, &src[..1500]).unwrap();
    let e = open(&p).err().expect("must fail").to_string();
    assert!(e.contains("cut.sif") && e.contains("SIF header"), "{e}");
    // Cut inside the first frame: no whole frame.
    let p = dir.path().join("noframe.sif");
    std::fs::write(&p, &src[..src.len() - 1000]).unwrap();
    let e = open(&p).err().expect("must fail").to_string();
    assert!(
        e.contains("noframe.sif") && e.contains("not one whole frame"),
        "{e}"
    );
}

#[test]
fn fits_roman_fpn_map() {
    // 21 MB, not copied into the repository: the project's full data folder beside the checkout
    // has it (CI), a clone alone skips this test.
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/emccd-real/roman-fpn/fpn_map.fits");
    if !p.exists() {
        eprintln!(
            "skipped: the Roman coronagraph FPN map (optional data) is missing: {}",
            p.display()
        );
        return;
    }
    let (info, f) = read_all(&p).unwrap();
    assert_eq!((info.width, info.height, info.frames), (2200, 1200, 1));
    assert_eq!(info.pixel_type, PixelType::F64);
    // Reference values computed from the raw big-endian float64 data with Python's struct.
    let mu = mean(&f[0]);
    assert!((mu - 21.628675197669903).abs() < 1e-4, "mean {mu}");
    let (lo, hi) = f[0]
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    assert!(
        (lo as f64 + 335.83285732634835).abs() < 1e-3
            && (hi as f64 - 1462.2520547080253).abs() < 1e-3
    );
    // Row 13, column 1088: the image area's first pixel.
    assert!((f[0][13 * 2200 + 1088] as f64 + 72.248995709527).abs() < 1e-4);
}

#[test]
fn lanl_tiff_stacks() {
    let (info, frames) =
        read_all(data("emccd-real/lanl-calibration/gain-GS/300x-gain.tif")).unwrap();
    assert_eq!((info.width, info.height), (3, 3));
    assert_eq!(info.frames, frames.len());
    assert!(info.frames >= 1000, "{}", info.frames);
    let (adu, _) = read_all(data("emccd-real/lanl-calibration/gain-GS/ADU_map.tif")).unwrap();
    assert_eq!((adu.width, adu.height), (3, 3));
}

#[test]
fn png_scenes_become_luminance() {
    let (info, f) = read_all(data("clean/natural/Kodak24/kodim01.png")).unwrap();
    assert_eq!(info.format, Format::Png);
    assert_eq!(info.frames, 1);
    assert!(f[0].iter().all(|&x| (0.0..=255.0).contains(&x)));
    let (info, _) = read_all(data("clean/microscopy/fmd-confocal-bpae/field1-avg50.png")).unwrap();
    assert!(info.width >= 256 && info.height >= 256);
}

#[test]
fn unknown_and_missing_files_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("notes.txt");
    std::fs::write(&p, "hello").unwrap();
    let e = open(&p).err().unwrap().to_string();
    assert!(e.contains("notes.txt") && e.contains("not a TIFF"), "{e}");
    let e = open(dir.path().join("missing.tif"))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("missing.tif"), "{e}");
}

#[test]
fn rgb_tiff_reads_as_bt601_luminance() {
    let path = data("clean/natural/McMaster/1.tif");
    let (info, frames) = emccd_io::read_all(&path).unwrap();
    assert_eq!((info.width, info.height, info.frames), (500, 500, 1));
    // Independent decode of the same pixel's RGB with the tiff crate.
    let mut dec =
        tiff::decoder::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()))
            .unwrap();
    let tiff::decoder::DecodingResult::U8(rgb) = dec.read_image().unwrap() else {
        panic!("8-bit RGB expected")
    };
    for i in [0usize, 1234, 250 * 500 + 250, 500 * 500 - 1] {
        let want = 0.299 * rgb[3 * i] as f32
            + 0.587 * rgb[3 * i + 1] as f32
            + 0.114 * rgb[3 * i + 2] as f32;
        assert!(
            (frames[0][i] - want).abs() < 1e-3,
            "pixel {i}: {} vs {want}",
            frames[0][i]
        );
    }
}

/// An RGB TIFF with separate planes (what tifffile writes for a `(3, H, W)` array unless told
/// `photometric='minisblack'`; made by tifffile 2024) is read as the luminance a contiguous RGB
/// TIFF gives, pixel by pixel, with a warning that says how a 3-frame stack would look like
/// this; before, its rows were taken from the three planes in turn.
#[test]
fn planar_rgb_tiff_is_read_as_luminance_with_a_warning() {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/planar_rgb_u16.tif");
    let (info, f) = read_all(&p).unwrap();
    assert_eq!((info.width, info.height, info.frames), (8, 6, 1));
    for y in 0..6 {
        for x in 0..8 {
            let (r, g, b) = (
                (100 + 10 * x + y) as f32,
                (2000 + x * y) as f32,
                (30000 - 100 * y) as f32,
            );
            let want = 0.299 * r + 0.587 * g + 0.114 * b;
            let got = f[0][y * 8 + x];
            assert!((got - want).abs() < 0.01, "({x}, {y}): {got} vs {want}");
        }
    }
    let w = info.metadata.warnings.join(" ");
    assert!(
        w.contains("separate planes") && w.contains("minisblack"),
        "{w}"
    );
}

/// An RGB float32 TIFF (three SampleFormat values, one per channel), interleaved or in separate
/// planes as tifffile writes them, is read as its luminance like an integer one; it was
/// refused with "tag has invalid type".
#[test]
fn rgb_float_tiff_is_read_as_luminance() {
    for name in ["rgb_f32.tif", "planar_rgb_f32.tif"] {
        let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures")
            .join(name);
        let (info, f) = read_all(&p).unwrap();
        assert_eq!((info.width, info.height, info.frames), (8, 6, 1), "{name}");
        for y in 0..6 {
            for x in 0..8 {
                let (x, y) = (x as f32, y as f32);
                let (r, g, b) = (0.5 + 0.25 * x + y, 3.0 + 0.125 * x * y, -2.0 + 0.5 * y);
                let want = 0.299 * r + 0.587 * g + 0.114 * b;
                let got = f[0][(y * 8.0 + x) as usize];
                assert!(
                    (got - want).abs() < 1e-4,
                    "{name} ({x}, {y}): {got} vs {want}"
                );
            }
        }
    }
}
