//! Shared by the movie tests.

use emccd_denoise::Denoiser;

/// In-memory raw frames streamed through `denoise_frames` as `emccd denoise` streams a file
/// named `nan.tif`: the error's message, if any, and the frames handed over, in order.
pub fn stream(fd: &Denoiser, exposure_s: f64, raws: &[Vec<f32>]) -> (Option<String>, Vec<usize>) {
    let mut emitted = Vec::new();
    let n = raws.len();
    let r = emccd_denoise::movie::denoise_frames(
        fd,
        exposure_s,
        n,
        0..n,
        &|j| format!("nan.tif: frame {}", j + 1),
        &mut |j, buf| {
            if let Some(buf) = buf {
                buf.copy_from_slice(&raws[j]);
            }
            Ok(())
        },
        &mut |j, _| {
            emitted.push(j);
            Ok(())
        },
    );
    (r.err().map(|e| e.to_string()), emitted)
}
