//! The session store: the sessions `SubmitSessions` accepted, in `STORE_DIR`, read by every
//! process that has the same store (the service, a run's actors) to build its model.
//!
//! On disk:
//! - `sessions.jsonl`: the stored sessions, one JSON object per line, in commit order. Only
//!   its first `log_bytes` bytes (see `commit.json`) are committed: what follows is the rest of
//!   a commit that failed or was cut short by a crash, which readers never read and the writer
//!   cuts off when it opens the store.
//! - `commit.json`: `{"log_bytes": N, "sessions": M}`, the commit point. Each commit copies
//!   a call's staged sessions to the end of the log, syncs it, appends their ids to the index,
//!   syncs that, then writes this record beside and renames it into place: a call's sessions
//!   are all in the store or none are. A store written before this record existed is
//!   committed up to its last complete line (the writer adds the record when it opens it).
//! - `id_key`: the store's secret key ([`IdKey`], 32 hex digits), drawn when the store is
//!   created; the index hashes ids with it, so no client can make its id collide with
//!   another's. A store without one (from an older version) gets one, and its index is
//!   rebuilt with it.
//! - `session_ids.bin`: the index, `M` little-endian u64 keyed hashes ([`IdKey::hash`]) of
//!   the stored sessions' ids, in log order. Entries past `M` (a failed commit's) are cut
//!   off when the writer opens the store; a shorter file (lost, or from an older store) is
//!   rebuilt from the log. A `session_id` that is stored already is never stored again,
//!   across restarts.
//! - `staging/`: one file per call in progress ([`StagedSessions`]), emptied when the writer
//!   opens the store.
//! - `catalogue.json` and `model_counts.json` belong to the model (`data`,
//!   `model_checkpoint`).
//!
//! The writer holds a file lock on the log (one writer per store), the committed record and
//! the set of stored id hashes: 8 bytes per stored session plus the hash set's overhead, never
//! a session's body. Two different ids with the same 64-bit keyed hash would make the second
//! a duplicate: by chance only (the key is secret), about 3 in 10^8 among 10^6 stored
//! sessions (n^2 / 2^65).

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::RecsysError;
use super::sessions::{IdKey, Session};
use super::staging::{Staged, StagedSessions, StagingArea};
pub use super::stored_ids::StoredIds;

/// The store's log of sessions in `dir`.
pub fn sessions_file(dir: &Path) -> PathBuf {
    dir.join("sessions.jsonl")
}

fn commit_file(dir: &Path) -> PathBuf {
    dir.join("commit.json")
}

fn index_file(dir: &Path) -> PathBuf {
    dir.join("session_ids.bin")
}

fn key_file(dir: &Path) -> PathBuf {
    dir.join("id_key")
}

/// The store's key, and whether it was drawn now (the store had none). A key file that
/// cannot be read as a key is an error, naming it: a new key would change every hash.
fn read_or_create_key(dir: &Path) -> Result<(IdKey, bool), RecsysError> {
    let path = key_file(dir);
    match std::fs::read_to_string(&path) {
        Ok(text) => IdKey::from_text(&text).map(|k| (k, false)).ok_or_else(|| {
            RecsysError::Data(format!(
                "session store {}: not a key (32 hex digits); restore it from a backup, or \
                 delete it to draw a new one and rebuild the index",
                path.display()
            ))
        }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let key = IdKey::random();
            replace_file(&path, key.to_text().as_bytes())?;
            Ok((key, true))
        }
        Err(e) => Err(io(&path)(e)),
    }
}

fn staging_dir(dir: &Path) -> PathBuf {
    dir.join("staging")
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> RecsysError + use<> {
    let path = path.to_owned();
    move |source| RecsysError::Io { path, source }
}

/// Writes `bytes` to `path` all at once for readers: to a file beside it, synced, then
/// renamed into place (and the directory synced), so a reader finds the old content or the
/// new, never a part.
pub(super) fn replace_file(path: &Path, bytes: &[u8]) -> Result<(), RecsysError> {
    static WRITES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = WRITES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = path.with_extension(format!("{}-{n}.tmp", std::process::id()));
    let written = File::create(&tmp)
        .and_then(|mut f| f.write_all(bytes).and_then(|()| f.sync_data()))
        .and_then(|()| std::fs::rename(&tmp, path));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(path)(e));
    }
    // the rename is done; a failed directory sync only makes it less sure to survive a crash
    if let Some(dir) = path.parent()
        && let Err(e) = File::open(dir).and_then(|d| d.sync_all())
    {
        tracing::warn!("session store: syncing {}: {e}", dir.display());
    }
    Ok(())
}

