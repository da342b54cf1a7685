//! The actor's stepping thread: snapshots installed as they arrive (one that does not fit is
//! refused once and the weights kept), the learner's evaluation requests answered, random play
//! for the embedder's pre-training, on-policy pacing, and each rollout's transitions and
//! fragments handed to the async side's queues.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use jsae_net::security::Security;
use jsae_record::{Recorder, RecordingInfo};
use jsae_settings::TrainConfig;
use jsae_telemetry::{ActorMetrics, ActorSample};
use jsae_wire::{EmbeddingSnapshot, PolicySnapshot, pb};
use tokio::sync::{mpsc, watch};

use crate::pacing::{Pace, Pacing};
use crate::random_play::RandomPlay;
use crate::recent_embeddings::RecentEmbeddings;
use crate::worker::ActorWorker;

/// How an actor run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ActorExit {
    /// The learner ended the run.
    Finished,
    /// Stopped from outside (signal, or the caller's stop future).
    Stopped,
}

/// What an actor did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ActorReport {
    /// How it ended.
    pub exit: ActorExit,
    /// Env steps taken.
    pub env_steps: u64,
    /// Rollout fragments queued for the learner.
    pub fragments: u64,
    /// Every policy version applied, in order.
    pub policy_versions: Vec<u64>,
    /// Every embedding version applied, in order.
    pub embedding_versions: Vec<u64>,
}

/// Where the actor connects, and who it is.
#[derive(Debug, Clone)]
pub struct ActorOptions {
    /// This actor's id (distinct per actor: it seeds the environments and keys the learner's
    /// step count).
    pub id: u64,
    /// Embedder URL (JSAE).
    pub embedder: Option<String>,
    /// Learner URL.
    pub learner: String,
    /// An MCAP file every stepped transition goes into, and the run's name in it.
    pub record: Option<(PathBuf, String)>,
    /// The Prometheus families the stepping thread updates.
    pub metrics: ActorMetrics,
    /// TLS and the token sent to the embedder and the learner.
    pub security: Security,
    /// Where a gym environment's workers connect, and how many this actor starts
    /// (`--env-listen`; remote environments only).
    pub env_host: Option<jsae_remote_envs::HostPlan>,
}

pub(crate) enum Control {
    Evaluate(pb::EvalRequest),
    Finish,
}

/// The stepping thread's ends of the channels to the async side.
pub(crate) struct Links {
    pub(crate) embedding: watch::Receiver<Option<Arc<EmbeddingSnapshot>>>,
    pub(crate) policy: watch::Receiver<Option<Arc<PolicySnapshot>>>,
    pub(crate) control: std::sync::mpsc::Receiver<Control>,
    pub(crate) transitions: mpsc::Sender<pb::TransitionBatch>,
    pub(crate) fragments: mpsc::Sender<pb::RolloutFragment>,
    pub(crate) reports: mpsc::Sender<pb::EvalReport>,
    /// How many times the embedder's stream opened again after it was lost.
    pub(crate) embedder_lost: Arc<AtomicU64>,
    /// The environments the learner last said to step (its `Share`; 0: all).
    pub(crate) share: Arc<AtomicU64>,
}

/// Steps until the run ends or `stop`, recording every transition when asked; the recording
/// is finished (its summary written) however the loop ends.
pub(crate) fn stepping_loop(
    config: &TrainConfig,
    options: &ActorOptions,
    links: &Links,
    stop: &AtomicBool,
    pool: Option<Box<dyn jsae_envs::EnvPool>>,
) -> anyhow::Result<ActorReport> {
    let mut worker = match pool {
        Some(pool) => ActorWorker::with_pool(config, options.id, config.device, pool),
        None => ActorWorker::new(config, options.id, config.device)?,
    };
    let mut recorder = match &options.record {
        Some((path, run_id)) => {
            let info =
                RecordingInfo::of_run(config, run_id, worker.state_space(), worker.action_space());
            worker.set_recording(true);
            Some(Recorder::create(path, &info)?)
        }
        None => None,
    };
    let result = step_until_done(config, options, links, stop, &mut worker, &mut recorder);
    if let Some(r) = recorder {
        let path = r.path().to_path_buf();
        let n = r.finish()?;
        tracing::info!(
            "actor {}: {n} transitions recorded in {}",
            options.id,
            path.display()
        );
    }
    result
}

