//! The embedding model: phi (states -> X), g (actions -> E), T (X x E -> S) and, for
//! continuous actions, the decoder f (E -> A). The AE and RA baselines share its inference
//! side (phi, the g-table or f) and differ in their training heads and losses
//! ([`baselines`]); [`Representation`] picks which.
//!
//! As in the public reference code: phi and g are one linear layer without bias followed by
//! tanh (for categorical inputs a table: a linear layer on one-hots), T is one linear layer.
//! For factored categorical states phi sums one table row per factor (a linear layer on the
//! concatenated one-hots) and T predicts one categorical per factor.

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::{Device, Int, Tensor, TensorData};
use jsae_wire::{ActionBatch, ActionSpace, StateBatch, StateSpace};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::EmbeddingConfig;
use jsae_nn::{self as nn, Mlp, MlpConfig, ObsNorm};
use jsae_settings::Representation;

mod baselines;
mod transfer;
mod wide_softmax;

/// The trainable parts. Exactly one of each `*_table` / `*_linear` pair is present.
#[derive(Module, Debug)]
pub struct EmbeddingNet {
    /// phi for categorical states: `[sum of factor sizes, m]`.
    phi_table: Option<Param<Tensor<2>>>,
    /// phi for real states: `[dim -> m]`, no bias.
    phi_linear: Option<Linear>,
    /// g for discrete actions: `[n, d]`.
    g_table: Option<Param<Tensor<2>>>,
    /// g for continuous actions: `[dim -> d]`, no bias.
    g_linear: Option<Linear>,
    /// T's hidden layer (tanh), when `transition_hidden > 0` (JSAE).
    transition_in: Option<Linear>,
    /// T: `[m + d (or the hidden width) -> logits over next states | next state]` (JSAE).
    transition: Option<Linear>,
    /// f for continuous actions: `E -> A` (one hidden layer; the AE's is one linear layer).
    decoder: Option<Mlp>,
    /// AE: the state auto-encoder's second layer, `X -> logits over states | state`.
    state_decoder: Option<Linear>,
    /// AE, discrete actions: the action auto-encoder's second layer, `E -> logits over A`.
    action_decoder: Option<Linear>,
    /// RA: the inverse model after phi, `concat(phi(s), phi(s')) -> E` (tanh on the output).
    inverse: Option<Mlp>,
    /// RA, discrete actions: log of the scale of f's logits `-scale * |e - z_a|^2`.
    inverse_log_scale: Option<Param<Tensor<1>>>,
    /// Running statistics of real-valued states (`normalize_states`): phi sees normalised
    /// states and T predicts normalised next states.
    state_norm: Option<ObsNorm>,
}

/// The embedding model of one environment: the network and the spaces it was built for.
#[derive(Debug, Clone)]
pub struct EmbeddingModel {
    net: EmbeddingNet,
    representation: Representation,
    states: StateSpace,
    actions: ActionSpace,
    offsets: Vec<u32>,
    config: EmbeddingConfig,
    device: Device,
}

