//! The policy and the critic: separate tanh MLPs on the policy input `x`, with a diagonal
//! Gaussian head (state-independent log-std parameter, so the std `exp(log_std)` stays
//! positive) or a categorical head. This is the acting half (the head's outputs, sampling,
//! the mode) and the weights whole (the critic too, so that the bytes load as one record);
//! the losses that train it are the learner's. A recommender's count prior
//! ([`crate::prior`]) is not part of the model: the caller passes it to
//! [`Policy::head_outputs`] and [`Policy::act`].

use std::sync::{Arc, OnceLock};

use burn::module::{Module, Param};
use burn::tensor::{Device, Tensor};
use jsae_nn::{
    self as nn, HostInput, HostMlp, Mlp, MlpConfig, MlpWork, PairCross, RecordError, SparseRows,
};
use jsae_wire::{ActionBatch, ActionSpace};
use ndarray::ArrayView2;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::prior::CountPrior;
use jsae_nn::ObsNorm;
use jsae_settings::PpoConfig;

mod prior_bytes;
pub use prior_bytes::PolicyPrior;

/// The smallest log-std a Gaussian head acts with (the parameter is clamped to it).
pub const LOG_STD_MIN: f32 = -5.0;
/// The largest log-std a Gaussian head acts with.
pub const LOG_STD_MAX: f32 = 2.0;
/// `ln(2 pi) / 2`, the Gaussian log-density's constant per component.
pub const HALF_LOG_2PI: f32 = 0.918_938_5;
/// A bound on `|z|` of a standard normal draw by `rand_distr`'s ziggurat from 53 random bits
/// (its tail gives at most about 13.7).
const MAX_NORMAL_DRAW: f32 = 20.0;

/// The distribution the policy outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum PolicyHead {
    /// Diagonal Gaussian over `dim` reals (action embeddings, or raw continuous actions).
    Gaussian {
        /// Number of components.
        dim: usize,
    },
    /// Categorical over `n` actions.
    Categorical {
        /// Number of actions.
        n: usize,
    },
}

impl PolicyHead {
    /// The space the policy samples in (what fragments carry).
    pub fn action_space(self) -> ActionSpace {
        match self {
            Self::Gaussian { dim } => ActionSpace::Continuous {
                dim,
                low: vec![f32::NEG_INFINITY; dim],
                high: vec![f32::INFINITY; dim],
            },
            Self::Categorical { n } => ActionSpace::Discrete { n },
        }
    }

    /// The behaviour log-probabilities an actor acting with this head can report
    /// ([`Policy::act`]), `(lowest, highest)`, which the learner accepts at the wire
    /// ([`jsae_wire::FragmentBounds`]). Gaussian, per component: the density's peak at the
    /// smallest std, down to a draw [`MAX_NORMAL_DRAW`] stds out at the largest std.
    /// Categorical: an action is drawn only where its weight `exp(l - max)` is positive in
    /// `f32` (at least `2^-149`), so its log-probability is at least `ln 2^-149 - ln n`; it
    /// is never above 0. Each side has a margin of 1 (rounding) per component.
    pub fn behaviour_logp_range(self) -> (f32, f32) {
        match self {
            Self::Gaussian { dim } => {
                let dim = dim as f32;
                let lowest = 0.5 * MAX_NORMAL_DRAW * MAX_NORMAL_DRAW + LOG_STD_MAX + HALF_LOG_2PI;
                (
                    -(lowest + 1.0) * dim,
                    (-LOG_STD_MIN - HALF_LOG_2PI + 1.0) * dim,
                )
            }
            Self::Categorical { n } => {
                let smallest_weight = 149.0 * std::f32::consts::LN_2;
                (-(smallest_weight + (n.max(1) as f32).ln() + 1.0), 0.0)
            }
        }
    }

    /// Width of the actor network's output.
    fn outputs(self) -> usize {
        match self {
            Self::Gaussian { dim } => dim,
            Self::Categorical { n } => n,
        }
    }
}

/// Actor and critic weights.
#[derive(Module, Debug)]
pub struct PolicyNet {
    actor: Mlp,
    critic: Mlp,
    log_std: Param<Tensor<1>>,
    /// Input normalisation (`ppo.normalize_obs`).
    obs_norm: Option<ObsNorm>,
}

