//! PPO on embedded tuples (JSAE) or raw states and actions (plain PPO).
//!
//! The learner owns the policy and critic, ingests rollout fragments tagged with the policy
//! and embedding versions that produced them, measures policy lag and drops stale data, runs
//! PPO updates (GAE with terminated/truncated kept apart, clipped surrogate, value loss,
//! entropy bonus, per-minibatch advantage normalisation, global grad-norm clipping, linear LR
//! annealing) and publishes versioned policy snapshots.
//!
//! Layout: `lifecycle` (the learner on its run directory: resume, warm start, checkpoints,
//! metrics rows and the summary, for the service and the one-process driver alike),
//! `policy_eval` (what the losses need of the policy beyond acting; the policy
//! itself, its acting half, is `jsae_agent::Policy`), `gae`, `normalise` (running
//! statistics, reward scaling), `ppo` (the learner), `fused` (the PPO minibatch loss and
//! gradients on the host, checked against burn's autodiff; the default update path),
//! `update_row` (an update's scalars for metrics.csv and TensorBoard, written by
//! `jsae_run_dir`), `service` (the gRPC learner service), `synthetic` (random fragments for
//! benchmarks and tests), `visits` (the exploration bonus's visit counts over all actors).
//! The settings are `jsae_settings::PpoConfig`.

#![forbid(unsafe_code)]

pub mod fused;
pub mod gae;
pub mod lifecycle;
pub mod normalise;
mod policy_eval;
mod ppo;
pub mod service;
pub mod synthetic;
mod update_row;
pub mod visits;

pub use jsae_settings::{PpoConfig, UpdatePath};
pub use policy_eval::{Evaluation, PolicyEval};
pub use ppo::{
    ClaimWentBack, Ingested, LagStats, Learner, LearnerError, LoggedPurchases, PretrainReport,
    StateError, UpdateMetrics, UpdateReport, clipped_surrogate_loss,
};
pub use update_row::{UPDATE_COLUMNS, update_scalars};