fn uniform_table(
    rows: usize,
    cols: usize,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> Param<Tensor<2>> {
    // a linear layer on one-hots of width `rows`: U(-1/sqrt(rows), 1/sqrt(rows))
    let k = 1.0 / (rows as f32).sqrt();
    let values: Vec<f32> = (0..rows * cols).map(|_| rng.random_range(-k..k)).collect();
    Param::from_tensor(nn::tensor2(values, rows, cols, device))
}

fn uniform_linear(
    d_in: usize,
    d_out: usize,
    bias: bool,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> Linear {
    let k = 1.0 / (d_in as f32).sqrt();
    let w: Vec<f32> = (0..d_in * d_out).map(|_| rng.random_range(-k..k)).collect();
    let b = bias.then(|| (0..d_out).map(|_| rng.random_range(-k..k)).collect());
    nn::linear_from_host(w, b, d_in, d_out, device)
}

impl EmbeddingModel {
    /// A freshly initialised model of `representation` for the given spaces (JSAE's
    /// parameters are drawn in the same order as before the baselines existed, so a seed
    /// gives the same JSAE model; the baselines draw their own heads after phi and g).
    pub fn new(
        config: &EmbeddingConfig,
        representation: Representation,
        states: &StateSpace,
        actions: &ActionSpace,
        rng: &mut ChaCha8Rng,
        device: &Device,
    ) -> Self {
        let (m, d) = (config.state_dim, config.action_dim);
        let ra = representation == Representation::ActionRepresentation;
        let (phi_table, phi_linear) = match states {
            StateSpace::Categorical { sizes } => (
                Some(uniform_table(sizes.iter().sum(), m, rng, device)),
                None,
            ),
            StateSpace::Real { dim } => (None, Some(uniform_linear(*dim, m, false, rng, device))),
        };
        let (g_table, g_linear, decoder) = match actions {
            ActionSpace::Discrete { n } => (Some(uniform_table(*n, d, rng, device)), None, None),
            ActionSpace::Continuous { dim, .. } => {
                // RA has no action encoder: its embeddings come from the inverse model.
                let g = (!ra).then(|| uniform_linear(*dim, d, false, rng, device));
                let hidden = match representation {
                    Representation::AutoEncoder => vec![],
                    _ => vec![config.decoder_hidden],
                };
                let decoder = MlpConfig {
                    input: d,
                    hidden,
                    output: *dim,
                    output_gain: 1.0,
                    skip: false,
                    zero_inputs: 0,
                };
                (None, g, Some(decoder.init(rng, device)))
            }
        };
        let mut net = EmbeddingNet {
            phi_table,
            phi_linear,
            g_table,
            g_linear,
            transition_in: None,
            transition: None,
            decoder,
            state_decoder: None,
            action_decoder: None,
            inverse: None,
            inverse_log_scale: None,
            state_norm: match states {
                StateSpace::Real { dim } if config.normalize_states => {
                    Some(ObsNorm::new(*dim, device))
                }
                _ => None,
            },
        };
        match representation {
            Representation::Jsae | Representation::Raw => {
                let t_in = match config.transition_hidden {
                    0 => m + d,
                    h => {
                        net.transition_in = Some(uniform_linear(m + d, h, true, rng, device));
                        h
                    }
                };
                net.transition = Some(uniform_linear(
                    t_in,
                    states.feature_len(),
                    true,
                    rng,
                    device,
                ));
            }
            Representation::AutoEncoder => {
                baselines::autoencoder_heads(&mut net, config, states, actions, rng, device)
            }
            Representation::ActionRepresentation => {
                baselines::inverse_heads(&mut net, config, actions, rng, device)
            }
        }
        let offsets = match states {
            StateSpace::Categorical { sizes } => sizes
                .iter()
                .scan(0u32, |acc, &s| {
                    let o = *acc;
                    *acc += s as u32;
                    Some(o)
                })
                .collect(),
            StateSpace::Real { .. } => Vec::new(),
        };
        Self {
            net,
            representation,
            states: states.clone(),
            actions: actions.clone(),
            offsets,
            config: config.clone(),
            device: device.clone(),
        }
    }

    /// Which representation it is (which heads it has, which losses train it).
    pub fn representation(&self) -> Representation {
        self.representation
    }

    /// The settings it was built with.
    pub fn config(&self) -> &EmbeddingConfig {
        &self.config
    }

    /// The state space.
    pub fn state_space(&self) -> &StateSpace {
        &self.states
    }

    /// The action space.
    pub fn action_space(&self) -> &ActionSpace {
        &self.actions
    }

    /// The device its tensors live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// The network (for the optimiser).
    pub fn net(&self) -> &EmbeddingNet {
        &self.net
    }

    /// Replaces the network (after an optimiser step).
    pub fn set_net(&mut self, net: EmbeddingNet) {
        self.net = net;
    }

    /// A copy for inference on `device` (no autodiff).
    pub fn for_inference(&self, device: &Device) -> Self {
        Self {
            net: self.net.valid().to_device(device),
            device: device.clone(),
            ..self.clone()
        }
    }

    /// The weights as bytes (what a snapshot carries).
    pub fn to_bytes(&self) -> Result<Vec<u8>, nn::RecordError> {
        nn::into_bytes(&self.net)
    }

    /// Loads weights from snapshot bytes (structure checked).
    pub fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), nn::RecordError> {
        self.net = nn::from_bytes(self.net.clone(), bytes)?;
        Ok(())
    }

    fn state_tensor(&self, states: &StateBatch) -> StateInput {
        match states {
            StateBatch::Categorical { factors, data } => {
                let idx: Vec<i64> = data
                    .iter()
                    .enumerate()
                    .map(|(i, &v)| i64::from(v + self.offsets[i % factors]))
                    .collect();
                let n = idx.len();
                StateInput::Indices(
                    Tensor::from_data(TensorData::new(idx, [n]), &self.device),
                    *factors,
                )
            }
            StateBatch::Real { dim, data } => StateInput::Values(self.normalised(nn::tensor2(
                data.clone(),
                data.len() / dim,
                *dim,
                &self.device,
            ))),
        }
    }

    fn normalised(&self, states: Tensor<2>) -> Tensor<2> {
        match &self.net.state_norm {
            Some(norm) => norm.apply(states),
            None => states,
        }
    }

    /// Merges real-valued states into the normalisation statistics (no-op without them).
    pub fn update_state_stats(&mut self, states: &StateBatch) {
        let device = self.device.clone();
        if let (Some(norm), StateBatch::Real { data, .. }) = (&mut self.net.state_norm, states) {
            norm.update(data, &device);
        }
    }

    /// phi: `[batch] states -> [batch, m]`.
    pub fn embed_states(&self, states: &StateBatch) -> Tensor<2> {
        let input = self.state_tensor(states);
        self.phi(input)
    }

    fn phi(&self, input: StateInput) -> Tensor<2> {
        let pre = match (input, &self.net.phi_table, &self.net.phi_linear) {
            (StateInput::Indices(idx, factors), Some(table), _) => {
                let rows = table.val().select(0, idx); // [batch * factors, m]
                let [n, m] = rows.dims();
                if factors == 1 {
                    rows
                } else {
                    rows.reshape([n / factors, factors, m])
                        .sum_dim(1)
                        .reshape([n / factors, m])
                }
            }
            (StateInput::Values(v), _, Some(linear)) => linear.forward(v),
            _ => unreachable_state(),
        };
        pre.tanh()
    }

    /// g: `[batch] actions -> [batch, d]`.
    pub fn embed_actions(&self, actions: &ActionBatch) -> Tensor<2> {
        let pre = match (actions, &self.net.g_table, &self.net.g_linear) {
            (ActionBatch::Discrete(a), Some(table), _) => {
                let idx: Vec<i64> = a.iter().map(|&v| i64::from(v)).collect();
                let n = idx.len();
                table.val().select(
                    0,
                    Tensor::<1, Int>::from_data(TensorData::new(idx, [n]), &self.device),
                )
            }
            (ActionBatch::Continuous { dim, data }, _, Some(linear)) => linear.forward(
                nn::tensor2(data.clone(), data.len() / dim, *dim, &self.device),
            ),
            _ => unreachable_action(),
        };
        pre.tanh()
    }

    /// Every discrete action's embedding `g(a)`, `[n, d]` (None for continuous actions).
    pub fn action_table(&self) -> Option<Tensor<2>> {
        self.net.g_table.as_ref().map(|t| t.val().tanh())
    }

    /// T: next-state logits (categorical) or prediction (real), `[batch, feature_len]`.
    pub fn predict_next(&self, x: Tensor<2>, e: Tensor<2>) -> Tensor<2> {
        let input = Tensor::cat(vec![x, e], 1);
        let input = match &self.net.transition_in {
            Some(hidden) => hidden.forward(input).tanh(),
            None => input,
        };
        match &self.net.transition {
            Some(t) => t.forward(input),
            None => panic!("only JSAE's model has a transition model T"),
        }
    }

    /// f for continuous actions: `[batch, d] -> [batch, action dim]` (None for discrete).
    pub fn decode(&self, e: Tensor<2>) -> Option<Tensor<2>> {
        self.net.decoder.as_ref().map(|f| f.forward(e))
    }

    /// The losses on a minibatch as (model loss, decoder loss), by representation: JSAE's
    /// `-log P(s'|s,a)` (cross-entropy per factor, or MSE) for phi, g and T and f's
    /// reconstruction MSE on detached `g(a)` (zero for discrete actions, whose f is a
    /// nearest-neighbour lookup); the AE's and RA's are documented in `model/baselines.rs`.
    pub fn losses(
        &self,
        states: &StateBatch,
        actions: &ActionBatch,
        next_states: &StateBatch,
    ) -> (Tensor<1>, Tensor<1>) {
        match self.representation {
            Representation::AutoEncoder => return self.autoencoder_losses(states, actions),
            Representation::ActionRepresentation => {
                return self.inverse_losses(states, actions, next_states);
            }
            Representation::Jsae | Representation::Raw => {}
        }
        let x = self.embed_states(states);
        let e = self.embed_actions(actions);
        let out = self.predict_next(x, e.clone());
        let model_loss = self.state_loss(out, next_states);
        let decoder_loss = match (actions, self.decode(e.detach())) {
            (ActionBatch::Continuous { .. }, Some(pred)) => self.action_mse(pred, actions),
            _ => Tensor::zeros([1], &self.device),
        };
        (model_loss.reshape([1]), decoder_loss.reshape([1]))
    }

    /// The sum over a categorical state's factors of `nll(columns, targets)`: each factor's
    /// columns of a layer's output and that factor's value in every state of `states` (None
    /// for real states).
    pub(super) fn per_factor(
        &self,
        states: &StateBatch,
        mut nll: impl FnMut(std::ops::Range<usize>, Vec<u32>) -> Tensor<1>,
    ) -> Option<Tensor<1>> {
        let (StateBatch::Categorical { factors, data }, StateSpace::Categorical { sizes }) =
            (states, &self.states)
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
        Some(total.unwrap_or_else(|| Tensor::zeros([1], &self.device)))
    }

    /// How well `out` (logits per factor, or a prediction) predicts `target` states: the
    /// summed cross-entropy per factor, or the MSE on normalised states.
    fn state_loss(&self, out: Tensor<2>, target: &StateBatch) -> Tensor<1> {
        let batch = out.dims()[0];
        let per_factor = self.per_factor(target, |columns, t| {
            let logits = out.clone().slice([0..batch, columns]);
            cross_entropy(
                logits,
                self.index_column(t.into_iter().map(i64::from).collect()),
            )
        });
        if let Some(loss) = per_factor {
            return loss;
        }
        match target {
            StateBatch::Real { dim, data } => {
                let target = self.normalised(nn::tensor2(
                    data.clone(),
                    data.len() / dim,
                    *dim,
                    &self.device,
                ));
                (out - target).square().mean()
            }
            _ => unreachable_state(),
        }
    }

    /// MSE of predicted continuous actions against `actions`.
    fn action_mse(&self, pred: Tensor<2>, actions: &ActionBatch) -> Tensor<1> {
        match actions {
            ActionBatch::Continuous { dim, data } => {
                let target = nn::tensor2(data.clone(), data.len() / dim, *dim, &self.device);
                (pred - target).square().mean()
            }
            ActionBatch::Discrete(_) => unreachable_action(),
        }
    }

    /// Integer targets as a `[batch, 1]` column.
    fn index_column(&self, target: Vec<i64>) -> Tensor<2, Int> {
        let n = target.len();
        Tensor::<2, Int>::from_data(TensorData::new(target, [n, 1]), &self.device)
    }
}

/// Mean cross-entropy of integer targets (`[batch, 1]`) under `logits` (`[batch, n]`),
/// as `logsumexp(logits) - logits[target]`: cheaper than materialising a log-softmax.
pub fn cross_entropy(logits: Tensor<2>, target: Tensor<2, Int>) -> Tensor<1> {
    let shift = logits.clone().max_dim(1).detach(); // [batch, 1]
    let lse = (logits.clone() - shift.clone()).exp().sum_dim(1).log() + shift;
    let picked = logits.gather(1, target);
    (lse - picked).mean()
}

enum StateInput {
    Indices(Tensor<1, Int>, usize),
    Values(Tensor<2>),
}

// The constructors pair each table with its input kind; batches are validated against the
// same spaces before they reach the model, so a mismatch is a programming error.
fn unreachable_state() -> ! {
    panic!("state batch kind does not match the embedding model's state space")
}

fn unreachable_action() -> ! {
    panic!("action batch kind does not match the embedding model's action space")
}
