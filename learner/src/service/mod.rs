//! The learner as a gRPC service (`jsae.v1.Learner`).
//!
//! `PushFragments` validates each fragment (dimensions, finite values, a policy version this
//! learner has published) and queues it; one thread owns the [`Learner`]: PPO updates, the
//! run directory (metrics.csv and TensorBoard scalars per update, the latest policy checkpoint before each snapshot
//! is published, summary.json at the end) and the end of the run: at `env_steps` it asks the
//! actors for deterministic evaluation episodes on the policy stream, writes the summary on
//! the first report, tells the actors to finish, and returns.
//!
//! Embedding versions: a fragment computed under an older embedding than the newest one seen
//! is dropped, and the first fragment of a newer embedding drops the partial batch gathered
//! under the old one (its `x` and `e` mean something else now); both count as
//! `dropped_embedding`. A fragment of an embedding version the embedder has not published is
//! refused (after a short grace for the learner to hear of it). A restarted learner resumes
//! from `checkpoints/policy-latest.ckpt`: the weights with their version, so actors that kept
//! running stay valid, and the training state (optimiser, scaler, step accounts, wall time).
//! A fresh run (neither resumed nor warm-started) first pre-trains on logged purchases where
//! `ppo.recommender.logged_pretrain_epochs` asks (the recommender), before its first snapshot, which the
//! actors wait for.

mod evaluation;
mod grpc;
mod input;
mod roster;
mod training;

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicU64;
use std::time::Duration;

use jsae_net::security::{Security, SecurityFlags};
use jsae_net::{self as net, client};
use jsae_run_dir::{RunDir, Weights};
use jsae_settings::{EmbedderFlag, ListenFlag, RunFlags, TrainConfig};
use jsae_telemetry::{LearnerMetrics, MetricsFlag, MetricsRegistry};
use jsae_wire::FragmentBounds;
use jsae_wire::{MAX_MESSAGE_BYTES, pb};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};

use crate::lifecycle::LearnerRun;
use crate::{Learner, LoggedPurchases};
use grpc::PolicyState;
pub use grpc::{LearnerService, MAX_FRAGMENT_STEPS};
use input::Input;
use jsae_run_dir::{Resume, Summary};

/// Messages queued between the service and the learner thread.
const QUEUE: usize = 256;
/// How often the learner thread looks for a round past its deadline.
const TICK: Duration = Duration::from_millis(100);
use training::LearnerLoop;
pub use training::latest_checkpoint;

/// What the learner follows and where it reads from, beside its settings (the run directory
/// is `config.out`).
#[derive(Debug, Clone)]
pub struct LearnerOptions {
    /// The embedder to follow (JSAE, AE, RA): embedding versions and losses for the metrics and the
    /// final embedding checkpoint.
    pub embedder: Option<String>,
    /// Logged purchases a fresh run's policy learns from before its first snapshot, where
    /// the settings ask (`ppo.recommender.logged_prior`, `ppo.recommender.logged_pretrain_epochs`).
    pub logged: Option<Arc<LoggedPurchases>>,
    /// A stopped run continued (`jsae train --resume`): there must be a checkpoint. Its actors
    /// count from zero again, in new incarnations; the learner counts on from the
    /// checkpoint's env steps and wall time (from the last metrics.csv row's where the
    /// checkpoint carries no training state).
    pub resume: bool,
    /// The Prometheus families the learner thread updates (served where `--metrics-listen`
    /// asks).
    pub metrics: LearnerMetrics,
    /// TLS and the token: required of the learner's callers, sent to the embedder.
    pub security: Security,
}

/// Reads a run's logged purchases where its settings ask for them (None where they do not);
/// the reason when they cannot be read. The learner knows no data set: its caller does.
pub type LogsSource = fn(&TrainConfig) -> Result<Option<LoggedPurchases>, String>;

/// The [`LogsSource`] of a learner that reads no data set (the `jsae-learner` binary): runs
/// whose settings ask for logs are refused with what to do instead.
pub fn no_logs(config: &TrainConfig) -> Result<Option<LoggedPurchases>, String> {
    if config.ppo.wants_logs() {
        return Err(
            "the run's settings ask for logged purchases (ppo.recommender.logged_prior or \
             ppo.recommender.logged_pretrain_epochs) and this binary reads no data set: run `jsae learner`, \
             which reads the recommender's, or set both off"
                .into(),
        );
    }
    Ok(None)
}

