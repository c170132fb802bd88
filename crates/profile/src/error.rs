use std::path::PathBuf;

/// Errors loading, saving or validating a profile.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A file of the profile is damaged or inconsistent.
    #[error("{0}")]
    Format(String),
    /// A parameter is out of its valid range (NaN gain, mismatched map sizes, …).
    #[error("{0}")]
    Parameter(String),
    /// A recording that cannot be read.
    #[error(transparent)]
    Read(#[from] emccd_io::Error),
    /// An operating-system error.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// An error with the file it concerns.
    #[error("{}: {source}", path.display())]
    WithPath {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        #[source]
        source: Box<Error>,
    },
}

impl Error {
    pub(crate) fn at(self, path: impl Into<PathBuf>) -> Error {
        match self {
            e @ Error::WithPath { .. } => e,
            e => Error::WithPath {
                path: path.into(),
                source: Box::new(e),
            },
        }
    }
}

/// Result alias for this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
