//! The embedder's training loop: collect uniformly random transitions, pre-train phi/g/T/f
//! on them, then keep training on the replay buffer on a schedule; every finished round
//! publishes a new versioned snapshot. The model is any [`RepresentationModel`] (JSAE's by
//! default).

use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, AdamWConfig, ModuleOptimizer};
use jsae_run_dir::InitSource;
use jsae_settings::{Representation, TrainConfig};
use jsae_wire::{ActionSpace, EmbeddingSnapshot, StateSpace, TransitionBatch, ValidationError};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

mod logged;
mod logged_estimate;
mod logged_lookahead;

pub use logged_estimate::CountedEstimate;
pub use logged_lookahead::LookaheadEstimate;

pub use logged::{LoggedItems, LoggedReport};

use crate::pretrain_progress::{PretrainObserver, PretrainProgress};
use crate::replay::Replay;
use crate::representation::{RepresentationModel, TrainingModel};
use crate::structure::ActionStructure;
use crate::{EmbeddingConfig, EmbeddingTraining};
use jsae_agent::EmbeddingModel;
use jsae_nn::{self as nn, BurnDevice, DeviceKind};

/// What the trainer has done so far.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EmbedderStats {
    /// Published snapshot version (0: none yet).
    pub version: u64,
    /// Minibatch steps taken.
    pub steps: u64,
    /// Mean model loss (-log P(s'|s,a) or MSE) of the last round.
    pub model_loss: f32,
    /// Mean decoder loss of the last round (0 for discrete actions).
    pub decoder_loss: f32,
    /// Transitions received.
    pub transitions: u64,
    /// Transitions the replay buffer dropped to make room.
    pub overwritten: u64,
    /// The action embeddings' structure at the last snapshot ([`ActionStructure`]; None
    /// where the environment gives no action displacements).
    pub action_structure: Option<f32>,
}

/// Owns the representation model (JSAE's by default), its optimiser and the replay buffer.
#[derive(Debug)]
pub struct EmbedderTrainer<M: RepresentationModel = TrainingModel> {
    config: EmbeddingConfig,
    model: M,
    optim: OptimDebug,
    replay: Replay,
    rng: ChaCha8Rng,
    since_update: usize,
    /// No more continuous updates ([`EmbedderTrainer::hold`]).
    held: bool,
    stats: EmbedderStats,
    structure: Option<ActionStructure>,
    pretrain_observer: Option<PretrainObserver>,
    /// Logged purchases for the pre-training's first passes ([`logged`]).
    logged: Option<std::sync::Arc<LoggedItems>>,
}

/// The optimiser (burn's has no `Debug`).
struct OptimDebug(ModuleOptimizer);

impl std::fmt::Debug for OptimDebug {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Adam")
    }
}

impl EmbedderTrainer {
    /// The trainer of a run: its embedding settings, representation, seed and device, with
    /// the environment's action motions measured where it has them.
    pub fn for_run(config: &TrainConfig, states: &StateSpace, actions: &ActionSpace) -> Self {
        Self::new(
            config.embedding.clone(),
            config.algo.representation(),
            states,
            actions,
            config.seed,
            config.device,
        )
        .with_action_motions(config.env.action_motions(&config.environment))
    }

    /// A trainer with a freshly initialised model of `representation`.
    pub fn new(
        config: EmbeddingConfig,
        representation: Representation,
        states: &StateSpace,
        actions: &ActionSpace,
        seed: u64,
        device: DeviceKind,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x656d_6265_6464_6572);
        let model = EmbeddingModel::new(
            &config,
            representation,
            states,
            actions,
            &mut rng,
            &device.train_device(),
        );
        Self::with_model(config, TrainingModel::new(model, seed), rng)
    }

    /// Warm-starts the model from another run's newest embedding (`--init-from`): every part
    /// whose shape matches is copied ([`EmbeddingModel::warm_start_from`]); pre-training still
    /// runs, so parts that did not carry over (g for a new action space) are fitted around the
    /// ones that did. Returns the parts copied.
    pub fn warm_start(&mut self, source: &InitSource) -> Result<Vec<&'static str>, String> {
        let bytes = source
            .embedding
            .as_ref()
            .ok_or_else(|| format!("{}: no embedding checkpoint", source.dir.display()))?;
        let (states, actions) = source.config.spaces();
        let mut from = EmbeddingModel::new(
            &source.config.embedding,
            source.config.algo.representation(),
            &states,
            &actions,
            &mut ChaCha8Rng::seed_from_u64(0),
            &self.model.device().clone(),
        );
        from.load_bytes(bytes)
            .map_err(|e| format!("{}: {e}", source.dir.display()))?;
        let copied = self.model.warm_start_from(&from);
        self.model.tables_from_model();
        Ok(copied)
    }
}

