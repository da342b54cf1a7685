//! The PPO learner: ingests rollout fragments, updates the policy and critic once a batch
//! is complete, and publishes versioned policy snapshots.
//!
//! Staleness rules: a fragment whose policy version is more than `max_policy_lag` behind is
//! dropped (and counted). Fragments carry the embedding version that computed their `x`;
//! when a newer embedding version arrives, buffered fragments of older versions are
//! dropped (their `x` live in the old state-embedding space, which the critic and the new
//! fragments no longer share) and fragments of older versions that arrive later are dropped
//! too. Every drop is counted in the metrics.

use std::collections::HashMap;

use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor};
use jsae_embedder::nn::{self, BurnDevice, DeviceKind, RecordError};
use jsae_proto::{ActionBatch, EpisodeStat, PolicySnapshot, RolloutFragment, ValidationError};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use crate::PpoConfig;
use crate::gae::{GaeStep, gae};
use crate::normalise::RewardScaler;
use crate::policy::{Policy, PolicyHead};

/// Why the learner refused or dropped a fragment.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    /// The fragment is malformed.
    #[error("invalid fragment: {0}")]
    Invalid(#[from] ValidationError),
    /// Weights could not be serialised.
    #[error(transparent)]
    Record(#[from] RecordError),
}

/// What happened to an ingested fragment.
#[derive(Debug)]
pub enum Ingested {
    /// Kept for the next update.
    Buffered,
    /// Dropped: produced by a policy too many versions old.
    DroppedLag,
    /// Dropped: computed with an outdated embedding.
    DroppedEmbedding,
    /// It completed a batch: the policy was updated.
    Updated(Box<UpdateReport>),
}

/// Metrics of one update (one row of metrics.csv).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct UpdateMetrics {
    /// Update number, from 1.
    pub update: u64,
    /// Env steps of all actors so far.
    pub env_steps: u64,
    /// Steps in this update's batch.
    pub batch_steps: usize,
    /// Mean return of training episodes finished since the last update (None if none).
    pub return_mean: Option<f64>,
    /// Success rate of those episodes, where the environment has one.
    pub success_rate: Option<f64>,
    /// Episodes finished since the last update.
    pub episodes: usize,
    /// Mean policy lag of this batch's fragments.
    pub policy_lag_mean: f64,
    /// Largest policy lag of this batch's fragments.
    pub policy_lag_max: u64,
    /// Fragments dropped for lag so far.
    pub dropped_lag: u64,
    /// Fragments dropped for an outdated embedding so far.
    pub dropped_embedding: u64,
    /// Clipped surrogate loss (last epoch mean).
    pub policy_loss: f64,
    /// Value loss (last epoch mean).
    pub value_loss: f64,
    /// Entropy (last epoch mean).
    pub entropy: f64,
    /// Approximate KL between behaviour and updated policy (last epoch mean).
    pub approx_kl: f64,
    /// Fraction of samples whose ratio was clipped (last epoch mean).
    pub clip_frac: f64,
    /// Global gradient norm before clipping (mean).
    pub grad_norm: f64,
    /// Learning rate used.
    pub lr: f64,
    /// Epochs run (fewer than configured if the KL target stopped it).
    pub epochs: usize,
    /// Mean log-std of the Gaussian head (0 for categorical).
    pub log_std_mean: f64,
    /// Explained variance of the value predictions.
    pub explained_variance: f64,
    /// Embedding version of the batch.
    pub embedding_version: u64,
    /// New policy version.
    pub policy_version: u64,
}

/// An update's result: metrics and the new weights.
#[derive(Debug)]
pub struct UpdateReport {
    /// Metrics.
    pub metrics: UpdateMetrics,
    /// The new policy.
    pub snapshot: PolicySnapshot,
}

/// Lag accounting over a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LagStats {
    /// Sum of lags of accepted fragments.
    pub sum: u64,
    /// Accepted fragments.
    pub count: u64,
    /// Largest lag accepted.
    pub max: u64,
}

