//! SSIM and PSNR against scikit-image (values in fixtures/ssim_reference.json, made by
//! fixtures/make_ssim_fixture.py from BSD68 crops): agreement within 1e-4.

use std::path::Path;

#[test]
fn ssim_and_psnr_match_scikit_image() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
    let cases: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("ssim_reference.json")).unwrap())
            .unwrap();
    for c in cases.as_array().unwrap() {
        let name = c["name"].as_str().unwrap();
        let (info, r) = emccd_io::read_all(dir.join(format!("{name}_ref.tif"))).unwrap();
        let (_, t) = emccd_io::read_all(dir.join(format!("{name}_test.tif"))).unwrap();
        let range = c["data_range"].as_f64().unwrap();
        let s = emccd_eval::ssim(
            &t[0],
            &r[0],
            info.width,
            info.height,
            range,
            Default::default(),
        );
        let p = emccd_eval::psnr(&t[0], &r[0], range);
        let (ws, wp) = (c["ssim"].as_f64().unwrap(), c["psnr"].as_f64().unwrap());
        assert!(
            (s - ws).abs() < 1e-4,
            "{name}: SSIM {s} vs scikit-image {ws}"
        );
        assert!(
            (p - wp).abs() < 1e-4,
            "{name}: PSNR {p} vs scikit-image {wp}"
        );
    }
}
