//! The embedding an agent acts through: the model's structure and inference side (phi, g's
//! table, the decoder f) in [`model`], and a published snapshot loaded for acting
//! ([`Embedding`]: phi for states, f by nearest neighbour over the g-table or the decoder).

mod model;
mod snapshot;

pub use model::{EmbeddingModel, EmbeddingNet, uniform_linear};
pub use snapshot::Embedding;