/// Installs the embedding the policy to evaluate was trained on (`version`, 0: not said),
/// where this actor still holds it and holds a newer one; else says what it evaluates on.
fn evaluation_embedding(
    worker: &mut ActorWorker,
    recent: &RecentEmbeddings,
    version: u64,
    actor: u64,
) {
    let current = worker.embedding_version();
    if version == 0 || version == current {
        return;
    }
    match recent.get(version).map(|e| worker.use_embedding(e)) {
        Some(Ok(())) => tracing::info!(
            "actor {actor}: evaluating on embedding v{version}, the policy's (v{current} came \
             after its last update)"
        ),
        Some(Err(err)) => tracing::warn!(
            "actor {actor}: embedding v{version} refused ({err}); evaluating on v{current}"
        ),
        None => tracing::warn!(
            "actor {actor}: the policy was trained on embedding v{version}, which this actor \
             no longer holds; evaluating on v{current}"
        ),
    }
}

/// What the stepping loop keeps between rollouts.
struct Stepper<'a> {
    config: &'a TrainConfig,
    options: &'a ActorOptions,
    links: &'a Links,
    report: ActorReport,
    needs_embedder: bool,
    pacing: Pacing,
    /// The newest embedding and policy versions refused (they do not fit this actor's
    /// model): refused once, logged, and the current weights kept.
    refused: (Option<u64>, Option<u64>),
    random_play: RandomPlay,
    evaluation: Option<pb::EvalRequest>,
    recent: RecentEmbeddings,
}

fn step_until_done(
    config: &TrainConfig,
    options: &ActorOptions,
    links: &Links,
    stop: &AtomicBool,
    worker: &mut ActorWorker,
    recorder: &mut Option<Recorder>,
) -> anyhow::Result<ActorReport> {
    let mut stepper = Stepper {
        config,
        options,
        links,
        report: ActorReport {
            exit: ActorExit::Stopped,
            env_steps: 0,
            fragments: 0,
            policy_versions: Vec::new(),
            embedding_versions: Vec::new(),
        },
        needs_embedder: config.algo.representation().needs_embedder(),
        pacing: Pacing::new(
            config.rollouts_per_policy,
            Duration::from_millis(config.policy_wait_ms),
        ),
        refused: (None, None),
        random_play: RandomPlay::new(config.random_play_share()),
        evaluation: None,
        recent: RecentEmbeddings::default(),
    };
    loop {
        stepper.report.env_steps = worker.env_steps();
        if stop.load(Ordering::Relaxed) {
            return Ok(stepper.report);
        }
        stepper.install_snapshots(worker);
        if stepper.finished() {
            stepper.report.exit = ActorExit::Finished;
            return Ok(stepper.report);
        }
        stepper.evaluate_when_asked(worker);
        let Some((version, acting)) = stepper.ready(worker) else {
            continue;
        };
        stepper.rollout(worker, recorder, version, acting)?;
        if let Some(reason) = worker.env_failure() {
            anyhow::bail!("actor {}'s environments: {reason}", options.id);
        }
    }
}

