//! The PPO minibatch step on the host: the loss and every parameter's gradient in one pass
//! (`loss`), with the dense products on a GEMM kernel and the MLPs' buffers reused between
//! minibatches ([`jsae_nn::host`]), instead of a graph of ~30 small tensor operations through
//! burn's autodiff. Same model, same parameters: [`HostPolicy`] is read from the burn
//! [`Policy`] and written back into it ([`HostParams::write_into`]). The host keeps the weights
//! of every layer after the first as `[out, in]` (burn's `Linear` weights are `[in, out]`),
//! and the gradients come out in the host's layout; [`jsae_nn::HostMlp::weight`] reads
//! either in burn's.
//!
//! The loss is the one `ppo::update`'s burn path builds: the clipped surrogate, minus
//! `ent_coef` times the mean entropy, plus `vf_coef` times the (optionally clipped) value
//! loss, plus `next_purchase_coef` times the mean cross-entropy of the categorical policy
//! against the item bought next (where one was); where burn's `max_pair` has a tie the gradient goes to the unclipped term, as
//! burn's does. `tests` checks both against burn's autodiff.

mod categorical;
mod loss;
#[cfg(test)]
mod tests;

use jsae_nn::{HostInput, HostMlp, MlpWork};
use ndarray::Array1;

use jsae_agent::{CountPrior, Policy, PolicyHead};

/// The largest log-ratio the surrogate takes as it is: beyond it the ratio is held at
/// `exp(20)` (about 4.9e8) and its gradient is 0, so a behaviour log-probability far below
/// the policy's own (which PPO's clip leaves unbounded where the advantage is negative) can
/// neither overflow the ratio to infinity nor dominate the update. Real batches stay far
/// below it (their ratios are within a few tenths of 1).
pub const LOG_RATIO_MAX: f32 = 20.0;

/// The clipped surrogate of one sample, `max(-A r, -A clip(r))` with `r =
/// exp(min(log_ratio, LOG_RATIO_MAX))`, and its derivative with respect to the
/// log-probability (a tie, or a NaN, takes the unclipped branch, as burn's `max_pair` does;
/// beyond the hold the derivative is 0, as burn's `clamp_max` gives).
pub(super) fn surrogate(log_ratio: f32, adv: f32, clip: f32) -> (f32, f32) {
    let held = log_ratio > LOG_RATIO_MAX;
    let r = if held { LOG_RATIO_MAX } else { log_ratio }.exp();
    let unclipped = -adv * r;
    let clipped = -adv * r.clamp(1.0 - clip, 1.0 + clip);
    if clipped > unclipped {
        (clipped, 0.0)
    } else if held {
        (unclipped, 0.0)
    } else {
        (unclipped, -adv * r)
    }
}

/// The policy's trainable parameters on the host (and, for gradients, their layout).
#[derive(Debug, Clone, PartialEq)]
pub struct HostParams {
    /// The actor MLP.
    pub actor: HostMlp,
    /// The critic MLP.
    pub critic: HostMlp,
    /// The log-std parameter (Gaussian; one unused value for categorical), unclamped.
    pub log_std: Array1<f32>,
}

/// The gradient of the loss for every parameter, in the parameters' layout.
pub type HostGrads = HostParams;

impl HostParams {
    /// Writes these parameters into `policy` (after the host update trained them), keeping
    /// each parameter's id and the observation statistics.
    pub fn write_into(&self, policy: &mut Policy) {
        policy.set_host_weights(
            &self.actor,
            &self.critic,
            self.log_std.as_slice().unwrap_or(&[]),
        );
    }

    /// Zeros in this shape.
    pub fn zeros_like(&self) -> Self {
        Self {
            actor: self.actor.zeros_like(),
            critic: self.critic.zeros_like(),
            log_std: Array1::zeros(self.log_std.len()),
        }
    }

    /// Every parameter as a flat slice: actor layers, critic layers, log-std.
    pub fn slices(&self) -> Vec<&[f32]> {
        let mut out = self.actor.slices();
        out.extend(self.critic.slices());
        out.push(self.log_std.as_slice().unwrap_or(&[]));
        out
    }

