//! Messages exchanged by the JSAE-RL components, and their validation.
//!
//! The actor, the embedder and the learner own their state and talk only through the
//! messages defined here: [`TransitionBatch`] (actor -> embedder), [`RolloutFragment`]
//! (actor -> learner), [`EmbeddingSnapshot`] and [`PolicySnapshot`] (services -> actors),
//! and [`EvalReport`] (actor -> learner at the end of a run). In one-process mode they travel
//! as plain values; the gRPC transport wraps the same types (`proto/jsae.proto`).
//!
//! Layout: `spaces` (state and action spaces), `batch` (flat state and action storage),
//! `messages` (the messages), `validate` (checks every receiver runs on input), `settings`
//! (every setting of a run, read the same way by every service), `wire` (the generated gRPC
//! code, conversions, snapshot chunking, size limits), `net` (serving with TCP_NODELAY,
//! health, reflection, shutdown signals, a service's `main`, backoff), `accept` (only
//! connections that speak in time reach a server, and how many may be open), `streams`
//! (open streams and calls capped in all and per connection), `security` (the
//! token and TLS), `status` (the one mapping of refusals to gRPC codes), `run_dir` (the run
//! directory's file names; the latest checkpoint's layout and checksum in
//! `checkpoint_file`), `random_id` (identifiers nobody can guess) and `client` (following
//! snapshot streams with reconnection).

#![forbid(unsafe_code)]

pub mod accept;
mod batch;
mod checkpoint_file;
pub mod client;
mod codec;
mod health;
pub mod logging;
mod messages;
pub mod net;
mod random_id;
pub mod run_dir;
pub mod security;
pub mod settings;
mod spaces;
mod status;
pub mod streams;
mod validate;
pub mod wire;

pub use batch::{ActionBatch, StateBatch};
pub use messages::{
    EmbeddingSnapshot, EpisodeStat, EvalReport, PolicySnapshot, RolloutFragment, TransitionBatch,
};
pub use random_id::random_id;
pub use spaces::{ActionSpace, StateSpace};
pub use status::{RpcError, TooLargeIsExhausted, receive_error};
pub use validate::{FragmentBounds, MAX_ABS_POLICY_INPUT, ValidationError, check_episodes};
