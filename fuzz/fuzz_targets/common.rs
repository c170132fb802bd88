//! Shared by the frame-reader targets: the input is read from memory with the default limits,
//! and every frame the reader accepts is decoded, as `denoise` would.

#![allow(dead_code)] // each target uses its part

use emccd_io::{FrameReader, Limits};
use std::io::Cursor;
use std::path::PathBuf;

/// A per-process scratch file in memory-backed /dev/shm where there is one (for loaders that
/// take paths).
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
    // The readers refuse sizes the input cannot hold (uncompressed data past its length,
    // compressed data past its method's best ratio) and sizes past the default limits, so
    // this allocation is bounded by the input and the limits.
    let mut buf = vec![0f32; n];
    while let Ok(true) = r.read_frame(&mut buf) {}
}

/// A reader target: the input opened from memory with `new` and the default [`Limits`], and
/// every frame it accepts decoded. It may refuse the bytes, never panic, hang or allocate beyond
/// what the input holds.
pub fn fuzz_reader<R: FrameReader>(
    new: fn(Cursor<Vec<u8>>, Limits) -> emccd_io::Result<R>,
) {
    afl::fuzz!(|data: &[u8]| {
        if let Ok(mut r) = new(Cursor::new(data.to_vec()), Limits::GENEROUS) {
            drain(&mut r);
        }
    });
}
