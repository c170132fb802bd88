//! The calibration streaming benchmark, small.

#[test]
fn the_streaming_bench_reads_what_it_wrote_and_removes_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut called = false;
    let r = emccd_calib::bench::streaming(dir.path(), 1, &mut || called = true).unwrap();
    // At least two frames, so a variance exists; 512×512 u16 each, plus the TIFF's headers.
    assert_eq!(r.frames, 2);
    assert!(r.bytes >= (2 * 512 * 512 * 2) as f64);
    assert!(called && r.decode_s > 0.0 && r.reference_s > 0.0);
    assert!(r.decode_gb_s().is_finite() && r.reference_gb_s().is_finite());
    assert!(!dir.path().join("stack.tif").exists());
}
