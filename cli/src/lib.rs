//! The `jsae` command: its subcommands over the libraries that do the work.
//!
//! Layout: `commands` (every subcommand and what it runs), `train_command` (`jsae train`'s
//! arguments, settings, run directory and `--resume`; the training itself is jsae-train's),
//! `replay` (`jsae env-replay`, the Gymnasium parity check), `experiments` (`jsae sweep` over
//! the jsae-experiments crate and `jsae report` over jsae-report), `eval` (`jsae eval`, a
//! run's checkpoints evaluated again), `recommender_eval` (`jsae recommender-eval`, held-out
//! hit rate and NDCG), the one-shot gRPC clients (`oneshot`, `health`, `recommender_client`),
//! `closed_pipe` (a closed standard output ends a command quietly) and `service_bin` (the
//! binaries `jsae-embedder`, `jsae-learner` and `jsae-actor`, which are those subcommands).
//! Plots and reports are jsae-report's, benchmarks jsae-bench's. The binary `jsae`
//! (src/bin/jsae.rs) parses the command line and calls these; it also starts the services
//! themselves (`jsae embedder|learner|actor|recommender`).

#![forbid(unsafe_code)]

pub mod closed_pipe;
pub mod commands;
pub mod eval;
pub mod experiments;
pub mod health;
pub mod oneshot;
pub mod recommender_client;
pub mod recommender_eval;
pub mod replay;
pub mod service_bin;
pub mod train_command;
