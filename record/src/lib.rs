//! Recordings of stepped transitions as MCAP files.
//!
//! Every transition an actor steps becomes one protobuf message
//! (`jsae.record.v1.Transition`, `proto/transition.proto`) on the channel [`TOPIC`]; the
//! schema travels inside the file as a FileDescriptorSet, so the MCAP tools, Foxglove and the
//! Python `mcap` reader decode a recording without this crate. Chunks are zstd-compressed and
//! closed at least every [`FLUSH_EVERY`], so a crash loses at most the open chunk.
//!
//! Layout: [`writer`] (the [`Recorder`] actors write with), [`reader`] (reading a recording
//! back, for pre-training and `jsae record-info`).

#![forbid(unsafe_code)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use jsae_wire::{ActionSpace, StateSpace};
use serde::{Deserialize, Serialize};

pub mod reader;
pub mod writer;

pub use reader::{RecordSummary, Recording, read, summarize};
pub use writer::{FLUSH_EVERY, RecordedSteps, Recorder};

/// The generated protobuf types of `proto/transition.proto`.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod pb {
    include!(concat!(env!("OUT_DIR"), "/jsae.record.v1.rs"));
}

/// The encoded FileDescriptorSet of `proto/transition.proto`: the schema in every recording.
pub const TRANSITION_SCHEMA: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/transition.fds"));
/// The schema's name: the message's full protobuf name.
pub const SCHEMA_NAME: &str = "jsae.record.v1.Transition";
/// The channel transitions are written on.
pub const TOPIC: &str = "/jsae/transitions";

/// What a recording's channel says about the run that stepped it (its metadata).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordingInfo {
    /// The run's name (its directory's name under `jsae train`).
    pub run_id: String,
    /// The environment's CLI name.
    pub env: String,
    /// The algorithm's CLI name.
    pub algo: String,
    /// The run's seed.
    pub seed: u64,
    /// The environment's state space.
    pub states: StateSpace,
    /// The environment's action space.
    pub actions: ActionSpace,
}

impl RecordingInfo {
    /// What a run of `config` named `run_id`, stepping environments of these spaces, records.
    pub fn of_run(
        config: &jsae_settings::TrainConfig,
        run_id: &str,
        states: &StateSpace,
        actions: &ActionSpace,
    ) -> Self {
        Self {
            run_id: run_id.to_string(),
            env: config.env.as_str().to_string(),
            algo: config.algo.as_str().to_string(),
            seed: config.seed,
            states: states.clone(),
            actions: actions.clone(),
        }
    }

    /// The channel metadata: plain strings, the spaces as JSON.
    fn to_metadata(&self) -> BTreeMap<String, String> {
        BTreeMap::from([
            ("run_id".to_string(), self.run_id.clone()),
            ("env".to_string(), self.env.clone()),
            ("algo".to_string(), self.algo.clone()),
            ("seed".to_string(), self.seed.to_string()),
            ("state_space".to_string(), json(&self.states)),
            ("action_space".to_string(), json(&self.actions)),
        ])
    }

    /// Reads the channel metadata back.
    fn from_metadata(m: &BTreeMap<String, String>) -> Result<Self, String> {
        let get = |key: &str| {
            m.get(key)
                .cloned()
                .ok_or_else(|| format!("the channel's metadata lacks {key:?}"))
        };
        let parse = |key: &str, text: String| format!("the channel's {key}: {text}");
        Ok(Self {
            run_id: get("run_id")?,
            env: get("env")?,
            algo: get("algo")?,
            seed: get("seed")?
                .parse()
                .map_err(|e: std::num::ParseIntError| parse("seed", e.to_string()))?,
            states: serde_json::from_str(&get("state_space")?)
                .map_err(|e| parse("state_space", e.to_string()))?,
            actions: serde_json::from_str(&get("action_space")?)
                .map_err(|e| parse("action_space", e.to_string()))?,
        })
    }
}

/// A space as JSON for the metadata.
fn json<T: Serialize>(value: &T) -> String {
    serde_json::to_string(value).unwrap_or_default()
}

/// Why a recording could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The file could not be created, written or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The MCAP library refused.
    #[error("{path}: MCAP: {source}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: mcap::McapError,
    },
    /// The file is not a recording of transitions (or not of this run's spaces).
    #[error("{path}: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

impl RecordError {
    fn io(path: &Path) -> impl FnOnce(std::io::Error) -> Self + '_ {
        move |source| Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    fn mcap(path: &Path) -> impl FnOnce(mcap::McapError) -> Self + '_ {
        move |source| Self::Mcap {
            path: path.to_path_buf(),
            source,
        }
    }

    fn format(path: &Path, reason: impl Into<String>) -> Self {
        Self::Format {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }
}