    /// Every parameter as a flat mutable slice, in the order of [`Self::slices`].
    pub fn slices_mut(&mut self) -> Vec<&mut [f32]> {
        let mut out = self.actor.slices_mut();
        out.extend(self.critic.slices_mut());
        out.push(self.log_std.as_slice_mut().unwrap_or(&mut []));
        out
    }

    /// The weights that read the input, as (place among [`Self::slices`], values per input
    /// row): each MLP's first layer, and the actor's input-to-output path where it has one.
    pub fn input_layers(&self) -> Vec<(usize, usize)> {
        let actor_slices = self.actor.slices().len();
        let mut out = vec![
            (0, self.actor.w[0].ncols()),
            (actor_slices, self.critic.w[0].ncols()),
        ];
        if let (Some(i), Some(skip)) = (self.actor.skip_slice(), &self.actor.skip) {
            out.push((i, skip.ncols()));
        }
        out
    }

    /// Per slice of [`Self::slices`]: `touched` rows of the weights that read the input
    /// ([`Self::input_layers`]), nothing for the others (a lazy Adam step's rows).
    pub fn input_rows<'a>(&self, touched: &'a [u32]) -> Vec<Option<jsae_nn::host::Rows<'a>>> {
        let mut out = vec![None; self.slices().len()];
        for (i, width) in self.input_layers() {
            out[i] = Some(jsae_nn::host::Rows {
                width,
                rows: touched,
            });
        }
        out
    }
}

/// A policy on the host: its parameters and its head.
#[derive(Debug, Clone, PartialEq)]
pub struct HostPolicy {
    /// The trainable parameters.
    pub params: HostParams,
    /// The output distribution.
    pub head: PolicyHead,
    /// Whether the Gaussian mean is tanh-bounded.
    pub tanh_mean: bool,
    /// The log-std up to which the entropy bonus counts.
    pub entropy_log_std_max: f32,
    /// The prior the categorical logits add (`ppo.recommender.logged_prior`), not trained.
    pub prior: Option<std::sync::Arc<CountPrior>>,
}

/// One minibatch, or one run of a minibatch's rows ([`minibatch_parts`]), as `ppo::update`
/// builds it (inputs already normalised, advantages normalised over the whole minibatch if
/// configured).
#[derive(Debug, Clone)]
pub struct HostMinibatch<'a> {
    /// Network inputs (normalised when the policy normalises), `[b, input]`.
    pub x: HostInput<'a>,
    /// Gaussian actions `[b * dim]`, or empty.
    pub continuous: &'a [f32],
    /// Categorical actions `[b]`, or empty.
    pub discrete: &'a [u32],
    /// Behaviour log-probabilities.
    pub old_logp: &'a [f32],
    /// Advantages.
    pub adv: &'a [f32],
    /// Returns.
    pub returns: &'a [f32],
    /// Values at collection time.
    pub old_values: &'a [f32],
    /// The item bought after each sample (`u32::MAX`: none), or empty.
    pub next_purchase: &'a [u32],
}

/// The loss's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossConfig {
    /// Surrogate (and value) clip range.
    pub clip: f32,
    /// Clip the value loss.
    pub clip_value_loss: bool,
    /// Entropy coefficient.
    pub ent_coef: f32,
    /// Value-loss coefficient.
    pub vf_coef: f32,
    /// Weight of the next-purchase cross-entropy (categorical head; 0: off).
    pub next_purchase_coef: f32,
}

/// The loss's parts, as `ppo::update` reports them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossParts {
    /// The whole loss.
    pub total: f32,
    /// Clipped surrogate.
    pub pg: f32,
    /// Value loss.
    pub value: f32,
    /// Mean entropy.
    pub entropy: f32,
    /// The next-purchase cross-entropy, unweighted (summed over the samples with a next
    /// purchase, divided by all; 0 when the loss is off).
    pub next_purchase: f32,
}