impl<M: RepresentationModel> EmbedderTrainer<M> {
    /// A trainer for `model` (on the training device), drawing minibatches with `rng`.
    pub fn with_model(config: EmbeddingConfig, model: M, rng: ChaCha8Rng) -> Self {
        let optim = if config.decoupled_weight_decay {
            AdamWConfig::new()
                .with_epsilon(1e-8)
                .with_weight_decay(config.weight_decay)
                .init()
        } else {
            AdamConfig::new()
                .with_epsilon(1e-8)
                .with_weight_decay(Some(WeightDecayConfig::new(config.weight_decay)))
                .init()
        };
        Self {
            replay: Replay::new(
                config.replay_capacity,
                model.state_space(),
                model.action_space(),
            ),
            config,
            model,
            optim: OptimDebug(optim),
            rng,
            since_update: 0,
            held: false,
            stats: EmbedderStats::default(),
            structure: None,
            pretrain_observer: None,
            logged: None,
        }
    }

    /// Hands every pass of pre-training to `observe` (a progress bar), besides the log.
    pub fn observe_pretraining(&mut self, observe: impl FnMut(&PretrainProgress) + Send + 'static) {
        self.pretrain_observer = Some(PretrainObserver(Box::new(observe)));
    }

    /// Measures every snapshot's action embeddings against each action's true displacement
    /// (`jsae_settings::EnvName::action_motions`); None leaves it unmeasured.
    pub fn with_action_motions(mut self, motions: Option<Vec<[f64; 2]>>) -> Self {
        self.structure = motions.and_then(ActionStructure::new);
        self
    }

    /// Statistics so far.
    pub fn stats(&self) -> &EmbedderStats {
        &self.stats
    }

    /// The model being trained (autodiff device).
    pub fn model(&self) -> &M {
        &self.model
    }

    /// Transitions in the replay buffer.
    pub fn replay_len(&self) -> usize {
        self.replay.len()
    }

    /// Whether pre-training is done (a first snapshot exists).
    pub fn pretrained(&self) -> bool {
        self.stats.version > 0
    }

    /// Validates (shapes, ranges, finite values; the reward bound is the service's, at the
    /// wire) and stores a batch of transitions.
    pub fn ingest(&mut self, batch: &TransitionBatch) -> Result<(), ValidationError> {
        batch.validate(
            self.model.state_space(),
            self.model.action_space(),
            f32::MAX,
        )?;
        self.check_next_items(batch)?;
        self.model.observe_states(&batch.states);
        self.replay.push(batch);
        self.since_update += batch.len();
        self.stats.transitions += batch.len() as u64;
        self.stats.overwritten = self.replay.overwritten();
        Ok(())
    }

    /// Stops the continuous updates for good: the embedding stays at its current version
    /// (pre-training still runs if it has not yet). The run's last part trains the policy on
    /// one embedding, the one it is evaluated with (`embedding.hold_from`).
    pub fn hold(&mut self) {
        self.held = true;
    }

    /// Whether [`EmbedderTrainer::hold`] was called.
    pub fn held(&self) -> bool {
        self.held
    }

