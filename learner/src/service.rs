//! The learner as a gRPC service (`jsae.v1.Learner`).
//!
//! `PushFragments` validates each fragment (dimensions, finite values, a policy version this
//! learner has published) and queues it; one thread owns the [`Learner`]: PPO updates, the
//! run directory (metrics.csv per update, the latest policy checkpoint before each snapshot
//! is published, summary.json at the end) and the end of the run: at `env_steps` it asks the
//! actors for deterministic evaluation episodes on the policy stream, writes the summary on
//! the first report, tells the actors to finish, and returns.
//!
//! Embedding versions: a fragment computed under an older embedding than the newest one seen
//! is dropped, and the first fragment of a newer embedding drops the partial batch gathered
//! under the old one (its `x` and `e` mean something else now); both count as
//! `dropped_embedding`. A restarted learner resumes from `checkpoints/policy-latest.bpk` with
//! its version, so actors that kept running stay valid.

use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use jsae_proto::settings::TrainConfig;
use jsae_proto::wire::{self, MAX_MESSAGE_BYTES, pb};
use jsae_proto::{
    ActionSpace, EmbeddingSnapshot, EvalReport, PolicySnapshot, RolloutFragment, client, net,
};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use crate::{Ingested, Learner, MetricsWriter, Summary};

/// Messages queued between the service and the learner thread.
const QUEUE: usize = 256;

/// Largest fragment accepted, in steps.
pub const MAX_FRAGMENT_STEPS: usize = 65_536;

/// What the learner thread is told.
#[derive(Debug)]
enum Input {
    Fragment(Box<RolloutFragment>),
    Embedding(EmbeddingSnapshot),
    Eval(EvalReport, u64),
}

/// What the policy stream carries: the current snapshot, an evaluation request, the end.
#[derive(Debug, Clone, Default)]
struct PolicyState {
    snapshot: Option<Arc<PolicySnapshot>>,
    evaluate: Option<pb::EvalRequest>,
    finished: bool,
}

/// The `jsae.v1.Learner` implementation.
#[derive(Debug, Clone)]
pub struct LearnerService {
    x_dim: usize,
    actions: ActionSpace,
    version: Arc<AtomicU64>,
    queue: mpsc::Sender<Input>,
    state: watch::Receiver<PolicyState>,
    stopping: watch::Receiver<bool>,
}

impl LearnerService {
    fn check(&self, index: u64, msg: pb::RolloutFragment) -> Result<RolloutFragment, Status> {
        if msg.rewards.len() > MAX_FRAGMENT_STEPS {
            return Err(Status::resource_exhausted(format!(
                "fragment {index}: {} steps, at most {MAX_FRAGMENT_STEPS}",
                msg.rewards.len()
            )));
        }
        let bad = |e: String| Status::invalid_argument(format!("fragment {index}: {e}"));
        let fragment = RolloutFragment::try_from(msg).map_err(|e| bad(e.to_string()))?;
        fragment
            .validate(self.x_dim, &self.actions)
            .map_err(|e| bad(e.to_string()))?;
        let current = self.version.load(Ordering::Acquire);
        if fragment.policy_version > current {
            return Err(bad(format!(
                "unknown policy version {} (this learner is at {current})",
                fragment.policy_version
            )));
        }
        Ok(fragment)
    }
}

#[tonic::async_trait]
impl pb::learner_server::Learner for LearnerService {
    async fn push_fragments(
        &self,
        request: Request<Streaming<pb::RolloutFragment>>,
    ) -> Result<Response<pb::PushSummary>, Status> {
        let accepted =
            net::receive_all(request.into_inner(), &self.stopping, "learner", |i, msg| {
                let checked = self.check(i, msg);
                async move {
                    self.queue
                        .send(Input::Fragment(Box::new(checked?)))
                        .await
                        .map_err(|_| Status::unavailable("the learner is shutting down"))
                }
            })
            .await?;
        Ok(Response::new(pb::PushSummary {
            accepted,
            rejected: 0,
        }))
    }

    type WatchPolicyStream = ReceiverStream<Result<pb::PolicyEvent, Status>>;

