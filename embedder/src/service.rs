//! The embedder as a gRPC service (`jsae.v1.Embedder`).
//!
//! `PushTransitions` validates every batch against the run's spaces and hands it to a bounded
//! queue (backpressure reaches the actors when training is behind); one training thread owns
//! the [`EmbedderTrainer`]: it pre-trains once enough random transitions are in, then trains on
//! its schedule, and publishes each snapshot to every `WatchEmbedding` subscriber (latest
//! wins: a slow subscriber skips versions rather than queueing them). `HoldEmbedding` (the
//! learner's, from `embedding.hold_from` of the run on) ends the updates for good.

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use jsae_net as net;
use jsae_net::security::{Security, SecurityFlags};
use jsae_net::streams::StreamLimit;
use jsae_run_dir::{Checkpoints, Resume, Weights};
use jsae_settings::{ListenFlag, RunFlags, TrainConfig};
use jsae_telemetry::{EmbedderMetrics, EmbedderSample, MetricsFlag, MetricsRegistry};
use jsae_wire::{self as wire, MAX_MESSAGE_BYTES, pb};
use jsae_wire::{ActionSpace, EmbeddingSnapshot, RpcError, StateSpace, TransitionBatch};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use crate::lifecycle::EmbedderRun;
use crate::{EmbedderTrainer, LoggedItems};

/// Transition batches queued between the service and the training thread: few, so that
/// backpressure reaches the actors while a training round runs.
const QUEUE_BATCHES: usize = 2;

/// The HTTP/2 receive window of the embedder's calls, per call and per connection: what an
/// actor's transitions may have in flight beyond the queue. With hyper's default (about 1 MB,
/// some 20 gridworld batches of 2,048 transitions an actor) 4 actors ran 100k transitions and
/// more ahead of the embedder's training, which then published 7 versions in a 500k-step run
/// where one process publishes 24, and the policy learned on a stale embedding.
const RECEIVE_WINDOW: u32 = 64 * 1024;

/// Largest transition batch accepted, in transitions.
pub const MAX_BATCH_TRANSITIONS: usize = 65_536;

type Published = watch::Receiver<Option<Arc<EmbeddingSnapshot>>>;

/// The `jsae.v1.Embedder` implementation.
#[derive(Debug, Clone)]
pub struct EmbedderService {
    states: StateSpace,
    actions: ActionSpace,
    /// `ppo.max_abs_reward`: the largest reward magnitude accepted, as the learner's.
    max_abs_reward: f32,
    queue: mpsc::Sender<TransitionBatch>,
    published: Published,
    stopping: watch::Receiver<bool>,
    accepted: Arc<AtomicU64>,
    /// Set by `HoldEmbedding`; the training thread stops its continuous updates.
    held: Arc<AtomicBool>,
    /// The open embedding streams, capped in all and per connection.
    watches: StreamLimit,
}

#[tonic::async_trait]
impl pb::embedder_server::Embedder for EmbedderService {
    async fn push_transitions(
        &self,
        request: Request<Streaming<pb::TransitionBatch>>,
    ) -> Result<Response<pb::PushSummary>, Status> {
        let accepted = net::receive_all(
            request.into_inner(),
            &self.stopping,
            "embedder",
            |i, msg| {
                let checked = if msg.rewards.len() > MAX_BATCH_TRANSITIONS {
                    Err(RpcError::ResourceExhausted(format!(
                        "transition batch {i}: {} transitions, at most {MAX_BATCH_TRANSITIONS}",
                        msg.rewards.len()
                    )))
                } else {
                    TransitionBatch::try_from(msg)
                        .and_then(|b| {
                            b.validate(&self.states, &self.actions, self.max_abs_reward)
                                .map(|()| b)
                        })
                        .map_err(|e| {
                            RpcError::InvalidArgument(format!("transition batch {i}: {e}"))
                        })
                };
                async move {
                    self.queue
                        .send(checked?)
                        .await
                        .map_err(|_| RpcError::shutting_down("embedder"))?;
                    self.accepted.fetch_add(1, Ordering::Relaxed);
                    Ok(())
                }
            },
        )
        .await?;
        Ok(Response::new(pb::PushSummary {
            accepted,
            rejected: 0,
        }))
    }

    type WatchEmbeddingStream = ReceiverStream<Result<pb::SnapshotChunk, Status>>;

    async fn watch_embedding(
        &self,
        request: Request<pb::WatchRequest>,
    ) -> Result<Response<Self::WatchEmbeddingStream>, Status> {
        let permit = self.watches.enter(request.remote_addr())?;
        // the snapshot's chunks are cut as they are sent, from the one shared snapshot
        let stream = net::watch_stream(self.published.clone(), &self.stopping, permit, |current| {
            let chunks = current.clone().map(wire::embedding_chunks);
            (chunks.into_iter().flatten(), false)
        });
        Ok(Response::new(stream))
    }

