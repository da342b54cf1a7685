//! The PPO learner: ingests rollout fragments, updates the policy and critic once a batch
//! is complete, and publishes versioned policy snapshots.
//!
//! Staleness rules: a fragment whose policy version is more than `max_policy_lag` behind is
//! dropped (and counted). Fragments carry the embedding version that computed their `x`;
//! when a newer embedding version arrives, buffered fragments of older versions are
//! dropped (their `x` live in the old state-embedding space, which the critic and the new
//! fragments no longer share) and fragments of older versions that arrive later are dropped
//! too. Every drop is counted in the metrics.
//!
//! Fragments whose rewards exceed `ppo.max_abs_reward` in magnitude are refused (with the
//! other malformed ones), and the run's env steps are credited from the fragments' claims,
//! never beyond the steps they deliver (`credits`).
//!
//! Layout: the learner and its buffer with the staleness rules (here), `credits` (the env
//! steps credited per actor incarnation), `batch` (fragments to a flat batch with GAE, and
//! minibatches), `update` (the PPO update and its burn path), `fused_update` (its host path,
//! the default), `report` (what ingesting and updating report), `saved_state` (what a
//! checkpoint carries besides the weights) in `state_codec`'s layout.

mod batch;
#[cfg(test)]
mod bounds_tests;
mod credits;
mod fused_update;
mod pretrain;
mod report;
#[cfg(test)]
mod resume_tests;
mod saved_state;
mod state_codec;
#[cfg(test)]
mod tests;
mod update;

use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::tensor::Device;
use jsae_nn::{BurnDevice, DeviceKind, RecordError};
use jsae_wire::{EpisodeStat, FragmentBounds, PolicySnapshot, RolloutFragment};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::PpoConfig;
use crate::fused::HostPolicy;
use crate::normalise::RewardScaler;
use crate::visits::VisitBonus;
use batch::{Batch, BatchBuffers};
pub use credits::ClaimWentBack;
use credits::StepCredits;
use fused_update::FusedState;
use jsae_agent::{CountPrior, Policy, PolicyHead, PolicyPrior};
pub use pretrain::{LoggedPurchases, PretrainReport};
pub use report::{Ingested, LagStats, LearnerError, UpdateMetrics, UpdateReport};
pub use state_codec::StateError;
pub use update::clipped_surrogate_loss;

/// Adam's epsilon, on both update paths.
const ADAM_EPSILON: f32 = 1e-5;

struct Adam(ModuleOptimizer);

impl std::fmt::Debug for Adam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Adam")
    }
}

/// The PPO learner's whole state.
#[derive(Debug)]
pub struct Learner {
    config: PpoConfig,
    policy: Policy,
    /// The count prior the policy's logits add (`ppo.recommender.logged_prior`), beside it.
    prior: PolicyPrior,
    inference_device: Device,
    optim: Adam,
    fused: FusedState,
    buffers: BatchBuffers,
    rng: ChaCha8Rng,
    version: u64,
    total_env_steps: u64,
    /// The env steps credited to each actor incarnation's claims.
    credits: StepCredits,
    embedding_version: u64,
    /// The embedding version of the last update's batch (0: no update yet in this process).
    trained_embedding_version: u64,
    pending: Vec<RolloutFragment>,
    pending_steps: usize,
    batch_lag: LagStats,
    run_lag: LagStats,
    dropped_lag: u64,
    dropped_embedding: u64,
    episodes: Vec<EpisodeStat>,
    reward_scaler: Option<RewardScaler>,
    updates: u64,
    /// Updates whose weights came out not finite, undone (the weights before them kept).
    updates_refused: u64,
    /// The exploration bonus's visit counts over all actors (`exploration.bonus`; None: off).
    visits: Option<VisitBonus>,
}

