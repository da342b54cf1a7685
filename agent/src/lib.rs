//! The acting side of a trained agent, which the actor, the Recommender and the trainers all
//! depend on: the policy's acting half ([`policy`]: the head's outputs, sampling, the mode)
//! with the count prior it may be given ([`prior`]), the embedding it acts through
//! ([`embedding`]: phi, f, the nearest action), greedy decoding ([`greedy`]), and the
//! [`Weights`] in use, swapped in whole as snapshots arrive. Nothing here trains: PPO's
//! losses are the learner's, the embedding's losses the embedder's.

#![forbid(unsafe_code)]

pub mod embedding;
pub mod greedy;
pub mod policy;
pub mod prior;
mod weights;

pub use embedding::{Embedding, EmbeddingModel, EmbeddingNet};
pub use policy::{Policy, PolicyHead, PolicyNet, PolicyPrior, policy_shape};
pub use prior::CountPrior;
pub use weights::{SwapError, Weights};
