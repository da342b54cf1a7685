//! The session store: sessions submitted to the Recommender service, appended as JSON lines
//! to `STORE_DIR/sessions.jsonl` and synced to disk before the service answers, so an
//! accepted session survives a crash. Readers (the n-gram model's refresh, in the actors and
//! the service) take only complete lines, from where they stopped last time.

use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::RecsysError;
use super::sessions::Session;

/// The store's file in `dir`.
pub fn sessions_file(dir: &Path) -> PathBuf {
    dir.join("sessions.jsonl")
}

/// Appends sessions to the store (one writer per store, held by a file lock).
#[derive(Debug)]
pub struct SessionStore {
    path: PathBuf,
    file: std::fs::File,
}

impl SessionStore {
    /// Opens (or creates) the store in `dir`. A last line cut short by a crash (never
    /// acknowledged to a client) is cut off, so the next append starts on a fresh line.
    pub fn open(dir: &Path) -> Result<Self, RecsysError> {
        let io = |path: &Path| {
            let path = path.to_owned();
            move |source| RecsysError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let path = sessions_file(dir);
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .read(true)
            .append(true)
            .open(&path)
            .map_err(io(&path))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(RecsysError::Data(format!(
                    "session store {}: another process writes to it (one writer per store)",
                    path.display()
                )));
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(io(&path)(e)),
        }
        let mut text = Vec::new();
        file.read_to_end(&mut text).map_err(io(&path))?;
        if text.last().is_some_and(|&b| b != b'\n') {
            let keep = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
            tracing::warn!(
                "session store {}: dropping an incomplete last line ({} bytes)",
                path.display(),
                text.len() - keep
            );
            file.set_len(keep as u64).map_err(io(&path))?;
            file.seek(SeekFrom::End(0)).map_err(io(&path))?;
        }
        Ok(Self { path, file })
    }

    /// Appends `sessions` and syncs them to disk.
    pub fn append(&mut self, sessions: &[Session]) -> Result<(), RecsysError> {
        let mut buf = Vec::new();
        for s in sessions {
            serde_json::to_writer(&mut buf, s).map_err(|e| RecsysError::Io {
                path: self.path.clone(),
                source: e.into(),
            })?;
            buf.push(b'\n');
        }
        let io = |source| RecsysError::Io {
            path: self.path.clone(),
            source,
        };
        let before = self.file.metadata().map_err(io)?.len();
        let written = self
            .file
            .write_all(&buf)
            .and_then(|()| self.file.sync_data());
        if let Err(e) = written {
            // a torn line would swallow the next append: cut back to the last whole one
            let _ = self.file.set_len(before);
            return Err(io(e));
        }
        Ok(())
    }
}

/// Reads the complete lines of the store in `dir` from byte `offset` on; returns the
/// sessions and the offset after the last complete line. A missing store is empty; a line
/// that does not parse is skipped with a warning.
pub fn read_since(dir: &Path, offset: u64) -> Result<(Vec<Session>, u64), RecsysError> {
    let path = sessions_file(dir);
    let mut file = match std::fs::File::open(&path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok((Vec::new(), offset)),
        Err(source) => return Err(RecsysError::Io { path, source }),
    };
    let mut text = Vec::new();
    file.seek(SeekFrom::Start(offset))
        .and_then(|_| file.read_to_end(&mut text))
        .map_err(|source| RecsysError::Io {
            path: path.clone(),
            source,
        })?;
    let complete = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    let mut sessions = Vec::new();
    for line in text[..complete].split(|&b| b == b'\n') {
        if line.is_empty() {
            continue;
        }
        match serde_json::from_slice::<Session>(line) {
            Ok(s) => sessions.push(s),
            Err(e) => tracing::warn!("session store {}: skipping a line: {e}", path.display()),
        }
    }
    Ok((sessions, offset + complete as u64))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recsys::Purchase;

    #[test]
    fn appended_sessions_are_read_back_once_and_a_torn_line_is_dropped() {
        let dir = std::env::temp_dir().join(format!("jsae-store-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let s = |id: &str| Session {
            session_id: id.into(),
            purchases: vec![Purchase {
                item_id: "x".into(),
                price: 2.5,
                time_unix_ms: 7,
            }],
        };
        let mut store = SessionStore::open(&dir).expect("opens");
        store.append(&[s("a"), s("b")]).expect("appends");
        let (got, offset) = read_since(&dir, 0).expect("reads");
        assert_eq!(got, vec![s("a"), s("b")]);
        drop(store);
        // a crash in the middle of a write
        let mut f = std::fs::OpenOptions::new()
            .append(true)
            .open(sessions_file(&dir))
            .expect("open");
        f.write_all(b"{\"session_id\":\"c\",\"purch")
            .expect("write");
        assert_eq!(read_since(&dir, offset).expect("reads").0, vec![]);
        let mut store = SessionStore::open(&dir).expect("reopens");
        store.append(&[s("d")]).expect("appends");
        let (got, _) = read_since(&dir, offset).expect("reads");
        assert_eq!(got, vec![s("d")]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
