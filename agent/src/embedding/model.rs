//! The embedding model: phi (states -> X), g (actions -> E), T (X x E -> S) and, for
//! continuous actions, the decoder f (E -> A). The AE and RA baselines share its inference
//! side (phi, the g-table or f) and differ in their training heads; [`Representation`] picks
//! which. This is the model's structure (every part, so that a snapshot's bytes load whole)
//! and its inference side; the losses that train it are the embedder's
//! (`jsae_embedder::EmbeddingTraining`).
//!
//! As in the public reference code: phi and g are one linear layer without bias followed by
//! tanh (for categorical inputs a table: a linear layer on one-hots), T is one linear layer.
//! For factored categorical states phi sums one table row per factor (a linear layer on the
//! concatenated one-hots) and T predicts one categorical per factor.

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::{Device, Int, Tensor, TensorData};
use jsae_wire::{ActionBatch, ActionSpace, StateBatch, StateSpace};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use jsae_nn::{self as nn, Mlp, MlpConfig, ObsNorm};
use jsae_settings::{EmbeddingConfig, Representation};

use super::init::{Tables, action_parts, uniform_linear, uniform_table};

/// The trainable parts. Exactly one of each `*_table` / `*_linear` pair is present.
#[derive(Module, Debug)]
pub struct EmbeddingNet {
    /// phi for categorical states: `[sum of factor sizes, m]`.
    pub phi_table: Option<Param<Tensor<2>>>,
    /// phi's pair rows (`embedding.recommender.pair_buckets`): `[buckets, m]`, one added per
    /// state, picked by a hash of its last two factors' columns; they start at zero.
    pub phi_pair: Option<Param<Tensor<2>>>,
    /// phi for real states: `[dim -> m]`, no bias.
    pub phi_linear: Option<Linear>,
    /// g for discrete actions: `[n, d]`.
    pub g_table: Option<Param<Tensor<2>>>,
    /// g for continuous actions: `[dim -> d]`, no bias.
    pub g_linear: Option<Linear>,
    /// T's hidden layer (tanh), when `transition_hidden > 0` (JSAE).
    pub transition_in: Option<Linear>,
    /// T: `[m + d (or the hidden width) -> logits over next states | next state]` (JSAE).
    pub transition: Option<Linear>,
    /// f for continuous actions: `E -> A` (one hidden layer; the AE's is one linear layer).
    pub decoder: Option<Mlp>,
    /// AE: the state auto-encoder's second layer, `X -> logits over states | state`.
    pub state_decoder: Option<Linear>,
    /// AE, discrete actions: the action auto-encoder's second layer, `E -> logits over A`.
    pub action_decoder: Option<Linear>,
    /// RA: the inverse model after phi, `concat(phi(s), phi(s')) -> E` (tanh on the output).
    pub inverse: Option<Mlp>,
    /// RA, discrete actions: log of the scale of f's logits `-scale * |e - z_a|^2`.
    pub inverse_log_scale: Option<Param<Tensor<1>>>,
    /// The next-item head (`embedding.recommender.next_item_coef`): `X -> E`, `h = tanh(.)`.
    pub next_item: Option<Linear>,
    /// The log of the next-item logits' scale, `-scale * |h(x) - g(i)|^2`.
    pub next_item_log_scale: Option<Param<Tensor<1>>>,
    /// Running statistics of real-valued states (`normalize_states`): phi sees normalised
    /// states and T predicts normalised next states.
    pub state_norm: Option<ObsNorm>,
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

/// Where each factor's one-hot columns start in phi's table (categorical states).
fn factor_offsets(states: &StateSpace) -> Vec<u32> {
    match states {
        StateSpace::Categorical { sizes } => sizes
            .iter()
            .scan(0u32, |acc, &s| {
                let o = *acc;
                *acc += s as u32;
                Some(o)
            })
            .collect(),
        StateSpace::Real { .. } => Vec::new(),
    }
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
        Self::build(
            config,
            representation,
            states,
            actions,
            Tables::Drawn,
            rng,
            device,
        )
    }

    /// The model's structure with zero tables, for snapshot bytes to replace
    /// ([`Self::load_owned_bytes`]): the tables' memory is taken only by the loaded ones.
    pub fn template(
        config: &EmbeddingConfig,
        representation: Representation,
        states: &StateSpace,
        actions: &ActionSpace,
        device: &Device,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        Self::build(
            config,
            representation,
            states,
            actions,
            Tables::Zeros,
            &mut rng,
            device,
        )
    }

