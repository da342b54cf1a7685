//! The learner's training thread: it owns the [`LearnerRun`] (the learner on its run
//! directory: the latest policy checkpoint before each snapshot is published, metrics.csv per
//! update, summary.json at the end) and ends the run: at `env_steps` it asks an actor for
//! deterministic evaluation episodes (the one whose fragment reached them, or another if that
//! one's stream closes: [`Evaluation`]), writes the summary on its report and tells the actors
//! to finish.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use jsae_run_dir::{RunDir, Weights};
use jsae_settings::TrainConfig;
use jsae_telemetry::{LearnerMetrics, LearnerSample};
use jsae_wire::{EmbeddingSnapshot, EvalReport, PolicySnapshot};
use tokio::sync::{mpsc, watch};

use super::evaluation::Evaluation;
use super::grpc::PolicyState;
use super::input::Input;
use super::roster::Roster;
use crate::lifecycle::LearnerRun;
use crate::{Ingested, LoggedPurchases, UpdateReport};
use jsae_run_dir::Summary;

/// The round reached its batch (logged when its silent actors were left out).
fn round_completed(roster: &mut Roster, now: Instant) {
    let missing = roster.completed(now);
    if !missing.is_empty() {
        tracing::info!(
            "a round filled past its deadline without actors {missing:?}: left out of the batch \
             until they send again"
        );
    }
}

/// The latest policy checkpoint of a run directory, if any.
pub fn latest_checkpoint(out: &RunDir) -> Option<PolicySnapshot> {
    let (version, bytes) = out.checkpoints().read_latest(Weights::Policy)?;
    Some(PolicySnapshot { version, bytes })
}

pub(super) struct LearnerLoop {
    pub(super) config: TrainConfig,
    pub(super) run: LearnerRun,
    pub(super) publish: watch::Sender<PolicyState>,
    /// Set from `embedding.hold_from` of the run on: the embedder is asked to hold its
    /// embedding (a task in the service repeats the request).
    pub(super) hold: watch::Sender<bool>,
    pub(super) version: Arc<AtomicU64>,
    pub(super) embedding: Option<EmbeddingSnapshot>,
    /// What a fresh run's policy learns from (where the settings ask) before the first
    /// snapshot, which the actors wait for.
    pub(super) logged: Option<Arc<LoggedPurchases>>,
    pub(super) telemetry: LearnerMetrics,
}

impl LearnerLoop {
    /// Publishes a snapshot (checkpointed already).
    fn publish_snapshot(&mut self, snapshot: PolicySnapshot) {
        self.version.store(snapshot.version, Ordering::Release);
        let snapshot = Arc::new(snapshot);
        self.publish.send_modify(|s| s.snapshot = Some(snapshot));
    }

    /// Sets the learner's batch to the roster's; records the update when what is buffered
    /// already makes it. The actors' shares go out first, so that each rollout under the new
    /// snapshot is collected with them.
    fn resize_batch(&mut self, roster: &mut Roster, now: Instant) -> anyhow::Result<()> {
        self.publish_shares(roster);
        if let Some(report) = self
            .run
            .learner_mut()
            .set_batch_steps(roster.batch_steps())?
        {
            round_completed(roster, now);
            self.publish_shares(roster);
            self.record_update(report)?;
        }
        Ok(())
    }

    /// Tells each actor its share of a shared batch where the shares changed (a round ended,
    /// or an actor joined); called before the snapshot of the update that ends a round goes
    /// out, so the next round's rollouts are stepped with them.
    fn publish_shares(&mut self, roster: &Roster) {
        if self.publish.borrow().shares == *roster.shares() {
            return;
        }
        let shares = roster.shares().clone();
        let said: Vec<String> = shares.iter().map(|(a, n)| format!("{a}: {n}")).collect();
        tracing::info!(
            "the batch's {} environments shared among the actors present (actor: environments) \
             {{{}}}",
            self.config.shared_batch_envs().unwrap_or(0),
            said.join(", ")
        );
        self.publish.send_modify(|s| s.shares = shares);
    }

    /// Records an update (its checkpoint and metrics row, [`LearnerRun::record_update`]),
    /// publishes its snapshot, and logs it and updates the Prometheus families.
    fn record_update(&mut self, report: UpdateReport) -> anyhow::Result<()> {
        self.run.record_update(&report, self.embedding.as_ref())?;
        self.publish_snapshot(report.snapshot);
        tracing::info!(
            "update {}: {} env steps ({} in the batch), return {:.3}, lag {:.2}",
            report.metrics.update,
            report.metrics.env_steps,
            report.metrics.batch_steps,
            report.metrics.return_mean.unwrap_or(f64::NAN),
            report.metrics.policy_lag_mean
        );
        self.telemetry
            .observe_update(report.metrics.policy_lag_mean);
        if !*self.hold.borrow()
            && self
                .config
                .embedding_held_at(self.run.learner().env_steps())
        {
            tracing::info!(
                "{} of {} env steps: asking the embedder to hold embedding v{} (embedding.hold_from)",
                self.run.learner().env_steps(),
                self.config.env_steps,
                self.run.learner().embedding_version()
            );
            self.hold.send_replace(true);
        }
        Ok(())
    }