    async fn hold_embedding(
        &self,
        _request: Request<pb::HoldRequest>,
    ) -> Result<Response<pb::Ack>, Status> {
        self.held.store(true, Ordering::Relaxed);
        Ok(Response::new(pb::Ack {}))
    }
}

/// Where the embedder keeps its checkpoints, if anywhere.
#[derive(Debug, Clone, Default)]
pub struct EmbedderOptions {
    /// Each published snapshot is written here as `embedding-v{N}.bpk` and as
    /// `embedding-latest.ckpt` (with its version and a checksum, `run_dir::Checkpoints`); an embedder
    /// started on a directory that holds them continues from there.
    pub checkpoint_dir: Option<PathBuf>,
    /// A recording (MCAP) to pre-train on at start instead of waiting for random play; not
    /// read when a checkpoint is resumed.
    pub pretrain_from: Option<PathBuf>,
    /// The logged purchases a fresh embedding pre-trains on first, where the settings ask
    /// (`embedding.recommender.logged_pretrain_epochs`).
    pub logged: Option<Arc<LoggedItems>>,
    /// The Prometheus families the training thread updates.
    pub metrics: EmbedderMetrics,
    /// TLS and the token every RPC but health needs.
    pub security: Security,
}

fn training_loop(
    config: &TrainConfig,
    states: &StateSpace,
    actions: &ActionSpace,
    mut queue: mpsc::Receiver<TransitionBatch>,
    held: &AtomicBool,
    publish: &watch::Sender<Option<Arc<EmbeddingSnapshot>>>,
    options: &EmbedderOptions,
) -> Result<(), String> {
    let mut trainer = EmbedderTrainer::for_run(config, states, actions);
    match &options.logged {
        Some(logged) => trainer.set_logged(logged.clone())?,
        None if config.embedding.recommender.logged_pretrain_epochs > 0 => {
            return Err(
                "embedding.recommender.logged_pretrain_epochs asks for the logged purchases and \
                 none were given (`jsae embedder` reads the recommender's)"
                    .into(),
            );
        }
        None => {}
    }
    let (mut run, first) = EmbedderRun::open(
        config,
        trainer,
        options.checkpoint_dir.as_deref(),
        Resume::IfCheckpoint,
        options.pretrain_from.as_deref(),
        &mut |line| tracing::info!("{line}"),
    )?;
    if let Some(first) = first {
        publish.send_replace(Some(Arc::new(first)));
    }
    while let Some(batch) = queue.blocking_recv() {
        run.trainer_mut()
            .ingest(&batch)
            .map_err(|e| e.to_string())?;
        if !run.trainer().held() && held.load(Ordering::Relaxed) {
            run.trainer_mut().hold();
            tracing::info!(
                "embedding held at v{}: no more updates (the learner asked, embedding.hold_from)",
                run.trainer().stats().version
            );
        }
        if let Some(snap) = run.trainer_mut().poll().map_err(|e| e.to_string())? {
            publish_snapshot(snap, &run, publish);
        }
        let stats = run.trainer().stats();
        options.metrics.observe_batch(&EmbedderSample {
            transitions: stats.transitions,
            embedding_version: stats.version,
            losses: (stats.model_loss, stats.decoder_loss),
            queue_depth: queue.len(),
            replay_len: run.trainer().replay_len(),
        });
    }
    Ok(())
}

/// Logs a new snapshot, checkpoints it and hands it to the subscribers.
fn publish_snapshot(
    snap: EmbeddingSnapshot,
    run: &EmbedderRun,
    publish: &watch::Sender<Option<Arc<EmbeddingSnapshot>>>,
) {
    tracing::info!(
        "embedding v{} published ({} transitions, model loss {:.4}, decoder loss {:.4})",
        snap.version,
        run.trainer().stats().transitions,
        snap.model_loss,
        snap.decoder_loss
    );
    if let Err(e) = run.checkpoint(&snap) {
        tracing::warn!("embedding checkpoint v{}: {e}", snap.version);
    }
    publish.send_replace(Some(Arc::new(snap)));
}

