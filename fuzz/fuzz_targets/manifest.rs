//! The calibration manifest parser on arbitrary text.

fn main() {
    afl::fuzz!(|data: &[u8]| {
        if let Ok(text) = std::str::from_utf8(data) {
            let _ = emccd_calib::manifest::Manifest::parse(text, std::path::Path::new("fuzz.toml"));
        }
    });
}