impl Stepper<'_> {
    /// Installs the newest embedding (newer than any installed: after the evaluation went
    /// back to an older one, the worker stays on it) and the newest policy, unless refused.
    fn install_snapshots(&mut self, worker: &mut ActorWorker) {
        let id = self.options.id;
        let newest = self.links.embedding.borrow().clone();
        let installed = self.report.embedding_versions.last().copied().unwrap_or(0);
        if let Some(e) = newest
            && e.version > installed
            && self.refused.0 != Some(e.version)
        {
            match worker.set_embedding(&e) {
                Ok(()) => {
                    self.report.embedding_versions.push(e.version);
                    tracing::info!("actor {id}: embedding v{}", e.version);
                    self.recent.installed(e);
                }
                Err(err) => {
                    tracing::error!("actor {id}: embedding refused: {err}");
                    self.refused.0 = Some(e.version);
                }
            }
        }
        let newest = self.links.policy.borrow().clone();
        if let Some(p) = newest
            && Some(p.version) != worker.policy_version()
            && self.refused.1 != Some(p.version)
        {
            match worker.set_policy(&p) {
                Ok(()) => self.report.policy_versions.push(p.version),
                Err(err) => {
                    tracing::error!("actor {id}: policy refused: {err}");
                    self.refused.1 = Some(p.version);
                }
            }
        }
    }

    /// Reads the learner's control messages: whether it ended the run (an evaluation
    /// request is kept for [`Self::evaluate_when_asked`]).
    fn finished(&mut self) -> bool {
        while let Ok(c) = self.links.control.try_recv() {
            match c {
                Control::Finish => return true,
                Control::Evaluate(r) => self.evaluation = Some(r),
            }
        }
        false
    }

    /// Runs the asked evaluation on the newest weights this actor was sent (an actor asked
    /// the moment it connects, replacing one that died, may not hold them yet) and reports it.
    fn evaluate_when_asked(&mut self, worker: &mut ActorWorker) {
        let newest_policy = self.links.policy.borrow().as_ref().map(|p| p.version);
        let weights_current = worker.policy_version().is_some()
            && (newest_policy == worker.policy_version() || newest_policy == self.refused.1)
            && (!self.needs_embedder || worker.embedding_version() > 0);
        let Some(r) = weights_current.then(|| self.evaluation.take()).flatten() else {
            return;
        };
        let id = self.options.id;
        tracing::info!(
            "actor {id}: {} evaluation episodes on policy v{}",
            r.episodes,
            worker.policy_version().unwrap_or(0)
        );
        evaluation_embedding(worker, &self.recent, r.embedding_version, id);
        let eval = worker.evaluate(r.episodes as usize, r.seed);
        let _ = self
            .links
            .reports
            .blocking_send(eval.to_wire(id, r.request_id));
        self.pacing.restart_wait(std::time::Instant::now());
    }

    /// Whether to step now: the policy version to act with and whether the policy acts
    /// (else random play before the first embedding); None after a short wait (no policy
    /// yet, waiting for the first embedding, or for the learner's pacing).
    fn ready(&mut self, worker: &ActorWorker) -> Option<(u64, bool)> {
        // Random play only until this actor's share of the pre-training transitions is in
        // (another share when the embedder went away before its first embedding); then wait
        // for the first embedding rather than spend the budget on more.
        let first_embedding = self.needs_embedder && worker.embedding_version() == 0;
        if first_embedding
            && let Some(until) = self.random_play.embedder_lost(
                worker.env_steps(),
                self.links.embedder_lost.load(Ordering::Relaxed),
            )
        {
            tracing::warn!(
                "actor {}: the embedder went away before its first embedding and is back; random play for \
                 its pre-training again, until {until} env steps",
                self.options.id
            );
        }
        let waiting_for_embedding = first_embedding && self.random_play.waits(worker.env_steps());
        let version = worker.policy_version().filter(|_| !waiting_for_embedding);
        let Some(version) = version else {
            std::thread::sleep(Duration::from_millis(5));
            return None;
        };
        // On-policy pacing (see `pacing`): random play before the first embedding is not.
        let acting = worker.embedding_version() > 0 || !self.needs_embedder;
        if !acting {
            self.pacing.reset();
        } else if self.pacing.pace(
            (version, worker.embedding_version()),
            std::time::Instant::now(),
        ) == Pace::Wait
        {
            std::thread::sleep(Duration::from_millis(1));
            return None;
        }
        Some((version, acting))
    }

    /// One rollout of the environments the learner's share says, its transitions to the
    /// embedder and the recording, its fragments to the learner.
    fn rollout(
        &mut self,
        worker: &mut ActorWorker,
        recorder: &mut Option<Recorder>,
        version: u64,
        acting: bool,
    ) -> anyhow::Result<()> {
        let links = self.links;
        let before = worker.active_envs();
        let stepped = worker.set_active_envs(links.share.load(Ordering::Relaxed) as usize);
        if stepped != before {
            tracing::info!(
                "actor {}: steps {stepped} of its {} environments (its share of the learner's batch)",
                self.options.id,
                self.config.envs_per_actor
            );
        }
        let rollout = worker.collect(self.config.rollout_len);
        if let (Some(r), Some(steps)) = (recorder.as_mut(), &rollout.recorded) {
            r.write(&rollout.transitions, steps)?;
        }
        if self.needs_embedder && !rollout.transitions.is_empty() {
            links
                .transitions
                .blocking_send(rollout.transitions.into())
                .map_err(|_| anyhow::anyhow!("the transition queue closed"))?;
        }
        let sent_fragments = rollout.fragments.len() as u64;
        for f in rollout.fragments {
            links
                .fragments
                .blocking_send(f.into())
                .map_err(|_| anyhow::anyhow!("the fragment queue closed"))?;
        }
        if acting && sent_fragments > 0 {
            self.pacing.sent();
        }
        self.report.fragments += sent_fragments;
        let queued = |max: usize, free: usize| max.saturating_sub(free);
        self.options.metrics.observe_rollout(&ActorSample {
            env_steps: worker.env_steps(),
            versions: (version, worker.embedding_version()),
            queued: (
                queued(
                    links.transitions.max_capacity(),
                    links.transitions.capacity(),
                ),
                queued(links.fragments.max_capacity(), links.fragments.capacity()),
            ),
            fragments: sent_fragments,
        });
        Ok(())
    }
}
