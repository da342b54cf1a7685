//! The recommender's environment: purchase sessions from five sources (REES46 CSV, the
//! Instacart sample, MovieLens-100K, a seeded generator, a generated large catalogue:
//! `large_catalogue`), the session store that `SubmitSessions` commits to
//! (`store`, with each call's `staging`), the n-gram MDP built from them (Shani et al.:
//! `ngram_counts` made into `ngram`, kept current by `model_handle`, the store's part
//! checkpointed by `model_checkpoint`; the catalogue alone by `catalogue_handle`), and the
//! environment over it. The gRPC Recommender service is the `jsae-recommender` crate.

use std::path::PathBuf;

mod catalogue;
pub mod catalogue_handle;
pub mod data;
pub mod env;
pub mod instacart;
pub mod large_catalogue;
pub mod model_checkpoint;
pub mod model_handle;
pub mod movielens;
pub mod ngram;
pub mod ngram_counts;
pub mod rees46;
pub mod sessions;
pub mod staging;
pub mod store;
mod stored_ids;
pub mod synthetic;

pub use catalogue_handle::{CatalogueHandle, catalogue_handle};
pub use data::{held_out_sessions, is_held_out};
pub use env::RecommenderEnv;
pub use model_handle::{ModelHandle, model_handle};
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
