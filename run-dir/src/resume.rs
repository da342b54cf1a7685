//! Whether a run's components go on from their checkpoints ([`Resume`]).

/// Whether a component goes on from its latest checkpoint in the run directory (the learner's
/// `jsae_learner::lifecycle`, the embedder's `jsae_embedder::lifecycle`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Resume {
    /// A fresh run: a checkpoint there is not read (the driver cleared the directory).
    Never,
    /// A restarted service: from the checkpoint if there is one (the learner then counts the
    /// env steps its still running actors report; the embedder starts afresh from a
    /// checkpoint that does not fit its model).
    IfCheckpoint,
    /// A stopped run continued (`jsae train --resume`): there must be a checkpoint; its actors
    /// start again from zero, so the run counts on from the checkpoint's env steps and wall
    /// time (from the last metrics.csv row's where the checkpoint has no training state).
    Required,
}