impl Learner {
    /// A learner for policy inputs of width `input` and the given head; `total_env_steps`
    /// is the run's budget (for learning-rate annealing).
    pub fn new(
        config: PpoConfig,
        input: usize,
        head: PolicyHead,
        total_env_steps: u64,
        seed: u64,
        device: DeviceKind,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6c65_6172_6e65_7200);
        let policy = Policy::new(&config, input, head, &mut rng, &device.train_device());
        let optim = AdamConfig::new().with_epsilon(ADAM_EPSILON).init();
        let reward_scaler = config
            .reward_scaling
            .then(|| RewardScaler::new(config.gamma, 10.0));
        Self {
            prior: PolicyPrior::new(&config),
            config,
            policy,
            inference_device: device.device(),
            optim: Adam(optim),
            fused: FusedState::new(),
            buffers: BatchBuffers::default(),
            rng,
            version: 0,
            total_env_steps,
            credits: StepCredits::new(0),
            embedding_version: 0,
            trained_embedding_version: 0,
            pending: Vec::new(),
            pending_steps: 0,
            batch_lag: LagStats::default(),
            run_lag: LagStats::default(),
            dropped_lag: 0,
            dropped_embedding: 0,
            episodes: Vec::new(),
            reward_scaler,
            updates: 0,
            updates_refused: 0,
            visits: None,
        }
    }

    /// The learner of a run: its policy shape from the environment's spaces and the
    /// algorithm, one batch = one rollout round of the run's actors
    /// ([`jsae_settings::TrainConfig::round_steps`]).
    pub fn for_run(config: &jsae_settings::TrainConfig) -> Self {
        let (states, actions) = config.spaces();
        let (input, head) = jsae_agent::policy_shape(config, &states, &actions);
        let mut ppo = config.ppo.clone();
        ppo.batch_steps = config.round_steps();
        let mut learner = Self::new(
            ppo,
            input,
            head,
            config.env_steps,
            config.seed,
            config.device,
        );
        learner.credits = StepCredits::new(config.random_play_allowance());
        learner.visits = VisitBonus::new(config.exploration.bonus);
        learner
    }

    /// The run's summary, from the evaluation report and this learner's counters.
    pub fn summary(
        &self,
        config: &jsae_settings::TrainConfig,
        env_steps: u64,
        wall_seconds: f64,
        eval: &jsae_wire::EvalReport,
    ) -> jsae_run_dir::Summary {
        let meta = jsae_run_dir::RunMeta {
            env: config.env.as_str().into(),
            algo: config.algo.as_str().into(),
            seed: config.seed,
            device: config.device.as_str().into(),
        };
        jsae_run_dir::Summary::new(
            &meta,
            env_steps,
            wall_seconds,
            eval,
            self.updates(),
            (self.lag().mean(), self.lag().max),
            self.dropped(),
            self.version(),
        )
    }

    /// Current policy version (0: initial weights).
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Env steps of all actors so far: the steps credited to their fragments' claims
    /// (`credits`), and those of earlier processes.
    pub fn env_steps(&self) -> u64 {
        self.credits.total()
    }

    /// Counts on from `steps` env steps taken before (`jsae train --resume` from a checkpoint
    /// without training state: the run's actors start again from zero).
    pub fn count_steps_from(&mut self, steps: u64) {
        self.credits.count_from(steps);
    }

    /// The embedding version the current policy's last update was trained on (0: no update
    /// yet in this process). The newest one seen ([`Self::embedding_version`]) can be newer:
    /// its fragments wait for the next batch.
    pub fn trained_embedding_version(&self) -> u64 {
        self.trained_embedding_version
    }

    /// The newest embedding version of the fragments (0: none yet, or no embedding).
    pub fn embedding_version(&self) -> u64 {
        self.embedding_version
    }

    /// Lag statistics over the run.
    pub fn lag(&self) -> &LagStats {
        &self.run_lag
    }

    /// Updates done.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Fragments dropped for lag and for an outdated embedding.
    pub fn dropped(&self) -> (u64, u64) {
        (self.dropped_lag, self.dropped_embedding)
    }

    /// The policy (training device).
    pub fn policy(&self) -> &Policy {
        &self.policy
    }

    /// The count prior the policy's logits add (None unless `ppo.recommender.logged_prior` and counted).
    pub fn prior(&self) -> Option<&CountPrior> {
        self.prior.get()
    }

    /// The policy on the host, with its prior, as the fused update trains it.
    pub fn host_policy(&self) -> HostPolicy {
        HostPolicy::from_policy(&self.policy, self.prior.shared())
    }

    /// The space fragments' actions must be in.
    pub fn head(&self) -> PolicyHead {
        self.policy.head()
    }

    /// The current policy as a snapshot.
    pub fn snapshot(&self) -> Result<PolicySnapshot, RecordError> {
        Ok(PolicySnapshot {
            version: self.version,
            bytes: self
                .prior
                .encode(&self.policy.for_inference(&self.inference_device))?,
        })
    }

    /// Continues from a saved policy: loads the weights and takes its version, so actors'
    /// versions stay meaningful, and its update count (one version per update), so
    /// metrics.csv goes on numbering. The optimiser state starts afresh ([`Self::resume`]
    /// restores it too, from a checkpoint).
    pub fn restore(&mut self, snapshot: &PolicySnapshot) -> Result<(), RecordError> {
        self.prior.decode(&mut self.policy, &snapshot.bytes)?;
        self.version = snapshot.version;
        self.updates = self.updates.max(snapshot.version);
        self.optim = Adam(AdamConfig::new().with_epsilon(ADAM_EPSILON).init());
        self.fused = FusedState::new();
        Ok(())
    }

    /// Starts from another run's policy weights (`--init-from`): loads them (their shape
    /// must match this run's policy) and keeps this run's version line and counters.
    pub fn warm_start(&mut self, policy_bytes: &[u8]) -> Result<(), RecordError> {
        self.prior.decode(&mut self.policy, policy_bytes)?;
        self.fused = FusedState::new();
        Ok(())
    }

    /// Credits an actor incarnation with `steps` env steps in all, trusted: for a caller that
    /// steps its actors itself (the one-process driver), not for fragments from elsewhere,
    /// whose claims [`Self::ingest`] checks.
    pub fn observe_actor_steps(&mut self, actor_id: u64, incarnation: u64, steps: u64) {
        self.credits.trust(actor_id, incarnation, steps);
    }

    /// What a fragment may carry: this policy's input width and action space, rewards within
    /// `ppo.max_abs_reward`, log-probabilities the head can give.
    pub fn fragment_bounds(&self) -> FragmentBounds {
        let head = self.policy.head();
        FragmentBounds {
            x_dim: self.policy.input_dim(),
            actions: head.action_space(),
            max_abs_reward: self.config.max_abs_reward,
            logp: head.behaviour_logp_range(),
            // the environment is the service's to know (`LearnerService`)
            max_episode_steps: u32::MAX,
        }
    }

    /// Validates a fragment ([`Self::fragment_bounds`]; a step claim that does not go back)
    /// and buffers it, crediting its env steps and adding the exploration bonus of its
    /// visits (counted over all actors); runs an update when the batch is complete. An
    /// update that leaves weights not finite is undone (the weights before it are kept, and
    /// published again under the next version).
    pub fn ingest(&mut self, mut fragment: RolloutFragment) -> Result<Ingested, LearnerError> {
        fragment.validate(&self.fragment_bounds())?;
        self.credits.credit(
            fragment.actor_id,
            fragment.actor_incarnation,
            fragment.actor_env_steps,
            fragment.len() as u64,
        )?;
        if let Some(visits) = self.visits.as_mut() {
            visits.apply(&mut fragment);
        }
        let lag = self.version.saturating_sub(fragment.policy_version);
        if lag > self.config.max_policy_lag {
            self.dropped_lag += 1;
            return Ok(Ingested::DroppedLag);
        }
        if fragment.embedding_version < self.embedding_version {
            self.dropped_embedding += 1;
            return Ok(Ingested::DroppedEmbedding);
        }
        if fragment.embedding_version > self.embedding_version {
            self.embedding_version = fragment.embedding_version;
            self.dropped_embedding += self.pending.len() as u64;
            self.pending.clear();
            self.pending_steps = 0;
            self.batch_lag = LagStats::default();
        }
        // the episodes of kept fragments only: what is held waits for the batch, bounded by it
        self.episodes.extend_from_slice(&fragment.episodes);
        for stats in [&mut self.batch_lag, &mut self.run_lag] {
            stats.sum += lag;
            stats.count += 1;
            stats.max = stats.max.max(lag);
        }
        self.pending_steps += fragment.len();
        self.pending.push(fragment);
        if self.pending_steps < self.config.batch_steps {
            return Ok(Ingested::Buffered);
        }
        let report = self.update()?;
        Ok(Ingested::Updated(Box::new(report)))
    }

    /// Env steps buffered towards the next update.
    pub fn pending_steps(&self) -> usize {
        self.pending_steps
    }

    /// The env steps of the next batch (the learner service sets it to its actors' rollouts,
    /// or their shares of a shared batch, as actors come and go); updates at once, with the
    /// report, when what is buffered already makes the new batch.
    pub fn set_batch_steps(&mut self, steps: usize) -> Result<Option<UpdateReport>, LearnerError> {
        self.config.batch_steps = steps.max(1);
        if self.pending.is_empty() || self.pending_steps < self.config.batch_steps {
            return Ok(None);
        }
        self.update().map(Some)
    }

    /// Updates on what is buffered, however short of the batch (a round whose missing
    /// actors are overdue); None when nothing is.
    pub fn close_round(&mut self) -> Result<Option<UpdateReport>, LearnerError> {
        if self.pending.is_empty() {
            return Ok(None);
        }
        self.update().map(Some)
    }

    fn learning_rate(&self) -> f64 {
        if !self.config.anneal_lr || self.total_env_steps == 0 {
            return self.config.lr;
        }
        let done = self.env_steps().saturating_sub(self.pending_steps as u64) as f64;
        let frac = (1.0 - done / self.total_env_steps as f64).clamp(0.0, 1.0);
        self.config.lr * frac.max(1e-3)
    }

    /// The entropy bonus's cap for the update of the batch now buffered (it falls over the
    /// run's last part: `PpoConfig::entropy_log_std_cap_at`); None without a step budget.
    fn entropy_log_std_cap(&self) -> Option<f32> {
        if self.total_env_steps == 0 {
            return None;
        }
        let progress = self.env_steps() as f64 / self.total_env_steps as f64;
        self.config.entropy_log_std_cap_at(progress.min(1.0))
    }

    fn update(&mut self) -> Result<UpdateReport, LearnerError> {
        let fragments = std::mem::take(&mut self.pending);
        let batch_steps = self.pending_steps;
        self.pending_steps = 0;
        let lr = self.learning_rate();
        let std_cap = self.entropy_log_std_cap();
        if let Some(cap) = std_cap {
            self.policy.hold_log_std(cap);
        }
        // what the update starts from, kept should it end in weights that are not finite
        let before = (self.policy.clone(), self.fused.adam_moments());
        let mut metrics = UpdateMetrics::default();
        let mut epochs = 0;
        for part in split_batch(fragments, self.config.max_update_steps) {
            let batch = Batch::build(
                &self.policy,
                part,
                &self.config,
                self.reward_scaler.as_mut(),
                &mut self.buffers,
            );
            metrics = self.optimise(&batch, lr);
            epochs += metrics.epochs;
            // After the update: the actors' next rollouts use these statistics with these
            // weights.
            self.policy.update_obs_stats(&batch.x);
            self.buffers.recycle(batch);
        }
        if let Some(cap) = std_cap {
            // the policy gradient may have pushed the std past the cap in this update
            self.policy.hold_log_std(cap);
        }
        let non_finite = jsae_nn::non_finite_values(self.policy.net());
        if non_finite > 0 {
            let (policy, moments) = before;
            self.policy = policy;
            self.fused.set_adam_moments(moments);
            self.optim = Adam(AdamConfig::new().with_epsilon(ADAM_EPSILON).init());
            self.updates_refused += 1;
            tracing::warn!(
                "update {}: {non_finite} weights were NaN or infinite after it (policy loss \
                 {:.4e}, grad norm {:.4e}): the last finite weights are kept and published again \
                 under the next version, and this batch is lost ({} updates refused so far)",
                self.updates + 1,
                metrics.policy_loss,
                metrics.grad_norm,
                self.updates_refused
            );
        }
        metrics.log_std_mean = match self.policy.head() {
            PolicyHead::Gaussian { .. } => {
                let v = self.policy.log_std_values();
                f64::from(v.iter().sum::<f32>()) / v.len().max(1) as f64
            }
            PolicyHead::Categorical { .. } => 0.0,
        };
        metrics.epochs = epochs;
        self.version += 1;
        self.trained_embedding_version = self.embedding_version;
        self.updates += 1;
        let episodes = std::mem::take(&mut self.episodes);
        let lag = std::mem::take(&mut self.batch_lag);
        let (return_mean, success_rate) = episode_means(&episodes);
        let metrics = UpdateMetrics {
            update: self.updates,
            env_steps: self.env_steps(),
            batch_steps,
            return_mean,
            success_rate,
            episodes: episodes.len(),
            policy_lag_mean: lag.mean(),
            policy_lag_max: lag.max,
            dropped_lag: self.dropped_lag,
            dropped_embedding: self.dropped_embedding,
            lr,
            embedding_version: self.embedding_version,
            policy_version: self.version,
            ..metrics
        };
        Ok(UpdateReport {
            metrics,
            snapshot: self.snapshot()?,
        })
    }
}

