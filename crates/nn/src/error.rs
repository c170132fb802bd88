//! Errors of the network layer.

use std::path::Path;

/// What went wrong.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A model file is unreadable, foreign or inconsistent.
    #[error("{0}")]
    Model(String),
    /// An operating-system error on a file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// Input data (training images, recorded frames) are unusable.
    #[error("{0}")]
    Data(String),
    /// A file (a recording, an output store) that cannot be read or written.
    #[error(transparent)]
    File(#[from] emccd_io::Error),
    /// A frame of a recording that cannot be read: `at` names the file and the frame.
    #[error("{at}: {source}")]
    Frame {
        /// The file and the frame (from 1).
        at: String,
        /// Why.
        #[source]
        source: emccd_io::Error,
    },
    /// An error about one file or frame of several: `at` names it, `source` keeps its kind.
    #[error("{at}: {source}")]
    At {
        /// The file, or the file and the frame (from 1).
        at: String,
        /// What went wrong there.
        #[source]
        source: Box<Error>,
    },
}

impl Error {
    /// This error, about `at` (a file, or a file and its frame).
    pub fn at(self, at: impl Into<String>) -> Error {
        Error::At {
            at: at.into(),
            source: Box::new(self),
        }
    }

    /// An I/O error on `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Error {
        Error::Io {
            path: path.display().to_string(),
            source,
        }
    }
}

/// A profile that cannot serve a request (no slope, incomplete maps): the data are unusable.
impl From<emccd_profile::Error> for Error {
    fn from(e: emccd_profile::Error) -> Error {
        Error::Data(e.to_string())
    }
}

/// A frame the classical layer cannot denoise through its profile: the data are unusable.
impl From<emccd_classical::Error> for Error {
    fn from(e: emccd_classical::Error) -> Error {
        Error::Data(e.to_string())
    }
}

/// A noise model that cannot be built from the profile's parameters: the data are unusable.
impl From<emccd_camera::Error> for Error {
    fn from(e: emccd_camera::Error) -> Error {
        Error::Data(e.to_string())
    }
}

/// Result with [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
