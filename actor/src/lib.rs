//! The actor side of JSAE-RL, and the local launcher.
//!
//! Environments (`envs`: gridworld, gridworld-discrete, slotmachine, and HalfCheetah and Ant on
//! MuJoCo, behind one [`envs::Env`] trait; `replay`: `jsae env-replay` for the Gymnasium
//! parity check), the rollout worker (`worker`: vectorised stepping with batched `phi -> pi_i -> f`
//! inference, weight swaps, random play before the first embedding), the actor process
//! (`service`: the worker fed by the services' snapshot streams over gRPC), the one-process
//! training driver (`train`), the launcher of the services as processes (`launch`), progress
//! reporting (`progress`), plots (`plot`), the inference/update benchmark (`bench`), the
//! transport benchmark (`bench_transport`) and the MuJoCo stepping benchmark (`bench_mujoco`). The run configuration is `jsae_proto::settings`.

// One unsafe call (MuJoCo's global log configuration, envs/mujoco.rs) is allowed locally.
#![deny(unsafe_code)]

pub mod bench;
pub mod bench_mujoco;
pub mod bench_recommender;
pub mod bench_transport;
pub mod envs;
pub mod health;
pub mod launch;
pub mod oneshot;
pub mod plot;
pub mod progress;
pub mod recsys;
pub mod replay;
pub mod service;
pub mod train;
pub mod worker;

pub use jsae_proto::settings::{Algo, ConfigError, TrainConfig};
pub use train::{RunOutcome, TrainError, train_one_process};
pub use worker::{ActorWorker, Rollout};
