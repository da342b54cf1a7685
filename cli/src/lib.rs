//! The `jsae` command: training on this machine and the everyday tools.
//!
//! Layout: `train_command` (`jsae train`'s arguments, settings, run directory and `--resume`),
//! `train` (the one-process driver: embedder, learner and actors in lockstep, the
//! deterministic mode), `launch` (the services started as processes on loopback; `log_echo`
//! shows their warnings and errors on `jsae train`'s output), `progress`
//! (the progress bar), `plot` (a run directory's plots), `bench` (update, inference, transport,
//! MuJoCo and Recommender benchmarks), `replay` (`jsae env-replay`, the Gymnasium parity
//! check), `experiments` (`jsae sweep` and `jsae report` over the jsae-experiments crate),
//! `eval` (`jsae eval`, a run's checkpoints evaluated again), `recommender_eval` (`jsae
//! recommender-eval`, held-out hit rate and NDCG), `train::RunOptions` (`--record` and
//! `--pretrain-from`; the format is the jsae-record crate's), the one-shot gRPC clients
//! (`oneshot`, `health`, `recommender_client`) and `closed_pipe` (a closed standard output
//! ends a command quietly). The binary `jsae` (src/bin/jsae.rs) parses the command line and
//! calls these; it also starts the services themselves (`jsae embedder|learner|actor|
//! recommender`).

#![forbid(unsafe_code)]

pub mod bench;
pub mod closed_pipe;
pub mod commands;
pub mod eval;
pub mod experiments;
pub mod health;
pub mod launch;
pub mod log_echo;
pub mod logs;
pub mod oneshot;
pub mod plot;
pub mod progress;
pub mod recommender_client;
pub mod recommender_eval;
pub mod replay;
pub mod service_bin;
pub mod train;
pub mod train_command;

pub use train::{RunOptions, RunOutcome, TrainError, train_one_process, train_one_process_with};
