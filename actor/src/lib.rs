//! The actor: the rollout worker and the actor process.
//!
//! `worker` steps a vector of environments with one batched `phi -> pi_i -> f` inference per
//! step across them, swaps weights between rollouts and plays at random before the first
//! embedding; `service` is the actor process: the worker fed by the embedder's and the
//! learner's snapshot streams over gRPC, streaming transitions and fragments back from its
//! stepping thread (`stepping`), paced by `pacing` (rollouts per policy version, and a wait that adapts to the update time), its
//! random play before the first embedding bounded by `random_play`, and its streams to the
//! services kept open by `push`, which loses nothing while a service is away. The
//! environments are `jsae-envs`, the run configuration `jsae_settings`.

#![forbid(unsafe_code)]

pub mod pacing;
mod push;
pub mod random_play;
pub mod recent_embeddings;
pub mod service;
mod stepping;
pub mod worker;

pub use service::{ActorArgs, main};
pub use worker::{ActorWorker, Rollout, WorkerError};
