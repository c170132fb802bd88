//! Files this project writes, read back by the readers its users have: `tifffile` (whose ImageJ
//! handling is Fiji's) for TIFF and BigTIFF stacks, `astropy.io.fits` for FITS. Each stack has
//! frames that differ, so a reader that finds the wrong offset for frame 2 is caught.
//!
//! Needs `python3` with tifffile, astropy and numpy (`.ci/run` installs them and sets
//! `EMCCD_REQUIRE_PYTHON=1`, which turns a missing reader into a failure instead of a skip).

use std::path::Path;
use std::process::Command;

use emccd_io::{Metadata, SampleFormat, StackWriter};

const W: usize = 300;
const H: usize = 70;
/// Frame counts written: 2 is where tifffile's ImageJ shortcut misread the second frame.
const COUNTS: [usize; 2] = [2, 5];
const FRAMES: usize = 2;

fn value(frame: usize, i: usize) -> f32 {
    ((frame * 1000 + i * 3) % 65536) as f32
}

fn write(path: &Path, sample: SampleFormat, frames: usize) {
    let mut w = StackWriter::create(path, W, H, sample, Some(frames)).unwrap();
    w.set_metadata(&Metadata {
        exposure_s: Some(0.05),
        em_gain: Some(300.0),
        ..Metadata::default()
    });
    for k in 0..frames {
        let f: Vec<f32> = (0..W * H).map(|i| value(k, i)).collect();
        w.write_frame(&f).unwrap();
    }
    w.finish().unwrap();
}

const SCRIPT: &str = r#"
import json, sys
import numpy as np
path = sys.argv[1]
if path.endswith(".fits"):
    from astropy.io import fits
    with fits.open(path) as h:
        a = np.asarray(h[0].data, dtype=np.float64)
else:
    import tifffile
    a = np.asarray(tifffile.imread(path), dtype=np.float64)
print(json.dumps({"shape": list(a.shape), "values": a.ravel().tolist()}))
"#;

/// The readers, or `None` (skip) when they are not installed and not required.
fn python_ok() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import numpy, tifffile, astropy.io.fits"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok && std::env::var_os("EMCCD_REQUIRE_PYTHON").is_some() {
        panic!(
            "python3 with numpy, tifffile and astropy is required (EMCCD_REQUIRE_PYTHON is set)"
        );
    }
    if !ok {
        eprintln!("skipped: python3 with numpy, tifffile and astropy is not installed");
    }
    ok
}

fn check(name: &str, sample: SampleFormat) {
    if !python_ok() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for frames in COUNTS {
        let path = dir.path().join(name);
        write(&path, sample, frames);
        let out = Command::new("python3")
            .arg("-c")
            .arg(SCRIPT)
            .arg(&path)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let shape: Vec<usize> = v["shape"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap() as usize)
            .collect();
        assert_eq!(shape, vec![frames, H, W], "{name}: shape");
        let values = v["values"].as_array().unwrap();
        for k in 0..frames {
            for i in 0..W * H {
                let got = values[k * W * H + i].as_f64().unwrap();
                assert_eq!(
                    got,
                    value(k, i) as f64,
                    "{name}, {frames} frames: frame {k}, pixel {i}"
                );
            }
        }
    }
}

#[test]
fn tiff_u16_stack_reads_in_tifffile() {
    check("stack.tif", SampleFormat::U16);
}

#[test]
fn tiff_f32_stack_reads_in_tifffile() {
    check("stack.tif", SampleFormat::F32);
}

#[test]
fn bigtiff_stack_reads_in_tifffile() {
    check("stack.btf", SampleFormat::U16);
}

#[test]
fn fits_f32_stack_reads_in_astropy() {
    check("stack.fits", SampleFormat::F32);
}

#[test]
fn fits_u16_stack_reads_in_astropy() {
    check("stack.fits", SampleFormat::U16);
}

/// Our own reader still finds the camera metadata that replaced the ImageJ description.
#[test]
fn tiff_metadata_survives_without_an_imagej_description() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.tif");
    write(&path, SampleFormat::U16, FRAMES);
    let r = emccd_io::open(&path).unwrap();
    assert_eq!(r.info().frames, FRAMES);
    assert_eq!(r.info().metadata.exposure_s, Some(0.05));
    assert_eq!(r.info().metadata.em_gain, Some(300.0));
}

/// A non-finite value is refused with the frame and pixel named, and nothing is left behind.
#[test]
fn non_finite_frames_are_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["n.tif", "n.fits"] {
        let path = dir.path().join(name);
        let mut w = StackWriter::create(&path, W, H, SampleFormat::F32, Some(2)).unwrap();
        w.write_frame(&vec![1.0; W * H]).unwrap();
        let mut f = vec![1.0; W * H];
        f[2 * W + 5] = f32::NAN;
        let e = w.write_frame(&f).unwrap_err().to_string();
        assert!(
            e.contains("frame 2 ") && e.contains("pixel (5, 2)") && e.contains(name),
            "{e}"
        );
        drop(w);
        assert!(!path.exists(), "{name} was written");
    }
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "a temporary file was left"
    );
}
