//! The recommender's environment: purchase sessions from three sources (REES46 CSV, the
//! Instacart sample, a seeded generator), the session store that `SubmitSessions` appends to,
//! the n-gram MDP built from them (Shani et al.), and the environment over it. The gRPC
//! Recommender service is the `jsae-recommender` crate.

use std::path::PathBuf;

pub mod data;
pub mod env;
pub mod instacart;
pub mod ngram;
pub mod ngram_counts;
pub mod rees46;
pub mod sessions;
pub mod store;
pub mod synthetic;

pub use data::{ModelHandle, held_out_sessions, is_held_out, model_handle};
pub use env::RecommenderEnv;
pub use ngram::{Catalogue, NgramModel};
pub use ngram_counts::NgramCounts;
pub use sessions::{Purchase, Session};

/// Why the recommender's data could not be had.
#[derive(Debug, thiserror::Error)]
pub enum RecsysError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A data file is not in the expected format.
    #[error("{path}, line {line}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The line (1: the header).
        line: u64,
        /// What is wrong.
        reason: String,
    },
    /// The data holds nothing to build a model from, or does not fit the settings.
    #[error("{0}")]
    Data(String),
}
