//! Calibration errors. Every error about an input names the file it concerns.

use std::path::{Path, PathBuf};

/// What went wrong during calibration.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An input file is unreadable, damaged, or unsuitable (too few frames, saturated, NaN).
    #[error("{}: {message}", path.display())]
    Input {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A fit could not be made from the data given.
    #[error("{0}")]
    Fit(String),
    /// An output (the profile, the report) could not be written.
    #[error("writing {what}")]
    Write {
        /// What, and where.
        what: String,
        /// Why.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

impl Error {
    /// An input error for `path`.
    pub fn input(path: &Path, message: impl Into<String>) -> Error {
        Error::Input {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// Wraps an I/O-layer error; `emccd_io` errors already name their file.
    pub fn io(path: &Path, e: emccd_io::Error) -> Error {
        Error::Input {
            path: path.to_path_buf(),
            message: io_message(e),
        }
    }
}

/// The message of an I/O-layer error without the path it carries (the caller adds its own).
pub(crate) fn io_message(e: emccd_io::Error) -> String {
    match e {
        emccd_io::Error::WithPath { source, .. } => source.to_string(),
        other => other.to_string(),
    }
}

/// Result with [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
