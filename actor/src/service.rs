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
use jsae_telemetry::{ActorMetrics, MetricsFlag, MetricsRegistry};
use jsae_wire::{EmbeddingSnapshot, MAX_MESSAGE_BYTES, PolicySnapshot, pb};
use tokio::sync::{mpsc, watch};
use tonic::Code;

use crate::push::push_forever;
pub use crate::stepping::{ActorExit, ActorOptions, ActorReport};
use crate::stepping::{Control, Links, stepping_loop};

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
    let (reports_tx, reports_rx) = mpsc::channel::<pb::EvalReport>(2);
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
        let follow = (
            security.clone(),
            url,
            embedder_lost.clone(),
            gave_up_tx.clone(),
        );
        follow_embedder(&mut tasks, follow, embedding_tx);
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
    let hello = pb::WatchRequest {
        actor_id: options.id,
        evaluates: true,
        rollout_steps: (config.envs_per_actor * config.rollout_len) as u64,
        envs: u32::try_from(config.envs_per_actor).unwrap_or(0),
    };
    // a gym environment's workers connect to this actor's environment host
    let mut hosting = None;
    let mut pool: Option<Box<dyn jsae_envs::EnvPool>> = None;
    let mut pool_stop = None;
    if config.env == jsae_settings::EnvName::Gym {
        let plan = options
            .env_host
            .clone()
            .ok_or_else(|| anyhow::anyhow!("a gym environment needs --env-listen"))?;
        let (mut remote, hosted) = jsae_remote_envs::host(
            &config.environment.gym,
            config.envs_per_actor,
            &options.security,
            &plan,
        )
        .await
        .map_err(|e| anyhow::anyhow!(e))?;
        remote.set_max_abs_reward(f64::from(config.ppo.max_abs_reward));
        net::logging::announce_listening("jsae-actor environments", hosted.addr);
        pool_stop = Some(remote.stopper());
        pool = Some(Box::new(remote));
        hosting = Some(hosted);
    }
    let to_stepping = (policy_tx, control_tx, share.clone(), pool_stop.clone());
    let follow = (
        security.clone(),
        options.learner.clone(),
        gave_up_tx.clone(),
    );
    follow_learner(&mut tasks, follow, hello, to_stepping);
    push_to_learner(&mut tasks, learner_channel, fragments_rx, reports_rx);

    let stop_flag = Arc::new(AtomicBool::new(false));
    let stop_all = {
        let (stop_flag, pool_stop) = (stop_flag.clone(), pool_stop.clone());
        move || {
            stop_flag.store(true, Ordering::Relaxed);
            if let Some(p) = &pool_stop {
                p.store(true, Ordering::Relaxed);
            }
        }
    };
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
            stepping_loop(&config, &options, &links, &stop_flag, pool)
        })
    };
    tokio::pin!(stepping);
    tokio::pin!(stop);
    let exit = tokio::select! {
        r = &mut stepping => r?,
        Some(gave_up) = gave_up_rx.recv() => {
            stop_all();
            tasks.abort_all();
            anyhow::bail!("{gave_up}");
        }
        () = &mut stop => {
            stop_all();
            // the thread may be waiting on a full queue: give it a moment, then leave
            match tokio::time::timeout(Duration::from_secs(2), &mut stepping).await {
                Ok(r) => r?,
                Err(_) => anyhow::bail!("the stepping thread did not stop"),
            }
        }
    };
    tasks.abort_all();
    drop(hosting);
    exit
}

/// Follows the embedder's snapshots into `embedding` (counting the stream's losses); a
/// follower that gave up says so on its channel.
fn follow_embedder(
    tasks: &mut tokio::task::JoinSet<()>,
    (security, url, lost, gave_up): (Security, String, Arc<AtomicU64>, GaveUpTx),
    embedding: watch::Sender<Option<Arc<EmbeddingSnapshot>>>,
) {
    tasks.spawn(async move {
        let followed = client::watch_embedding_counting_losses(&security, &url, &lost, |s| {
            embedding.send_replace(Some(Arc::new(s)));
            async { true }
        })
        .await;
        if let Err(e) = followed {
            let _ = gave_up.send(e).await;
        }
    });
}