/// The commit point of a store: how much of the log, and of the index, is committed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CommitRecord {
    /// Committed bytes of `sessions.jsonl` (whole lines).
    pub log_bytes: u64,
    /// Committed entries of `session_ids.bin`: the stored sessions.
    pub sessions: u64,
}

/// The commit record of the store in `dir` (None: no store yet, or one from before records).
pub fn read_commit(dir: &Path) -> Result<Option<CommitRecord>, RecsysError> {
    let path = commit_file(dir);
    match std::fs::read(&path) {
        Ok(bytes) => serde_json::from_slice(&bytes)
            .map(Some)
            .map_err(|e| RecsysError::Parse {
                path,
                line: 1,
                reason: e.to_string(),
            }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(io(&path)(e)),
    }
}

/// What a commit did with a call's staged sessions.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CommitOutcome {
    /// Sessions stored.
    pub stored: u64,
    /// Their purchases.
    pub purchases: u64,
    /// Sessions not stored because their `session_id` was stored meanwhile (by another call).
    pub duplicates: u64,
}

/// Reads the committed lines of the store's log in `dir` between byte `from` (the end of a
/// line, 0 at first) and `until` (`u64::MAX`: the commit point), one session at a time to
/// `visit(session, the end of its line)`; returns the end of the last line read. A missing
/// store is empty; a line that does not parse is skipped with a warning. On an error,
/// `visit` has seen the sessions before it.
pub fn read_committed(
    dir: &Path,
    from: u64,
    until: u64,
    mut visit: impl FnMut(Session, u64),
) -> Result<u64, RecsysError> {
    // a store from before commit records: its complete lines
    let limit = read_commit(dir)?
        .map_or(u64::MAX, |r| r.log_bytes)
        .min(until);
    let path = sessions_file(dir);
    each_line(
        &path,
        from,
        limit,
        |line, end| match serde_json::from_slice::<Session>(line) {
            Ok(s) => visit(s, end),
            Err(e) => tracing::warn!("session store {}: skipping a line: {e}", path.display()),
        },
    )
}

/// The committed length of the store's log in `dir` (0 for no store): a record's, or for a
/// store from before records, the file's.
pub fn committed_bytes(dir: &Path) -> Result<u64, RecsysError> {
    if let Some(r) = read_commit(dir)? {
        return Ok(r.log_bytes);
    }
    let path = sessions_file(dir);
    match std::fs::metadata(&path) {
        Ok(m) => Ok(m.len()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(0),
        Err(e) => Err(io(&path)(e)),
    }
}

/// Calls `each(line, end of line)` for the complete lines of `path` between `offset` and
/// `limit`; returns the end of the last complete line (`offset` when there is none). A
/// missing file has no lines.
fn each_line(
    path: &Path,
    offset: u64,
    limit: u64,
    mut each: impl FnMut(&[u8], u64),
) -> Result<u64, RecsysError> {
    if offset >= limit {
        return Ok(offset);
    }
    let mut file = match File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(offset),
        Err(e) => return Err(io(path)(e)),
    };
    file.seek(SeekFrom::Start(offset)).map_err(io(path))?;
    let mut reader = BufReader::with_capacity(1 << 16, file.take(limit - offset));
    let (mut line, mut end) = (Vec::new(), offset);
    loop {
        line.clear();
        let n = reader.read_until(b'\n', &mut line).map_err(io(path))?;
        if n == 0 || line.last() != Some(&b'\n') {
            return Ok(end);
        }
        end += n as u64;
        each(&line[..n - 1], end);
    }
}

/// The keyed id hashes of the log's complete lines up to `limit`, and where the last one
/// ends.
fn scan_ids(path: &Path, limit: u64, key: IdKey) -> Result<(Vec<u64>, u64), RecsysError> {
    #[derive(Deserialize)]
    struct Id {
        session_id: String,
    }
    let mut hashes = Vec::new();
    let end = each_line(path, 0, limit, |line, _| {
        match serde_json::from_slice::<Id>(line) {
            Ok(id) => hashes.push(key.hash(&id.session_id)),
            Err(e) => tracing::warn!("session store {}: skipping a line: {e}", path.display()),
        }
    })?;
    Ok((hashes, end))
}

