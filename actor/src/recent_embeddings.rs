//! The embeddings an actor installed lately, by version, so that the end-of-run evaluation
//! runs on the embedding the final policy was trained on. In separate processes the embedder
//! trains on transitions that reach it after the learner's last update, so its last version
//! often arrives after the final policy; evaluated with it, the policy meets state and action
//! embeddings it never acted in, and its mean decoded into a loop where its samples solved the
//! task (docs/src/experiments/greedy-loops.md).

use std::collections::VecDeque;
use std::sync::Arc;

use jsae_wire::EmbeddingSnapshot;

/// How many versions are kept: the learner drops fragments of an older embedding than its
/// newest, so the final policy's is one of the last few the actor saw.
pub const KEPT: usize = 4;

/// The last [`KEPT`] embeddings installed, oldest first.
#[derive(Debug, Default)]
pub struct RecentEmbeddings {
    held: VecDeque<Arc<EmbeddingSnapshot>>,
}

impl RecentEmbeddings {
    /// Notes an installed embedding.
    pub fn installed(&mut self, snapshot: Arc<EmbeddingSnapshot>) {
        self.held.retain(|e| e.version != snapshot.version);
        self.held.push_back(snapshot);
        while self.held.len() > KEPT {
            self.held.pop_front();
        }
    }

    /// The embedding of `version`, if it is still held.
    pub fn get(&self, version: u64) -> Option<&Arc<EmbeddingSnapshot>> {
        self.held.iter().find(|e| e.version == version)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn snapshot(version: u64) -> Arc<EmbeddingSnapshot> {
        Arc::new(EmbeddingSnapshot::from_bytes(version, Vec::new()))
    }

    #[test]
    fn keeps_the_last_versions_installed() {
        let mut recent = RecentEmbeddings::default();
        for v in 1..=6 {
            recent.installed(snapshot(v));
        }
        recent.installed(snapshot(6));
        assert!(recent.get(2).is_none());
        for v in 3..=6 {
            assert_eq!(recent.get(v).map(|e| e.version), Some(v));
        }
    }
}