/// What the learner's stream tells the stepping thread: snapshots, the evaluation and
/// finish controls, and this actor's share of the batch; and the remote environments'
/// stop flag, which the run's end sets (a pool waiting for workers stops waiting).
type ToStepping = (
    watch::Sender<Option<Arc<PolicySnapshot>>>,
    std::sync::mpsc::Sender<Control>,
    Arc<AtomicU64>,
    Option<Arc<AtomicBool>>,
);

type GaveUpTx = mpsc::Sender<client::GaveUp>;

/// Follows the learner's policy stream (saying `hello`) into the stepping thread's ends.
fn follow_learner(
    tasks: &mut tokio::task::JoinSet<()>,
    (security, url, gave_up): (Security, String, GaveUpTx),
    hello: pb::WatchRequest,
    (policy, control, share, pool_stop): ToStepping,
) {
    let id = hello.actor_id;
    tasks.spawn(async move {
        let followed = client::watch_policy(&security, &url, hello, |event| {
            let go_on = match event {
                PolicyEvent::Snapshot(s) => {
                    policy.send_replace(Some(Arc::new(s)));
                    true
                }
                // only a request addressed to this actor is run
                PolicyEvent::Evaluate(r) if r.actor_id == id => {
                    control.send(Control::Evaluate(r)).is_ok()
                }
                PolicyEvent::Evaluate(r) => {
                    tracing::warn!(
                        "actor {id}: an evaluation request for actor {} ignored",
                        r.actor_id
                    );
                    true
                }
                PolicyEvent::Finish => {
                    let _ = control.send(Control::Finish);
                    if let Some(stop) = &pool_stop {
                        stop.store(true, Ordering::Relaxed);
                    }
                    false
                }
                PolicyEvent::Share(envs) => {
                    share.store(u64::from(envs), Ordering::Relaxed);
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
}

/// Streams the fragments to the learner (losing none while it is away) and sends the
/// evaluation reports, retried while it is unavailable.
fn push_to_learner(
    tasks: &mut tokio::task::JoinSet<()>,
    channel: jsae_net::security::Connection,
    fragments: mpsc::Receiver<pb::RolloutFragment>,
    mut reports: mpsc::Receiver<pb::EvalReport>,
) {
    let pushing = channel.clone();
    tasks.spawn(push_forever("learner", fragments, move |stream| {
        let mut c = pb::learner_client::LearnerClient::new(pushing.clone())
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        async move {
            c.push_fragments(stream)
                .await
                .map(tonic::Response::into_inner)
        }
    }));
    tasks.spawn(async move {
        while let Some(report) = reports.recv().await {
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
    /// Environments stepped together [default: the settings file's, else the environment and
    /// algorithm's (`envs_per_actor` in `jsae config`)].
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
    /// Where the workers of a gym environment connect (`host:port`; port 0 picks a free
    /// one, printed on stdout as `jsae-actor environments listening on ADDR`). The actor
    /// starts `environment.gym.workers` of them itself (0: none, they connect by hand).
    #[arg(long, env = "JSAE_ENV_LISTEN", default_value = "127.0.0.1:0")]
    pub env_listen: String,
    /// Where the workers this actor starts write their output [default: this process's].
    #[arg(long, value_name = "DIR")]
    pub worker_logs: Option<PathBuf>,
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
            let env_host =
                (config.env == jsae_settings::EnvName::Gym).then(|| jsae_remote_envs::HostPlan {
                    listen: args.env_listen.clone(),
                    workers: config.environment.gym.workers as usize,
                    log_dir: args.worker_logs.clone(),
                    name: format!("{id}-"),
                    worker_env: args.security.to_env(),
                });
            let options = ActorOptions {
                id,
                embedder,
                learner: args.learner,
                record,
                metrics,
                security,
                env_host,
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
