//! The actor process: an [`ActorWorker`] stepping its environments on a blocking thread,
//! fed by two snapshot streams (embedder and learner) and feeding two client streams
//! (raw transitions to the embedder, embedded fragments to the learner).
//!
//! - Weights are swapped between rollouts, whole, to the newest version received.
//! - Until a policy exists it waits; until an embedding exists (JSAE) it acts at random.
//! - Every connection is retried with backoff: a service that goes away and comes back is
//!   rejoined without restarting the actor. A message in hand when a stream broke is sent
//!   again on the next one; one the service refused as malformed is dropped and logged.
//! - Backpressure: when a service is behind or away the queues fill and stepping waits.
//! - The learner's evaluation request is answered with deterministic episodes; its finish
//!   event ends the process with exit 0, as SIGINT/SIGTERM do.

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use jsae_net::client::{self, PolicyEvent};
use jsae_net::security::{Security, SecurityFlags};
use jsae_net::{self as net, Backoff};
use jsae_settings::{EmbedderFlag, RunFlags, TrainConfig};
use jsae_telemetry::{ActorMetrics, ActorSample, MetricsFlag, MetricsRegistry};
use jsae_wire::{EmbeddingSnapshot, PolicySnapshot};
use jsae_wire::{MAX_MESSAGE_BYTES, pb};
use tokio::sync::{mpsc, watch};
use tonic::Code;

use crate::pacing::{Pace, Pacing};
use crate::push::push_forever;
use crate::random_play::RandomPlay;
use crate::recent_embeddings::RecentEmbeddings;
use crate::worker::ActorWorker;
use jsae_record::{Recorder, RecordingInfo};

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
}

enum Control {
    Evaluate(pb::EvalRequest),
    Finish,
}

/// The stepping thread's ends of the channels to the async side.
struct Links {
    embedding: watch::Receiver<Option<Arc<EmbeddingSnapshot>>>,
    policy: watch::Receiver<Option<Arc<PolicySnapshot>>>,
    control: std::sync::mpsc::Receiver<Control>,
    transitions: mpsc::Sender<pb::TransitionBatch>,
    fragments: mpsc::Sender<pb::RolloutFragment>,
    reports: mpsc::Sender<pb::EvalReport>,
    /// How many times the embedder's stream opened again after it was lost.
    embedder_lost: Arc<AtomicU64>,
    /// The environments the learner last said to step (its `Share`; 0: all).
    share: Arc<AtomicU64>,
}

