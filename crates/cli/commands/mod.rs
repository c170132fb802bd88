//! One module per subcommand: an `Args` struct (the `--help` text) and a `run`.

pub mod adapt;
pub mod bench;
pub mod calibrate;
pub mod count;
pub mod denoise;
pub mod evaluate;
pub mod info;
pub mod profile;
pub mod simulate;
pub mod synthesize;
pub mod train;
