//! Shared by the frame-reader targets: the input goes to a file (the readers take paths), and
//! every frame the reader accepts is decoded, as `denoise` would.

#![allow(dead_code)] // each target uses its part

use emccd_io::FrameReader;
use std::path::{Path, PathBuf};

/// A per-process scratch file in memory-backed /dev/shm where there is one.
pub fn scratch(ext: &str) -> PathBuf {
    let dir = if std::path::Path::new("/dev/shm").is_dir() {
        PathBuf::from("/dev/shm")
    } else {
        std::env::temp_dir()
    };
    dir.join(format!("emccd-fuzz-{}.{ext}", std::process::id()))
}

/// Decodes every frame; errors are the expected outcome for most inputs.
pub fn drain(r: &mut dyn FrameReader) {
    let n = r.info().frame_len();
    // The readers refuse sizes the file cannot hold; a frame here is at most the file's size
    // in pixels, so this allocation is bounded by the input.
    let mut buf = vec![0f32; n];
    while let Ok(true) = r.read_frame(&mut buf) {}
}

/// A reader target: the input written to a scratch file named `*.ext`, opened with `open`, and
/// every frame it accepts decoded. It may refuse the bytes, never panic, hang or allocate beyond
/// what the file holds.
pub fn fuzz_reader<R: FrameReader>(ext: &str, open: fn(&Path) -> emccd_io::Result<R>) {
    let path = scratch(ext);
    afl::fuzz!(|data: &[u8]| {
        if std::fs::write(&path, data).is_ok() {
            if let Ok(mut r) = open(&path) {
                drain(&mut r);
            }
        }
    });
}
