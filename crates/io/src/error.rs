//! Errors of the readers and writers, sorted by who must act (as the `tiff` crate does).

use std::path::PathBuf;

/// What went wrong while reading or writing image data.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file is damaged or is not what its header claims.
    #[error("{0}")]
    Format(String),
    /// The file is valid, but it uses a feature this reader does not handle.
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// The caller asked for something impossible (wrong frame size, mixed sizes in one stack).
    #[error("{0}")]
    Usage(String),
    /// An operating-system error.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// An error with the file it concerns attached.
    #[error("{}: {source}", path.display())]
    WithPath {
        /// The file that was being read or written.
        path: PathBuf,
        /// What went wrong.
        #[source]
        source: Box<Error>,
    },
}

impl Error {
    /// Attaches the path of the file this error concerns (once).
    pub fn with_path(self, path: impl Into<PathBuf>) -> Error {
        match self {
            e @ Error::WithPath { .. } => e,
            e => Error::WithPath {
                path: path.into(),
                source: Box::new(e),
            },
        }
    }
}

impl From<tiff::TiffError> for Error {
    fn from(e: tiff::TiffError) -> Self {
        match e {
            tiff::TiffError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
                Error::Format(format!("TIFF ends early (truncated file?): {io}"))
            }
            tiff::TiffError::IoError(io) => Error::Io(io),
            tiff::TiffError::UnsupportedError(u) => Error::Unsupported(format!("TIFF: {u}")),
            other => Error::Format(format!("TIFF: {other}")),
        }
    }
}

/// Result alias for this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
