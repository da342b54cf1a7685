//! f for discrete actions: which action's embedding `g(a)` is nearest to a point `e` of the
//! action-embedding space. [`NearestAction`] scans every row exactly: the reference, and the
//! tests' oracle. [`ApproxNearest`] searches an HNSW graph whose search width is calibrated
//! against the exact scan when it is built, for catalogues too large to scan at every step.
//! [`ActionIndex`] is either, chosen by the number of actions.

#![forbid(unsafe_code)]

use std::sync::Arc;

mod approx;
mod exact;

pub use approx::{ApproxNearest, ApproxSettings, IndexError, calibration_queries, recall};
pub use exact::NearestAction;

/// f over a table of action embeddings: exact below a size, approximate from it. Clones
/// share an approximate index.
#[derive(Debug, Clone)]
pub enum ActionIndex {
    /// Every row scanned.
    Exact(NearestAction),
    /// An HNSW graph.
    Approx(Arc<ApproxNearest>),
}

impl ActionIndex {
    /// The exact scan for fewer than `approx_from` rows (0: never approximate), else the
    /// approximate index built with `settings`.
    pub fn build(
        table: &[f32],
        d: usize,
        approx_from: usize,
        settings: &ApproxSettings,
    ) -> Result<Self, IndexError> {
        let n = table.len().checked_div(d).unwrap_or(0);
        if approx_from == 0 || n < approx_from {
            Ok(Self::Exact(NearestAction::new(table, d)))
        } else {
            ApproxNearest::build(table, d, settings).map(|x| Self::Approx(Arc::new(x)))
        }
    }

    /// Number of actions.
    pub fn len(&self) -> usize {
        match self {
            Self::Exact(x) => x.len(),
            Self::Approx(x) => x.len(),
        }
    }

    /// Whether there are no actions.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Embedding width.
    pub fn dim(&self) -> usize {
        match self {
            Self::Exact(x) => x.dim(),
            Self::Approx(x) => x.dim(),
        }
    }

    /// Nearest action of every row of `es` (`[batch, d]`), appended to `out`.
    pub fn nearest_batch(&mut self, es: &[f32], out: &mut Vec<u32>) {
        match self {
            Self::Exact(x) => x.nearest_batch(es, out),
            Self::Approx(x) => x.nearest_batch(es, out),
        }
    }

    /// The `k` actions among the first `rows` nearest to `e`, as `(action, distance)`,
    /// nearest first (exactly or approximately).
    pub fn k_nearest(&self, e: &[f32], k: usize, rows: usize) -> Vec<(u32, f32)> {
        match self {
            Self::Exact(x) => x.k_nearest(e, k, rows),
            Self::Approx(x) => x.k_nearest(e, k, rows),
        }
    }
}

#[cfg(test)]
mod tests;
