//! Environments stepped by worker processes over gRPC, for `--env gym:ID`: the actor serves
//! [`EnvHost`] (`wire/proto/jsae.proto`), Python workers (`python -m jsae.envs`, the
//! package in `python/`) connect to it and host Gymnasium environments, and the actor steps
//! them through a [`RemotePool`], the same [`jsae_envs::EnvPool`] its built-in environments
//! are stepped through: the policy runs once per step for every connected environment, in
//! Rust. `codec` turns observations and actions into their wire form and checks what
//! workers send; `host` checks a worker's hello against the run; `pool` places the
//! environments on workers and ends the episodes of one that goes away; `workers` starts
//! an actor's own worker processes.

#![forbid(unsafe_code)]

mod codec;
mod host;
mod hosted;
mod pool;
mod workers;

pub use codec::MAX_ABS_REWARD;
pub use host::{EnvHost, MAX_WORKER_ENVS, PROTOCOL, gym_space};
pub use hosted::{HostPlan, Hosting, host, host_on_own_runtime};
pub use pool::{GATHER_TIMEOUT, REPLY_TIMEOUT, RemotePool};
pub use workers::{WorkerPlan, WorkerProcesses};
