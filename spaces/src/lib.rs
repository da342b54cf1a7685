//! State and action spaces ([`StateSpace`], [`ActionSpace`]) and flat row-major storage of
//! many states or actions ([`StateBatch`], [`ActionBatch`]): the types the environments, the
//! messages, the settings and the models all speak.

#![forbid(unsafe_code)]

mod batch;
mod spaces;

pub use batch::{ActionBatch, StateBatch};
pub use spaces::{ActionSpace, StateSpace};