    async fn watch_policy(
        &self,
        _request: Request<pb::WatchRequest>,
    ) -> Result<Response<Self::WatchPolicyStream>, Status> {
        use pb::policy_event::Event;
        let mut state = self.state.clone();
        let stop = net::stopped(&self.stopping);
        let (tx, rx) = mpsc::channel(4);
        tokio::spawn(async move {
            tokio::pin!(stop);
            let (mut sent_version, mut sent_eval) = (None, None);
            loop {
                let now = state.borrow_and_update().clone();
                let mut events = Vec::new();
                if let Some(s) = &now.snapshot
                    && sent_version != Some(s.version)
                {
                    sent_version = Some(s.version);
                    events.extend(wire::policy_chunks(s).into_iter().map(Event::Chunk));
                }
                if let Some(e) = &now.evaluate
                    && sent_eval != Some(e.request_id)
                {
                    sent_eval = Some(e.request_id);
                    events.push(Event::Evaluate(*e));
                }
                if now.finished {
                    events.push(Event::Finish(pb::Finish {}));
                }
                for event in events {
                    let msg = pb::PolicyEvent { event: Some(event) };
                    if tx.send(Ok(msg)).await.is_err() {
                        return;
                    }
                }
                if now.finished {
                    return;
                }
                tokio::select! {
                    r = state.changed() => if r.is_err() { return },
                    () = tx.closed() => return,
                    () = &mut stop => return,
                }
            }
        });
        Ok(Response::new(ReceiverStream::new(rx)))
    }

    async fn report_eval(
        &self,
        request: Request<pb::EvalReport>,
    ) -> Result<Response<pb::Ack>, Status> {
        let (report, id) = EvalReport::from_wire(request.into_inner())
            .map_err(|e| Status::invalid_argument(format!("eval report: {e}")))?;
        let asked = self.state.borrow().evaluate.map(|e| e.request_id);
        if asked != Some(id) {
            return Err(Status::failed_precondition(format!(
                "no evaluation request {id} is open"
            )));
        }
        self.queue
            .send(Input::Eval(report, id))
            .await
            .map_err(|_| Status::unavailable("the learner is shutting down"))?;
        Ok(Response::new(pb::Ack {}))
    }
}

/// Where the learner writes its run directory.
#[derive(Debug, Clone)]
pub struct LearnerOptions {
    /// The run directory (metrics.csv, summary.json, checkpoints/).
    pub out: PathBuf,
    /// The embedder to follow (JSAE): embedding versions and losses for the metrics and the
    /// final embedding checkpoint.
    pub embedder: Option<String>,
}

fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

/// The latest policy checkpoint of a run directory, if any.
pub fn latest_checkpoint(out: &Path) -> Option<PolicySnapshot> {
    let ckpt = out.join("checkpoints");
    let version = std::fs::read_to_string(ckpt.join("policy-latest.version"))
        .ok()?
        .trim()
        .parse()
        .ok()?;
    let bytes = std::fs::read(ckpt.join("policy-latest.bpk")).ok()?;
    Some(PolicySnapshot { version, bytes })
}

fn save_checkpoint(out: &Path, s: &PolicySnapshot) -> std::io::Result<()> {
    let ckpt = out.join("checkpoints");
    write_atomic(&ckpt.join("policy-latest.bpk"), &s.bytes)?;
    write_atomic(
        &ckpt.join("policy-latest.version"),
        format!("{}\n", s.version).as_bytes(),
    )
}

struct LearnerLoop {
    config: TrainConfig,
    out: PathBuf,
    learner: Learner,
    metrics: MetricsWriter,
    publish: watch::Sender<PolicyState>,
    version: Arc<AtomicU64>,
    embedding: Option<EmbeddingSnapshot>,
    started: Instant,
}

impl LearnerLoop {
    fn publish_snapshot(&mut self, snapshot: PolicySnapshot) -> std::io::Result<()> {
        save_checkpoint(&self.out, &snapshot)?;
        self.version.store(snapshot.version, Ordering::Release);
        let snapshot = Arc::new(snapshot);
        self.publish.send_modify(|s| s.snapshot = Some(snapshot));
        Ok(())
    }

