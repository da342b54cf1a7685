//! The checkpoint of a model's store part, `STORE/model_counts.json`: the n-gram counts of the
//! store's sessions up to a point of its log, and the catalogue as those sessions extended
//! it. A process loading the model starts from it and reads only the log after that point,
//! so its start takes time and memory of the model's size (catalogue and contexts), not the
//! store's. It is a cache: written now and then by any process that follows the store (the
//! same log gives the same counts everywhere, since the catalogue is pinned), replaced
//! atomically, and ignored (the whole log is read instead) when it does not fit the store.

use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::RecsysError;
use super::ngram::Catalogue;
use super::ngram_counts::NgramCounts;
use super::sessions::bytes_hash;
use super::store;

/// New store bytes read since the last checkpoint after which the model's owner writes one.
pub const CHECKPOINT_EVERY_BYTES: u64 = 16 * 1024 * 1024;

/// Bytes of the log before the checkpoint's point whose hash it keeps: a log replaced since
/// (a store deleted and started again) does not match.
const FINGERPRINT_BYTES: u64 = 4096;

/// The checkpoint file in a store directory.
pub fn checkpoint_file(dir: &Path) -> PathBuf {
    dir.join("model_counts.json")
}

/// The store part of a model at a point of the store's log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelCheckpoint {
    /// The log's bytes counted (the end of a line).
    pub log_bytes: u64,
    /// [`bytes_hash`] of the log's last [`FINGERPRINT_BYTES`] before `log_bytes`.
    pub fingerprint: u64,
    /// The catalogue: the pinned one, extended by the items of the sessions counted.
    pub catalogue: Catalogue,
    /// The counts of the sessions in the log's first `log_bytes` bytes.
    pub counts: NgramCounts,
}

/// The fingerprint of the log in `dir` at `log_bytes`.
fn fingerprint(dir: &Path, log_bytes: u64) -> Result<u64, RecsysError> {
    let path = store::sessions_file(dir);
    let io = |source| RecsysError::Io {
        path: path.clone(),
        source,
    };
    let start = log_bytes.saturating_sub(FINGERPRINT_BYTES);
    let mut bytes = Vec::new();
    let mut file = std::fs::File::open(&path).map_err(io)?;
    file.seek(SeekFrom::Start(start)).map_err(io)?;
    file.take(log_bytes - start)
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if (bytes.len() as u64) < log_bytes - start {
        return Err(RecsysError::Data(format!(
            "{}: shorter than {log_bytes} bytes",
            path.display()
        )));
    }
    Ok(bytes_hash(&bytes))
}

/// Writes the checkpoint of `counts` (the sessions of the log's first `log_bytes` bytes) and
/// `catalogue` into the store in `dir`.
pub fn save(
    dir: &Path,
    log_bytes: u64,
    catalogue: &Catalogue,
    counts: &NgramCounts,
) -> Result<(), RecsysError> {
    #[derive(Serialize)]
    struct Borrowed<'a> {
        log_bytes: u64,
        fingerprint: u64,
        catalogue: &'a Catalogue,
        counts: &'a NgramCounts,
    }
    let json = serde_json::to_vec(&Borrowed {
        log_bytes,
        fingerprint: fingerprint(dir, log_bytes)?,
        catalogue,
        counts,
    })
    .map_err(|e| RecsysError::Data(e.to_string()))?;
    store::replace_file(&checkpoint_file(dir), &json)
}

/// The store's checkpoint where there is one that fits: the store's log still holds what it
/// counted, its catalogue extends `pinned`, its counts have `pinned`'s capacity. Anything
/// else (none, unreadable, another store's) is None: the caller reads the whole log.
pub fn load(dir: &Path, pinned: &Catalogue) -> Option<ModelCheckpoint> {
    let path = checkpoint_file(dir);
    let bytes = match std::fs::read(&path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => {
            tracing::warn!(
                "recommender: {}: {e}; reading the whole store",
                path.display()
            );
            return None;
        }
    };
    let why_not = || -> Result<ModelCheckpoint, String> {
        let mut c: ModelCheckpoint = serde_json::from_slice(&bytes).map_err(|e| e.to_string())?;
        c.catalogue.reindex();
        let capacity = pinned.capacity();
        let extends = (0..pinned.len() as u32).all(|k| c.catalogue.id(k) == pinned.id(k));
        if c.catalogue.capacity() != capacity || !extends || !c.counts.fits(capacity) {
            return Err("made for another catalogue".into());
        }
        let committed = store::committed_bytes(dir).map_err(|e| e.to_string())?;
        if c.log_bytes > committed
            || fingerprint(dir, c.log_bytes).map_err(|e| e.to_string())? != c.fingerprint
        {
            return Err("made for another log".into());
        }
        Ok(c)
    };
    match why_not() {
        Ok(c) => Some(c),
        Err(e) => {
            tracing::warn!(
                "recommender: {}: {e}; reading the whole store",
                path.display()
            );
            None
        }
    }
}