/// A batch's fragments in consecutive parts of at least `max` steps each (the last takes
/// what remains when less than `max` would be left over), in arrival order; the whole batch
/// when `max` is None.
fn split_batch(fragments: Vec<RolloutFragment>, max: Option<usize>) -> Vec<Vec<RolloutFragment>> {
    let Some(max) = max.filter(|&m| m > 0) else {
        return vec![fragments];
    };
    let total: usize = fragments.iter().map(RolloutFragment::len).sum();
    let mut parts = vec![Vec::new()];
    let (mut in_part, mut left) = (0, total);
    for f in fragments {
        // a new part once this one is full, unless what is left would make a short last one
        if in_part >= max && left >= max {
            parts.push(Vec::new());
            in_part = 0;
        }
        in_part += f.len();
        left -= f.len();
        if let Some(part) = parts.last_mut() {
            part.push(f);
        }
    }
    parts
}

fn episode_means(episodes: &[EpisodeStat]) -> (Option<f64>, Option<f64>) {
    if episodes.is_empty() {
        return (None, None);
    }
    let n = episodes.len() as f64;
    let ret = episodes.iter().map(|e| e.ret).sum::<f64>() / n;
    let successes: Vec<bool> = episodes.iter().filter_map(|e| e.success).collect();
    let success = (!successes.is_empty())
        .then(|| successes.iter().filter(|&&s| s).count() as f64 / successes.len() as f64);
    (Some(ret), success)
}
