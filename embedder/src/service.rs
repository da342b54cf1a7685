//! The embedder as a gRPC service (`jsae.v1.Embedder`).
//!
//! `PushTransitions` validates every batch against the run's spaces and hands it to a bounded
//! queue (backpressure reaches the actors when training is behind); one training thread owns
//! the [`EmbedderTrainer`]: it pre-trains once enough random transitions are in, then trains on
//! its schedule, and publishes each snapshot to every `WatchEmbedding` subscriber (latest
//! wins: a slow subscriber skips versions rather than queueing them).

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use jsae_proto::net;
use jsae_proto::settings::TrainConfig;
use jsae_proto::wire::{self, MAX_MESSAGE_BYTES, pb};
use jsae_proto::{ActionSpace, EmbeddingSnapshot, StateSpace, TransitionBatch};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use crate::EmbedderTrainer;

/// Transition batches queued between the service and the training thread: few, so that
/// backpressure reaches the actors while a training round runs.
const QUEUE_BATCHES: usize = 2;

/// Largest transition batch accepted, in transitions.
pub const MAX_BATCH_TRANSITIONS: usize = 65_536;

type Published = watch::Receiver<Option<Arc<EmbeddingSnapshot>>>;

/// The `jsae.v1.Embedder` implementation.
#[derive(Debug, Clone)]
pub struct EmbedderService {
    states: StateSpace,
    actions: ActionSpace,
    queue: mpsc::Sender<TransitionBatch>,
    published: Published,
    stopping: watch::Receiver<bool>,
    accepted: Arc<AtomicU64>,
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
                    Err(Status::resource_exhausted(format!(
                        "transition batch {i}: {} transitions, at most {MAX_BATCH_TRANSITIONS}",
                        msg.rewards.len()
                    )))
                } else {
                    TransitionBatch::try_from(msg)
                        .and_then(|b| b.validate(&self.states, &self.actions).map(|()| b))
                        .map_err(|e| Status::invalid_argument(format!("transition batch {i}: {e}")))
                };
                async move {
                    self.queue
                        .send(checked?)
                        .await
                        .map_err(|_| Status::unavailable("the embedder is shutting down"))?;
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
        _request: Request<pb::WatchRequest>,
    ) -> Result<Response<Self::WatchEmbeddingStream>, Status> {
        let mut published = self.published.clone();
        let stop = net::stopped(&self.stopping);
        let (tx, rx) = mpsc::channel(4);
        tokio::spawn(async move {
            tokio::pin!(stop);
            loop {
                let current = published.borrow_and_update().clone();
                if let Some(s) = current {
                    for chunk in wire::embedding_chunks(&s) {
                        if tx.send(Ok(chunk)).await.is_err() {
                            return;
                        }
                    }
                }
                tokio::select! {
                    r = published.changed() => if r.is_err() { return },
                    () = tx.closed() => return,
                    () = &mut stop => return,
                }
            }
        });
        Ok(Response::new(ReceiverStream::new(rx)))
    }
}

/// Where the embedder keeps its checkpoints, if anywhere.
#[derive(Debug, Clone, Default)]
pub struct EmbedderOptions {
    /// Each published snapshot is written here as `embedding-v{N}.bpk` and as
    /// `embedding-latest.bpk` (with its version in `embedding-latest.version`); an embedder
    /// started on a directory that holds them continues from there.
    pub checkpoint_dir: Option<PathBuf>,
}

fn write_checkpoint(dir: &std::path::Path, name: &str, bytes: &[u8]) {
    let tmp = dir.join(format!(".{name}.tmp"));
    let result = std::fs::create_dir_all(dir)
        .and_then(|()| std::fs::write(&tmp, bytes))
        .and_then(|()| std::fs::rename(&tmp, dir.join(name)));
    if let Err(e) = result {
        tracing::warn!("checkpoint {name} in {}: {e}", dir.display());
    }
}

/// The latest embedding checkpoint in `dir`, if any.
pub fn latest_checkpoint(dir: &std::path::Path) -> Option<EmbeddingSnapshot> {
    let version = std::fs::read_to_string(dir.join("embedding-latest.version"))
        .ok()?
        .trim()
        .parse()
        .ok()?;
    let bytes = std::fs::read(dir.join("embedding-latest.bpk")).ok()?;
    Some(EmbeddingSnapshot {
        version,
        bytes,
        model_loss: 0.0,
        decoder_loss: 0.0,
    })
}

