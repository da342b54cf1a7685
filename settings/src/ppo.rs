//! PPO settings.

use serde::{Deserialize, Serialize};

pub use crate::ppo_recommender::RecommenderPpoConfig;

/// PPO settings. Defaults follow the common PPO implementation details (orthogonal init,
/// Adam eps 1e-5, GAE, clipped surrogate, advantage normalisation, global grad-norm
/// clipping, linear LR annealing) with the paper's grid where it searched (lr, std, batch,
/// network size, lambda 0.97).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PpoConfig {
    /// Env steps per update (all fragments of one rollout round together).
    pub batch_steps: usize,
    /// Passes over the batch per update.
    pub epochs: usize,
    /// Steps per minibatch (unless `minibatches` is set).
    pub minibatch_size: usize,
    /// Minibatches per epoch (None: the batch is cut into minibatches of `minibatch_size`).
    /// Set, the minibatch is the batch over this count ([`PpoConfig::minibatch_len`]): where
    /// the batch is one rollout of every actor present (the default; unless `batch_envs`),
    /// the minibatch grows with the actors and an update takes the same number of gradient
    /// steps whatever their count, each on more samples (split between the learner's
    /// threads). With one actor of 2,048 steps, 32 is the same as a `minibatch_size` of 64.
    pub minibatches: Option<usize>,
    /// Adam learning rate at the start.
    pub lr: f64,
    /// Anneal the learning rate linearly to 0 over the run.
    pub anneal_lr: bool,
    /// Discount.
    pub gamma: f64,
    /// GAE lambda.
    pub gae_lambda: f64,
    /// Surrogate clip range.
    pub clip: f64,
    /// Also clip the value loss around the old values.
    pub clip_value_loss: bool,
    /// Value loss weight.
    pub vf_coef: f64,
    /// Entropy bonus weight.
    pub ent_coef: f64,
    /// The log-std up to which the entropy bonus counts the Gaussian's std (its gradient
    /// stops there; only the policy gradient moves the std further). Unset: E's rule
    /// ([`PpoConfig::entropy_log_std_cap`]).
    pub entropy_log_std_max: Option<f32>,
    /// Where the entropy bonus's cap ends the run (None: E's rule,
    /// [`PpoConfig::entropy_log_std_cap_at`]). From `entropy_cap_anneal_from` of the run's
    /// env steps on, the cap falls linearly from `entropy_log_std_max` to this value and
    /// becomes a ceiling: the std is held under it after every update, so a policy whose
    /// std the bonus held wide commits by the end of the run and its mean is a policy of
    /// its own. Without a bonus (`ent_coef` 0) or a step budget nothing is held.
    pub entropy_log_std_final: Option<f32>,
    /// The share of the run's env steps after which the entropy bonus's cap starts to fall
    /// (`entropy_log_std_final`).
    pub entropy_cap_anneal_from: f64,
    /// The share of the run's env steps at which the cap reaches `entropy_log_std_final`
    /// (after `entropy_cap_anneal_from`, at most 1); it stays there for the rest of the run.
    pub entropy_cap_anneal_to: f64,
    /// Global gradient-norm limit.
    pub max_grad_norm: f32,
    /// Normalise advantages per minibatch.
    pub norm_adv: bool,
    /// Stop an update's epochs early once approx-KL exceeds this (None: never).
    pub target_kl: Option<f64>,
    /// Hidden widths of the policy and of the critic (separate networks, tanh).
    pub hidden: Vec<usize>,
    /// Add to the actor a linear path from its input straight to its outputs, starting at
    /// zero ("wide and deep"): on one-hot states (the recommender's items) a score per
    /// (state item, action) that a narrow hidden layer cannot hold.
    pub wide_actor: bool,
    /// Initial log standard deviation of the Gaussian policy.
    pub init_log_std: f32,
    /// Bound the Gaussian mean with tanh to `[-1, 1]` (JSAE: the action-embedding space is
    /// tanh-bounded, and a mean outside it maps every sample to the same action).
    pub tanh_mean: bool,
    /// Scale rewards by a running estimate of the discounted return's std.
    pub reward_scaling: bool,
    /// The largest reward magnitude a fragment may carry: the learner refuses a fragment with
    /// a larger one (INVALID_ARGUMENT on the wire, a warning in the log), so that one
    /// finite but absurd reward (3e38) cannot inflate the reward scaler's statistics and
    /// poison the run. Default 1e6: far above every environment's step reward (gridworlds
    /// and the slot machine below 10, MuJoCo below 100, the recommender's item prices in the
    /// thousands at most); raise it for an environment that pays more.
    pub max_abs_reward: f32,
    /// Normalise the policy input by running mean and variance (clipped to +-10); the
    /// statistics are part of the policy's weights, snapshots and checkpoints.
    pub normalize_obs: bool,
    /// Fragments produced by a policy more than this many versions old are dropped.
    pub max_policy_lag: u64,
    /// The most env steps one PPO update takes (None: a whole batch). A larger batch (one
    /// rollout of every actor present, where it grows with them) is optimised in consecutive passes over parts of about
    /// this size, in the order the fragments arrived, each a full update (every epoch, its
    /// own advantage normalisation) starting from the last, before the batch's one policy is
    /// published: as many clipped steps per env step as with one actor, whatever the actor
    /// count. The later parts' ratios are taken against the log-probs their actors acted
    /// with (PPO's clip on the behaviour policy).
    pub max_update_steps: Option<usize>,
    /// Which implementation runs the update: `fused` (host loss, gradients and Adam over
    /// GEMMs; the default) or `burn` (burn's autodiff graph; the reference, slower).
    pub update: UpdatePath,
    /// The recommender's own (`[ppo.recommender]`: the next-purchase loss, the logged
    /// purchases, the pair feature; for `--env recommender --algo ppo` only).
    pub recommender: RecommenderPpoConfig,
}

