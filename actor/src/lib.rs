//! The actor side of JSAE-RL, and the local launcher.
//!
//! Environments (`envs`: gridworld, gridworld-discrete, slotmachine behind one [`envs::Env`]
//! trait), the rollout worker (`worker`: vectorised stepping with batched `phi -> pi_i -> f`
//! inference, weight swaps, random play before the first embedding), the one-process
//! training driver (`train`), the run configuration (`config`), progress reporting
//! (`progress`), plots (`plot`) and the inference/update benchmark (`bench`).

#![forbid(unsafe_code)]

pub mod bench;
pub mod config;
pub mod envs;
pub mod plot;
pub mod progress;
pub mod train;
pub mod worker;

pub use config::{Algo, ConfigError, TrainConfig};
pub use train::{RunOutcome, TrainError, train_one_process};
pub use worker::{ActorWorker, Rollout};