    fn run(mut self, mut queue: mpsc::Receiver<Input>) -> anyhow::Result<Summary> {
        let first = self.learner.snapshot()?;
        self.publish_snapshot(first)?;
        let request = pb::EvalRequest {
            request_id: self.started.elapsed().as_nanos() as u64 | 1,
            episodes: self.config.eval_episodes as u32,
            seed: self.config.eval_seed(),
        };
        let mut evaluating = false;
        while let Some(input) = queue.blocking_recv() {
            match input {
                Input::Embedding(s) => self.embedding = Some(s),
                Input::Fragment(f) if !evaluating => {
                    match self.learner.ingest(*f) {
                        Ok(Ingested::Updated(report)) => {
                            let loss = self.embedding.as_ref().map(|s| s.model_loss);
                            let wall = self.started.elapsed().as_secs_f64();
                            self.metrics.write(&report.metrics, wall, loss)?;
                            tracing::info!(
                                "update {}: {} env steps, return {:.3}, lag {:.2}",
                                report.metrics.update,
                                report.metrics.env_steps,
                                report.metrics.return_mean.unwrap_or(f64::NAN),
                                report.metrics.policy_lag_mean
                            );
                            self.publish_snapshot(report.snapshot)?;
                        }
                        Ok(_) => {}
                        Err(e) => tracing::warn!("fragment refused: {e}"),
                    }
                    if self.learner.env_steps() >= self.config.env_steps {
                        evaluating = true;
                        tracing::info!(
                            "{} env steps reached: asking the actors for {} evaluation episodes",
                            self.learner.env_steps(),
                            request.episodes
                        );
                        self.publish.send_modify(|s| s.evaluate = Some(request));
                    }
                }
                Input::Fragment(_) => {}
                Input::Eval(report, id) if evaluating && id == request.request_id => {
                    return self.finish(&report);
                }
                Input::Eval(..) => {}
            }
        }
        anyhow::bail!("the learner stopped before the run ended")
    }

    fn finish(self, eval: &EvalReport) -> anyhow::Result<Summary> {
        let summary = self.learner.summary(
            &self.config,
            self.learner.env_steps(),
            self.started.elapsed().as_secs_f64(),
            eval,
        );
        let ckpt = self.out.join("checkpoints");
        let last = self.learner.snapshot()?;
        write_atomic(
            &ckpt.join(format!("policy-v{}.bpk", last.version)),
            &last.bytes,
        )?;
        if let Some(e) = &self.embedding {
            write_atomic(
                &ckpt.join(format!("embedding-v{}.bpk", e.version)),
                &e.bytes,
            )?;
        }
        summary.write(&self.out)?;
        self.publish.send_modify(|s| s.finished = true);
        Ok(summary)
    }
}

/// Serves the learner on `listener` until the run ends (the summary is written and the
/// actors are told) or `shutdown` resolves.
pub async fn serve(
    config: TrainConfig,
    listener: TcpListener,
    options: LearnerOptions,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<Option<Summary>> {
    let out = options.out.clone();
    std::fs::create_dir_all(out.join("checkpoints"))?;
    let mut learner = Learner::for_run(&config);
    let resumed = match latest_checkpoint(&out) {
        Some(s) => {
            learner.restore(&s)?;
            tracing::info!("resuming from the policy checkpoint, version {}", s.version);
            true
        }
        None => false,
    };
    let metrics = if resumed {
        MetricsWriter::append(&out)?
    } else {
        std::fs::write(out.join("config.toml"), config.to_toml())?;
        MetricsWriter::create(&out)?
    };
    let (queue_tx, queue_rx) = mpsc::channel(QUEUE);
    let (publish_tx, publish_rx) = watch::channel(PolicyState::default());
    let (stop_tx, stop_rx) = watch::channel(false);
    let version = Arc::new(AtomicU64::new(learner.version()));
    let service = LearnerService {
        x_dim: learner.policy().input_dim(),
        actions: learner.head().action_space(),
        version: version.clone(),
        queue: queue_tx.clone(),
        state: publish_rx.clone(),
        stopping: stop_rx.clone(),
    };
    if let Some(url) = options.embedder.clone() {
        let queue = queue_tx.clone();
        let stop = net::stopped(&stop_rx);
        tokio::spawn(async move {
            let follow = client::watch_embedding(&url, |s| {
                let queue = queue.clone();
                async move { queue.send(Input::Embedding(s)).await.is_ok() }
            });
            tokio::select! {
                () = follow => {}
                () = stop => {}
            }
        });
    }
    drop(queue_tx);
    let run = LearnerLoop {
        config,
        out,
        learner,
        metrics,
        publish: publish_tx,
        version,
        embedding: None,
        started: Instant::now(),
    };
    let (done_tx, done_rx) = tokio::sync::oneshot::channel::<()>();
    let thread = std::thread::Builder::new()
        .name("learner-train".into())
        .spawn(move || {
            let result = run.run(queue_rx);
            let _ = done_tx.send(());
            result
        })?;
    let (health, health_service) = tonic_health::server::health_reporter();
    health
        .set_serving::<pb::learner_server::LearnerServer<LearnerService>>()
        .await;
    let server = pb::learner_server::LearnerServer::new(service)
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES);
    let finished = publish_rx.clone();
    let end = async move {
        tokio::select! {
            () = shutdown => tracing::info!("learner: shutting down"),
            _ = done_rx => {
                if finished.borrow().finished {
                    // let the actors read the finish event before the streams close
                    tokio::time::sleep(Duration::from_millis(500)).await;
                }
            }
        }
        let _ = stop_tx.send(true);
    };
    tonic::transport::Server::builder()
        .add_service(health_service)
        .add_service(net::reflection()?)
        .add_service(server)
        .serve_with_incoming_shutdown(net::incoming(listener), end)
        .await?;
    if !thread.is_finished() && !publish_rx.borrow().finished {
        // interrupted: the thread ends when its queue closes (the service is gone)
        tracing::info!("learner: interrupted before the end of the run");
    }
    match tokio::task::spawn_blocking(move || thread.join()).await? {
        Ok(Ok(summary)) => Ok(Some(summary)),
        Ok(Err(_)) if !publish_rx.borrow().finished => Ok(None),
        Ok(Err(e)) => Err(e),
        Err(_) => anyhow::bail!("the learner thread panicked"),
    }
}