impl LagStats {
    /// Mean lag.
    pub fn mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum as f64 / self.count as f64
        }
    }
}

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
    inference_device: Device,
    optim: Adam,
    rng: ChaCha8Rng,
    version: u64,
    total_env_steps: u64,
    actor_steps: HashMap<u64, u64>,
    embedding_version: u64,
    pending: Vec<RolloutFragment>,
    pending_steps: usize,
    batch_lag: LagStats,
    run_lag: LagStats,
    dropped_lag: u64,
    dropped_embedding: u64,
    episodes: Vec<EpisodeStat>,
    reward_scaler: Option<RewardScaler>,
    updates: u64,
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
        let optim = AdamConfig::new().with_epsilon(1e-5).init();
        let reward_scaler = config
            .reward_scaling
            .then(|| RewardScaler::new(config.gamma, 10.0));
        Self {
            config,
            policy,
            inference_device: device.device(),
            optim: Adam(optim),
            rng,
            version: 0,
            total_env_steps,
            actor_steps: HashMap::new(),
            embedding_version: 0,
            pending: Vec::new(),
            pending_steps: 0,
            batch_lag: LagStats::default(),
            run_lag: LagStats::default(),
            dropped_lag: 0,
            dropped_embedding: 0,
            episodes: Vec::new(),
            reward_scaler,
            updates: 0,
        }
    }

    /// The learner of a run: its policy shape from the environment's spaces and the
    /// algorithm, one batch = one rollout round of all actors.
    pub fn for_run(config: &jsae_proto::settings::TrainConfig) -> Self {
        let (states, actions) = config.spaces();
        let (input, head) = crate::policy_shape(config, &states, &actions);
        let mut ppo = config.ppo.clone();
        ppo.batch_steps = config.round_steps();
        Self::new(
            ppo,
            input,
            head,
            config.env_steps,
            config.seed,
            config.device,
        )
    }

    /// The run's summary, from the evaluation report and this learner's counters.
    pub fn summary(
        &self,
        config: &jsae_proto::settings::TrainConfig,
        env_steps: u64,
        wall_seconds: f64,
        eval: &jsae_proto::EvalReport,
    ) -> crate::Summary {
        let meta = crate::RunMeta {
            env: config.env.as_str().into(),
            algo: config.algo.as_str().into(),
            seed: config.seed,
            device: config.device.as_str().into(),
        };
        crate::Summary::new(
            &meta,
            env_steps,
            wall_seconds,
            eval,
            self.updates(),
            self.lag(),
            self.dropped(),
            self.version(),
        )
    }

    /// Current policy version (0: initial weights).
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Env steps of all actors so far.
    pub fn env_steps(&self) -> u64 {
        self.actor_steps.values().sum()
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

    /// The space fragments' actions must be in.
    pub fn head(&self) -> PolicyHead {
        self.policy.head()
    }

    /// The current policy as a snapshot.
    pub fn snapshot(&self) -> Result<PolicySnapshot, RecordError> {
        Ok(PolicySnapshot {
            version: self.version,
            bytes: self
                .policy
                .for_inference(&self.inference_device)
                .to_bytes()?,
        })
    }

    /// Continues from a saved policy (a restarted learner): loads the weights and takes its
    /// version, so actors' versions stay meaningful, and its update count (one version per
    /// update), so metrics.csv goes on numbering. The optimiser state starts afresh.
    pub fn restore(&mut self, snapshot: &PolicySnapshot) -> Result<(), RecordError> {
        self.policy.load_bytes(&snapshot.bytes)?;
        self.version = snapshot.version;
        self.updates = self.updates.max(snapshot.version);
        Ok(())
    }

    /// Records an actor's step count (also carried by fragments).
    pub fn observe_actor_steps(&mut self, actor_id: u64, steps: u64) {
        let e = self.actor_steps.entry(actor_id).or_insert(0);
        *e = (*e).max(steps);
    }

    /// Validates a fragment and buffers it; runs an update when the batch is complete.
    pub fn ingest(&mut self, fragment: RolloutFragment) -> Result<Ingested, LearnerError> {
        fragment.validate(self.policy.input_dim(), &self.policy.head().action_space())?;
        self.observe_actor_steps(fragment.actor_id, fragment.actor_env_steps);
        self.episodes.extend_from_slice(&fragment.episodes);
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

    fn learning_rate(&self) -> f64 {
        if !self.config.anneal_lr || self.total_env_steps == 0 {
            return self.config.lr;
        }
        let done = self.env_steps().saturating_sub(self.pending_steps as u64) as f64;
        let frac = (1.0 - done / self.total_env_steps as f64).clamp(0.0, 1.0);
        self.config.lr * frac.max(1e-3)
    }

    fn update(&mut self) -> Result<UpdateReport, LearnerError> {
        let fragments = std::mem::take(&mut self.pending);
        let batch_steps = self.pending_steps;
        self.pending_steps = 0;
        let lr = self.learning_rate();
        let batch = Batch::build(
            &self.policy,
            fragments,
            &self.config,
            self.reward_scaler.as_mut(),
        );
        let metrics = self.optimise(&batch, lr);
        // After the update: the actors' next rollouts use these statistics with these weights.
        self.policy.update_obs_stats(&batch.x);
        self.version += 1;
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

    fn optimise(&mut self, batch: &Batch, lr: f64) -> UpdateMetrics {
        let n = batch.len();
        let device = self.policy.device().clone();
        let mut order: Vec<usize> = (0..n).collect();
        let mb = self.config.minibatch_size.min(n).max(1);
        let clip = self.config.clip as f32;
        let (mut grad_sum, mut grad_count) = (0.0, 0);
        let mut last = EpochStats::default();
        let mut epochs = 0;
        for _ in 0..self.config.epochs {
            order.shuffle(&mut self.rng);
            let mut stats = EpochStats::default();
            for rows in order.chunks(mb) {
                let m = batch.minibatch(rows, self.config.norm_adv, &device);
                let eval = self.policy.evaluate(m.x, &m.actions);
                let log_ratio = eval.logp - m.old_logp;
                let pg_loss = clipped_surrogate_loss(log_ratio.clone(), m.adv, clip);
                let v_loss = if self.config.clip_value_loss {
                    let unclipped = (eval.value.clone() - m.returns.clone()).square();
                    let clipped_v =
                        m.old_values.clone() + (eval.value - m.old_values).clamp(-clip, clip);
                    let clipped = (clipped_v - m.returns).square();
                    unclipped.max_pair(clipped).mean().mul_scalar(0.5)
                } else {
                    (eval.value - m.returns).square().mean().mul_scalar(0.5)
                };
                let entropy = eval.entropy.mean();
                let loss = pg_loss.clone()
                    - entropy.clone().mul_scalar(self.config.ent_coef as f32)
                    + v_loss.clone().mul_scalar(self.config.vf_coef as f32);
                let mut grads = GradientsParams::from_grads(loss.backward(), self.policy.net());
                let norm = nn::clip_global_grad_norm(
                    self.policy.net(),
                    &mut grads,
                    self.config.max_grad_norm,
                );
                grad_sum += f64::from(norm);
                grad_count += 1;
                let net = self.optim.0.step(lr, self.policy.net().clone(), grads);
                self.policy.set_net(net);
                let lr_host = nn::to_vec(log_ratio.detach());
                stats.add(
                    &lr_host,
                    clip,
                    pg_loss.into_scalar::<f32>(),
                    v_loss.into_scalar::<f32>(),
                    entropy.into_scalar::<f32>(),
                );
            }
            epochs += 1;
            last = stats;
            if self
                .config
                .target_kl
                .is_some_and(|target| last.approx_kl() > target)
            {
                break;
            }
        }
        let log_std = match self.policy.head() {
            PolicyHead::Gaussian { .. } => {
                let v = self.policy.log_std_values();
                f64::from(v.iter().sum::<f32>()) / v.len().max(1) as f64
            }
            PolicyHead::Categorical { .. } => 0.0,
        };
        UpdateMetrics {
            policy_loss: last.mean(last.pg),
            value_loss: last.mean(last.v),
            entropy: last.mean(last.ent),
            approx_kl: last.approx_kl(),
            clip_frac: last.clip_frac(),
            grad_norm: grad_sum / f64::from(grad_count.max(1)),
            epochs,
            log_std_mean: log_std,
            explained_variance: batch.explained_variance(),
            ..UpdateMetrics::default()
        }
    }
}

/// PPO's clipped surrogate: `mean(max(-A r, -A clip(r, 1-c, 1+c)))` with
/// `r = exp(log_ratio)`, all `[batch]`.
pub fn clipped_surrogate_loss(log_ratio: Tensor<1>, adv: Tensor<1>, clip: f32) -> Tensor<1> {
    let ratio = log_ratio.exp();
    let unclipped = ratio.clone() * adv.clone().neg();
    let clipped = ratio.clamp(1.0 - clip, 1.0 + clip) * adv.neg();
    unclipped.max_pair(clipped).mean()
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

#[derive(Debug, Default)]
struct EpochStats {
    pg: f64,
    v: f64,
    ent: f64,
    kl: f64,
    clipped: f64,
    samples: f64,
    minibatches: f64,
}

impl EpochStats {
    fn add(&mut self, log_ratio: &[f32], clip: f32, pg: f32, v: f32, ent: f32) {
        for &lr in log_ratio {
            let r = lr.exp();
            self.kl += f64::from((r - 1.0) - lr);
            if (r - 1.0).abs() > clip {
                self.clipped += 1.0;
            }
        }
        self.samples += log_ratio.len() as f64;
        self.pg += f64::from(pg);
        self.v += f64::from(v);
        self.ent += f64::from(ent);
        self.minibatches += 1.0;
    }

    fn mean(&self, sum: f64) -> f64 {
        sum / self.minibatches.max(1.0)
    }

    fn approx_kl(&self) -> f64 {
        self.kl / self.samples.max(1.0)
    }

    fn clip_frac(&self) -> f64 {
        self.clipped / self.samples.max(1.0)
    }
}

/// A batch flattened for minibatching: `[n]` rows of x, actions, old log-probs, advantages,
/// returns and old values.
struct Batch {
    x_dim: usize,
    x: Vec<f32>,
    actions: ActionBatch,
    logp: Vec<f32>,
    adv: Vec<f32>,
    returns: Vec<f32>,
    values: Vec<f32>,
}

struct Minibatch {
    x: Tensor<2>,
    actions: ActionBatch,
    old_logp: Tensor<1>,
    adv: Tensor<1>,
    returns: Tensor<1>,
    old_values: Tensor<1>,
}

impl Batch {
    fn build(
        policy: &Policy,
        fragments: Vec<RolloutFragment>,
        config: &PpoConfig,
        mut scaler: Option<&mut RewardScaler>,
    ) -> Self {
        let x_dim = policy.input_dim();
        // One critic pass over every x, truncation bootstrap x and tail x.
        let mut all_x = Vec::new();
        for f in &fragments {
            all_x.extend_from_slice(&f.x);
            all_x.extend_from_slice(&f.truncated_next_x);
            all_x.extend_from_slice(&f.last_next_x);
        }
        let rows = all_x.len() / x_dim.max(1);
        let critic = policy.for_inference(&policy.device().clone().inner());
        let values = nn::to_vec(critic.value(nn::tensor2(all_x, rows, x_dim, critic.device())));

        let mut out = Batch {
            x_dim,
            x: Vec::new(),
            actions: match &fragments.first().map(|f| &f.actions) {
                Some(ActionBatch::Continuous { dim, .. }) => ActionBatch::Continuous {
                    dim: *dim,
                    data: Vec::new(),
                },
                _ => ActionBatch::Discrete(Vec::new()),
            },
            logp: Vec::new(),
            adv: Vec::new(),
            returns: Vec::new(),
            values: Vec::new(),
        };
        let mut offset = 0;
        for mut f in fragments {
            let t_len = f.len();
            let cuts = f.truncated.iter().filter(|&&t| t).count();
            let v = &values[offset..offset + t_len];
            let cut_v = &values[offset + t_len..offset + t_len + cuts];
            let tail_v = values[offset + t_len + cuts];
            offset += t_len + cuts + 1;
            let ends: Vec<bool> = f
                .terminated
                .iter()
                .zip(&f.truncated)
                .map(|(a, b)| *a || *b)
                .collect();
            if let Some(s) = scaler.as_deref_mut() {
                s.scale((f.actor_id, f.env_index), &mut f.rewards, &ends);
            }
            let mut cut = 0;
            let steps: Vec<GaeStep> = (0..t_len)
                .map(|t| {
                    let next_value = if f.truncated[t] {
                        cut += 1;
                        cut_v[cut - 1]
                    } else if t + 1 < t_len {
                        v[t + 1]
                    } else {
                        tail_v
                    };
                    GaeStep {
                        reward: f.rewards[t],
                        value: v[t],
                        next_value,
                        terminated: f.terminated[t],
                        episode_end: ends[t],
                    }
                })
                .collect();
            let (adv, ret) = gae(&steps, config.gamma as f32, config.gae_lambda as f32);
            out.x.extend_from_slice(&f.x);
            out.actions.extend_from(&f.actions);
            out.logp.extend_from_slice(&f.logp);
            out.adv.extend(adv);
            out.returns.extend(ret);
            out.values.extend_from_slice(v);
        }
        out
    }

    fn len(&self) -> usize {
        self.logp.len()
    }

    fn explained_variance(&self) -> f64 {
        let n = self.returns.len().max(1) as f64;
        let mean = |v: &[f32]| v.iter().map(|&a| f64::from(a)).sum::<f64>() / n;
        let var =
            |v: &[f32], m: f64| v.iter().map(|&a| (f64::from(a) - m).powi(2)).sum::<f64>() / n;
        let diff: Vec<f32> = self
            .returns
            .iter()
            .zip(&self.values)
            .map(|(r, v)| r - v)
            .collect();
        let var_ret = var(&self.returns, mean(&self.returns));
        if var_ret <= 0.0 {
            return 0.0;
        }
        1.0 - var(&diff, mean(&diff)) / var_ret
    }

    fn minibatch(&self, rows: &[usize], norm_adv: bool, device: &Device) -> Minibatch {
        let d = self.x_dim;
        let mut x = Vec::with_capacity(rows.len() * d);
        let mut actions = match &self.actions {
            ActionBatch::Discrete(_) => ActionBatch::Discrete(Vec::with_capacity(rows.len())),
            ActionBatch::Continuous { dim, .. } => ActionBatch::Continuous {
                dim: *dim,
                data: Vec::with_capacity(rows.len() * dim),
            },
        };
        let pick = |v: &[f32]| rows.iter().map(|&r| v[r]).collect::<Vec<f32>>();
        for &r in rows {
            x.extend_from_slice(&self.x[r * d..(r + 1) * d]);
            actions.push_row_of(&self.actions, r);
        }
        let mut adv = pick(&self.adv);
        if norm_adv && adv.len() > 1 {
            let n = adv.len() as f32;
            let mean = adv.iter().sum::<f32>() / n;
            let std = (adv.iter().map(|a| (a - mean).powi(2)).sum::<f32>() / (n - 1.0)).sqrt();
            adv.iter_mut().for_each(|a| *a = (*a - mean) / (std + 1e-8));
        }
        Minibatch {
            x: nn::tensor2(x, rows.len(), d, device),
            actions,
            old_logp: nn::tensor1(pick(&self.logp), device),
            adv: nn::tensor1(adv, device),
            returns: nn::tensor1(pick(&self.returns), device),
            old_values: nn::tensor1(pick(&self.values), device),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipped_surrogate_matches_hand_computed_values() {
        let device = DeviceKind::Flex.device();
        // ratios 1.5, 0.5, 1.1, 0.7 with advantages 1, 1, -2, -1 and clip 0.2:
        //  1.5, A=1:  max(-1.5, -1.2) = -1.2
        //  0.5, A=1:  max(-0.5, -0.8) = -0.5
        //  1.1, A=-2: max(2.2, 2.2)   =  2.2
        //  0.7, A=-1: max(0.7, 0.8)   =  0.8
        // mean = (-1.2 - 0.5 + 2.2 + 0.8) / 4 = 0.325
        let ratios: [f32; 4] = [1.5, 0.5, 1.1, 0.7];
        let log_ratio = nn::tensor1(ratios.iter().map(|r| r.ln()).collect(), &device);
        let adv = nn::tensor1(vec![1.0, 1.0, -2.0, -1.0], &device);
        let loss = clipped_surrogate_loss(log_ratio, adv, 0.2).into_scalar::<f32>();
        assert!((loss - 0.325).abs() < 1e-5, "{loss}");
    }
}
