//! The calibration streaming benchmark, small.

#[test]
fn the_streaming_bench_reads_what_it_wrote_and_removes_it() {
    let dir = tempfile::tempdir().unwrap();
    let r = emccd_calib::bench::streaming(dir.path(), 1).unwrap();
    // At least two frames, so a variance exists; 512×512 u16 each, plus the TIFF's headers.
    assert_eq!(r.frames, 2);
    assert!(r.bytes >= (2 * 512 * 512 * 2) as f64);
    assert!(r.decode_s > 0.0 && r.reference_s > 0.0);
    // On Linux both are reported (a process's peak is never zero), and a peak never falls.
    let [before, after] = r.peak_mib;
    if cfg!(target_os = "linux") {
        assert!(before > 0.0 && after >= before, "{before} → {after} MiB");
    }
    assert!(r.decode_gb_s().is_finite() && r.reference_gb_s().is_finite());
    assert!(!dir.path().join("stack.tif").exists());
}
