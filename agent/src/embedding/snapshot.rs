//! A published embedding loaded for acting: phi for states, and f (nearest neighbour over
//! the g-table, or the decoder MLP) for action embeddings.

use burn::tensor::Device;
use jsae_settings::{EmbeddingConfig, Representation};
use jsae_wire::{ActionBatch, ActionSpace, EmbeddingSnapshot, StateBatch, StateSpace};

use super::EmbeddingModel;
use jsae_action_index::{ActionIndex, ApproxSettings};
use jsae_nn::{self as nn, RecordError};

/// The inference side of the embedding model, swapped in whole when a snapshot arrives.
#[derive(Debug, Clone)]
pub struct Embedding {
    model: EmbeddingModel,
    nearest: Option<ActionIndex>,
    version: u64,
}

impl Embedding {
    /// Builds the model structure of `representation` from a snapshot's bytes.
    pub fn from_snapshot(
        config: &EmbeddingConfig,
        representation: Representation,
        states: &StateSpace,
        actions: &ActionSpace,
        snapshot: &EmbeddingSnapshot,
        device: &Device,
    ) -> Result<Self, RecordError> {
        let mut model = EmbeddingModel::template(config, representation, states, actions, device);
        model.load_bytes(&snapshot.bytes)?;
        Self::indexed(model, config, snapshot.version, 0)
    }

    /// [`Self::from_snapshot`] from a snapshot the caller gives up: its bytes are read without
    /// a copy and dropped before f's index is built (at a million items each copy is 768 MB);
    /// an approximate index is built by `index_threads` threads (0: every core).
    pub fn from_owned_snapshot(
        config: &EmbeddingConfig,
        representation: Representation,
        states: &StateSpace,
        actions: &ActionSpace,
        (snapshot, index_threads): (EmbeddingSnapshot, usize),
        device: &Device,
    ) -> Result<Self, RecordError> {
        let mut model = EmbeddingModel::template(config, representation, states, actions, device);
        model.load_owned_bytes(snapshot.bytes)?;
        // the bytes are dropped: back to the kernel before the index's memory comes on top
        nn::release_freed();
        let embedding = Self::indexed(model, config, snapshot.version, index_threads)?;
        // and g's copy the index was built from
        nn::release_freed();
        Ok(embedding)
    }

    /// The loaded `model` with f's index over its action table.
    fn indexed(
        model: EmbeddingModel,
        config: &EmbeddingConfig,
        version: u64,
        threads: usize,
    ) -> Result<Self, RecordError> {
        let nearest = model
            .action_table()
            .map(|t| {
                ActionIndex::build(
                    &nn::to_vec(t),
                    config.action_dim,
                    config.approx_nearest_from,
                    &ApproxSettings {
                        threads,
                        ..ApproxSettings::default()
                    },
                )
            })
            .transpose()
            .map_err(|e| RecordError(format!("f's action index: {e}")))?;
        Ok(Self {
            model,
            nearest,
            version,
        })
    }

    /// The snapshot version.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Width of the policy's input ([`Self::embed_states`]).
    pub fn state_dim(&self) -> usize {
        self.model.config().policy_input_dim()
    }

    /// Width of an action embedding.
    pub fn action_dim(&self) -> usize {
        self.model.config().action_dim
    }

    /// The model.
    pub fn model(&self) -> &EmbeddingModel {
        &self.model
    }

    /// The policy's input for every state (phi, and the next-item head's pre-activation
    /// where the model has one: [`EmbeddingModel::policy_input`]), `[batch, state_dim]`
    /// row-major, in `out` (cleared first).
    pub fn embed_states(&self, states: &StateBatch, out: &mut Vec<f32>) {
        out.clear();
        if !states.is_empty() {
            out.extend(nn::to_vec(self.model.policy_input(states)));
        }
    }

    /// g of every discrete action, `[n, d]` row-major (None for continuous actions).
    pub fn action_table(&self) -> Option<Vec<f32>> {
        self.model.action_table().map(nn::to_vec)
    }

    /// f: maps each action embedding (`[batch, d]`) to an action, appended to `out`.
    pub fn decode(&mut self, e: &[f32], out: &mut ActionBatch) {
        match (out, &mut self.nearest) {
            (ActionBatch::Discrete(actions), Some(nearest)) => nearest.nearest_batch(e, actions),
            (ActionBatch::Continuous { data, .. }, None) => {
                let d = self.model.config().action_dim;
                let t = nn::tensor2(e.to_vec(), e.len() / d, d, self.model.device());
                if let Some(a) = self.model.decode(t) {
                    data.extend(nn::to_vec(a));
                }
            }
            _ => {}
        }
    }

    /// The nearest-neighbour index over actions (discrete actions only).
    pub fn nearest(&self) -> Option<&ActionIndex> {
        self.nearest.as_ref()
    }
}
