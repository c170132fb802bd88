//! The SIF reader on arbitrary bytes (see `common::fuzz_reader`).

mod common;

fn main() {
    common::fuzz_reader(emccd_io::sif::SifReader::new);
}
