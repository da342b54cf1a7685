//! The two baselines' heads and losses. Both keep JSAE's inference side, so actors, the
//! recommender and the plots use them unchanged: phi embeds states, the g-table's rows are
//! what nearest-neighbour f decodes to (discrete actions), and the decoder MLP is f for
//! continuous actions.
//!
//! - **AE**: two auto-encoders, one for states and one for actions, each two layers: the
//!   first is phi (or g), a linear layer and tanh, the second decodes it back to its input.
//!   Losses: the state's reconstruction (cross-entropy per factor, or MSE on normalised
//!   states), reported as the model loss, and the action's (cross-entropy over the actions,
//!   or MSE), reported as the decoder loss. Nothing ties either embedding to the dynamics.
//! - **RA** (Chandak et al. 2019): an inverse model `e = tanh(h(phi(s), phi(s')))` predicts
//!   the embedding of the action that led from s to s', and f maps it back: for discrete
//!   actions a softmax over `-scale * |e - z_a|^2` with one learned point `z_a = tanh(row)`
//!   per action (the g-table), so f's most likely action is the nearest `z_a`, which is the
//!   decode used when acting; for continuous actions the decoder MLP. One loss, `-log f(a|e)`
//!   (or the MSE of f(e) against a), trains h, phi, f and the scale together; it is reported
//!   as the model loss. The policy acts on raw states and outputs e.

use burn::module::Param;
use burn::tensor::{Device, Int, Tensor, TensorData};
use jsae_nn::MlpConfig;
use jsae_proto::{ActionBatch, ActionSpace, StateBatch, StateSpace};
use rand_chacha::ChaCha8Rng;

use super::{EmbeddingModel, EmbeddingNet, cross_entropy, uniform_linear, unreachable_action};
use crate::EmbeddingConfig;

/// RA's initial logit scale: a unit step in squared distance is 10 nats.
const INITIAL_SCALE: f32 = 10.0;

/// AE: each auto-encoder's second layer.
pub(super) fn autoencoder_heads(
    net: &mut EmbeddingNet,
    config: &EmbeddingConfig,
    states: &StateSpace,
    actions: &ActionSpace,
    rng: &mut ChaCha8Rng,
    device: &Device,
) {
    let (m, d) = (config.state_dim, config.action_dim);
    net.state_decoder = Some(uniform_linear(m, states.feature_len(), true, rng, device));
    if let ActionSpace::Discrete { n } = actions {
        net.action_decoder = Some(uniform_linear(d, *n, true, rng, device));
    }
}

/// RA: the inverse model on `concat(phi(s), phi(s'))`, and the logits' scale.
pub(super) fn inverse_heads(
    net: &mut EmbeddingNet,
    config: &EmbeddingConfig,
    actions: &ActionSpace,
    rng: &mut ChaCha8Rng,
    device: &Device,
) {
    let inverse = MlpConfig {
        input: 2 * config.state_dim,
        hidden: vec![config.decoder_hidden],
        output: config.action_dim,
        output_gain: 1.0,
    };
    net.inverse = Some(inverse.init(rng, device));
    if matches!(actions, ActionSpace::Discrete { .. }) {
        let log_scale = TensorData::new(vec![INITIAL_SCALE.ln()], [1]);
        net.inverse_log_scale = Some(Param::from_tensor(Tensor::from_data(log_scale, device)));
    }
}

impl EmbeddingModel {
    /// AE: (state reconstruction loss, action reconstruction loss).
    pub(super) fn autoencoder_losses(
        &self,
        states: &StateBatch,
        actions: &ActionBatch,
    ) -> (Tensor<1>, Tensor<1>) {
        let (Some(state_decoder), x) = (&self.net.state_decoder, self.embed_states(states)) else {
            panic!("an AE model has a state decoder")
        };
        let state_loss = self.state_loss(state_decoder.forward(x), states);
        let e = self.embed_actions(actions);
        let action_loss = match (actions, &self.net.action_decoder) {
            (ActionBatch::Discrete(a), Some(decoder)) => {
                cross_entropy(decoder.forward(e), self.action_column(a))
            }
            (ActionBatch::Continuous { .. }, _) => match self.decode(e) {
                Some(pred) => self.action_mse(pred, actions),
                None => unreachable_action(),
            },
            _ => unreachable_action(),
        };
        (state_loss.reshape([1]), action_loss.reshape([1]))
    }

    /// RA: `(-log f(a | h(s, s')) or MSE, 0)`.
    pub(super) fn inverse_losses(
        &self,
        states: &StateBatch,
        actions: &ActionBatch,
        next_states: &StateBatch,
    ) -> (Tensor<1>, Tensor<1>) {
        let e = self.infer_action_embeddings(states, next_states);
        let loss = match (actions, self.action_logits(e.clone())) {
            (ActionBatch::Discrete(a), Some(logits)) => {
                cross_entropy(logits, self.action_column(a))
            }
            (ActionBatch::Continuous { .. }, _) => match self.decode(e) {
                Some(pred) => self.action_mse(pred, actions),
                None => unreachable_action(),
            },
            _ => unreachable_action(),
        };
        (loss.reshape([1]), Tensor::zeros([1], &self.device))
    }

    /// RA's inverse model: the embedding of the action that led from each s to s',
    /// `[batch, d]`.
    pub fn infer_action_embeddings(&self, states: &StateBatch, next: &StateBatch) -> Tensor<2> {
        let Some(inverse) = &self.net.inverse else {
            panic!("only an RA model has an inverse model")
        };
        let x = Tensor::cat(vec![self.embed_states(states), self.embed_states(next)], 1);
        inverse.forward(x).tanh()
    }

    /// RA's f over discrete actions: `-scale * |e - z_a|^2` for every action, `[batch, n]`
    /// (None for continuous actions).
    pub fn action_logits(&self, e: Tensor<2>) -> Option<Tensor<2>> {
        let (z, log_scale) = (self.action_table()?, self.net.inverse_log_scale.as_ref()?);
        let e_sq = e.clone().square().sum_dim(1); // [batch, 1]
        let z_sq = z.clone().square().sum_dim(1).transpose(); // [1, n]
        let dist = e_sq + z_sq - e.matmul(z.transpose()) * 2.0;
        let scale = log_scale.val().exp().reshape([1, 1]);
        Some(dist * scale.neg())
    }

    fn action_column(&self, actions: &[u32]) -> Tensor<2, Int> {
        self.index_column(actions.iter().map(|&a| i64::from(a)).collect())
    }
}