    /// Trains if a round is due (pre-training once enough random transitions arrived, then
    /// continuous updates every `update_every` transitions until held) and returns the new
    /// snapshot.
    pub fn poll(&mut self) -> Result<Option<EmbeddingSnapshot>, nn::RecordError> {
        if !self.pretrained() {
            if self.replay.len()
                < self
                    .config
                    .pretrain_budget(self.model.state_space(), self.model.action_space())
            {
                return Ok(None);
            }
            self.pretrain();
        } else if !self.held
            && self.config.update_every > 0
            && self.since_update >= self.config.update_every
        {
            let lr = self.config.update_lr;
            let steps = self.config.update_steps;
            let mut loss = (0.0, 0.0);
            for _ in 0..steps {
                let mb = self.replay.sample(self.config.batch_size, &mut self.rng);
                let l = self.step(&mb, lr);
                loss = (loss.0 + l.0 / steps as f32, loss.1 + l.1 / steps as f32);
            }
            self.stats.model_loss = loss.0;
            self.stats.decoder_loss = loss.1;
        } else {
            return Ok(None);
        }
        self.end_round().map(Some)
    }

    /// Transitions pre-training waits for (`embedding.pretrain_budget`).
    pub fn pretrain_budget(&self) -> usize {
        self.config
            .pretrain_budget(self.model.state_space(), self.model.action_space())
    }

    /// Pre-trains at once on `batch` (a recording's transitions: `--pretrain-from`) instead
    /// of waiting for random play; returns the first snapshot.
    pub fn pretrain_on(&mut self, batch: &TransitionBatch) -> Result<EmbeddingSnapshot, String> {
        if self.pretrained() {
            return Err("the embedding is pre-trained already".into());
        }
        if batch.is_empty() {
            return Err("no transitions to pre-train on".into());
        }
        self.ingest(batch).map_err(|e| e.to_string())?;
        self.pretrain();
        self.end_round().map_err(|e| e.to_string())
    }

    /// Ends a training round: the next version, its structure measured, its snapshot.
    fn end_round(&mut self) -> Result<EmbeddingSnapshot, nn::RecordError> {
        self.since_update = 0;
        self.stats.version += 1;
        self.stats.action_structure = self.structure.as_ref().and_then(|s| {
            let (table, d) = self.model.action_embeddings()?;
            s.measure(&table, d)
        });
        self.snapshot()
    }

    /// Pre-training: `pretrain_epochs` passes of shuffled minibatches over the buffer.
    fn pretrain(&mut self) {
        self.pretrain_on_logs();
        let n = self.replay.len();
        let mut order: Vec<usize> = (0..n).collect();
        let bs = self.config.batch_size.min(n);
        let lr = self.config.lr;
        let mut loss = (0.0, 0.0);
        let started = std::time::Instant::now();
        for epoch in 1..=self.config.pretrain_epochs {
            order.shuffle(&mut self.rng);
            let (mut sum, mut count) = ((0.0, 0.0), 0);
            for rows in order.chunks(bs) {
                let mb = self.replay.gather(rows);
                let l = self.step(&mb, lr);
                sum = (sum.0 + l.0, sum.1 + l.1);
                count += 1;
            }
            loss = (sum.0 / count as f32, sum.1 / count as f32);
            let progress = PretrainProgress {
                epoch,
                epochs: self.config.pretrain_epochs,
                transitions: n,
                elapsed: started.elapsed(),
            };
            match self.pretrain_observer.as_mut() {
                // the observer shows it (a progress bar, or log lines it paces itself)
                Some(PretrainObserver(observe)) => observe(&progress),
                None if progress.worth_logging() => tracing::info!("{progress}"),
                None => {}
            }
        }
        self.stats.model_loss = loss.0;
        self.stats.decoder_loss = loss.1;
        tracing::info!(
            transitions = n,
            epochs = self.config.pretrain_epochs,
            model_loss = loss.0,
            decoder_loss = loss.1,
            "embedding pre-trained"
        );
    }

    /// One optimiser step of the model on a minibatch; returns (model loss, decoder loss).
    pub fn step(&mut self, mb: &crate::replay::Minibatch, lr: f64) -> (f32, f32) {
        let losses = self.model.train_step(&mut self.optim.0, mb, lr);
        self.stats.steps += 1;
        losses
    }

    /// Mean losses over a fixed set of transitions, without training.
    pub fn evaluate(&self, mb: &crate::replay::Minibatch) -> (f32, f32) {
        self.model.evaluate(mb)
    }

