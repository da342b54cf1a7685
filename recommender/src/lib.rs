//! The Recommender gRPC service (docs/src/recommender.md) and the reference recommenders.
//!
//! `Recommend` answers the k best items for a purchase history from the current policy,
//! `SubmitSessions` validates sessions and commits the good ones of a call to the session
//! store all at once (nothing of a call that fails), once per `session_id`; the n-gram model
//! is rebuilt from the store on a schedule.
//!
//! Layout: `scoring` (the core: weights in use, state from a history, JSAE's nearest items or
//! PPO's most likely ones, the store's writer), `grpc` (the handlers and `serve`), `submit`
//! (SubmitSessions: staging, commit, the limits), `sources` (weights followed from a live run
//! or loaded from a run directory's checkpoints), `cli` (`jsae recommender`'s flags and main),
//! `baseline` (the reference policies: popular, item-kNN, the greedy rule; with random,
//! their returns), `offline` (hit rate@k, NDCG@k and MRR@k on held-out sessions), `logs` (the logged
//! purchases a fresh learner's policy learns from), `session_wire` (sessions to and from
//! their gRPC form).
//! The environment, data and session store are `jsae_envs::recsys`.

#![forbid(unsafe_code)]

pub mod baseline;
pub mod cli;
pub mod grpc;
pub mod offline;
mod ranking;
pub mod scoring;
mod session_wire;
pub mod sources;
pub mod submit;

pub use cli::{RecommenderArgs, main};
pub use grpc::{RecommenderService, serve};
pub use scoring::{MAX_HISTORY, Recommendation, Recommender, catalogue_tag};
pub use session_wire::{session_from_wire, session_to_wire};
pub use sources::{WeightSources, load_run};
pub use submit::{
    MAX_BYTES_IN_FLIGHT, MAX_CALL_BYTES, MAX_CALLS_PER_CONNECTION, MAX_CONCURRENT_CALLS,
    MAX_ERRORS_LISTED, MAX_REQUEST_BYTES, MAX_SESSIONS_PER_CALL, MAX_WAITING_CALLS, SLOT_WAIT,
    SUBMIT_CALL_TIMEOUT, SUBMIT_IDLE_TIMEOUT, SubmitBudget,
};
