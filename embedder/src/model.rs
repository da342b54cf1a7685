//! Training the embedding model ([`EmbeddingModel`], whose structure and inference side are
//! the acting crate's): the running state statistics, T, and the losses by representation.
//! JSAE's `-log P(s'|s,a)` (cross-entropy per factor, or MSE) trains phi, g and T, and f's
//! reconstruction MSE on detached `g(a)` trains f (zero for discrete actions, whose f is a
//! nearest-neighbour lookup); the AE's and RA's losses are in [`baselines`].

use burn::tensor::{Int, Tensor, TensorData};
use jsae_agent::EmbeddingModel;
use jsae_nn as nn;
use jsae_settings::Representation;
use jsae_wire::{ActionBatch, StateBatch, StateSpace};

mod baselines;
mod transfer;
pub(crate) mod wide_softmax;

/// What training needs of the embedding model beyond acting.
pub trait EmbeddingTraining {
    /// Merges real-valued states into the normalisation statistics (no-op without them).
    fn update_state_stats(&mut self, states: &StateBatch);

    /// T: next-state logits (categorical) or prediction (real), `[batch, feature_len]`.
    fn predict_next(&self, x: Tensor<2>, e: Tensor<2>) -> Tensor<2>;

    /// The losses on a minibatch as (model loss, decoder loss), by representation.
    fn losses(
        &self,
        states: &StateBatch,
        actions: &ActionBatch,
        next_states: &StateBatch,
    ) -> (Tensor<1>, Tensor<1>);

    /// RA's inverse model: the embedding of the action that led from each s to s',
    /// `[batch, d]`.
    fn infer_action_embeddings(&self, states: &StateBatch, next: &StateBatch) -> Tensor<2>;

    /// The next-item loss alone: the mean cross-entropy of the item bought after each of
    /// `states` (`items[i]` after row `i`) under the next-item head (None without it).
    fn next_item_loss(&self, states: &StateBatch, items: &[u32]) -> Option<Tensor<1>>;

    /// The next-item loss against distributions: the mean cross-entropy of `probs` (`[rows,
    /// n]` row-major, each summing to 1) after each of `states` under the head (None
    /// without it).
    fn next_item_soft_loss(&self, states: &StateBatch, probs: &[f32]) -> Option<Tensor<1>>;

    /// Copies every part of `source` whose shape matches this model's (both of the same
    /// representation); returns the names of the parts copied.
    fn warm_start_from(&mut self, source: &EmbeddingModel) -> Vec<&'static str>;
}

impl EmbeddingTraining for EmbeddingModel {
    fn update_state_stats(&mut self, states: &StateBatch) {
        let device = self.device().clone();
        if let (Some(norm), StateBatch::Real { data, .. }) =
            (&mut self.net_mut().state_norm, states)
        {
            norm.update(data, &device);
        }
    }

    fn predict_next(&self, x: Tensor<2>, e: Tensor<2>) -> Tensor<2> {
        let input = Tensor::cat(vec![x, e], 1);
        let input = match &self.net().transition_in {
            Some(hidden) => hidden.forward(input).tanh(),
            None => input,
        };
        match &self.net().transition {
            Some(t) => t.forward(input),
            None => panic!("only JSAE's model has a transition model T"),
        }
    }

    fn losses(
        &self,
        states: &StateBatch,
        actions: &ActionBatch,
        next_states: &StateBatch,
    ) -> (Tensor<1>, Tensor<1>) {
        match self.representation() {
            Representation::AutoEncoder => {
                return baselines::autoencoder_losses(self, states, actions);
            }
            Representation::ActionRepresentation => {
                return baselines::inverse_losses(self, states, actions, next_states);
            }
            Representation::Jsae | Representation::Raw => {}
        }
        let x = self.embed_states(states);
        let e = self.embed_actions(actions);
        let out = self.predict_next(x.clone(), e.clone());
        let mut model_loss = state_loss(self, out, next_states);
        let coef = self.config().recommender.next_item_coef;
        if let (Some(logits), Some(items)) = (self.next_item_logits(x), last_factor(next_states)) {
            let target = index_column(self, items.into_iter().map(i64::from).collect());
            model_loss = model_loss + cross_entropy(logits, target) * coef as f32;
        }
        let decoder_loss = match (actions, self.decode(e.detach())) {
            (ActionBatch::Continuous { .. }, Some(pred)) => action_mse(self, pred, actions),
            _ => Tensor::zeros([1], self.device()),
        };
        (model_loss.reshape([1]), decoder_loss.reshape([1]))
    }

    fn infer_action_embeddings(&self, states: &StateBatch, next: &StateBatch) -> Tensor<2> {
        baselines::infer_action_embeddings(self, states, next)
    }

    fn next_item_loss(&self, states: &StateBatch, items: &[u32]) -> Option<Tensor<1>> {
        let logits = self.next_item_logits(self.embed_states(states))?;
        let target = index_column(self, items.iter().map(|&i| i64::from(i)).collect());
        Some(cross_entropy(logits, target))
    }