/// Which implementation runs the PPO update; both compute the same loss, gradients and Adam
/// step (checked against each other in the learner's tests).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum UpdatePath {
    /// Host loss, gradients and Adam over GEMMs.
    #[default]
    Fused,
    /// burn's autodiff graph and optimiser.
    Burn,
}

impl Default for PpoConfig {
    fn default() -> Self {
        Self {
            batch_steps: 2048,
            epochs: 10,
            minibatch_size: 256,
            minibatches: None,
            lr: 3e-4,
            anneal_lr: true,
            gamma: 0.99,
            gae_lambda: 0.95,
            clip: 0.2,
            clip_value_loss: false,
            vf_coef: 0.5,
            ent_coef: 0.0,
            entropy_log_std_max: None,
            entropy_log_std_final: None,
            entropy_cap_anneal_from: 0.75,
            entropy_cap_anneal_to: 1.0,
            max_grad_norm: 0.5,
            norm_adv: true,
            target_kl: None,
            hidden: vec![64, 64],
            wide_actor: false,
            init_log_std: 0.0,
            tanh_mean: false,
            reward_scaling: true,
            max_abs_reward: DEFAULT_MAX_ABS_REWARD,
            normalize_obs: false,
            max_policy_lag: 4,
            max_update_steps: None,
            update: UpdatePath::Fused,
            recommender: RecommenderPpoConfig::default(),
        }
    }
}

/// Most hidden layers a network may have (settings beyond are refused before anything is
/// allocated).
pub const MAX_LAYERS: usize = 8;
/// Widest hidden layer (`ppo.hidden`, `embedding.transition_hidden`, `decoder_hidden`).
pub const MAX_WIDTH: usize = 8_192;
/// Most weights between `ppo.hidden`'s layers together (2^24: 64 MiB of f32 per network).
pub const MAX_HIDDEN_WEIGHTS: usize = 1 << 24;
/// Largest `ppo.batch_steps` and `ppo.minibatch_size` (the learner's limit on announced
/// rollouts, 2^22).
pub const MAX_BATCH_STEPS: usize = 1 << 22;
/// Most epochs over one batch.
pub const MAX_EPOCHS: usize = 1_000;