/// The first `n` hashes of an index file, or None where it holds fewer.
fn read_index(path: &Path, n: u64) -> Result<Option<Vec<u64>>, RecsysError> {
    let mut bytes = Vec::new();
    match File::open(path) {
        Ok(f) => f.take(n * 8).read_to_end(&mut bytes).map_err(io(path))?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io(path)(e)),
    };
    if (bytes.len() as u64) < n * 8 {
        return Ok(None);
    }
    Ok(Some(
        bytes
            .chunks_exact(8)
            .map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()))
            .collect(),
    ))
}

fn index_bytes(hashes: &[u64]) -> Vec<u8> {
    hashes.iter().flat_map(|h| h.to_le_bytes()).collect()
}

/// The store's writer (one per store, held by a file lock on the log).
#[derive(Debug)]
pub struct SessionStore {
    dir: PathBuf,
    log: File,
    index: File,
    committed: CommitRecord,
    ids: StoredIds,
    staging: StagingArea,
}

impl SessionStore {
    /// Opens (or creates) the store in `dir`: takes the writer's lock, empties `staging/`,
    /// cuts what follows the commit point off the log and the index (rebuilding the index
    /// from the log where it is short), and loads the index.
    pub fn open(dir: &Path) -> Result<Self, RecsysError> {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let path = sessions_file(dir);
        let log = std::fs::OpenOptions::new()
            .create(true)
            .read(true)
            .append(true)
            .open(&path)
            .map_err(io(&path))?;
        match log.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(RecsysError::Data(format!(
                    "session store {}: another process writes to it (one writer per store)",
                    path.display()
                )));
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(io(&path)(e)),
        }
        let staging = staging_dir(dir);
        match std::fs::remove_dir_all(&staging) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(io(&staging)(e)),
        }
        std::fs::create_dir_all(&staging).map_err(io(&staging))?;

        let log_len = log.metadata().map_err(io(&path))?.len();
        let (key, new_key) = read_or_create_key(dir)?;
        let (committed, hashes) = match read_commit(dir)? {
            Some(r) if log_len < r.log_bytes => {
                return Err(RecsysError::Data(format!(
                    "session store {}: {log_len} bytes, fewer than the {} committed",
                    path.display(),
                    r.log_bytes
                )));
            }
            // an index hashed without this key (a key just drawn) is rebuilt with it
            Some(r) if new_key => Self::rebuild_index(dir, r.log_bytes, key)?,
            Some(r) => match read_index(&index_file(dir), r.sessions)? {
                Some(hashes) => (r, hashes),
                None => Self::rebuild_index(dir, r.log_bytes, key)?,
            },
            None => Self::rebuild_index(dir, log_len, key)?,
        };
        if log_len > committed.log_bytes {
            tracing::warn!(
                "session store {}: dropping {} uncommitted bytes",
                path.display(),
                log_len - committed.log_bytes
            );
            log.set_len(committed.log_bytes).map_err(io(&path))?;
        }
        let index_path = index_file(dir);
        let index = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&index_path)
            .map_err(io(&index_path))?;
        index
            .set_len(committed.sessions * 8)
            .map_err(io(&index_path))?;
        let ids = StoredIds::new(key);
        ids.insert(hashes);
        Ok(Self {
            dir: dir.to_owned(),
            log,
            index,
            committed,
            staging: StagingArea::new(staging, ids.clone()),
            ids,
        })
    }

    /// Writes the index of the log's complete lines up to `limit` and the commit record that
    /// covers them.
    fn rebuild_index(
        dir: &Path,
        limit: u64,
        key: IdKey,
    ) -> Result<(CommitRecord, Vec<u64>), RecsysError> {
        let (hashes, log_bytes) = scan_ids(&sessions_file(dir), limit, key)?;
        replace_file(&index_file(dir), &index_bytes(&hashes))?;
        let record = CommitRecord {
            log_bytes,
            sessions: hashes.len() as u64,
        };
        write_commit(dir, record)?;
        Ok((record, hashes))
    }

    /// The ids stored (shared: it follows the commits).
    pub fn ids(&self) -> StoredIds {
        self.ids.clone()
    }

    /// The commit point now.
    pub fn committed(&self) -> CommitRecord {
        self.committed
    }

    /// Where calls stage their sessions (shared: staging needs no lock on the writer).
    pub fn staging(&self) -> StagingArea {
        self.staging.clone()
    }

    /// A new staging file for one call's sessions.
    pub fn stage(&self) -> Result<StagedSessions, RecsysError> {
        self.staging.stage()
    }

    /// Moves the staged sessions whose ids are not stored yet into the store, all or none:
    /// appended to the log and synced, their ids appended to the index and synced, then the
    /// new commit record put in place. On failure the log and the index are cut back and
    /// nothing is stored. The staging file is deleted either way.
    pub fn commit(&mut self, mut staged: StagedSessions) -> Result<CommitOutcome, RecsysError> {
        if staged.is_empty() {
            return Ok(CommitOutcome::default());
        }
        let mut outcome = CommitOutcome::default();
        let mut hashes = Vec::new();
        let appended = self.append_new(&mut staged, &mut outcome, &mut hashes);
        let record = CommitRecord {
            log_bytes: self.committed.log_bytes + appended.as_ref().map_or(0, |b| *b),
            sessions: self.committed.sessions + hashes.len() as u64,
        };
        let done = appended.and_then(|_| {
            if hashes.is_empty() {
                return Ok(());
            }
            let index_path = index_file(&self.dir);
            (&self.index)
                .write_all(&index_bytes(&hashes))
                .and_then(|()| self.index.sync_data())
                .map_err(io(&index_path))?;
            write_commit(&self.dir, record)
        });
        if let Err(e) = done {
            // cut back to the commit point, so the next commit starts there
            let _ = self.log.set_len(self.committed.log_bytes);
            let _ = self.index.set_len(self.committed.sessions * 8);
            return Err(e);
        }
        self.committed = record;
        self.ids.insert(hashes);
        Ok(outcome)
    }

    /// Copies the staged lines of ids not stored yet to the end of the log and syncs it;
    /// returns the bytes appended, and fills in the outcome and the new ids' hashes.
    fn append_new(
        &mut self,
        staged: &mut StagedSessions,
        outcome: &mut CommitOutcome,
        hashes: &mut Vec<u64>,
    ) -> Result<u64, RecsysError> {
        let path = sessions_file(&self.dir);
        let lines = staged.lines.clone();
        let staging_path = staged.path().to_owned();
        let mut from = BufReader::with_capacity(1 << 16, staged.written()?);
        let mut to = BufWriter::with_capacity(1 << 16, &self.log);
        let mut bytes = 0;
        for line in &lines {
            if self.ids.contains_hash(line.hash) {
                outcome.duplicates += 1;
                let skip = i64::try_from(line.bytes).unwrap_or(i64::MAX);
                from.seek_relative(skip).map_err(io(&staging_path))?;
                continue;
            }
            let copied =
                std::io::copy(&mut (&mut from).take(line.bytes), &mut to).map_err(io(&path))?;
            if copied != line.bytes {
                return Err(RecsysError::Data(format!(
                    "{}: cut short ({copied} of {} bytes)",
                    staging_path.display(),
                    line.bytes
                )));
            }
            bytes += copied;
            outcome.stored += 1;
            outcome.purchases += line.purchases;
            hashes.push(line.hash);
        }
        to.flush().map_err(io(&path))?;
        drop(to);
        self.log.sync_data().map_err(io(&path))?;
        Ok(bytes)
    }

    /// Stages and commits `sessions` at once (ids stored already are skipped).
    pub fn append(&mut self, sessions: &[Session]) -> Result<CommitOutcome, RecsysError> {
        let mut staged = self.stage()?;
        let mut duplicates = 0;
        for s in sessions {
            if staged.push(s)? == Staged::Duplicate {
                duplicates += 1;
            }
        }
        let mut outcome = self.commit(staged)?;
        outcome.duplicates += duplicates;
        Ok(outcome)
    }
}

fn write_commit(dir: &Path, record: CommitRecord) -> Result<(), RecsysError> {
    let json = serde_json::to_vec(&record).map_err(|e| RecsysError::Data(e.to_string()))?;
    replace_file(&commit_file(dir), &json)
}

#[cfg(test)]
#[path = "store_tests.rs"]
mod tests;
