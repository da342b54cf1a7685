//! A training on this machine. `one_process`: the embedder, the learner and the actors in
//! lockstep on one thread (the deterministic mode), opened on the run directory as their
//! services open it; `launch`: the services started as processes on loopback (`log_echo`
//! shows their warnings and errors on `jsae train`'s output); `progress`: the progress bar
//! or, without a terminal, a log line per phase; `logs`: the recommender's logged purchases a
//! fresh learner learns from. `jsae train` (jsae-cli) builds the settings and calls these.

#![forbid(unsafe_code)]

pub mod launch;
pub mod log_echo;
pub mod logs;
pub mod one_process;
pub mod progress;

pub use one_process::{
    RunOptions, RunOutcome, TrainError, actor_worker, run_id, train_one_process,
    train_one_process_with,
};