/// [`PpoConfig::max_abs_reward`]'s default.
pub const DEFAULT_MAX_ABS_REWARD: f32 = 1e6;

/// The entropy bonus's log-std cap for a policy in an action-embedding space (tanh-bounded
/// mean, E = [-1, 1]^d, g tanh-bounded too). f maps every sample outside E to an action on
/// its rim, so far past E's half-width (log-std 0) a larger std adds Gaussian entropy that
/// the decoded actions do not have, and the bonus would raise it for free.
/// Measured on gridworld-discrete (docs/src/experiments/greedy-loops.md): with no cap 4 of
/// 20 runs at 512/1,024 actions ended at log-std 0.7-1.5 with sampled returns of -1.4 to 0.3,
/// one of them looping under greedy evaluation; with the cap at 0 one seed in 10 at each of
/// 2,048 and 4,096 actions never explored far enough to find the goal.
pub const EMBEDDED_ENTROPY_LOG_STD_MAX: f32 = 0.5;

/// Where the entropy bonus's cap ends a run for a policy in an action-embedding space (std
/// 0.37 in E = [-1, 1]^d). With the cap held at [`EMBEDDED_ENTROPY_LOG_STD_MAX`] to the end, a
/// gridworld run that found the goal late kept the bonus's std (log std 0.5) and its mean
/// decoded into a two-step loop while its samples solved the task
/// (docs/src/experiments/greedy-loops.md); the 1M-step runs that solved the task early ended at log std -1.07 to
/// -0.13 on the policy gradient alone. Ending at -1.5 by 0.9 of the run was measured too and
/// did not remove the loops that remain (same page).
pub const EMBEDDED_ENTROPY_LOG_STD_FINAL: f32 = -1.0;

impl PpoConfig {
    /// Where the entropy bonus stops counting the std (None: nowhere below the log-std
    /// clamp): the setting, else [`EMBEDDED_ENTROPY_LOG_STD_MAX`] for a tanh-bounded mean.
    pub fn entropy_log_std_cap(&self) -> Option<f32> {
        self.entropy_log_std_max
            .or(self.tanh_mean.then_some(EMBEDDED_ENTROPY_LOG_STD_MAX))
    }

    /// The largest log std the policy may keep after an update at `progress` (the share of
    /// the run's env steps done, in [0, 1]): None before `entropy_cap_anneal_from`, without
    /// an entropy bonus or without a cap to start from; then falling linearly from the cap
    /// to `entropy_log_std_final` (else [`EMBEDDED_ENTROPY_LOG_STD_FINAL`] for a tanh-bounded
    /// mean) at the end of the run. The entropy bonus stops there too.
    pub fn entropy_log_std_cap_at(&self, progress: f64) -> Option<f32> {
        let start = self.entropy_log_std_cap()?;
        let end = self
            .entropy_log_std_final
            .or(self.tanh_mean.then_some(EMBEDDED_ENTROPY_LOG_STD_FINAL))?;
        let (from, to) = (self.entropy_cap_anneal_from, self.entropy_cap_anneal_to);
        if self.ent_coef <= 0.0 || progress.is_nan() || progress <= from {
            return None;
        }
        let t = ((progress - from) / (to - from)).min(1.0) as f32;
        Some(start + (end - start) * t)
    }

    /// Samples per minibatch of a batch (or part) of `steps` samples: `minibatch_size`, or
    /// `steps / minibatches` rounded up where `minibatches` is set; at least 1, at most
    /// `steps`. The one rule both update paths and the benches use.
    pub fn minibatch_len(&self, steps: usize) -> usize {
        let len = match self.minibatches {
            Some(count) => steps.div_ceil(count.max(1)),
            None => self.minibatch_size,
        };
        len.min(steps).max(1)
    }

    /// Whether a fresh policy learns from logged purchases (`logged_prior`,
    /// `logged_pretrain_epochs`).
    pub fn wants_logs(&self) -> bool {
        self.recommender.wants_logs()
    }

