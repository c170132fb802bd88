//! The TIFF reader on arbitrary bytes (see `common::fuzz_reader`).

mod common;

fn main() {
    common::fuzz_reader(emccd_io::tiff_io::TiffReader::new);
}