/// Samples per part below which a minibatch is not split between threads: at PPO's usual
/// 64 the actor's and the critic's halves already keep two threads busy, and smaller
/// products run below the kernel's speed.
const PART_ROWS: usize = 64;

/// Into how many parts (runs of rows, in order) a minibatch of `rows` samples is split for
/// [`HostPolicy::loss_and_grads`]: one per rayon thread where each has at least
/// [`PART_ROWS`]. Splitting the rows keeps both cores busy where one MLP is much larger than
/// the other (a categorical actor over hundreds of actions beside a one-output critic).
pub fn minibatch_parts(rows: usize) -> usize {
    (rows / PART_ROWS).clamp(1, rayon::current_num_threads().max(1))
}

/// One part's buffers: both MLPs' activations, the gradients of its samples' terms, and
/// their `logp - old_logp`.
#[derive(Debug, Clone)]
struct PartWork {
    actor: MlpWork,
    critic: MlpWork,
    grads: HostGrads,
    log_ratio: Vec<f32>,
}

impl PartWork {
    fn new(policy: &HostPolicy) -> Self {
        Self {
            actor: MlpWork::default(),
            critic: MlpWork::default(),
            grads: policy.params.zeros_like(),
            log_ratio: Vec::new(),
        }
    }
}

/// Buffers of one minibatch step, kept between minibatches: each part's (the first part's
/// gradients become the minibatch's; a minibatch of fewer parts leaves the others' for later
/// ones), and `logp - old_logp` per sample.
#[derive(Debug, Clone)]
pub struct FusedWork {
    parts: Vec<PartWork>,
    log_ratio: Vec<f32>,
    /// One-hot inputs' first-layer gradients are added into the rows they pick
    /// ([`jsae_nn::InputWeights::Accumulate`]); the caller clears those rows after each step.
    pub accumulate_input_rows: bool,
}

impl FusedWork {
    /// Buffers for `policy`'s shapes.
    pub fn new(policy: &HostPolicy) -> Self {
        Self {
            parts: vec![PartWork::new(policy)],
            log_ratio: Vec::new(),
            accumulate_input_rows: false,
        }
    }

    /// The gradients of the last [`HostPolicy::loss_and_grads`].
    pub fn grads(&self) -> &HostGrads {
        &self.parts[0].grads
    }

    /// Sets the gradients to zero in `rows` (per slice of [`HostParams::slices`], as
    /// [`HostParams::input_rows`] gives them): after a lazy step, with
    /// [`Self::accumulate_input_rows`], the rows it read.
    pub fn clear_grad_rows(&mut self, rows: &[Option<jsae_nn::host::Rows<'_>>]) {
        for (g, r) in self.parts[0].grads.slices_mut().into_iter().zip(rows) {
            if let Some(r) = r {
                jsae_nn::host::zero_rows(g, *r);
            }
        }
    }

    /// `logp - old_logp` per sample of the last minibatch.
    pub fn log_ratio(&self) -> &[f32] {
        &self.log_ratio
    }
}

impl HostPolicy {
    /// The trainable parameters of `policy`, copied to the host, with the prior its logits
    /// add.
    pub fn from_policy(policy: &Policy, prior: Option<std::sync::Arc<CountPrior>>) -> Self {
        let (actor, critic, log_std) = policy.parts();
        Self {
            params: HostParams {
                actor: HostMlp::from_burn(actor),
                critic: HostMlp::from_burn(critic),
                log_std: Array1::from(jsae_nn::to_vec(log_std.val())),
            },
            head: policy.head(),
            tanh_mean: policy.tanh_mean(),
            entropy_log_std_max: policy.entropy_log_std_max(),
            prior,
        }
    }

    /// `V(x)` under `policy`'s critic for every row of `x` (network inputs, `[rows, input]`);
    /// only the critic is copied to the host.
    pub fn values(policy: &Policy, x: HostInput<'_>) -> Vec<f32> {
        let (_, critic, _) = policy.parts();
        let mut work = MlpWork::default();
        HostMlp::from_burn(critic).forward(x, &mut work);
        work.output().iter().copied().collect()
    }
}
