//! Every input the fuzzers (`fuzz/`, AFL++ through cargo-afl) found to crash a reader, replayed
//! through that reader: it must now refuse the file or open it with a frame the limits allow,
//! and decode it without a panic. Before the fix each of these made the caller allocate what the
//! header claimed (up to 137 GB) and abort.

use std::path::{Path, PathBuf};

use emccd_io::{FrameReader, Limits};

fn inputs(kind: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz")
        .join(kind);
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v
}

fn replay(r: &mut dyn FrameReader, file: &Path) {
    let n = r.info().frame_len();
    assert!(
        n <= Limits::GENEROUS.frame_pixels,
        "{}: {n}-pixel frame accepted",
        file.display()
    );
    let mut buf = vec![0f32; n];
    while let Ok(true) = r.read_frame(&mut buf) {}
}

#[test]
fn tiff_crashes_found_by_fuzzing_are_refused_or_bounded() {
    let files = inputs("tiff");
    assert!(files.len() >= 26);
    let mut refused = 0;
    for f in &files {
        match emccd_io::tiff_io::TiffReader::open(f) {
            Ok(mut r) => replay(&mut r, f),
            Err(e) => {
                assert!(!e.to_string().is_empty());
                refused += 1;
            }
        }
    }
    // All of them claim frames far beyond the limit.
    assert_eq!(refused, files.len());
}

#[test]
fn fits_crashes_found_by_fuzzing_are_errors() {
    // Each holds a header card whose value is a lone quote, on which fitsrs 0.4.1 panics
    // (slicing s[1..0]); the reader turns that into an error naming the damage.
    let files = inputs("fits");
    assert!(files.len() >= 9);
    for f in &files {
        let e = match emccd_io::fits::FitsReader::open(f) {
            Ok(mut r) => {
                replay(&mut r, f);
                continue;
            }
            Err(e) => e.to_string(),
        };
        assert!(e.contains("FITS header"), "{}: {e}", f.display());
    }
}
