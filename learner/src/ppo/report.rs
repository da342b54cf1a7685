//! What the learner reports: refused fragments, what happened to an ingested one, the
//! metrics of an update, and policy-lag statistics.

use jsae_nn::RecordError;
use jsae_wire::{PolicySnapshot, ValidationError};

/// Why the learner refused or dropped a fragment.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    /// The fragment is malformed.
    #[error("invalid fragment: {0}")]
    Invalid(#[from] ValidationError),
    /// Weights could not be serialised.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// Pre-training on logged purchases was asked of what it does not fit.
    #[error("pre-training on logged purchases: {0}")]
    Pretrain(String),
    /// The fragment's step claim went back within its actor's incarnation.
    #[error("fragment refused: {0}")]
    Claim(#[from] super::ClaimWentBack),
    /// A checkpoint's training state does not read.
    #[error(transparent)]
    State(#[from] super::StateError),
}

/// What happened to an ingested fragment.
#[derive(Debug)]
pub enum Ingested {
    /// Kept for the next update.
    Buffered,
    /// Dropped: produced by a policy too many versions old.
    DroppedLag,
    /// Dropped: computed with an outdated embedding.
    DroppedEmbedding,
    /// It completed a batch: the policy was updated.
    Updated(Box<UpdateReport>),
}

/// Metrics of one update (one row of metrics.csv).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct UpdateMetrics {
    /// Update number, from 1.
    pub update: u64,
    /// Env steps of all actors so far.
    pub env_steps: u64,
    /// Steps in this update's batch.
    pub batch_steps: usize,
    /// Mean return of training episodes finished since the last update (None if none).
    pub return_mean: Option<f64>,
    /// Success rate of those episodes, where the environment has one.
    pub success_rate: Option<f64>,
    /// Episodes finished since the last update.
    pub episodes: usize,
    /// Mean policy lag of this batch's fragments.
    pub policy_lag_mean: f64,
    /// Largest policy lag of this batch's fragments.
    pub policy_lag_max: u64,
    /// Fragments dropped for lag so far.
    pub dropped_lag: u64,
    /// Fragments dropped for an outdated embedding so far.
    pub dropped_embedding: u64,
    /// Clipped surrogate loss (last epoch mean).
    pub policy_loss: f64,
    /// Value loss (last epoch mean).
    pub value_loss: f64,
    /// Entropy (last epoch mean).
    pub entropy: f64,
    /// The next-purchase cross-entropy (last epoch mean; fused update only, 0 when off).
    pub next_purchase_loss: f64,
    /// Approximate KL between behaviour and updated policy (last epoch mean).
    pub approx_kl: f64,
    /// Fraction of samples whose ratio was clipped (last epoch mean).
    pub clip_frac: f64,
    /// Global gradient norm before clipping (mean).
    pub grad_norm: f64,
    /// Learning rate used.
    pub lr: f64,
    /// Epochs run (fewer than configured if the KL target stopped it).
    pub epochs: usize,
    /// Mean log-std of the Gaussian head (0 for categorical).
    pub log_std_mean: f64,
    /// Explained variance of the value predictions.
    pub explained_variance: f64,
    /// Embedding version of the batch.
    pub embedding_version: u64,
    /// New policy version.
    pub policy_version: u64,
}

/// An update's result: metrics and the new weights.
#[derive(Debug)]
pub struct UpdateReport {
    /// Metrics.
    pub metrics: UpdateMetrics,
    /// The new policy.
    pub snapshot: PolicySnapshot,
}

/// Lag accounting over a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LagStats {
    /// Sum of lags of accepted fragments.
    pub sum: u64,
    /// Accepted fragments.
    pub count: u64,
    /// Largest lag accepted.
    pub max: u64,
}

impl LagStats {
    /// Mean lag.
    pub fn mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum as f64 / self.count as f64
        }
    }
}
