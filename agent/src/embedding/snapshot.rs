//! A published embedding loaded for acting: phi for states, and f (nearest neighbour over
//! the g-table, or the decoder MLP) for action embeddings.

use burn::tensor::Device;
use jsae_settings::{EmbeddingConfig, Representation};
use jsae_wire::{ActionBatch, ActionSpace, EmbeddingSnapshot, StateBatch, StateSpace};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

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
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let mut model =
            EmbeddingModel::new(config, representation, states, actions, &mut rng, device);
        model.load_bytes(&snapshot.bytes)?;
        let nearest = model
            .action_table()
            .map(|t| {
                ActionIndex::build(
                    &nn::to_vec(t),
                    config.action_dim,
                    config.approx_nearest_from,
                    &ApproxSettings::default(),
                )
            })
            .transpose()
            .map_err(|e| RecordError(format!("f's action index: {e}")))?;
        Ok(Self {
            model,
            nearest,
            version: snapshot.version,
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