/// Steps until the run ends or `stop`, recording every transition when asked; the recording
/// is finished (its summary written) however the loop ends.
fn stepping_loop(
    config: &TrainConfig,
    options: &ActorOptions,
    links: &Links,
    stop: &AtomicBool,
) -> anyhow::Result<ActorReport> {
    let mut worker = ActorWorker::new(config, options.id, config.device)?;
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

fn step_until_done(
    config: &TrainConfig,
    options: &ActorOptions,
    links: &Links,
    stop: &AtomicBool,
    worker: &mut ActorWorker,
    recorder: &mut Option<Recorder>,
) -> anyhow::Result<ActorReport> {
    let mut report = ActorReport {
        exit: ActorExit::Stopped,
        env_steps: 0,
        fragments: 0,
        policy_versions: Vec::new(),
        embedding_versions: Vec::new(),
    };
    let needs_embedder = config.algo.representation().needs_embedder();
    let mut pacing = Pacing::new(
        config.rollouts_per_policy,
        Duration::from_millis(config.policy_wait_ms),
    );
    let mut refused: (Option<u64>, Option<u64>) = (None, None);
    let mut random_play = RandomPlay::new(config.random_play_share());
    let mut evaluation: Option<pb::EvalRequest> = None;
    let mut recent = RecentEmbeddings::default();
    loop {
        report.env_steps = worker.env_steps();
        if stop.load(Ordering::Relaxed) {
            return Ok(report);
        }
        // A snapshot that does not fit this actor's model (another run's service, a
        // different config) is refused once, logged, and the current weights kept.
        // (newer than any installed: after the evaluation went back to an older one, the
        // worker stays on it)
        let newest = links.embedding.borrow().clone();
        let installed = report.embedding_versions.last().copied().unwrap_or(0);
        if let Some(e) = newest
            && e.version > installed
            && refused.0 != Some(e.version)
        {
            match worker.set_embedding(&e) {
                Ok(()) => {
                    report.embedding_versions.push(e.version);
                    tracing::info!("actor {}: embedding v{}", options.id, e.version);
                    recent.installed(e);
                }
                Err(err) => {
                    tracing::error!("actor {}: embedding refused: {err}", options.id);
                    refused.0 = Some(e.version);
                }
            }
        }
        let newest = links.policy.borrow().clone();
        if let Some(p) = newest
            && Some(p.version) != worker.policy_version()
            && refused.1 != Some(p.version)
        {
            match worker.set_policy(&p) {
                Ok(()) => report.policy_versions.push(p.version),
                Err(err) => {
                    tracing::error!("actor {}: policy refused: {err}", options.id);
                    refused.1 = Some(p.version);
                }
            }
        }
        while let Ok(c) = links.control.try_recv() {
            match c {
                Control::Finish => {
                    report.exit = ActorExit::Finished;
                    return Ok(report);
                }
                Control::Evaluate(r) => evaluation = Some(r),
            }
        }
        // the evaluation runs on the newest weights this actor was sent (an actor asked the
        // moment it connects, replacing one that died, may not hold them yet)
        let newest_policy = links.policy.borrow().as_ref().map(|p| p.version);
        let weights_current = worker.policy_version().is_some()
            && (newest_policy == worker.policy_version() || newest_policy == refused.1)
            && (!needs_embedder || worker.embedding_version() > 0);
        if weights_current && let Some(r) = evaluation.take() {
            tracing::info!(
                "actor {}: {} evaluation episodes on policy v{}",
                options.id,
                r.episodes,
                worker.policy_version().unwrap_or(0)
            );
            evaluation_embedding(worker, &recent, r.embedding_version, options.id);
            let eval = worker.evaluate(r.episodes as usize, r.seed);
            let _ = links
                .reports
                .blocking_send(eval.to_wire(options.id, r.request_id));
            pacing.restart_wait(std::time::Instant::now());
        }
        // Random play only until this actor's share of the pre-training transitions is in
        // (another share when the embedder went away before its first embedding); then wait
        // for the first embedding rather than spend the budget on more.
        let first_embedding = needs_embedder && worker.embedding_version() == 0;
        if first_embedding
            && let Some(until) = random_play.embedder_lost(
                worker.env_steps(),
                links.embedder_lost.load(Ordering::Relaxed),
            )
        {
            tracing::warn!(
                "actor {}: the embedder went away before its first embedding and is back; random play for \
                 its pre-training again, until {until} env steps",
                options.id
            );
        }
        let waiting_for_embedding = first_embedding && random_play.waits(worker.env_steps());
        let Some(version) = worker.policy_version() else {
            std::thread::sleep(Duration::from_millis(5));
            continue;
        };
        if waiting_for_embedding {
            std::thread::sleep(Duration::from_millis(5));
            continue;
        }
        // On-policy pacing (see `pacing`): random play before the first embedding is not.
        let acting = worker.embedding_version() > 0 || !needs_embedder;
        if !acting {
            pacing.reset();
        } else if pacing.pace(
            (version, worker.embedding_version()),
            std::time::Instant::now(),
        ) == Pace::Wait
        {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        let before = worker.active_envs();
        let stepped = worker.set_active_envs(links.share.load(Ordering::Relaxed) as usize);
        if stepped != before {
            tracing::info!(
                "actor {}: steps {stepped} of its {} environments (its share of the learner's batch)",
                options.id,
                config.envs_per_actor
            );
        }
        let rollout = worker.collect(config.rollout_len);
        if let (Some(r), Some(steps)) = (recorder.as_mut(), &rollout.recorded) {
            r.write(&rollout.transitions, steps)?;
        }
        if needs_embedder && !rollout.transitions.is_empty() {
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
            pacing.sent();
        }
        report.fragments += sent_fragments;
        let queued = |max: usize, free: usize| max.saturating_sub(free);
        options.metrics.observe_rollout(&ActorSample {
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
    }
}

/// Runs one actor until the learner ends the run or `stop` resolves.
pub async fn run(
    config: TrainConfig,
    options: ActorOptions,
    stop: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<ActorReport> {
    let (embedding_tx, embedding_rx) = watch::channel(None);
    let (policy_tx, policy_rx) = watch::channel(None);
    let (control_tx, control_rx) = std::sync::mpsc::channel();
    let (transitions_tx, transitions_rx) = mpsc::channel::<pb::TransitionBatch>(1);
    let (fragments_tx, fragments_rx) = mpsc::channel::<pb::RolloutFragment>(16);
    let (reports_tx, mut reports_rx) = mpsc::channel::<pb::EvalReport>(2);
    let embedder_lost = Arc::new(AtomicU64::new(0));
    let share = Arc::new(AtomicU64::new(0));
    let mut tasks = tokio::task::JoinSet::new();
    // a follower that gave up (its credentials refused again and again) ends the actor
    let (gave_up_tx, mut gave_up_rx) = mpsc::channel::<client::GaveUp>(2);
    let security = options.security.clone();
    let learner_channel = security.channel(&options.learner)?;

    if config.algo.representation().needs_embedder() {
        let url = options
            .embedder
            .clone()
            .ok_or_else(|| anyhow::anyhow!("--embedder is required for --algo jsae"))?;
        let channel = security.channel(&url)?;
        let watching = security.clone();
        let lost = embedder_lost.clone();
        let gave_up = gave_up_tx.clone();
        tasks.spawn(async move {
            let followed = client::watch_embedding_counting_losses(&watching, &url, &lost, |s| {
                embedding_tx.send_replace(Some(Arc::new(s)));
                async { true }
            })
            .await;
            if let Err(e) = followed {
                let _ = gave_up.send(e).await;
            }
        });
        tasks.spawn(push_forever("embedder", transitions_rx, move |stream| {
            let mut c = pb::embedder_client::EmbedderClient::new(channel.clone())
                .max_encoding_message_size(MAX_MESSAGE_BYTES);
            async move {
                c.push_transitions(stream)
                    .await
                    .map(tonic::Response::into_inner)
            }
        }));
    }
    {
        let url = options.learner.clone();
        let id = options.id;
        let watching = security.clone();
        let hello = pb::WatchRequest {
            actor_id: id,
            evaluates: true,
            rollout_steps: (config.envs_per_actor * config.rollout_len) as u64,
            envs: u32::try_from(config.envs_per_actor).unwrap_or(0),
        };
        let told = share.clone();
        let gave_up = gave_up_tx.clone();
        tasks.spawn(async move {
            let followed = client::watch_policy(&watching, &url, hello, |event| {
                let go_on = match event {
                    PolicyEvent::Snapshot(s) => {
                        policy_tx.send_replace(Some(Arc::new(s)));
                        true
                    }
                    // only a request addressed to this actor is run
                    PolicyEvent::Evaluate(r) if r.actor_id == id => {
                        control_tx.send(Control::Evaluate(r)).is_ok()
                    }
                    PolicyEvent::Evaluate(r) => {
                        tracing::warn!(
                            "actor {id}: an evaluation request for actor {} ignored",
                            r.actor_id
                        );
                        true
                    }
                    PolicyEvent::Finish => {
                        let _ = control_tx.send(Control::Finish);
                        false
                    }
                    PolicyEvent::Share(envs) => {
                        told.store(u64::from(envs), Ordering::Relaxed);
                        true
                    }
                };
                async move { go_on }
            })
            .await;
            if let Err(e) = followed {
                let _ = gave_up.send(e).await;
            }
        });
        let channel = learner_channel.clone();
        tasks.spawn(push_forever("learner", fragments_rx, move |stream| {
            let mut c = pb::learner_client::LearnerClient::new(channel.clone())
                .max_encoding_message_size(MAX_MESSAGE_BYTES);
            async move {
                c.push_fragments(stream)
                    .await
                    .map(tonic::Response::into_inner)
            }
        }));
        let channel = learner_channel;
        tasks.spawn(async move {
            while let Some(report) = reports_rx.recv().await {
                let mut backoff = Backoff::default();
                let mut c = pb::learner_client::LearnerClient::new(channel.clone());
                for _ in 0..20 {
                    match c.report_eval(report.clone()).await {
                        Ok(_) => break,
                        Err(s) if s.code() == Code::Unavailable => {
                            tokio::time::sleep(backoff.next_delay()).await;
                        }
                        Err(s) => {
                            tracing::warn!("evaluation report refused: {}", s.message());
                            break;
                        }
                    }
                }
            }
        });
    }

    let stop_flag = Arc::new(AtomicBool::new(false));
    let stepping = {
        let stop_flag = stop_flag.clone();
        tokio::task::spawn_blocking(move || {
            let links = Links {
                embedding: embedding_rx,
                policy: policy_rx,
                control: control_rx,
                transitions: transitions_tx,
                fragments: fragments_tx,
                reports: reports_tx,
                embedder_lost,
                share,
            };
            stepping_loop(&config, &options, &links, &stop_flag)
        })
    };
    tokio::pin!(stepping);
    tokio::pin!(stop);
    let exit = tokio::select! {
        r = &mut stepping => r?,
        Some(gave_up) = gave_up_rx.recv() => {
            stop_flag.store(true, Ordering::Relaxed);
            tasks.abort_all();
            anyhow::bail!("{gave_up}");
        }
        () = &mut stop => {
            stop_flag.store(true, Ordering::Relaxed);
            // the thread may be waiting on a full queue: give it a moment, then leave
            match tokio::time::timeout(Duration::from_secs(2), &mut stepping).await {
                Ok(r) => r?,
                Err(_) => anyhow::bail!("the stepping thread did not stop"),
            }
        }
    };
    tasks.abort_all();
    exit
}

/// The actor's command line (docs/src/operations/services.md).
#[derive(Debug, Clone, clap::Parser)]
#[command(
    name = "jsae-actor",
    version,
    about = "JSAE-RL actor: steps environments, streams transitions and fragments",
    mut_arg("env", |a| a.help(jsae_settings::SERVICE_ENV_HELP)),
    mut_arg("seed", |a| a.help(jsae_settings::SERVICE_SEED_HELP))
)]
pub struct ActorArgs {
    /// `--embedder`.
    #[command(flatten)]
    pub embedder: EmbedderFlag,
    /// Learner URL (`http://host:port`, `https://` with --tls-ca).
    #[arg(long, env = "JSAE_LEARNER")]
    pub learner: String,
    /// `--env/--algo/--seed/--config`.
    #[command(flatten)]
    pub run: RunFlags,
    /// Environments stepped together [default: the settings file's, else 16].
    #[arg(long, env = "JSAE_ENVS")]
    pub envs: Option<usize>,
    /// This actor's id; give every actor of a run its own [default: from the process id and
    /// the clock].
    #[arg(long, env = "JSAE_ACTOR_ID")]
    pub id: Option<u64>,
    /// Record every transition this actor steps into an MCAP file (replaced if it exists;
    /// docs/src/operations/recordings.md).
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// The run's name in the recording [default: the file's name without .mcap].
    #[arg(long, requires = "record")]
    pub run_id: Option<String>,
    /// `--metrics-listen`.
    #[command(flatten)]
    pub metrics: MetricsFlag,
    /// `--auth-token-file`, `--tls-*`.
    #[command(flatten)]
    pub security: SecurityFlags,
}

/// Runs the actor process: exit 0 when the learner ends the run or on SIGINT/SIGTERM, 2 for a
/// bad configuration, 1 when it fails.
pub fn main(args: ActorArgs) -> std::process::ExitCode {
    let config = args
        .run
        .for_service()
        .map_err(|e| e.to_string())
        .and_then(|mut c| {
            c.envs_per_actor = args.envs.unwrap_or(c.envs_per_actor);
            c.validate().map_err(|e| e.to_string())?;
            let security = args.security.load()?;
            security.check_url("--learner", &args.learner)?;
            let embedder = args
                .embedder
                .for_run(&c, |flag, url| security.check_url(flag, url))?;
            Ok((c, embedder, security))
        });
    let id = args.id.unwrap_or_else(|| {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64);
        nanos ^ (u64::from(std::process::id()) << 32)
    });
    net::service_main(
        "jsae-actor",
        config,
        |(config, embedder, security), shutdown| async move {
            let record = args.record.map(|path| {
                let run_id = args.run_id.unwrap_or_else(|| {
                    path.file_stem()
                        .map_or_else(String::new, |s| s.to_string_lossy().into_owned())
                });
                (path, run_id)
            });
            let mut registry = MetricsRegistry::default();
            let metrics = ActorMetrics::register(&mut registry);
            jsae_telemetry::serve(&args.metrics, registry).await?;
            let options = ActorOptions {
                id,
                embedder,
                learner: args.learner,
                record,
                metrics,
                security,
            };
            Ok(run(config, options, shutdown).await?)
        },
        |report| {
            tracing::info!(
                "actor {id}: {:?} after {} env steps",
                report.exit,
                report.env_steps
            );
        },
    )
}
