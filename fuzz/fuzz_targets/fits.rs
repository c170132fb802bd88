//! The FITS reader on arbitrary bytes: it may refuse them, never panic, hang or allocate
//! beyond what the file holds.

mod common;

fn main() {
    let path = common::scratch("fits");
    afl::fuzz!(|data: &[u8]| {
        if std::fs::write(&path, data).is_ok() {
            if let Ok(mut r) = emccd_io::fits::FitsReader::open(&path) {
                common::drain(&mut r);
            }
        }
    });
}
