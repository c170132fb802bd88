//! Bounded memory: a temporal method holds its window, not the recording. A counting allocator
//! records the peak of live heap bytes while `denoise_file` runs `--method temporal` over an
//! 8-frame and a 64-frame stack.

use emccd_denoise::stack::denoise_file;
use emccd_denoise::{Denoiser, Method, Units};
use emccd_profile::Recording;

#[path = "../../calib/tests/counting/mod.rs"]
mod counting;

const W: usize = 64;
const H: usize = 64;

fn write_stack(path: &std::path::Path, frames: usize) {
    let mut wr =
        emccd_io::StackWriter::create(path, W, H, emccd_io::SampleFormat::U16, Some(frames))
            .unwrap();
    wr.set_metadata(&emccd_io::Metadata {
        exposure_s: Some(0.01),
        ..Default::default()
    });
    let mut f = vec![0f32; W * H];
    for k in 0..frames {
        for (i, v) in f.iter_mut().enumerate() {
            *v = 500.0 + ((i * 7 + k * 13) % 11) as f32 * 20.0;
        }
        wr.write_frame(&f).unwrap();
    }
    wr.finish().unwrap();
}

#[test]
fn a_temporal_run_holds_its_window_not_the_recording() {
    let p = emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(W, H))
        .unwrap();
    let fd = Denoiser {
        profile: &p,
        method: Method::Temporal,
        model: None,
        tiling: Default::default(),
        ensemble: 1,
        units: Units::Dn,
        window: 2,
    };
    let dir = tempfile::tempdir().unwrap();
    let peak = |frames: usize| {
        let input = dir.path().join(format!("in{frames}.tif"));
        write_stack(&input, frames);
        let out = dir.path().join(format!("out{frames}.tif"));
        let rec = Recording::open(&input, &p, None, "--exposure-s", false).unwrap();
        counting::peak_during(|| denoise_file(&fd, rec, &out, &mut || ()).unwrap()).1
    };
    // One worker, so the peak does not depend on how the workers' buffers happen to overlap.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let (short, long) = pool.install(|| {
        peak(3);
        (peak(8), peak(64))
    });
    // A frame held is 16 KiB, with its single-frame estimate 32 KiB: holding the recording
    // would add 56 · 32 KiB ≈ 1.8 MB for the long stack. Allow 64 KiB for the TIFF writer's
    // and reader's per-page tables.
    println!("peak {short} B for 8 frames, {long} B for 64");
    assert!(
        long <= short + 64 * 1024,
        "peak {short} B for 8 frames, {long} B for 64"
    );
}