/// The learner's command line (CONTRACT.md).
#[derive(Debug, Clone, clap::Args)]
pub struct LearnerArgs {
    /// Address to listen on (`host:port`; port 0 picks a free one, printed on stdout).
    #[arg(long, env = "JSAE_LISTEN")]
    pub listen: String,
    /// Embedder URL (`http://host:port`; needed by `--algo jsae`).
    #[arg(long, env = "JSAE_EMBEDDER")]
    pub embedder: Option<String>,
    /// Environment.
    #[arg(long, value_enum, env = "JSAE_ENV")]
    pub env: jsae_proto::settings::EnvName,
    /// Algorithm.
    #[arg(long, value_enum, env = "JSAE_ALGO")]
    pub algo: jsae_proto::settings::Algo,
    /// Seed.
    #[arg(long, env = "JSAE_SEED")]
    pub seed: u64,
    /// Env steps of the run (all actors together).
    #[arg(long, env = "JSAE_ENV_STEPS")]
    pub env_steps: u64,
    /// Run directory.
    #[arg(long, env = "JSAE_OUT")]
    pub out: PathBuf,
    /// Settings file (TOML, as a run's config.toml).
    #[arg(long, env = "JSAE_CONFIG")]
    pub config: Option<PathBuf>,
}

/// Runs the learner process: exit 0 at the end of the run (or on SIGINT/SIGTERM), 2 for a bad
/// configuration, 1 when it fails.
pub fn main(args: LearnerArgs) -> std::process::ExitCode {
    use std::process::ExitCode;
    let config = TrainConfig::for_service(args.env, args.algo, args.seed, args.config.as_deref())
        .and_then(|mut c| {
            c.env_steps = args.env_steps;
            c.out = args.out.clone();
            c.validate().map(|()| c)
        });
    let config = match config {
        Ok(c) if c.algo.uses_embedding() && args.embedder.is_none() => {
            eprintln!(
                "jsae-learner: --embedder is required for --algo {}",
                c.algo.as_str()
            );
            return ExitCode::from(2);
        }
        Ok(c) => c,
        Err(e) => {
            eprintln!("jsae-learner: {e}");
            return ExitCode::from(2);
        }
    };
    net::init_logging();
    let runtime = match net::runtime() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("jsae-learner: {e}");
            return ExitCode::FAILURE;
        }
    };
    let embedder = config
        .algo
        .uses_embedding()
        .then_some(args.embedder)
        .flatten();
    let result = runtime.block_on(async {
        let shutdown = net::shutdown_signal()?;
        let listener = net::bind(&args.listen).await?;
        println!("jsae-learner listening on {}", listener.local_addr()?);
        let options = LearnerOptions {
            out: args.out,
            embedder,
        };
        serve(config, listener, options, shutdown).await
    });
    match result {
        Ok(Some(summary)) => {
            println!(
                "{}",
                serde_json::to_string_pretty(&summary).unwrap_or_default()
            );
            ExitCode::SUCCESS
        }
        Ok(None) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("jsae-learner: {e:#}");
            ExitCode::FAILURE
        }
    }
}