/// A policy with its critic, on one device.
#[derive(Debug, Clone)]
pub struct Policy {
    net: PolicyNet,
    head: PolicyHead,
    input: usize,
    tanh_mean: bool,
    /// Where the entropy bonus stops counting the log-std (`PpoConfig::entropy_log_std_cap`).
    entropy_log_std_max: f32,
    /// The crossed pair feature the networks read after `input` (`ppo.recommender.pair_buckets`,
    /// `pair_hashes`, `pair_scale`), if any.
    pair: Option<PairCross>,
    /// The actor on the host, for inference on crossed one-hot inputs (a lookup of a few
    /// weight rows instead of a dense product over every bucket); copied from `net` at the
    /// first use after the weights change.
    host_actor: OnceLock<Arc<HostMlp>>,
    device: Device,
}

impl Policy {
    /// Fresh weights: orthogonal init, gain sqrt(2) hidden, 0.01 policy head, 1.0 value head.
    pub fn new(
        config: &PpoConfig,
        input: usize,
        head: PolicyHead,
        rng: &mut ChaCha8Rng,
        device: &Device,
    ) -> Self {
        // the Gaussian mean starts at the input's last `dim` columns: the embedder's next-item
        // head (`ppo.recommender.mean_at_next_item`)
        let anchored = config.recommender.mean_at_next_item
            && matches!(head, PolicyHead::Gaussian { dim } if dim <= input);
        let actor = MlpConfig {
            input,
            hidden: config.hidden.clone(),
            output: head.outputs(),
            output_gain: 0.01,
            skip: config.wide_actor || anchored,
            zero_inputs: config.recommender.pair_buckets,
            skip_identity: anchored.then(|| input - head.outputs()),
        }
        .init(rng, device);
        let critic = MlpConfig {
            input,
            hidden: config.hidden.clone(),
            output: 1,
            output_gain: 1.0,
            skip: false,
            zero_inputs: config.recommender.pair_buckets,
            skip_identity: None,
        }
        .init(rng, device);
        let dim = match head {
            PolicyHead::Gaussian { dim } => dim,
            PolicyHead::Categorical { .. } => 1,
        };
        let log_std = Param::from_tensor(nn::tensor1(vec![config.init_log_std; dim], device));
        Self {
            net: PolicyNet {
                actor,
                critic,
                log_std,
                obs_norm: config.normalize_obs.then(|| ObsNorm::new(input, device)),
            },
            head,
            input,
            tanh_mean: config.tanh_mean,
            entropy_log_std_max: config.entropy_log_std_cap().unwrap_or(LOG_STD_MAX),
            pair: (config.recommender.pair_buckets > 0).then_some(PairCross {
                buckets: config.recommender.pair_buckets,
                hashes: config.recommender.pair_hashes,
                value: config.recommender.pair_scale,
            }),
            host_actor: OnceLock::new(),
            device: device.clone(),
        }
    }

    /// The crossed pair feature after the input ([`jsae_nn::SparseRows::crossed`]), if any.
    pub fn pair_feature(&self) -> Option<PairCross> {
        self.pair
    }

    /// The output distribution.
    pub fn head(&self) -> PolicyHead {
        self.head
    }

    /// Width of the input `x`.
    pub fn input_dim(&self) -> usize {
        self.input
    }

    /// The device.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// The actor MLP, the critic MLP and the (unclamped) log-std parameter.
    pub fn parts(&self) -> (&Mlp, &Mlp, &Param<Tensor<1>>) {
        (&self.net.actor, &self.net.critic, &self.net.log_std)
    }

    /// Whether the Gaussian mean is tanh-bounded.
    pub fn tanh_mean(&self) -> bool {
        self.tanh_mean
    }

    /// The log-std up to which the entropy bonus counts.
    pub fn entropy_log_std_max(&self) -> f32 {
        self.entropy_log_std_max
    }

    /// Holds a Gaussian policy's log std at most `max` (the entropy bonus's falling cap,
    /// `PpoConfig::entropy_log_std_cap_at`): the parameter is clamped to it and the bonus
    /// stops there from now on. A categorical policy has no std to hold.
    pub fn hold_log_std(&mut self, max: f32) {
        if !matches!(self.head, PolicyHead::Gaussian { .. }) {
            return;
        }
        self.entropy_log_std_max = self.entropy_log_std_max.min(max);
        let held: Vec<f32> = nn::to_vec(self.net.log_std.val())
            .into_iter()
            .map(|v| v.min(max))
            .collect();
        self.net.log_std = self.net.log_std.clone().map(|old| nn::replaced(old, &held));
        self.host_actor = OnceLock::new();
    }