    /// Checks the settings; the reason names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        self.validate_schedule()?;
        self.recommender
            .validate(self.update == UpdatePath::Fused, self.normalize_obs)?;
        self.validate_sizes()
    }

    /// The batch, the rates, the discounts, the clip and the entropy cap's schedule.
    fn validate_schedule(&self) -> Result<(), String> {
        if self.batch_steps == 0 || self.epochs == 0 || self.minibatch_size == 0 {
            return Err(
                "ppo.batch_steps, ppo.epochs and ppo.minibatch_size must be positive".into(),
            );
        }
        if self.minibatches == Some(0) {
            return Err("ppo.minibatches must be positive (or left out)".into());
        }
        for (key, lr) in [
            ("lr", self.lr),
            (
                "recommender.logged_pretrain_lr",
                self.recommender.logged_pretrain_lr,
            ),
        ] {
            if !(lr > 0.0 && lr.is_finite()) {
                return Err(format!("ppo.{key} must be positive, got {lr}"));
            }
        }
        if !(0.0..=1.0).contains(&self.gamma) || !(0.0..=1.0).contains(&self.gae_lambda) {
            return Err("ppo.gamma and ppo.gae_lambda must be in [0, 1]".into());
        }
        if self.clip.is_nan()
            || self.clip <= 0.0
            || self.max_grad_norm.is_nan()
            || self.max_grad_norm <= 0.0
        {
            return Err("ppo.clip and ppo.max_grad_norm must be positive".into());
        }
        for (key, v) in [
            ("entropy_log_std_max", self.entropy_log_std_max),
            ("entropy_log_std_final", self.entropy_log_std_final),
        ] {
            if v.is_some_and(|v| !v.is_finite()) {
                return Err(format!("ppo.{key} must be a finite number"));
            }
        }
        if !(0.0..1.0).contains(&self.entropy_cap_anneal_from) {
            return Err(format!(
                "ppo.entropy_cap_anneal_from must be in [0, 1), got {}",
                self.entropy_cap_anneal_from
            ));
        }
        if !(self.entropy_cap_anneal_to > self.entropy_cap_anneal_from
            && self.entropy_cap_anneal_to <= 1.0)
        {
            return Err(format!(
                "ppo.entropy_cap_anneal_to must be in (entropy_cap_anneal_from, 1], got {}",
                self.entropy_cap_anneal_to
            ));
        }
        Ok(())
    }

    /// The networks' and the batch's sizes against the limits a settings file may ask for.
    fn validate_sizes(&self) -> Result<(), String> {
        if self.hidden.is_empty() || self.hidden.contains(&0) {
            return Err("ppo.hidden needs at least one positive width".into());
        }
        let between = (self.hidden.windows(2).map(|w| w[0].saturating_mul(w[1])))
            .fold(0, usize::saturating_add);
        let widest = self.hidden.iter().copied().max().unwrap_or(0);
        if self.hidden.len() > MAX_LAYERS || widest > MAX_WIDTH || between > MAX_HIDDEN_WEIGHTS {
            return Err(format!(
                "ppo.hidden: at most {MAX_LAYERS} layers of at most {MAX_WIDTH} units and \
                 {MAX_HIDDEN_WEIGHTS} weights between them (MAX_HIDDEN_WEIGHTS), got {:?}",
                self.hidden
            ));
        }
        for (key, v, most) in [
            ("batch_steps", self.batch_steps, MAX_BATCH_STEPS),
            ("minibatch_size", self.minibatch_size, MAX_BATCH_STEPS),
            ("epochs", self.epochs, MAX_EPOCHS),
        ] {
            if v > most {
                return Err(format!("ppo.{key} is {v}, at most {most}"));
            }
        }
        if self.max_abs_reward.is_nan() || self.max_abs_reward <= 0.0 {
            return Err(format!(
                "ppo.max_abs_reward must be positive, got {}",
                self.max_abs_reward
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "ppo_tests.rs"]
mod tests;
