//! Why a report or a figure could not be made ([`ReportError`]).

use std::path::PathBuf;

/// Why a report could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// A file could not be read or written.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The folder holds no finished run.
    #[error("{0}: no finished run (runs/SETTING/RUN/summary.json)")]
    Empty(PathBuf),
    /// A figure could not be drawn.
    #[error("figure {path}: {message}")]
    Figure {
        /// The figure.
        path: PathBuf,
        /// Why.
        message: String,
    },
}
