//! A profile directory whose profile.toml is arbitrary bytes, beside a valid maps file of an
//! 8×8 crop of the bundled profile (what `seeds/profile` was written from).

fn main() {
    let dir = std::env::temp_dir().join(format!("emccd-fuzz-profile-{}", std::process::id()));
    emccd_profile::default_profile()
        .crop(0, 0, 8, 8)
        .expect("crop")
        .save(&dir)
        .expect("save");
    let toml = dir.join("profile.toml");
    afl::fuzz!(|data: &[u8]| {
        if std::fs::write(&toml, data).is_ok() {
            let _ = emccd_profile::CameraProfile::load(&dir);
        }
    });
}