    fn build(
        config: &EmbeddingConfig,
        representation: Representation,
        states: &StateSpace,
        actions: &ActionSpace,
        tables: Tables,
        rng: &mut ChaCha8Rng,
        device: &Device,
    ) -> Self {
        let (m, d) = (config.state_dim, config.action_dim);
        let (phi_table, phi_linear) = match states {
            StateSpace::Categorical { sizes } => (
                Some(uniform_table(sizes.iter().sum(), m, tables, rng, device)),
                None,
            ),
            StateSpace::Real { dim } => (None, Some(uniform_linear(*dim, m, false, rng, device))),
        };
        let (g_table, g_linear, decoder) =
            action_parts(config, representation, actions, tables, rng, device);
        let mut net = EmbeddingNet {
            phi_table,
            phi_pair: None,
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
            next_item: None,
            next_item_log_scale: None,
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
                // at catalogue scale T's output rows are the embedder's alone, on the host
                // (`embedding.sampled_softmax_from`)
                if config.samples_items(states, actions) {
                    return Self::assembled(
                        net,
                        representation,
                        states,
                        actions,
                        config,
                        rng,
                        device,
                    );
                }
                net.transition = Some(uniform_linear(
                    t_in,
                    states.feature_len(),
                    true,
                    rng,
                    device,
                ));
            }
            Representation::AutoEncoder => {
                autoencoder_heads(&mut net, config, states, actions, rng, device)
            }
            Representation::ActionRepresentation => {
                inverse_heads(&mut net, config, actions, rng, device)
            }
        }
        Self::assembled(net, representation, states, actions, config, rng, device)
    }

    /// The model from its network so far: the item heads drawn last, then the rest.
    fn assembled(
        mut net: EmbeddingNet,
        representation: Representation,
        states: &StateSpace,
        actions: &ActionSpace,
        config: &EmbeddingConfig,
        rng: &mut ChaCha8Rng,
        device: &Device,
    ) -> Self {
        item_heads(&mut net, config, states, rng, device);
        Self {
            net,
            representation,
            states: states.clone(),
            actions: actions.clone(),
            offsets: factor_offsets(states),
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

    /// The network, to change in place (its state statistics, a warm start).
    pub fn net_mut(&mut self) -> &mut EmbeddingNet {
        &mut self.net
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

    /// Loads weights from snapshot bytes (structure checked; a catalogue tag after them,
    /// [`jsae_wire::CatalogueTag`], is the reader's to check and is passed over here).
    pub fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), nn::RecordError> {
        let (_, bytes) = jsae_wire::CatalogueTag::split(bytes);
        self.net = nn::from_bytes(self.net.clone(), bytes)?;
        Ok(())
    }

    /// [`Self::load_bytes`] from bytes the caller gives up (no copy of them is made).
    pub fn load_owned_bytes(&mut self, mut bytes: Vec<u8>) -> Result<(), nn::RecordError> {
        let model = jsae_wire::CatalogueTag::split(&bytes).1.len();
        bytes.truncate(model);
        self.net = nn::from_owned_bytes(self.net.clone(), bytes)?;
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
                let pairs = self.pair_rows(&idx, *factors).map(Box::new);
                let n = idx.len();
                StateInput::Indices(
                    Tensor::from_data(TensorData::new(idx, [n]), &self.device),
                    *factors,
                    pairs,
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

    /// Real-valued states as phi sees them and T predicts them: normalised by the running
    /// statistics when the model keeps them (`normalize_states`).
    pub fn normalised(&self, states: Tensor<2>) -> Tensor<2> {
        match &self.net.state_norm {
            Some(norm) => norm.apply(states),
            None => states,
        }
    }

    /// phi: `[batch] states -> [batch, m]`.
    pub fn embed_states(&self, states: &StateBatch) -> Tensor<2> {
        let input = self.state_tensor(states);
        self.phi(input)
    }

    fn phi(&self, input: StateInput) -> Tensor<2> {
        let pre = match (input, &self.net.phi_table, &self.net.phi_linear) {
            (StateInput::Indices(idx, factors, pairs), Some(table), _) => {
                let rows = table.val().select(0, idx); // [batch * factors, m]
                let [n, m] = rows.dims();
                let summed = if factors == 1 {
                    rows
                } else {
                    rows.reshape([n / factors, factors, m])
                        .sum_dim(1)
                        .reshape([n / factors, m])
                };
                match (pairs, &self.net.phi_pair) {
                    (Some(pairs), Some(pair_table)) => summed + pair_table.val().select(0, *pairs),
                    _ => summed,
                }
            }
            (StateInput::Values(v), _, Some(linear)) => linear.forward(v),
            _ => unreachable_state(),
        };
        pre.tanh()
    }

    /// The rows of phi's table each categorical state reads, a state's factors in order
    /// (`[batch * factors]`; empty for real states).
    pub fn phi_rows(&self, states: &StateBatch) -> Vec<u32> {
        match states {
            StateBatch::Categorical { factors, data } => data
                .iter()
                .enumerate()
                .map(|(i, &v)| v + self.offsets[i % factors])
                .collect(),
            StateBatch::Real { .. } => Vec::new(),
        }
    }

    /// phi of categorical states from the sum of each one's table rows (`[batch, m]`,
    /// summed elsewhere: the embedder keeps the table on the host at catalogue scale) and
    /// those rows ([`Self::phi_rows`], `factors` to a state): its pair row added where the
    /// model has them, then tanh.
    pub fn phi_of_row_sums(&self, summed: Tensor<2>, rows: &[u32], factors: usize) -> Tensor<2> {
        let idx: Vec<i64> = rows.iter().map(|&r| i64::from(r)).collect();
        match (self.pair_rows(&idx, factors), &self.net.phi_pair) {
            (Some(pairs), Some(table)) => (summed + table.val().select(0, pairs)).tanh(),
            _ => summed.tanh(),
        }
    }

    /// The pair row of each state (`[batch]`) from its factors' columns `idx` (offsets
    /// added), when phi has pair rows and the states two factors or more.
    fn pair_rows(&self, idx: &[i64], factors: usize) -> Option<Tensor<1, Int>> {
        let table = self.net.phi_pair.as_ref()?;
        if factors < 2 {
            return None;
        }
        let buckets = table.val().dims()[0];
        let cross = nn::PairCross {
            buckets,
            hashes: 1,
            value: 1.0,
        };
        let rows: Vec<i64> = idx
            .chunks_exact(factors)
            .map(|row| {
                let (a, b) = (row[factors - 2] as u32, row[factors - 1] as u32);
                cross.buckets_of(a, b).next().unwrap_or(0) as i64
            })
            .collect();
        let n = rows.len();
        Some(Tensor::from_data(TensorData::new(rows, [n]), &self.device))
    }

    /// The next-item head's pre-activation `W x + b`, `[batch, d]` (None without the head).
    pub fn next_item_pre(&self, x: Tensor<2>) -> Option<Tensor<2>> {
        self.net.next_item.as_ref().map(|h| h.forward(x))
    }

    /// Every item's next-item logit, `-scale * |h(x) - g(i)|^2`, `[batch, n]` (None
    /// without the head or a g-table).
    pub fn next_item_logits(&self, x: Tensor<2>) -> Option<Tensor<2>> {
        let h = self.next_item_pre(x)?.tanh(); // [batch, d]
        let g = self.action_table()?; // [n, d]
        let scale = self.net.next_item_log_scale.as_ref()?.val().exp(); // [1]
        let [batch, _] = h.dims();
        let n = g.dims()[0];
        let hh = h.clone().square().sum_dim(1); // [batch, 1]
        let gg = g.clone().square().sum_dim(1).reshape([1, n]);
        let dist = hh - h.matmul(g.transpose()) * 2.0 + gg; // [batch, n]
        Some(dist * scale.reshape([1, 1]).expand([batch, n]).neg())
    }

    /// The policy's input: phi, followed by the next-item head's pre-activation where the
    /// model has one, `[batch, m (+ d)]`.
    pub fn policy_input(&self, states: &StateBatch) -> Tensor<2> {
        let x = self.embed_states(states);
        match self.next_item_pre(x.clone()) {
            Some(h) => Tensor::cat(vec![x, h], 1),
            None => x,
        }
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

    /// f for continuous actions: `[batch, d] -> [batch, action dim]` (None for discrete).
    pub fn decode(&self, e: Tensor<2>) -> Option<Tensor<2>> {
        self.net.decoder.as_ref().map(|f| f.forward(e))
    }
}

enum StateInput {
    /// Every factor's column, the factors, each state's pair row (with pair rows).
    Indices(Tensor<1, Int>, usize, Option<Box<Tensor<1, Int>>>),
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

/// RA's initial logit scale: a unit step in squared distance is 10 nats.
const INITIAL_SCALE: f32 = 10.0;

/// AE: each auto-encoder's second layer (the losses: `jsae_embedder`'s `model/baselines.rs`).
fn autoencoder_heads(
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
fn inverse_heads(
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
        skip: false,
        zero_inputs: 0,
        skip_identity: None,
    };
    net.inverse = Some(inverse.init(rng, device));
    if matches!(actions, ActionSpace::Discrete { .. }) {
        let log_scale = TensorData::new(vec![INITIAL_SCALE.ln()], [1]);
        net.inverse_log_scale = Some(Param::from_tensor(Tensor::from_data(log_scale, device)));
    }
}

/// The recommender's item parts (`embedding.recommender`): phi's pair rows (zero) and the
/// next-item head, drawn after every other part so that a seed gives the same model without
/// them.
fn item_heads(
    net: &mut EmbeddingNet,
    config: &EmbeddingConfig,
    states: &StateSpace,
    rng: &mut ChaCha8Rng,
    device: &Device,
) {
    let items = &config.recommender;
    if items.pair_buckets > 0 && matches!(states, StateSpace::Categorical { .. }) {
        let zeros = vec![0.0; items.pair_buckets * config.state_dim];
        net.phi_pair = Some(Param::from_tensor(nn::tensor2(
            zeros,
            items.pair_buckets,
            config.state_dim,
            device,
        )));
    }
    if items.next_item() && net.g_table.is_some() {
        let (m, d) = (config.state_dim, config.action_dim);
        net.next_item = Some(uniform_linear(m, d, true, rng, device));
        let log_scale = TensorData::new(vec![INITIAL_SCALE.ln()], [1]);
        net.next_item_log_scale = Some(Param::from_tensor(Tensor::from_data(log_scale, device)));
    }
}
