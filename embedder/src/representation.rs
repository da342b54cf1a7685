//! The seam between the embedder's trainer and the model it trains. The trainer (replay
//! buffer, pre-training, continuous updates, versions, checkpoints) is the same for every
//! representation; what differs (the networks, their losses, their weights' bytes) sits
//! behind [`RepresentationModel`]. [`EmbeddingModel`] implements it for JSAE's phi/g/T/f and,
//! with other heads and losses, for the AE and RA baselines. Which questions a
//! representation answers for the rest of the system (does it embed states? does f decode
//! actions?) is `jsae_settings::Representation`.

use burn::optim::{GradientsParams, ModuleOptimizer};
use jsae_nn::RecordError;
use jsae_wire::{ActionSpace, StateBatch, StateSpace};

use jsae_agent::EmbeddingModel;

use crate::EmbeddingTraining;
use crate::replay::Minibatch;

/// A model the embedder trains from transitions and publishes as snapshots.
pub trait RepresentationModel: std::fmt::Debug + Send {
    /// The state space it takes.
    fn state_space(&self) -> &StateSpace;
    /// The action space it takes.
    fn action_space(&self) -> &ActionSpace;
    /// Updates input statistics (state normalisation) with new states.
    fn observe_states(&mut self, states: &StateBatch);
    /// One optimiser step on a minibatch at learning rate `lr`; returns (model loss, decoder
    /// loss) before the step (JSAE: `-log P(s'|s,a)` and f's; AE: the state and the action
    /// reconstruction; RA: `-log f(a | e(s, s'))` and 0).
    fn train_step(&mut self, optim: &mut ModuleOptimizer, mb: &Minibatch, lr: f64) -> (f32, f32);
    /// One optimiser step on the next-item loss alone (logged purchases: `items[i]` bought
    /// after row `i` of `states`); the loss before the step, None for a model without the
    /// next-item head (nothing trained).
    fn train_next_item_step(
        &mut self,
        _optim: &mut ModuleOptimizer,
        _states: &StateBatch,
        _items: &[u32],
        _lr: f64,
    ) -> Option<f32> {
        None
    }
    /// (model loss, decoder loss) on a minibatch, without training.
    fn evaluate(&self, mb: &Minibatch) -> (f32, f32);
    /// The weights, as inference-side snapshot bytes.
    fn snapshot_bytes(&self) -> Result<Vec<u8>, RecordError>;
    /// Loads weights from snapshot bytes.
    fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), RecordError>;
    /// Every discrete action's embedding, `[n, d]` row-major, and `d` (None for continuous
    /// actions).
    fn action_embeddings(&self) -> Option<(Vec<f32>, usize)>;
}

impl RepresentationModel for EmbeddingModel {
    fn state_space(&self) -> &StateSpace {
        EmbeddingModel::state_space(self)
    }

    fn action_space(&self) -> &ActionSpace {
        EmbeddingModel::action_space(self)
    }

    fn observe_states(&mut self, states: &StateBatch) {
        self.update_state_stats(states);
    }

    /// Every representation's losses (`EmbeddingModel::losses`), summed, one joint step.
    fn train_step(&mut self, optim: &mut ModuleOptimizer, mb: &Minibatch, lr: f64) -> (f32, f32) {
        let (model_loss, decoder_loss) = self.losses(&mb.states, &mb.actions, &mb.next_states);
        let total = model_loss.clone() + decoder_loss.clone();
        let grads = GradientsParams::from_grads(total.backward(), self.net());
        let net = optim.step(lr, self.net().clone(), grads);
        self.set_net(net);
        (
            model_loss.into_scalar::<f32>(),
            decoder_loss.into_scalar::<f32>(),
        )
    }

    fn train_next_item_step(
        &mut self,
        optim: &mut ModuleOptimizer,
        states: &StateBatch,
        items: &[u32],
        lr: f64,
    ) -> Option<f32> {
        let loss = self.next_item_loss(states, items)?;
        let grads = GradientsParams::from_grads(loss.backward(), self.net());
        let net = optim.step(lr, self.net().clone(), grads);
        self.set_net(net);
        Some(loss.into_scalar::<f32>())
    }

    fn evaluate(&self, mb: &Minibatch) -> (f32, f32) {
        let valid = self.for_inference(&self.device().clone().inner());
        let (a, b) = valid.losses(&mb.states, &mb.actions, &mb.next_states);
        (a.into_scalar::<f32>(), b.into_scalar::<f32>())
    }

    fn snapshot_bytes(&self) -> Result<Vec<u8>, RecordError> {
        self.for_inference(&self.device().clone().inner())
            .to_bytes()
    }

    fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), RecordError> {
        EmbeddingModel::load_bytes(self, bytes)
    }

    fn action_embeddings(&self) -> Option<(Vec<f32>, usize)> {
        let table = self.action_table()?;
        Some((jsae_nn::to_vec(table), self.config().action_dim))
    }
}