/// Serves the learner on `listener` until the run ends (the summary is written and the
/// actors are told) or `shutdown` resolves.
pub async fn serve(
    config: TrainConfig,
    listener: TcpListener,
    options: LearnerOptions,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<Option<Summary>> {
    let mut shutdown = Box::pin(shutdown);
    let Some(run) = open_run(&config, options.resume, &mut shutdown).await? else {
        return Ok(None);
    };
    let learner = run.learner();
    let (queue_tx, queue_rx) = mpsc::channel(QUEUE);
    let (publish_tx, publish_rx) = watch::channel(PolicyState::default());
    let (stop_tx, stop_rx) = watch::channel(false);
    let version = Arc::new(AtomicU64::new(learner.version()));
    // the highest embedding version published (fragments of a higher one are refused)
    let (published_tx, published_rx) = watch::channel(0u64);
    let service = LearnerService {
        bounds: FragmentBounds {
            max_episode_steps: config.env.max_episode_steps(&config.environment),
            ..learner.fragment_bounds()
        },
        version: version.clone(),
        embedding: options.embedder.is_some().then_some(published_rx),
        queue: queue_tx.clone(),
        state: publish_rx.clone(),
        stopping: stop_rx.clone(),
        shares_batch: config.shared_batch_envs().is_some(),
        watches: jsae_net::streams::StreamLimit::watches("WatchPolicy"),
        actor_ids: evaluation::ActorIds::default(),
    };
    // set by the loop from `embedding.hold_from` of the run on: the embedder is asked to hold
    let (hold_tx, hold_rx) = watch::channel(false);
    if let Some(url) = options.embedder.clone() {
        let follow = (url, options.security.clone(), stop_rx.clone());
        follow_embedder(follow, hold_rx, queue_tx.clone(), published_tx);
    }
    tick(&queue_tx);
    drop(queue_tx);
    let run = LearnerLoop {
        config,
        run,
        publish: publish_tx,
        hold: hold_tx,
        version,
        embedding: None,
        logged: options.logged.clone(),
        telemetry: options.metrics.clone(),
    };
    let (done_tx, done_rx) = tokio::sync::oneshot::channel::<()>();
    let thread = std::thread::Builder::new()
        .name("learner-train".into())
        .spawn(move || {
            let result = run.run(queue_rx);
            let _ = done_tx.send(());
            result
        })?;
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
    net::serve(server, listener, &options.security, None, end).await?;
    let interrupted = !thread.is_finished() && !publish_rx.borrow().finished;
    if interrupted {
        // interrupted: the thread ends when its queue closes (the service is gone)
        tracing::info!("learner: interrupted before the end of the run");
    }
    let Some(joined) = net::join_training(thread, interrupted, "learner").await else {
        return Ok(None);
    };
    match joined {
        Ok(Ok(summary)) => Ok(Some(summary)),
        Ok(Err(_)) if !publish_rx.borrow().finished => Ok(None),
        Ok(Err(e)) => Err(e),
        Err(_) => anyhow::bail!("the learner thread panicked"),
    }
}

/// Builds the learner (off the runtime: a large model takes a while, and a signal must be
/// heard meanwhile) and opens it on the run directory; None when `shutdown` came first.
async fn open_run(
    config: &TrainConfig,
    resume: bool,
    shutdown: &mut (impl Future<Output = ()> + Unpin),
) -> anyhow::Result<Option<LearnerRun>> {
    let build = tokio::task::spawn_blocking({
        let config = config.clone();
        move || Learner::for_run(&config)
    });
    let learner = tokio::select! {
        built = build => built?,
        () = shutdown => {
            tracing::info!("learner: stopped while building the model");
            return Ok(None);
        }
    };
    let resume = match resume {
        true => Resume::Required,
        false => Resume::IfCheckpoint,
    };
    let run = LearnerRun::open(config, learner, resume, &mut |line| {
        tracing::info!("{line}")
    })?;
    Ok(Some(run))
}

/// Follows the embedder at `url` (its snapshots into the queue, the newest version into
/// `published`) and asks it to hold its embedding once `hold` says so, until the service
/// stops.
fn follow_embedder(
    (url, security, stopping): (String, Security, watch::Receiver<bool>),
    mut hold: watch::Receiver<bool>,
    queue: mpsc::Sender<Input>,
    published: watch::Sender<u64>,
) {
    let (holding, at) = (security.clone(), url.clone());
    let (until, stop) = (net::stopped(&stopping), net::stopped(&stopping));
    tokio::spawn(async move {
        let ask = async {
            if hold.wait_for(|held| *held).await.is_ok() {
                client::hold_embedding(&holding, &at).await;
            }
        };
        tokio::select! {
            () = ask => {}
            () = until => {}
        }
    });
    tokio::spawn(async move {
        let follow = client::watch_embedding(&security, &url, |s| {
            let queue = queue.clone();
            published.send_if_modified(|newest| {
                let newer = s.version > *newest;
                *newest = (*newest).max(s.version);
                newer
            });
            async move { queue.send(Input::Embedding(s)).await.is_ok() }
        });
        tokio::select! {
            followed = follow => if let Err(e) = followed {
                tracing::error!("learner: {e}; no new embedding will arrive");
            },
            () = stop => {}
        }
    });
}

/// The round clock: a tick into the queue every [`TICK`]; through a weak sender, so that the
/// queue still closes when the service is gone.
fn tick(queue: &mpsc::Sender<Input>) {
    let ticks = queue.downgrade();
    tokio::spawn(async move {
        let mut every = tokio::time::interval(TICK);
        every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            every.tick().await;
            let Some(queue) = ticks.upgrade() else { break };
            // a full queue has work enough: the tick is not needed then
            let _ = queue.try_send(Input::Tick);
        }
    });
}

