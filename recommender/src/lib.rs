//! The Recommender gRPC service (CONTRACT.md) and the reference recommenders.
//!
//! `Recommend` answers the k best items for a purchase history from the current policy,
//! `SubmitSessions` validates sessions and appends the good ones to the session store, from
//! which the n-gram model is rebuilt on a schedule.
//!
//! Layout: `scoring` (the core: weights in use, state from a history, JSAE's nearest items or
//! PPO's most likely ones, the store), `grpc` (the handlers and `serve`), `sources` (weights
//! followed from a live run or loaded from a run directory's checkpoints), `cli` (`jsae
//! recommender`'s flags and main), `baseline` (the reference policies: popular, most likely next item; with random, their returns),
//! `offline` (hit rate@k and NDCG@k on held-out sessions), `logs` (the logged purchases a
//! fresh learner's policy learns from).
//! The environment, data and session store are `jsae_envs::recsys`.

#![forbid(unsafe_code)]

pub mod baseline;
pub mod cli;
pub mod grpc;
pub mod logs;
pub mod offline;
pub mod scoring;
pub mod sources;

pub use cli::{RecommenderArgs, main};
pub use grpc::{RecommenderService, serve};
pub use logs::logged_purchases;
pub use scoring::{
    MAX_ERRORS_LISTED, MAX_HISTORY, MAX_SESSIONS_PER_CALL, Recommendation, Recommender,
};
pub use sources::{WeightSources, load_run};