    /// The weights.
    pub fn net(&self) -> &PolicyNet {
        &self.net
    }

    /// Replaces the weights (after an optimiser step).
    pub fn set_net(&mut self, net: PolicyNet) {
        self.net = net;
        self.host_actor = OnceLock::new();
    }

    /// Replaces the trainable weights with host copies (what the learner's host update
    /// trained), keeping each parameter's id and the observation statistics.
    pub fn set_host_weights(&mut self, actor: &HostMlp, critic: &HostMlp, log_std: &[f32]) {
        self.host_actor = OnceLock::new();
        self.net.actor.set_from_host(actor);
        self.net.critic.set_from_host(critic);
        let values = log_std;
        self.net.log_std = self
            .net
            .log_std
            .clone()
            .map(|old| nn::replaced(old, values));
    }

    /// A copy for inference on `device`.
    pub fn for_inference(&self, device: &Device) -> Self {
        Self {
            net: self.net.valid().to_device(device),
            host_actor: OnceLock::new(),
            device: device.clone(),
            ..self.clone()
        }
    }

    /// The weights as one record's bytes (without a prior: [`crate::prior::PolicyPrior`]
    /// frames them with one where the settings ask).
    pub fn record_bytes(&self) -> Result<Vec<u8>, RecordError> {
        nn::into_bytes(&self.net)
    }

    /// Loads weights from [`Self::record_bytes`]'s bytes (structure checked).
    pub fn load_record(&mut self, bytes: &[u8]) -> Result<(), RecordError> {
        self.net = nn::from_bytes(self.net.clone(), bytes)?;
        self.host_actor = OnceLock::new();
        Ok(())
    }

    /// The log-std parameter clamped to `[LOG_STD_MIN, LOG_STD_MAX]`, as the head acts with it.
    pub fn log_std(&self) -> Tensor<1> {
        self.net.log_std.val().clamp(LOG_STD_MIN, LOG_STD_MAX)
    }

    /// Current log-std per component (Gaussian head).
    pub fn log_std_values(&self) -> Vec<f32> {
        nn::to_vec(self.log_std())
    }

    /// The network input: `x`, normalised when the policy normalises observations.
    pub fn network_input(&self, x: Tensor<2>) -> Tensor<2> {
        match &self.net.obs_norm {
            Some(norm) => norm.apply(x),
            None => x,
        }
    }

    /// Merges the rows of `x` (raw policy inputs, `[rows, input]`) into the observation
    /// statistics (no-op without normalisation).
    pub fn update_obs_stats(&mut self, x: &[f32]) {
        let device = self.device.clone();
        if let Some(norm) = &mut self.net.obs_norm {
            norm.update(x, &device);
        }
    }

    /// The observation statistics (mean, variance, count), if the policy normalises.
    pub fn obs_stats(&self) -> Option<(Vec<f32>, Vec<f32>, f64)> {
        self.net.obs_norm.as_ref().map(ObsNorm::stats)
    }

    /// The actor network's output: Gaussian means (tanh-bounded if configured) or logits
    /// (without a prior).
    pub fn actor_out(&self, x: Tensor<2>) -> Tensor<2> {
        let out = self.net.actor.forward(self.network_input(x)); // [batch, outputs]
        match self.head {
            PolicyHead::Gaussian { .. } if self.tanh_mean => out.tanh(),
            _ => out,
        }
    }

    /// The actor network's outputs for every row of `x` (`[batch, input]`), row-major: the
    /// Gaussian's mean (`[batch, dim]`) or the categorical's logits (`[batch, n]`), plus
    /// `prior`'s log-estimate where a categorical policy is given one.
    pub fn head_outputs(&self, x: &[f32], prior: Option<&CountPrior>) -> Vec<f32> {
        let batch = x.len() / self.input.max(1);
        if batch == 0 {
            return Vec::new();
        }
        let x = &x[..batch * self.input];
        let mut out = match self.pair {
            Some(cross) => self.crossed_head_outputs(x, cross),
            None => {
                nn::to_vec(self.actor_out(nn::tensor2(x.to_vec(), batch, self.input, &self.device)))
            }
        };
        if let Some(prior) = prior {
            let (n, mut cols) = (prior.actions(), Vec::new());
            for (row, logits) in x.chunks_exact(self.input).zip(out.chunks_exact_mut(n)) {
                prior.add_to_dense(row, logits, &mut cols);
            }
        }
        out
    }

