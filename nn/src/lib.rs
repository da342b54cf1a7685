//! Model building blocks shared by the embedder and the learner: the device choice (`device`),
//! seeded initialisation (`init`), a tanh MLP (`mlp`), input normalisation (`obs_norm`), host
//! <-> tensor conversion and weight records as bytes (`io`), global gradient-norm clipping
//! (`clip`), a check that weights are finite (`finite`), and training on the host without a
//! tensor graph (`host`: MLP forward/backward, Adam, fast exp/tanh). Every model of the project
//! is a burn module built from these. The crate also sets the process's heap allocator
//! (`allocator`: mimalloc), as every binary links it.

// `unsafe` is denied everywhere but in `host::dense`, the one call into a raw-pointer kernel,
// and in `allocator::release_freed`, a call into mimalloc that takes no pointers
#![deny(unsafe_code)]

mod allocator;
mod clip;
mod device;
mod finite;
pub mod host;
mod init;
mod io;
mod mlp;
mod obs_norm;

pub use allocator::release_freed;
pub use clip::clip_global_grad_norm;
pub use device::{BurnDevice, DeviceKind};
pub use finite::non_finite_values;
pub use host::{
    AdamMoments, HostAdam, HostInput, HostMlp, InputWeights, MlpWork, OutputBias, PairCross,
    SparseRows, clip_scale, global_norm, pair_bucket,
};
pub use init::{linear_from_host, orthogonal, seeded_linear};
pub use io::{RecordError, from_bytes, from_owned_bytes, into_bytes, tensor1, tensor2, to_vec};
pub use mlp::{Mlp, MlpConfig, replaced};
pub use obs_norm::ObsNorm;