    pub(super) fn run(mut self, mut queue: mpsc::Receiver<Input>) -> anyhow::Result<Summary> {
        let logged = self.logged.clone();
        let first = self
            .run
            .first_snapshot(logged.as_deref(), &mut |line| tracing::info!("{line}"))?;
        self.publish_snapshot(first);
        let mut evaluation =
            Evaluation::new(self.config.eval_episodes as u32, self.config.eval_seed());
        // the deadline's floor is half the actors' own: the learner gives up on a silent actor
        // before the others give up waiting for the round's update (actor/src/pacing.rs)
        let mut roster = Roster::new(
            self.config.round_steps(),
            (self.config.envs_per_actor * self.config.rollout_len) as u64,
            Duration::from_millis(self.config.policy_wait_ms) / 2,
        )
        .sharing(self.config.shared_batch_envs());
        while let Some(input) = queue.blocking_recv() {
            match input {
                Input::Embedding(s) => self.embedding = Some(s),
                Input::Stream { actor, opened } => {
                    match opened {
                        Some(a) => roster.open(actor, a.rollout_steps, a.envs),
                        None => roster.close(actor),
                    }
                    self.telemetry.observe_actors(roster.counts());
                    if let Some(request) = evaluation.roster_changed(&roster) {
                        self.publish.send_modify(|s| s.evaluate = Some(request));
                    }
                    if evaluation.open().is_none() {
                        self.resize_batch(&mut roster, Instant::now())?;
                    }
                }
                Input::Tick if evaluation.open().is_none() => {
                    self.close_overdue_round(&mut roster)?
                }
                Input::Tick => {}
                Input::Fragment(f) if evaluation.open().is_none() => {
                    let actor_id = f.actor_id;
                    self.take_fragment(*f, &mut roster, queue.len())?;
                    if self.run.learner().env_steps() >= self.config.env_steps {
                        let request = evaluation.ask(
                            actor_id,
                            &roster,
                            self.run.learner().trained_embedding_version(),
                        );
                        tracing::info!(
                            "{} env steps reached: asking actor {} for {} evaluation episodes",
                            self.run.learner().env_steps(),
                            request.actor_id,
                            request.episodes
                        );
                        self.publish.send_modify(|s| s.evaluate = Some(request));
                    }
                }
                Input::Fragment(_) => {}
                Input::Eval(report, id)
                    if evaluation.open().is_some_and(|r| r.request_id == id) =>
                {
                    return self.finish(&report);
                }
                Input::Eval(..) => {}
            }
        }
        anyhow::bail!("the learner stopped before the run ended")
    }

    /// A round past its deadline: updates on what it has, without its silent actors.
    fn close_overdue_round(&mut self, roster: &mut Roster) -> anyhow::Result<()> {
        let deadline = roster.deadline();
        let Some(missing) = roster.overdue(Instant::now()) else {
            return Ok(());
        };
        tracing::info!(
            "a round waited {:.1} s: updating on its {} env steps without actors \
             {missing:?}, left out of the batch until they send again",
            deadline.as_secs_f64(),
            self.run.learner().pending_steps()
        );
        self.publish_shares(roster);
        self.run
            .learner_mut()
            .set_batch_steps(roster.batch_steps())?;
        if let Some(report) = self.run.learner_mut().close_round()? {
            self.record_update(report)?;
        }
        self.telemetry.observe_actors(roster.counts());
        Ok(())
    }

    /// A fragment into the learner (an update recorded where it completes the batch), the
    /// roster told, the Prometheus families updated.
    fn take_fragment(
        &mut self,
        f: jsae_wire::RolloutFragment,
        roster: &mut Roster,
        queue_depth: usize,
    ) -> anyhow::Result<()> {
        let (actor_id, len) = (f.actor_id, f.len());
        let now = Instant::now();
        self.telemetry.observe_actor_steps(actor_id, len as u64);
        // one sent before its actor left counts on top of the survivors' batch
        let late = roster.late(actor_id, len as u64);
        if late {
            self.resize_batch(roster, now)?;
        }
        let buffered = match self.run.learner_mut().ingest(f) {
            Ok(Ingested::Updated(report)) => {
                round_completed(roster, now);
                self.publish_shares(roster);
                self.record_update(*report)?;
                true
            }
            Ok(Ingested::Buffered) => {
                let first = self.run.learner().pending_steps() == len;
                roster.buffered(actor_id, len as u64, first, now);
                true
            }
            // a dropped fragment still shows its actor alive
            Ok(_) => {
                roster.delivered(actor_id);
                false
            }
            Err(e) => {
                tracing::warn!("fragment refused: {e}");
                false
            }
        };
        if late && !buffered {
            roster.not_buffered(len as u64);
        }
        // an absent actor that sent again is back in the batch
        self.resize_batch(roster, now)?;
        let learner = self.run.learner();
        self.telemetry.observe_fragment(&LearnerSample {
            env_steps: learner.env_steps(),
            updates: learner.updates(),
            policy_version: learner.version(),
            embedding_version: learner.embedding_version(),
            dropped: learner.dropped(),
            queue_depth,
        });
        Ok(())
    }

    fn finish(mut self, eval: &EvalReport) -> anyhow::Result<Summary> {
        let summary = self
            .run
            .finish(&self.config, eval, self.embedding.as_ref())?;
        self.publish.send_modify(|s| s.finished = true);
        Ok(summary)
    }
}