    /// [`Self::head_outputs`] of one-hot rows `x` with their crossed pair feature, on the host.
    fn crossed_head_outputs(&self, x: &[f32], cross: PairCross) -> Vec<f32> {
        let rows = x.len() / self.input.max(1);
        let view = ArrayView2::from_shape((rows, self.input), x).expect("whole rows of the input");
        let crossed = SparseRows::crossed(view, cross);
        let actor = self
            .host_actor
            .get_or_init(|| Arc::new(HostMlp::from_burn(&self.net.actor)));
        let mut work = MlpWork::default();
        actor.forward(HostInput::Sparse(&crossed), &mut work);
        let out = work.output().iter().copied();
        match self.head {
            PolicyHead::Gaussian { .. } if self.tanh_mean => out.map(f32::tanh).collect(),
            _ => out.collect(),
        }
    }

    /// Samples (or, `deterministic`, takes the mean / most likely) action for every row of
    /// `x` (`[batch, input]`) under [`Self::head_outputs`] (with `prior`), appending them to
    /// `actions` and their log-probabilities to `logp`.
    pub fn act(
        &self,
        x: &[f32],
        prior: Option<&CountPrior>,
        deterministic: bool,
        rng: &mut ChaCha8Rng,
        actions: &mut ActionBatch,
        logp: &mut Vec<f32>,
    ) {
        let out = self.head_outputs(x, prior);
        if out.is_empty() {
            return;
        }
        match (self.head, actions) {
            (PolicyHead::Gaussian { dim }, ActionBatch::Continuous { data, .. }) => {
                let log_std = self.log_std_values();
                for mean in out.chunks_exact(dim) {
                    let mut lp = 0.0;
                    for ((&m, &ls), _) in mean.iter().zip(&log_std).zip(0..dim) {
                        let z: f32 = if deterministic {
                            0.0
                        } else {
                            rng.sample(StandardNormal)
                        };
                        data.push(m + ls.exp() * z);
                        lp += -0.5 * z * z - ls - HALF_LOG_2PI;
                    }
                    logp.push(lp);
                }
            }
            (PolicyHead::Categorical { n }, ActionBatch::Discrete(chosen)) => {
                for logits in out.chunks_exact(n) {
                    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                    let sum: f32 = logits.iter().map(|l| (l - max).exp()).sum();
                    let log_z = max + sum.ln();
                    let a = if deterministic {
                        logits
                            .iter()
                            .enumerate()
                            .fold(
                                (0, f32::NEG_INFINITY),
                                |b, (i, &l)| if l > b.1 { (i, l) } else { b },
                            )
                            .0
                    } else {
                        // rounding may leave `u` above 0 after the last action: the draw
                        // then takes the last action of positive weight (never one whose
                        // probability is 0 in f32)
                        let mut u = rng.random::<f32>() * sum;
                        let mut pick = None;
                        for (i, l) in logits.iter().enumerate() {
                            let weight = (l - max).exp();
                            if weight > 0.0 {
                                pick = Some(i);
                            }
                            u -= weight;
                            if u <= 0.0 && weight > 0.0 {
                                break;
                            }
                        }
                        pick.unwrap_or(0)
                    };
                    chosen.push(a as u32);
                    logp.push(logits[a] - log_z);
                }
            }
            _ => {}
        }
    }
}

/// The policy input width and head for a run, as its representation answers: phi's width
/// when it embeds states (else the raw features), a Gaussian over the action-embedding space
/// when f decodes actions (else the action space's own head).
pub fn policy_shape(
    config: &jsae_settings::TrainConfig,
    states: &jsae_wire::StateSpace,
    actions: &ActionSpace,
) -> (usize, PolicyHead) {
    let representation = config.algo.representation();
    let input = if representation.embeds_states() {
        config.embedding.policy_input_dim()
    } else {
        states.feature_len()
    };
    let head = match actions {
        _ if representation.decodes_actions() => PolicyHead::Gaussian {
            dim: config.embedding.action_dim,
        },
        ActionSpace::Discrete { n } => PolicyHead::Categorical { n: *n },
        ActionSpace::Continuous { dim, .. } => PolicyHead::Gaussian { dim: *dim },
    };
    (input, head)
}

#[cfg(test)]
mod tests;