/// The learner's command line (docs/src/operations/services.md).
#[derive(Debug, Clone, clap::Parser)]
#[command(
    name = "jsae-learner",
    version,
    about = "JSAE-RL learner: PPO on embedded tuples, publishes policy snapshots, ends the run",
    mut_arg("env", |a| a.help(jsae_settings::SERVICE_ENV_HELP)),
    mut_arg("seed", |a| a.help(jsae_settings::SERVICE_SEED_HELP))
)]
pub struct LearnerArgs {
    /// `--listen`.
    #[command(flatten)]
    pub listen: ListenFlag,
    /// `--embedder`.
    #[command(flatten)]
    pub embedder: EmbedderFlag,
    /// `--env/--algo/--seed/--config`.
    #[command(flatten)]
    pub run: RunFlags,
    /// Env steps of the run, all actors together [default: the settings file's, else the
    /// environment and algorithm's: `jsae config --env E --algo A` prints them all].
    #[arg(long, env = "JSAE_ENV_STEPS")]
    pub env_steps: Option<u64>,
    /// Run directory.
    #[arg(long, env = "JSAE_OUT")]
    pub out: PathBuf,
    /// Continue a stopped run whose actors start again from zero (`jsae train --resume`
    /// passes it): resume from the policy checkpoint and count on from the last
    /// metrics.csv row's env steps and wall time. Without it a restarted learner resumes
    /// from its checkpoint too, but counts the steps its (still running) actors report.
    #[arg(long)]
    pub resume: bool,
    /// `--metrics-listen`.
    #[command(flatten)]
    pub metrics: MetricsFlag,
    /// `--auth-token-file`, `--tls-*`.
    #[command(flatten)]
    pub security: SecurityFlags,
}

/// Runs the learner process: exit 0 at the end of the run (or on SIGINT/SIGTERM), 2 for a bad
/// configuration, 1 when it fails.
pub fn main(args: LearnerArgs, logs: LogsSource) -> std::process::ExitCode {
    let config = args
        .run
        .for_service()
        .map_err(|e| e.to_string())
        .and_then(|mut c| {
            c.env_steps = args.env_steps.unwrap_or(c.env_steps);
            c.out = args.out.clone();
            c.validate().map_err(|e| e.to_string())?;
            // a restart without --resume resumes a good checkpoint; damaged ones are refused
            // rather than overwritten with a run from version 0
            RunDir::new(&c.out)
                .checkpoints()
                .refuse_unreadable(Weights::Policy)?;
            let security = args.security.load()?;
            let embedder = args
                .embedder
                .for_run(&c, |flag, url| security.check_url(flag, url))?;
            let logged = logs(&c)?.map(Arc::new);
            Ok((c, embedder, logged, security))
        });
    net::service_main(
        "jsae-learner",
        config,
        |(config, embedder, logged, security), shutdown| async move {
            let listener = net::bind(&args.listen.listen).await?;
            let mut registry = MetricsRegistry::default();
            let metrics = LearnerMetrics::register(&mut registry);
            jsae_telemetry::serve(&args.metrics, registry).await?;
            net::logging::announce_listening("jsae-learner", listener.local_addr()?);
            let options = LearnerOptions {
                embedder,
                logged,
                resume: args.resume,
                metrics,
                security,
            };
            Ok(serve(config, listener, options, shutdown).await?)
        },
        |summary| {
            if let Some(summary) = summary {
                net::logging::print_result("the run's summary", &summary);
            }
        },
    )
}
