//! `FrameReader::skip_frame`, which a shard uses to reach its first frame: skipping frames and
//! then reading gives exactly the frame a full read gives at that place, in every format with a
//! seek of its own (TIFF pages, FITS cubes, SIF), and `false` past the end.

use std::path::Path;

use emccd_io::{SampleFormat, StackWriter};

fn check(path: &Path) {
    let (info, all) = emccd_io::read_all(path).unwrap();
    assert!(
        info.frames >= 2,
        "{}: {} frames",
        path.display(),
        info.frames
    );
    for start in 0..=info.frames {
        let mut r = emccd_io::open(path).unwrap();
        for _ in 0..start {
            assert!(r.skip_frame().unwrap());
        }
        let mut buf = vec![0f32; info.frame_len()];
        let got = r.read_frame(&mut buf).unwrap();
        assert_eq!(got, start < info.frames, "{} at {start}", path.display());
        if got {
            assert!(
                buf.iter()
                    .zip(&all[start])
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{}: frame {start} after skipping differs",
                path.display()
            );
        }
        if start == info.frames {
            assert!(!r.skip_frame().unwrap());
        }
    }
}

fn written(dir: &Path, name: &str) -> std::path::PathBuf {
    let (w, h, frames) = (37, 11, 5);
    let path = dir.join(name);
    let mut wr = StackWriter::create(&path, w, h, SampleFormat::U16, Some(frames)).unwrap();
    for k in 0..frames {
        let f: Vec<f32> = (0..w * h)
            .map(|i| ((i * 7 + k * 1000) % 4096) as f32)
            .collect();
        wr.write_frame(&f).unwrap();
    }
    wr.finish().unwrap();
    path
}

#[test]
fn skipping_then_reading_is_reading_at_that_frame() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["s.tif", "s.btf", "s.fits"] {
        check(&written(dir.path(), name));
    }
    let sif = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/emccd-real/andor-sif/ixon897_bias_truncated.sif");
    check(&sif);
}
