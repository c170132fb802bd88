//! Shared by the frame-reader targets: the input goes to a file (the readers take paths), and
//! every frame the reader accepts is decoded, as `denoise` would.

#![allow(dead_code)] // each target uses its part

use emccd_io::FrameReader;
use std::path::PathBuf;

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
