//! Streaming: reading a stack costs the same memory whatever its length. A counting allocator
//! records the peak of live heap bytes while `accumulate` reads a 10-frame and a 400-frame stack.

mod counting;

fn write_stack(path: &std::path::Path, frames: usize) {
    let (w, h) = (128, 128);
    let mut wr =
        emccd_io::StackWriter::create(path, w, h, emccd_io::SampleFormat::U16, Some(frames))
            .unwrap();
    let mut f = vec![0f32; w * h];
    for k in 0..frames {
        for (i, v) in f.iter_mut().enumerate() {
            *v = 500.0 + ((i * 7 + k * 13) % 11) as f32;
        }
        wr.write_frame(&f).unwrap();
    }
    wr.finish().unwrap();
}

fn peak_while_reading(path: &std::path::Path) -> usize {
    counting::peak_during(|| {
        emccd_calib::stats::accumulate(path, None, 2, &[], None, None, &emccd_calib::Silent)
            .unwrap()
    })
    .1
}

#[test]
fn memory_does_not_grow_with_frame_count() {
    let dir = tempfile::tempdir().unwrap();
    let (short, long) = (dir.path().join("short.tif"), dir.path().join("long.tif"));
    write_stack(&short, 10);
    write_stack(&long, 400);
    // Warm up rayon's pool so its one-time allocations do not count against either run.
    let _ = peak_while_reading(&short);
    let p10 = peak_while_reading(&short);
    let p400 = peak_while_reading(&long);
    // 400 frames of 128² f32 would be 26 MB if they were held; the streaming state is ~330 KB.
    // Allow 64 KiB of slack for the TIFF decoder's per-file tables (the IFD list grows with the
    // page count: 8 bytes a page).
    assert!(
        p400 <= p10 + 64 * 1024,
        "peak {p10} B for 10 frames, {p400} B for 400 frames"
    );
    assert!(p400 < 2_000_000, "peak {p400} B");
}
