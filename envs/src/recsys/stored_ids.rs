//! The ids of the sessions a store holds, as keyed hashes ([`StoredIds`]).

use std::collections::HashSet;
use std::sync::{Arc, RwLock};

use super::sessions::IdKey;

/// The keyed hashes of the stored sessions' ids, shared by the writer (which adds a
/// commit's) and the calls staging sessions (which skip ids stored already).
#[derive(Debug, Clone)]
pub struct StoredIds {
    key: IdKey,
    hashes: Arc<RwLock<HashSet<u64>>>,
}

impl StoredIds {
    pub(super) fn new(key: IdKey) -> Self {
        Self {
            key,
            hashes: Arc::default(),
        }
    }

    /// The store's keyed hash of a session id.
    pub fn hash(&self, session_id: &str) -> u64 {
        self.key.hash(session_id)
    }

    /// Whether a session with this id is stored.
    pub fn contains(&self, session_id: &str) -> bool {
        self.contains_hash(self.hash(session_id))
    }

    pub(super) fn contains_hash(&self, hash: u64) -> bool {
        self.hashes
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .contains(&hash)
    }

    /// Stored sessions (distinct id hashes).
    pub fn len(&self) -> usize {
        self.hashes.read().unwrap_or_else(|p| p.into_inner()).len()
    }

    /// Whether nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub(super) fn insert(&self, hashes: impl IntoIterator<Item = u64>) {
        self.hashes
            .write()
            .unwrap_or_else(|p| p.into_inner())
            .extend(hashes);
    }
}