    /// Continues from a saved snapshot (a restarted embedder): its weights and version, as
    /// pre-trained; the replay buffer refills from new transitions and the optimiser state
    /// starts afresh. The next snapshot is `version + 1`.
    pub fn restore(&mut self, snapshot: &EmbeddingSnapshot) -> Result<(), nn::RecordError> {
        self.model.load_bytes(&snapshot.bytes)?;
        self.stats.version = snapshot.version;
        self.stats.model_loss = snapshot.model_loss;
        self.stats.decoder_loss = snapshot.decoder_loss;
        self.stats.action_structure = snapshot.action_structure;
        Ok(())
    }

    /// The current weights as a snapshot with the current version.
    pub fn snapshot(&self) -> Result<EmbeddingSnapshot, nn::RecordError> {
        Ok(EmbeddingSnapshot {
            version: self.stats.version,
            bytes: {
                let mut bytes = self.model.snapshot_bytes()?;
                if let Some(tag) = self.logged.as_ref().and_then(|l| l.catalogue) {
                    tag.append_to(&mut bytes);
                }
                bytes
            },
            model_loss: self.stats.model_loss,
            decoder_loss: self.stats.decoder_loss,
            action_structure: self.stats.action_structure,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::Minibatch;
    use jsae_wire::{ActionBatch, StateBatch};
    use rand::Rng;

    /// A fixed dataset of a deterministic ring: s' = (s + a) mod 20.
    fn ring(n: usize, rng: &mut ChaCha8Rng) -> TransitionBatch {
        let s: Vec<u32> = (0..n).map(|_| rng.random_range(0..20)).collect();
        let a: Vec<u32> = (0..n).map(|_| rng.random_range(0..8)).collect();
        let next = s.iter().zip(&a).map(|(s, a)| (s + a) % 20).collect();
        TransitionBatch {
            actor_id: 0,
            states: StateBatch::Categorical {
                factors: 1,
                data: s,
            },
            actions: ActionBatch::Discrete(a),
            rewards: vec![0.0; n],
            next_states: StateBatch::Categorical {
                factors: 1,
                data: next,
            },
            terminated: vec![false; n],
        }
    }

    #[test]
    fn the_embedding_loss_falls_on_a_fixed_dataset() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let data = ring(512, &mut rng);
        let config = EmbeddingConfig {
            pretrain_transitions: 512,
            pretrain_per_action: 0,
            pretrain_epochs: 60,
            batch_size: 128,
            ..EmbeddingConfig::default()
        };
        let mut t = EmbedderTrainer::new(
            config,
            Representation::Jsae,
            &StateSpace::discrete(20),
            &ActionSpace::Discrete { n: 8 },
            1,
            DeviceKind::Flex,
        );
        let fixed = Minibatch {
            states: data.states.clone(),
            actions: data.actions.clone(),
            next_states: data.next_states.clone(),
        };
        let before = t.evaluate(&fixed).0;
        t.ingest(&data).expect("valid");
        let snap = t.poll().expect("serialises").expect("pre-trained");
        let after = t.evaluate(&fixed).0;
        assert!(after < 0.8 * before, "loss {before} -> {after}");
        assert!(
            (snap.model_loss - after).abs() < 0.5,
            "{} vs {after}",
            snap.model_loss
        );
    }

    #[test]
    fn continuous_models_train_phi_g_t_by_mse_and_f_to_reconstruct_actions() {
        // Unnormalised states in [0, 1]; normalised ones far from it (MuJoCo-like scales).
        for (normalize_states, offset, scale) in [(false, 0.0, 1.0), (true, 50.0, 20.0)] {
            continuous_model_trains(normalize_states, offset, scale);
        }
    }

    fn continuous_model_trains(normalize_states: bool, offset: f32, scale: f32) {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let n = 1024;
        let s: Vec<f32> = (0..2 * n).map(|_| rng.random_range(0.0..1.0)).collect();
        let a: Vec<f32> = (0..2 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let next: Vec<f32> = s.iter().zip(&a).map(|(s, a)| s + 0.1 * a).collect();
        let (s, next): (Vec<f32>, Vec<f32>) = (
            s.iter().map(|v| offset + scale * v).collect(),
            next.iter().map(|v| offset + scale * v).collect(),
        );
        let batch = TransitionBatch {
            actor_id: 0,
            states: StateBatch::Real { dim: 2, data: s },
            actions: ActionBatch::Continuous { dim: 2, data: a },
            rewards: vec![0.0; n],
            next_states: StateBatch::Real { dim: 2, data: next },
            terminated: vec![false; n],
        };
        let actions = ActionSpace::Continuous {
            dim: 2,
            low: vec![-1.0; 2],
            high: vec![1.0; 2],
        };
        let config = EmbeddingConfig {
            pretrain_transitions: n,
            pretrain_per_action: 0,
            pretrain_epochs: 40,
            batch_size: 128,
            normalize_states,
            ..EmbeddingConfig::default()
        };
        let mut t = EmbedderTrainer::new(
            config,
            Representation::Jsae,
            &StateSpace::Real { dim: 2 },
            &actions,
            1,
            DeviceKind::Flex,
        );
        let fixed = Minibatch {
            states: batch.states.clone(),
            actions: batch.actions.clone(),
            next_states: batch.next_states.clone(),
        };
        t.ingest(&batch).expect("valid");
        // The loss before training, under the statistics the batch gave (normalised case).
        let before = t.evaluate(&fixed);
        let snapshot = t.poll().expect("serialises").expect("pre-trained");
        let after = t.evaluate(&fixed);
        assert!(
            after.0 < 0.5 * before.0,
            "normalise {normalize_states}: model loss {before:?} -> {after:?}"
        );
        if normalize_states {
            // The statistics travel in the snapshot: a fresh model loaded from it embeds the
            // states exactly as the trained one does.
            let mut fresh = EmbedderTrainer::new(
                t.config.clone(),
                Representation::Jsae,
                &StateSpace::Real { dim: 2 },
                &actions,
                7,
                DeviceKind::Flex,
            );
            fresh.restore(&snapshot).expect("loads");
            let x = |tr: &EmbedderTrainer| nn::to_vec(tr.model().embed_states(&batch.states));
            assert_eq!(x(&fresh), x(&t));
        }
        assert!(
            after.1 < 0.5 * before.1,
            "decoder loss {before:?} -> {after:?}"
        );
    }

    #[test]
    fn malformed_batches_are_refused_and_nothing_is_stored() {
        let mut t = EmbedderTrainer::new(
            EmbeddingConfig::default(),
            Representation::Jsae,
            &StateSpace::discrete(20),
            &ActionSpace::Discrete { n: 8 },
            1,
            DeviceKind::Flex,
        );
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut bad = ring(4, &mut rng);
        bad.actions = ActionBatch::Discrete(vec![0, 1, 2, 99]);
        assert!(t.ingest(&bad).is_err());
        assert_eq!(t.replay_len(), 0);
    }

    /// A held trainer still pre-trains once, then publishes no new version whatever arrives.
    #[test]
    fn a_held_trainer_pretrains_and_then_publishes_nothing_new() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let config = EmbeddingConfig {
            pretrain_transitions: 256,
            pretrain_per_action: 0,
            pretrain_epochs: 2,
            batch_size: 64,
            update_every: 256,
            update_steps: 2,
            ..EmbeddingConfig::default()
        };
        let trainer = || {
            EmbedderTrainer::new(
                config.clone(),
                Representation::Jsae,
                &StateSpace::discrete(20),
                &ActionSpace::Discrete { n: 8 },
                1,
                DeviceKind::Flex,
            )
        };
        let (mut held, mut free) = (trainer(), trainer());
        held.hold();
        for t in [&mut held, &mut free] {
            t.ingest(&ring(256, &mut rng)).expect("valid");
            let first = t.poll().expect("serialises").expect("pre-trained");
            assert_eq!(first.version, 1);
            t.ingest(&ring(512, &mut rng)).expect("valid");
        }
        assert!(held.poll().expect("serialises").is_none());
        assert_eq!(held.stats().version, 1);
        let next = free.poll().expect("serialises").expect("an update is due");
        assert_eq!(next.version, 2);
    }
}
