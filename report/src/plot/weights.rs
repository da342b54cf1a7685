//! Which embedding checkpoint a run's plots are drawn from, and `summary.json` as the plots
//! read it.
//!
//! A run directory may still hold the checkpoints of an older run (the same `--out` used
//! twice, with more updates the first time): the newest file in `checkpoints/` is then not
//! this run's. The plots therefore draw the version the run's summary names.

use std::io;

use jsae_agent::Embedding;
use jsae_nn::{BurnDevice, RecordError};
use jsae_run_dir::Summary;
use jsae_run_dir::{RunDir, Weights, read_weights};
use jsae_settings::TrainConfig;
use jsae_wire::EmbeddingSnapshot;

/// The run's `summary.json`; `None` while there is none (a run still going, or one stopped
/// before its end). A summary that is there but not readable is an error.
pub fn read_summary(dir: &RunDir) -> io::Result<Option<Summary>> {
    let path = dir.summary_json();
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e),
    };
    serde_json::from_str(&text).map(Some).map_err(|e| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!("{}: {e}", path.display()),
        )
    })
}

/// The embedding checkpoint a run's plots are drawn from.
///
/// With a `summary.json`, exactly the version it names (`embedding_version`): the file
/// `checkpoints/embedding-vN.bpk`, or the latest file when that holds version N. A newer
/// checkpoint left in the folder by an older run is never taken instead; `None` when the
/// named version is not there, or the summary names none (version 0: a run without
/// embeddings).
///
/// Only when there is no summary yet (a run still going, or stopped before its end) the
/// newest embedding checkpoint in the folder, as [`latest_embedding`].
pub fn run_embedding(dir: &RunDir) -> io::Result<Option<EmbeddingSnapshot>> {
    let Some(summary) = read_summary(dir)? else {
        return Ok(latest_embedding(dir));
    };
    let version = summary.embedding_version;
    if version == 0 {
        return Ok(None);
    }
    let checkpoints = dir.checkpoints();
    let bytes = match std::fs::read(checkpoints.versioned(Weights::Embedding, version)) {
        Ok(bytes) => Some(bytes),
        Err(e) if e.kind() == io::ErrorKind::NotFound => checkpoints
            .read_latest(Weights::Embedding)
            .and_then(|(v, bytes)| (v == version).then_some(bytes)),
        Err(e) => return Err(e),
    };
    Ok(bytes.map(|bytes| EmbeddingSnapshot::from_bytes(version, bytes)))
}

/// The newest embedding checkpoint of a run, if any (whichever run wrote it: see
/// [`run_embedding`] for the one a finished run's summary names).
pub fn latest_embedding(dir: &RunDir) -> Option<EmbeddingSnapshot> {
    let (version, path) = dir.checkpoints().newest(Weights::Embedding)?;
    Some(EmbeddingSnapshot::from_bytes(
        version,
        read_weights(&path).ok()?,
    ))
}

/// `snapshot` loaded with the run's settings.
pub fn load_embedding(
    snapshot: &EmbeddingSnapshot,
    config: &TrainConfig,
) -> Result<Embedding, RecordError> {
    let (states, actions) = config.spaces();
    Embedding::from_snapshot(
        &config.embedding,
        config.algo.representation(),
        &states,
        &actions,
        snapshot,
        &config.device.device(),
    )
}

/// The newest embedding checkpoint of a run, loaded with the run's settings (None: the run
/// has no embedding checkpoint).
pub fn load_latest_embedding(
    dir: &RunDir,
    config: &TrainConfig,
) -> Option<Result<Embedding, RecordError>> {
    latest_embedding(dir).map(|s| load_embedding(&s, config))
}
