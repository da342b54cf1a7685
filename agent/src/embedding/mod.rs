//! The embedding an agent acts through: the model's structure and inference side (phi, g's
//! table, the decoder f) in [`model`] (its first values in `init`), and a published snapshot loaded for acting
//! ([`Embedding`]: phi for states, f by nearest neighbour over the g-table or the decoder).

mod init;
mod model;
mod snapshot;

pub use init::uniform_linear;
pub use model::{EmbeddingModel, EmbeddingNet};
pub use snapshot::Embedding;
