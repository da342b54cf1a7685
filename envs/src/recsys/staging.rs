//! One `SubmitSessions` call's sessions on their way into the session store: written to a
//! staging file of their own as they arrive (so a call never holds its sessions in memory),
//! and moved into the store by [`SessionStore::commit`](super::store::SessionStore::commit)
//! only when the call ends cleanly. Dropped without a commit (the call failed or was
//! cancelled), the file is deleted and the store never sees them.

use std::collections::HashSet;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use super::RecsysError;
use super::sessions::Session;
use super::stored_ids::StoredIds;

/// Where a store's calls stage their sessions (`STORE/staging/`); shared, so that calls start
/// staging without waiting for the writer (which may be busy with another call's commit).
#[derive(Debug, Clone)]
pub struct StagingArea {
    dir: PathBuf,
    calls: Arc<AtomicU64>,
    stored: StoredIds,
}

impl StagingArea {
    /// The staging area in `dir` (emptied by the writer when it opens the store), whose
    /// calls skip the ids of `stored`.
    pub(super) fn new(dir: PathBuf, stored: StoredIds) -> Self {
        Self {
            dir,
            calls: Arc::default(),
            stored,
        }
    }

    /// A new staging file for one call's sessions.
    pub fn stage(&self) -> Result<StagedSessions, RecsysError> {
        let n = self.calls.fetch_add(1, Ordering::Relaxed);
        StagedSessions::create(
            self.dir.join(format!("call-{n}.jsonl")),
            self.stored.clone(),
        )
    }
}

/// One staged session: its line in the staging file.
#[derive(Debug, Clone, Copy)]
pub(super) struct StagedLine {
    /// The store's keyed hash of its `session_id` ([`StoredIds::hash`]).
    pub(super) hash: u64,
    /// Bytes of its line, the newline included (lines follow each other in the file).
    pub(super) bytes: u64,
    /// Its purchases.
    pub(super) purchases: u64,
}

/// What became of a session given to [`StagedSessions::push`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Staged {
    /// Written to the staging file; the commit stores it (unless another call stores the same
    /// `session_id` first).
    New,
    /// Its `session_id` is stored already, or staged earlier in this call: not staged again.
    Duplicate,
}

/// The sessions of one call, staged in `STORE/staging/` until the call commits them.
#[derive(Debug)]
pub struct StagedSessions {
    path: PathBuf,
    file: BufWriter<File>,
    pub(super) lines: Vec<StagedLine>,
    hashes: HashSet<u64>,
    stored: StoredIds,
    bytes: u64,
    line: Vec<u8>,
}

impl StagedSessions {
    /// A new, empty staging file at `path`, deduplicating against the ids of `stored`.
    fn create(path: PathBuf, stored: StoredIds) -> Result<Self, RecsysError> {
        let file = std::fs::OpenOptions::new()
            .create_new(true)
            .read(true)
            .write(true)
            .open(&path)
            .map_err(|source| RecsysError::Io {
                path: path.clone(),
                source,
            })?;
        Ok(Self {
            path,
            file: BufWriter::with_capacity(1 << 16, file),
            lines: Vec::new(),
            hashes: HashSet::new(),
            stored,
            bytes: 0,
            line: Vec::new(),
        })
    }

    /// Writes `session` to the staging file, unless its `session_id` is stored already or
    /// was staged before in this call (a duplicate: not written, not an error). The write
    /// goes to the page cache, not to the disk: only a commit syncs.
    pub fn push(&mut self, session: &Session) -> Result<Staged, RecsysError> {
        let hash = self.stored.hash(&session.session_id);
        if self.hashes.contains(&hash) || self.stored.contains_hash(hash) {
            return Ok(Staged::Duplicate);
        }
        self.line.clear();
        serde_json::to_writer(&mut self.line, session)
            .map_err(|e| RecsysError::Data(format!("a session as JSON: {e}")))?;
        self.line.push(b'\n');
        self.file
            .write_all(&self.line)
            .map_err(|source| RecsysError::Io {
                path: self.path.clone(),
                source,
            })?;
        let bytes = self.line.len() as u64;
        self.bytes += bytes;
        self.hashes.insert(hash);
        self.lines.push(StagedLine {
            hash,
            bytes,
            purchases: session.purchases.len() as u64,
        });
        // a large session leaves a large buffer: give it back
        if self.line.capacity() > 1 << 20 {
            self.line = Vec::new();
        }
        Ok(Staged::New)
    }

    /// Sessions staged.
    pub fn len(&self) -> usize {
        self.lines.len()
    }

    /// Whether nothing is staged.
    pub fn is_empty(&self) -> bool {
        self.lines.is_empty()
    }

    /// Bytes staged (the lines the commit copies into the store).
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// The staging file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The staging file, written out and ready to be read from its start.
    pub(super) fn written(&mut self) -> Result<&File, RecsysError> {
        use std::io::Seek;
        let io = |source| RecsysError::Io {
            path: self.path.clone(),
            source,
        };
        self.file.flush().map_err(io)?;
        let mut file = self.file.get_ref();
        file.seek(std::io::SeekFrom::Start(0)).map_err(io)?;
        Ok(file)
    }
}

impl Drop for StagedSessions {
    /// Committed or not, the staging file goes.
    fn drop(&mut self) {
        if let Err(e) = std::fs::remove_file(&self.path)
            && e.kind() != std::io::ErrorKind::NotFound
        {
            tracing::warn!("session store: {}: {e}", self.path.display());
        }
    }
}