fn training_loop(
    config: &TrainConfig,
    states: &StateSpace,
    actions: &ActionSpace,
    mut queue: mpsc::Receiver<TransitionBatch>,
    publish: &watch::Sender<Option<Arc<EmbeddingSnapshot>>>,
    options: &EmbedderOptions,
) -> Result<(), String> {
    let mut trainer = EmbedderTrainer::new(
        config.embedding.clone(),
        states,
        actions,
        config.seed,
        config.device,
    );
    if let Some(dir) = &options.checkpoint_dir
        && let Some(saved) = latest_checkpoint(dir)
    {
        match trainer.restore(&saved) {
            Ok(()) => {
                tracing::info!(
                    "resuming from the embedding checkpoint, version {}",
                    saved.version
                );
                publish.send_replace(Some(Arc::new(saved)));
            }
            Err(e) => tracing::error!(
                "the embedding checkpoint in {} does not fit this model ({e}); starting afresh",
                dir.display()
            ),
        }
    }
    while let Some(batch) = queue.blocking_recv() {
        trainer.ingest(&batch).map_err(|e| e.to_string())?;
        if let Some(snap) = trainer.poll().map_err(|e| e.to_string())? {
            tracing::info!(
                "embedding v{} published ({} transitions, model loss {:.4}, decoder loss {:.4})",
                snap.version,
                trainer.stats().transitions,
                snap.model_loss,
                snap.decoder_loss
            );
            if let Some(dir) = &options.checkpoint_dir {
                let versioned = format!("embedding-v{}.bpk", snap.version);
                write_checkpoint(dir, &versioned, &snap.bytes);
                write_checkpoint(dir, "embedding-latest.bpk", &snap.bytes);
                let version = format!("{}\n", snap.version);
                write_checkpoint(dir, "embedding-latest.version", version.as_bytes());
            }
            publish.send_replace(Some(Arc::new(snap)));
        }
    }
    Ok(())
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
    let (queue_tx, queue_rx) = mpsc::channel(QUEUE_BATCHES);
    let (publish_tx, publish_rx) = watch::channel(None);
    let (stop_tx, stop_rx) = watch::channel(false);
    let service = EmbedderService {
        states: states.clone(),
        actions: actions.clone(),
        queue: queue_tx,
        published: publish_rx,
        stopping: stop_rx,
        accepted: Arc::new(AtomicU64::new(0)),
    };
    let trainer = {
        let config = config.clone();
        std::thread::Builder::new()
            .name("embedder-train".into())
            .spawn(move || {
                training_loop(&config, &states, &actions, queue_rx, &publish_tx, &options)
            })?
    };
    let (health, health_service) = tonic_health::server::health_reporter();
    health
        .set_serving::<pb::embedder_server::EmbedderServer<EmbedderService>>()
        .await;
    let server = pb::embedder_server::EmbedderServer::new(service)
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES);
    tonic::transport::Server::builder()
        .add_service(health_service)
        .add_service(net::reflection()?)
        .add_service(server)
        .serve_with_incoming_shutdown(net::incoming(listener), async move {
            shutdown.await;
            tracing::info!("embedder: shutting down");
            let _ = stop_tx.send(true);
        })
        .await?;
    // The server (and with it every queue sender) is gone: the thread drains and stops.
    tokio::task::spawn_blocking(move || trainer.join())
        .await?
        .map_err(|_| anyhow::anyhow!("the training thread panicked"))?
        .map_err(|e| anyhow::anyhow!("training: {e}"))?;
    Ok(())
}

/// The embedder's command line (CONTRACT.md).
#[derive(Debug, Clone, clap::Args)]
pub struct EmbedderArgs {
    /// Address to listen on (`host:port`; port 0 picks a free one, printed on stdout).
    #[arg(long, env = "JSAE_LISTEN")]
    pub listen: String,
    /// Environment.
    #[arg(long, value_enum, env = "JSAE_ENV")]
    pub env: jsae_proto::settings::EnvName,
    /// Algorithm.
    #[arg(long, value_enum, env = "JSAE_ALGO")]
    pub algo: jsae_proto::settings::Algo,
    /// Seed.
    #[arg(long, env = "JSAE_SEED")]
    pub seed: u64,
    /// Settings file (TOML, as a run's config.toml).
    #[arg(long, env = "JSAE_CONFIG")]
    pub config: Option<PathBuf>,
    /// Directory for snapshot checkpoints (an embedder started on one continues from it).
    #[arg(long, env = "JSAE_CHECKPOINT_DIR")]
    pub checkpoint_dir: Option<PathBuf>,
}

/// Runs the embedder process: exit 0 after SIGINT/SIGTERM and a final checkpoint, 2 for a bad
/// configuration, 1 when serving fails.
pub fn main(args: EmbedderArgs) -> std::process::ExitCode {
    use std::process::ExitCode;
    let config =
        match TrainConfig::for_service(args.env, args.algo, args.seed, args.config.as_deref()) {
            Ok(c) => c,
            Err(e) => {
                eprintln!("jsae-embedder: {e}");
                return ExitCode::from(2);
            }
        };
    net::init_logging();
    let runtime = match net::runtime() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("jsae-embedder: {e}");
            return ExitCode::FAILURE;
        }
    };
    let result = runtime.block_on(async {
        let shutdown = net::shutdown_signal()?;
        let listener = net::bind(&args.listen).await?;
        let addr = listener.local_addr()?;
        println!("jsae-embedder listening on {addr}");
        let options = EmbedderOptions {
            checkpoint_dir: args.checkpoint_dir,
        };
        serve(config, listener, options, shutdown).await
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("jsae-embedder: {e:#}");
            ExitCode::FAILURE
        }
    }
}
