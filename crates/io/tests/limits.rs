//! Readers on any seekable source, and the limits they put on what a header may claim.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use emccd_io::{from_reader, open, open_with, Limits, SampleFormat, StackWriter};

fn all_frames(r: &mut dyn emccd_io::FrameReader) -> Vec<Vec<f32>> {
    let mut out = Vec::new();
    let mut buf = vec![0f32; r.info().frame_len()];
    while r.read_frame(&mut buf).unwrap() {
        out.push(buf.clone());
    }
    out
}

fn stack(path: &Path, w: usize, h: usize, frames: usize) {
    let mut s = StackWriter::create(path, w, h, SampleFormat::F32, Some(frames)).unwrap();
    for k in 0..frames {
        let f: Vec<f32> = (0..w * h).map(|i| (k * 7919 + i) as f32 * 0.5).collect();
        s.write_frame(&f).unwrap();
    }
    s.finish().unwrap();
}

fn data(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(rel)
}

/// TIFF, BigTIFF, FITS, PNG and a real SIF: the same header and frames from the bytes in memory
/// as from the file.
#[test]
fn every_format_reads_the_same_from_memory_as_from_its_file() {
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for name in ["s.tif", "s.btf", "s.fits"] {
        let p = dir.path().join(name);
        stack(&p, 24, 16, 3);
        files.push(p);
    }
    let png = dir.path().join("p.png");
    let ramp: Vec<f32> = (0..24 * 16).map(|i| (i % 256) as f32).collect();
    emccd_io::write_png_preview(&png, 24, 16, &ramp, 0.0, 255.0).unwrap();
    files.push(png);
    files.push(data("emccd-real/andor-sif/ixon897_binned_gain56.sif"));
    for p in &files {
        let mut a = open(p).unwrap();
        let bytes = std::fs::read(p).unwrap();
        let mut b = from_reader(Cursor::new(bytes), Limits::default()).unwrap();
        assert_eq!(a.info(), b.info(), "{}", p.display());
        let (fa, fb) = (all_frames(a.as_mut()), all_frames(b.as_mut()));
        assert_eq!(fa.len(), a.info().frames, "{}", p.display());
        assert!(fa == fb, "{}: frames differ", p.display());
    }
}

/// Each limit refuses a file past it, with the number and the way to lift it in the message;
/// `Limits::NONE` (the CLI's `--no-limits`) opens the same file.
#[test]
fn each_limit_refuses_and_none_lifts_it() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["s.tif", "s.fits"] {
        let p = dir.path().join(name);
        stack(&p, 32, 32, 3);
        for (limits, want) in [
            (
                Limits {
                    frames: 2,
                    ..Limits::GENEROUS
                },
                "3 frames, beyond the limit of 2",
            ),
            (
                Limits {
                    frame_pixels: 1000,
                    ..Limits::GENEROUS
                },
                "32×32 pixels per frame, beyond the limit of 1000 pixels",
            ),
            (
                Limits {
                    bytes: 4095,
                    ..Limits::GENEROUS
                },
                "takes 4096 bytes, beyond the limit of 4095 bytes",
            ),
        ] {
            let e = match open_with(&p, limits) {
                Ok(_) => panic!("{name} opened with {limits:?}"),
                Err(e) => e.to_string(),
            };
            assert!(
                e.contains(want) && e.contains("--no-limits") && e.contains(name),
                "{name}: {e}"
            );
        }
        let mut r = open_with(&p, Limits::NONE).unwrap();
        assert_eq!(all_frames(r.as_mut()).len(), 3);
    }
}

#[test]
fn writing_sif_is_refused_with_the_reason_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("out.sif");
    let e = StackWriter::create(&p, 4, 4, SampleFormat::U16, Some(1))
        .err()
        .expect("SIF is read-only")
        .to_string();
    assert!(e.contains("reads it only") && e.contains("out.sif"), "{e}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}