/// Serves the embedder on `listener` until `shutdown` resolves, then drains the queue and
/// returns (every published snapshot is checkpointed as it is published).
pub async fn serve(
    config: TrainConfig,
    listener: TcpListener,
    options: EmbedderOptions,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let (states, actions) = config.spaces();
    let security = options.security.clone();
    let (queue_tx, queue_rx) = mpsc::channel(QUEUE_BATCHES);
    let (publish_tx, publish_rx) = watch::channel(None);
    let (stop_tx, stop_rx) = watch::channel(false);
    let service = EmbedderService {
        states: states.clone(),
        actions: actions.clone(),
        max_abs_reward: config.ppo.max_abs_reward,
        queue: queue_tx,
        published: publish_rx,
        stopping: stop_rx,
        accepted: Arc::new(AtomicU64::new(0)),
        held: Arc::new(AtomicBool::new(false)),
        watches: StreamLimit::watches("WatchEmbedding"),
    };
    // the training thread ends before the server only when it fails: the server then stops
    // at once, and the failure is this process's exit (not a service that answers on and
    // never trains)
    let (ended_tx, ended_rx) = tokio::sync::oneshot::channel::<()>();
    let (interrupted_tx, interrupted_rx) = watch::channel(false);
    let trainer = {
        let config = config.clone();
        let held = service.held.clone();
        std::thread::Builder::new()
            .name("embedder-train".into())
            .spawn(move || {
                let result = training_loop(
                    &config,
                    &states,
                    &actions,
                    queue_rx,
                    &held,
                    &publish_tx,
                    &options,
                );
                let _ = ended_tx.send(());
                result
            })?
    };
    let server = pb::embedder_server::EmbedderServer::new(service)
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES);
    net::serve(
        server,
        listener,
        &security,
        Some(RECEIVE_WINDOW),
        async move {
            tokio::select! {
                () = shutdown => {
                    tracing::info!("embedder: shutting down");
                    let _ = interrupted_tx.send(true);
                }
                _ = ended_rx => tracing::error!(
                    "embedder: the training thread stopped; shutting down (its error follows)"
                ),
            }
            let _ = stop_tx.send(true);
        },
    )
    .await?;
    // The server (and with it every queue sender) is gone: the thread drains and stops (or,
    // after a signal, is left to the process's exit when a round keeps it past the grace)
    let interrupted = *interrupted_rx.borrow();
    let Some(joined) = net::join_training(trainer, interrupted, "embedder").await else {
        return Ok(());
    };
    joined
        .map_err(|_| anyhow::anyhow!("the training thread panicked"))?
        .map_err(|e| anyhow::anyhow!("training: {e}"))?;
    Ok(())
}

/// The embedder's command line (docs/src/operations/services.md).
#[derive(Debug, Clone, clap::Parser)]
#[command(
    name = "jsae-embedder",
    version,
    about = "JSAE-RL embedder: trains phi/g/T/f on raw transitions and publishes snapshots",
    mut_arg("env", |a| a.help(jsae_settings::SERVICE_ENV_HELP)),
    mut_arg("seed", |a| a.help(jsae_settings::SERVICE_SEED_HELP))
)]
pub struct EmbedderArgs {
    /// `--listen`.
    #[command(flatten)]
    pub listen: ListenFlag,
    /// `--env/--algo/--seed/--config`.
    #[command(flatten)]
    pub run: RunFlags,
    /// Directory for snapshot checkpoints (an embedder started on one continues from it).
    #[arg(long, env = "JSAE_CHECKPOINT_DIR")]
    pub checkpoint_dir: Option<PathBuf>,
    /// Pre-train phi, g, T and f on the first transitions of this recording (`jsae train
    /// --record`) instead of fresh random play.
    #[arg(long, value_name = "FILE.mcap")]
    pub pretrain_from: Option<PathBuf>,
    /// `--metrics-listen`.
    #[command(flatten)]
    pub metrics: MetricsFlag,
    /// `--auth-token-file`, `--tls-*`.
    #[command(flatten)]
    pub security: SecurityFlags,
}

/// Reads a run's logged purchases where its settings ask for them (None where they do not);
/// the reason when they cannot be read. The embedder knows no data set: its caller does.
pub type LogsSource = fn(&TrainConfig) -> Result<Option<LoggedItems>, String>;

/// Runs the embedder process: exit 0 after SIGINT/SIGTERM and a final checkpoint, 2 for a bad
/// configuration, 1 when serving fails.
pub fn main(args: EmbedderArgs, logs: LogsSource) -> std::process::ExitCode {
    let config = args
        .run
        .for_service()
        .and_then(|c| c.validate().map(|()| c))
        .map_err(|e| e.to_string())
        .and_then(|c| match &args.pretrain_from {
            Some(path) if !path.is_file() => {
                Err(format!("--pretrain-from {}: no such file", path.display()))
            }
            _ => Ok(c),
        })
        .and_then(|c| {
            // damaged checkpoints are refused rather than overwritten from version 0
            if let Some(dir) = &args.checkpoint_dir {
                Checkpoints::new(dir).refuse_unreadable(Weights::Embedding)?;
            }
            let logged = logs(&c)?.map(Arc::new);
            Ok((c, args.security.load()?, logged))
        });
    let mut registry = MetricsRegistry::default();
    let metrics = EmbedderMetrics::register(&mut registry);
    net::service_main(
        "jsae-embedder",
        config,
        |(config, security, logged), shutdown| async move {
            let options = EmbedderOptions {
                checkpoint_dir: args.checkpoint_dir,
                pretrain_from: args.pretrain_from,
                logged,
                metrics,
                security,
            };
            let listener = net::bind(&args.listen.listen).await?;
            jsae_telemetry::serve(&args.metrics, registry).await?;
            net::logging::announce_listening("jsae-embedder", listener.local_addr()?);
            Ok(serve(config, listener, options, shutdown).await?)
        },
        |()| {},
    )
}
