//! What the gRPC handlers and the service's tasks queue for the learner thread.

use jsae_wire::{EmbeddingSnapshot, EvalReport, RolloutFragment};

/// What the learner thread is told.
#[derive(Debug)]
pub(super) enum Input {
    /// A checked fragment.
    Fragment(Box<RolloutFragment>),
    /// A new embedding version (JSAE).
    Embedding(EmbeddingSnapshot),
    /// An evaluation report and the request it answers.
    Eval(EvalReport, u64),
    /// An actor's policy stream opened (with what it announced) or closed (None).
    Stream {
        actor: u64,
        opened: Option<Announced>,
    },
    /// Time passes: an overdue round is closed (sent by a timer while the service runs).
    Tick,
}

/// What an actor says of itself when it opens its policy stream (`WatchRequest`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Announced {
    /// The env steps one rollout of all its environments delivers (0: it did not say).
    pub(super) rollout_steps: u64,
    /// Its environments (0: it did not say, and steps all of them whatever its share).
    pub(super) envs: u32,
}