    fn next_item_soft_loss(&self, states: &StateBatch, probs: &[f32]) -> Option<Tensor<1>> {
        let logits = self.next_item_logits(self.embed_states(states))?;
        let [rows, n] = logits.dims();
        let q = nn::tensor2(probs.to_vec(), rows, n, self.device());
        Some(soft_cross_entropy(logits, q))
    }

    fn warm_start_from(&mut self, source: &EmbeddingModel) -> Vec<&'static str> {
        transfer::warm_start(self, source)
    }
}

/// The sum over a categorical state's factors of `nll(columns, targets)`: each factor's
/// columns of a layer's output and that factor's value in every state of `states` (None
/// for real states).
fn per_factor(
    model: &EmbeddingModel,
    states: &StateBatch,
    mut nll: impl FnMut(std::ops::Range<usize>, Vec<u32>) -> Tensor<1>,
) -> Option<Tensor<1>> {
    let (StateBatch::Categorical { factors, data }, StateSpace::Categorical { sizes }) =
        (states, model.state_space())
    else {
        return None;
    };
    let mut total: Option<Tensor<1>> = None;
    let mut start = 0;
    for (f, &size) in sizes.iter().enumerate() {
        let target = data.iter().skip(f).step_by(*factors).copied().collect();
        let term = nll(start..start + size, target);
        total = Some(match total {
            None => term,
            Some(t) => t + term,
        });
        start += size;
    }
    Some(total.unwrap_or_else(|| Tensor::zeros([1], model.device())))
}

/// How well `out` (logits per factor, or a prediction) predicts `target` states: the
/// summed cross-entropy per factor, or the MSE on normalised states.
fn state_loss(model: &EmbeddingModel, out: Tensor<2>, target: &StateBatch) -> Tensor<1> {
    let batch = out.dims()[0];
    let per_factor = per_factor(model, target, |columns, t| {
        let logits = out.clone().slice([0..batch, columns]);
        cross_entropy(
            logits,
            index_column(model, t.into_iter().map(i64::from).collect()),
        )
    });
    if let Some(loss) = per_factor {
        return loss;
    }
    match target {
        StateBatch::Real { dim, data } => {
            let target = model.normalised(nn::tensor2(
                data.clone(),
                data.len() / dim,
                *dim,
                model.device(),
            ));
            (out - target).square().mean()
        }
        _ => unreachable_state(),
    }
}

/// The last factor of every categorical state (the recommender's item bought last; None for
/// real states).
pub(crate) fn last_factor(states: &StateBatch) -> Option<Vec<u32>> {
    match states {
        StateBatch::Categorical { factors, data } if *factors > 0 => Some(
            data.iter()
                .skip(factors - 1)
                .step_by(*factors)
                .copied()
                .collect(),
        ),
        _ => None,
    }
}

/// MSE of predicted continuous actions against `actions`.
fn action_mse(model: &EmbeddingModel, pred: Tensor<2>, actions: &ActionBatch) -> Tensor<1> {
    match actions {
        ActionBatch::Continuous { dim, data } => {
            let target = nn::tensor2(data.clone(), data.len() / dim, *dim, model.device());
            (pred - target).square().mean()
        }
        ActionBatch::Discrete(_) => unreachable_action(),
    }
}

/// Integer targets as a `[batch, 1]` column.
fn index_column(model: &EmbeddingModel, target: Vec<i64>) -> Tensor<2, Int> {
    let n = target.len();
    Tensor::<2, Int>::from_data(TensorData::new(target, [n, 1]), model.device())
}

/// Mean cross-entropy of integer targets (`[batch, 1]`) under `logits` (`[batch, n]`),
/// as `logsumexp(logits) - logits[target]`: cheaper than materialising a log-softmax.
pub fn cross_entropy(logits: Tensor<2>, target: Tensor<2, Int>) -> Tensor<1> {
    let shift = logits.clone().max_dim(1).detach(); // [batch, 1]
    let lse = (logits.clone() - shift.clone()).exp().sum_dim(1).log() + shift;
    let picked = logits.gather(1, target);
    (lse - picked).mean()
}

/// Mean cross-entropy of target distributions `q` (`[batch, n]`, rows summing to 1) under
/// `logits`: `logsumexp(logits) - sum_i q_i logits_i`.
pub fn soft_cross_entropy(logits: Tensor<2>, q: Tensor<2>) -> Tensor<1> {
    let shift = logits.clone().max_dim(1).detach(); // [batch, 1]
    let lse = (logits.clone() - shift.clone()).exp().sum_dim(1).log() + shift;
    let expected = (logits * q).sum_dim(1);
    (lse - expected).mean()
}

// Batches are validated against the model's spaces before they reach it, so a mismatch is a
// programming error.
fn unreachable_state() -> ! {
    panic!("state batch kind does not match the embedding model's state space")
}

fn unreachable_action() -> ! {
    panic!("action batch kind does not match the embedding model's action space")
}
