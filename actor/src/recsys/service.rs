//! The Recommender gRPC service (CONTRACT.md): `Recommend` answers the k best items for a
//! purchase history from the current policy, `SubmitSessions` validates sessions and appends
//! the good ones to the session store, from which the n-gram model is rebuilt on a schedule.
//!
//! - Weights: followed live from the learner (and, for JSAE, the embedder) and swapped in
//!   whole as new versions arrive; or loaded once from a finished run's checkpoints.
//! - JSAE: `x = phi(state)`, the policy's mean action embedding `e`, then the `k` items whose
//!   `g` rows are nearest to `e` (score: minus the distance). PPO: the `k` most likely items
//!   of the policy's softmax (score: the probability).
//! - The state is the last `history` known items of the request (items outside the model's
//!   catalogue are ignored and counted), padded with "none" as at the start of an episode.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};
use std::time::Duration;

use jsae_embedder::Embedding;
use jsae_embedder::nn::{BurnDevice, DeviceKind};
use jsae_learner::{Policy, policy_shape};
use jsae_proto::client::{self, PolicyEvent};
use jsae_proto::net;
use jsae_proto::settings::{Algo, EnvName, TrainConfig};
use jsae_proto::wire::{MAX_MESSAGE_BYTES, pb};
use jsae_proto::{ActionSpace, EmbeddingSnapshot, PolicySnapshot, StateBatch, StateSpace};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tokio::net::TcpListener;
use tonic::{Request, Response, Status, Streaming};

use super::data::{ModelHandle, RecsysError, model_handle};
use super::sessions::{MAX_ID_BYTES, Session, check_session};
use super::store::SessionStore;

/// Longest `history` a Recommend request may carry.
pub const MAX_HISTORY: usize = 1000;
/// Most sessions one SubmitSessions call may carry; more gets RESOURCE_EXHAUSTED (the
/// sessions before are kept).
pub const MAX_SESSIONS_PER_CALL: u64 = 100_000;
/// Errors listed in a SubmitSummary (the count of rejected sessions is always exact).
pub const MAX_ERRORS_LISTED: usize = 100;
/// Accepted sessions are written to the store in groups of this many (and at the end).
const STORE_BATCH: usize = 1024;
/// How often a followed run directory is checked for newer checkpoints.
const RUN_POLL: Duration = Duration::from_secs(3);

/// Why a request was refused; mapped to a gRPC status in one place.
#[derive(Debug, thiserror::Error)]
pub enum RecommendError {
    /// The request breaks the contract.
    #[error("{0}")]
    InvalidArgument(String),
    /// Over a documented limit.
    #[error("{0}")]
    ResourceExhausted(String),
    /// No policy (or, for JSAE, no embedding) has arrived yet.
    #[error("{0}")]
    Unavailable(String),
    /// The store could not be written.
    #[error("{0}")]
    Internal(String),
}

impl From<RecommendError> for Status {
    fn from(e: RecommendError) -> Self {
        match e {
            RecommendError::InvalidArgument(m) => Status::invalid_argument(m),
            RecommendError::ResourceExhausted(m) => Status::resource_exhausted(m),
            RecommendError::Unavailable(m) => Status::unavailable(m),
            RecommendError::Internal(m) => Status::internal(m),
        }
    }
}

/// One recommendation.
#[derive(Debug, Clone, PartialEq)]
pub struct Recommendation {
    /// `(item id, score)`, best first.
    pub items: Vec<(String, f32)>,
    /// The policy version used.
    pub policy_version: u64,
    /// The embedding version used (0 for PPO).
    pub embedding_version: u64,
    /// History entries outside the catalogue.
    pub unknown_items: u32,
}

/// The weights in use, replaced whole.
#[derive(Default)]
struct Weights {
    policy: Option<(u64, Policy)>,
    embedding: Option<(Embedding, Vec<f32>)>,
}

/// The recommender's core, without the transport.
pub struct Recommender {
    config: TrainConfig,
    model: Arc<ModelHandle>,
    states: StateSpace,
    actions: ActionSpace,
    template: Policy,
    device: burn::tensor::Device,
    weights: RwLock<Arc<Weights>>,
    store: Option<Mutex<SessionStore>>,
}

impl std::fmt::Debug for Recommender {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let w = self.weights();
        f.debug_struct("Recommender")
            .field("algo", &self.config.algo)
            .field("policy_version", &w.policy.as_ref().map(|p| p.0))
            .field(
                "embedding_version",
                &w.embedding.as_ref().map(|e| e.0.version()),
            )
            .finish()
    }
}

impl Recommender {
    /// A recommender for a `recommender` run's settings (the n-gram model's data and session
    /// store are the settings' `environment.recommender`).
    pub fn new(config: &TrainConfig, device: DeviceKind) -> Result<Self, RecsysError> {
        if config.env != EnvName::Recommender {
            return Err(RecsysError::Data(format!(
                "the settings are for --env {}, not recommender",
                config.env.as_str()
            )));
        }
        let r = &config.environment.recommender;
        let model = model_handle(r)?;
        let (states, actions) = EnvName::Recommender.spaces(&config.environment);
        let store = if r.store_dir.as_os_str().is_empty() {
            None
        } else {
            Some(Mutex::new(SessionStore::open(&r.store_dir)?))
        };
        let (input, head) = policy_shape(config, &states, &actions);
        let device = device.device();
        let template = Policy::new(
            &config.ppo,
            input,
            head,
            &mut ChaCha8Rng::seed_from_u64(0),
            &device,
        );
        Ok(Self {
            config: config.clone(),
            model,
            states,
            actions,
            template,
            device,
            weights: RwLock::new(Arc::new(Weights::default())),
            store,
        })
    }

    fn weights(&self) -> Arc<Weights> {
        self.weights
            .read()
            .map_or_else(|p| Arc::clone(p.get_ref()), |w| Arc::clone(&w))
    }

    fn replace(&self, edit: impl FnOnce(&mut Weights)) {
        let mut slot = self.weights.write().unwrap_or_else(|p| p.into_inner());
        let mut next = Weights {
            policy: slot.policy.clone(),
            embedding: slot.embedding.clone(),
        };
        edit(&mut next);
        *slot = Arc::new(next);
    }

    /// The policy version in use (None before the first).
    pub fn policy_version(&self) -> Option<u64> {
        self.weights().policy.as_ref().map(|p| p.0)
    }

    /// The embedding version in use (0: none).
    pub fn embedding_version(&self) -> u64 {
        self.weights()
            .embedding
            .as_ref()
            .map_or(0, |e| e.0.version())
    }

    /// Swaps in a policy snapshot (any other version than the one in use).
    pub fn set_policy(&self, snapshot: &PolicySnapshot) -> Result<(), String> {
        if self.policy_version() == Some(snapshot.version) {
            return Ok(());
        }
        let mut policy = self.template.clone();
        policy
            .load_bytes(&snapshot.bytes)
            .map_err(|e| format!("policy version {}: {e}", snapshot.version))?;
        self.replace(|w| w.policy = Some((snapshot.version, policy)));
        Ok(())
    }

    /// Swaps in a newer embedding snapshot.
    pub fn set_embedding(&self, snapshot: &EmbeddingSnapshot) -> Result<(), String> {
        if snapshot.version <= self.embedding_version() {
            return Ok(());
        }
        let embedding = Embedding::from_snapshot(
            &self.config.embedding,
            &self.states,
            &self.actions,
            snapshot,
            &self.device,
        )
        .map_err(|e| format!("embedding version {}: {e}", snapshot.version))?;
        let table = embedding.action_table().unwrap_or_default();
        self.replace(|w| w.embedding = Some((embedding, table)));
        Ok(())
    }

    /// The `k` best items after `history` (item ids, oldest first).
    pub fn recommend(&self, history: &[String], k: u32) -> Result<Recommendation, RecommendError> {
        let bad = RecommendError::InvalidArgument;
        if history.is_empty() {
            return Err(bad("history is empty: give at least one item id".into()));
        }
        if history.len() > MAX_HISTORY {
            return Err(bad(format!(
                "history holds {} items, more than the limit of {MAX_HISTORY}",
                history.len()
            )));
        }
        if let Some(i) = history
            .iter()
            .position(|h| h.is_empty() || h.len() > MAX_ID_BYTES)
        {
            return Err(bad(format!(
                "history[{i}] is empty or longer than {MAX_ID_BYTES} bytes"
            )));
        }
        let model = self.model.current();
        let catalogue = model.catalogue();
        let items = catalogue.len();
        if k == 0 || k as usize > items {
            return Err(bad(format!(
                "k must be in 1..={items} (the catalogue's size), got {k}"
            )));
        }
        let weights = self.weights();
        let Some((policy_version, policy)) = weights.policy.as_ref() else {
            return Err(RecommendError::Unavailable(
                "no policy yet: waiting for the learner's first snapshot".into(),
            ));
        };
        let known: Vec<u32> = history.iter().filter_map(|h| catalogue.slot(h)).collect();
        let unknown_items = (history.len() - known.len()) as u32;
        let n = self.config.environment.recommender.history as usize;
        let mut state = vec![catalogue.none(); n];
        let tail = &known[known.len().saturating_sub(n)..];
        state[n - tail.len()..].copy_from_slice(tail);
        let batch = StateBatch::Categorical {
            factors: n,
            data: state,
        };
        let mut x = Vec::new();
        let (scored, embedding_version) = if self.config.algo.uses_embedding() {
            let Some((embedding, table)) = weights.embedding.as_ref() else {
                return Err(RecommendError::Unavailable(
                    "no embedding yet: waiting for the embedder's first snapshot".into(),
                ));
            };
            embedding.embed_states(&batch, &mut x);
            let e = policy.head_outputs(&x);
            (
                nearest_items(table, &e, items, k as usize),
                embedding.version(),
            )
        } else {
            batch.write_features(&self.states, &mut x);
            let logits = policy.head_outputs(&x);
            (most_likely(&logits, items, k as usize), 0)
        };
        Ok(Recommendation {
            items: scored
                .into_iter()
                .filter_map(|(slot, score)| catalogue.id(slot).map(|id| (id.to_owned(), score)))
                .collect(),
            policy_version: *policy_version,
            embedding_version,
            unknown_items,
        })
    }

    /// Appends accepted sessions to the store (synced before it returns).
    fn store(&self, sessions: &[Session]) -> Result<(), RecommendError> {
        match &self.store {
            Some(store) if !sessions.is_empty() => store
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .append(sessions)
                .map_err(|e| RecommendError::Internal(format!("session store: {e}"))),
            _ => Ok(()),
        }
    }

    /// Whether sessions are kept (a session store is configured).
    pub fn has_store(&self) -> bool {
        self.store.is_some()
    }
}

/// The `k` rows of `table` (`[n, d]`, first `items` rows used) nearest to `e`, as
/// `(row, -distance)`, nearest first (ties: lower row first).
fn nearest_items(table: &[f32], e: &[f32], items: usize, k: usize) -> Vec<(u32, f32)> {
    let d = e.len().max(1);
    let mut all: Vec<(u32, f32)> = table
        .chunks_exact(d)
        .take(items)
        .enumerate()
        .map(|(a, row)| {
            let sq: f32 = row.iter().zip(e).map(|(r, x)| (r - x) * (r - x)).sum();
            (a as u32, -sq.sqrt())
        })
        .collect();
    best_k(&mut all, k);
    all
}

/// The `k` most likely of the first `items` actions under `logits`, as `(action, p)`.
fn most_likely(logits: &[f32], items: usize, k: usize) -> Vec<(u32, f32)> {
    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let z: f32 = logits.iter().map(|l| (l - max).exp()).sum();
    let mut all: Vec<(u32, f32)> = logits
        .iter()
        .take(items)
        .enumerate()
        .map(|(a, &l)| (a as u32, (l - max).exp() / z))
        .collect();
    best_k(&mut all, k);
    all
}

/// Keeps the `k` highest scores, highest first (ties: lower index first).
fn best_k(all: &mut Vec<(u32, f32)>, k: usize) {
    let order = |a: &(u32, f32), b: &(u32, f32)| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0));
    let k = k.min(all.len());
    if k == 0 {
        all.clear();
        return;
    }
    all.select_nth_unstable_by(k - 1, order);
    all.truncate(k);
    all.sort_by(order);
}

/// The gRPC face of a [`Recommender`].
#[derive(Debug, Clone)]
pub struct RecommenderService {
    inner: Arc<Recommender>,
}

impl RecommenderService {
    /// Serves `inner`.
    pub fn new(inner: Arc<Recommender>) -> Self {
        Self { inner }
    }
}

/// Writes `pending` to the store off the async threads (the sync waits for the disk).
async fn flush(inner: &Arc<Recommender>, pending: &mut Vec<Session>) -> Result<(), RecommendError> {
    if pending.is_empty() {
        return Ok(());
    }
    let inner = inner.clone();
    let batch = std::mem::take(pending);
    tokio::task::spawn_blocking(move || inner.store(&batch))
        .await
        .map_err(|e| RecommendError::Internal(e.to_string()))?
}

#[tonic::async_trait]
impl pb::recommender_server::Recommender for RecommenderService {
    async fn recommend(
        &self,
        request: Request<pb::RecommendRequest>,
    ) -> Result<Response<pb::RecommendResponse>, Status> {
        let r = request.into_inner();
        let out = self.inner.recommend(&r.history, r.k)?;
        Ok(Response::new(pb::RecommendResponse {
            items: out
                .items
                .into_iter()
                .map(|(item_id, score)| pb::ScoredItem { item_id, score })
                .collect(),
            policy_version: out.policy_version,
            embedding_version: out.embedding_version,
            unknown_items: out.unknown_items,
        }))
    }

    async fn submit_sessions(
        &self,
        request: Request<Streaming<pb::Session>>,
    ) -> Result<Response<pb::SubmitSummary>, Status> {
        let mut stream = request.into_inner();
        let mut summary = pb::SubmitSummary::default();
        let mut pending: Vec<Session> = Vec::new();
        let mut index: u64 = 0;
        loop {
            let message = match stream.message().await {
                Ok(Some(m)) => m,
                Ok(None) => break,
                Err(status) => {
                    // keep what was accepted before the stream broke (or a message was over
                    // the size limit: RESOURCE_EXHAUSTED)
                    flush(&self.inner, &mut pending).await?;
                    return Err(jsae_proto::wire::receive_error(status));
                }
            };
            if index >= MAX_SESSIONS_PER_CALL {
                flush(&self.inner, &mut pending).await?;
                return Err(RecommendError::ResourceExhausted(format!(
                    "more than {MAX_SESSIONS_PER_CALL} sessions in one call: the first \
                     {MAX_SESSIONS_PER_CALL} were processed ({} accepted); send the rest in \
                     another call",
                    summary.sessions_accepted
                ))
                .into());
            }
            let session = Session::from(message);
            match check_session(&session) {
                Ok(()) => {
                    summary.sessions_accepted += 1;
                    summary.purchases_accepted += session.purchases.len() as u64;
                    pending.push(session);
                    if pending.len() >= STORE_BATCH {
                        flush(&self.inner, &mut pending).await?;
                    }
                }
                Err(reason) => {
                    summary.sessions_rejected += 1;
                    if summary.errors.len() < MAX_ERRORS_LISTED {
                        let id: String = session.session_id.chars().take(64).collect();
                        summary.errors.push(format!(
                            "session {index} (session_id {id:?}): INVALID_ARGUMENT: {reason}"
                        ));
                    }
                }
            }
            index += 1;
        }
        if index == 0 {
            return Err(Status::invalid_argument(
                "no sessions: the stream was empty",
            ));
        }
        flush(&self.inner, &mut pending).await?;
        if summary.sessions_rejected > summary.errors.len() as u64 {
            let more = summary.sessions_rejected - summary.errors.len() as u64;
            summary
                .errors
                .push(format!("... and {more} more rejected sessions"));
        }
        Ok(Response::new(summary))
    }
}

/// Where the weights come from.
#[derive(Debug, Clone, Default)]
pub struct WeightSources {
    /// Learner URL to follow.
    pub learner: Option<String>,
    /// Embedder URL to follow (JSAE).
    pub embedder: Option<String>,
    /// A finished run directory whose checkpoints are loaded at start.
    pub run: Option<PathBuf>,
}

/// The newest `NAME-v{N}.bpk` (or `NAME-latest.bpk` with its `.version` file) in `dir`.
fn newest_checkpoint(dir: &Path, name: &str) -> Option<(u64, PathBuf)> {
    let mut best: Option<(u64, PathBuf)> =
        std::fs::read_to_string(dir.join(format!("{name}-latest.version")))
            .ok()
            .and_then(|v| v.trim().parse().ok())
            .map(|v| (v, dir.join(format!("{name}-latest.bpk"))));
    for entry in std::fs::read_dir(dir).ok()?.flatten() {
        let file = entry.file_name();
        let version = file
            .to_str()
            .and_then(|f| f.strip_prefix(&format!("{name}-v")))
            .and_then(|f| f.strip_suffix(".bpk"))
            .and_then(|v| v.parse::<u64>().ok());
        if let Some(v) = version
            && best.as_ref().is_none_or(|b| v > b.0)
        {
            best = Some((v, entry.path()));
        }
    }
    best
}

/// Loads the newest checkpoints of a run directory (`DIR/checkpoints`) into `rec` where
/// they differ from the versions in use; returns whether anything changed.
pub fn load_run(rec: &Recommender, dir: &Path) -> anyhow::Result<bool> {
    let ckpt = dir.join("checkpoints");
    let read =
        |path: &Path| std::fs::read(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()));
    let mut changed = false;
    if rec.config.algo.uses_embedding() {
        let (version, path) = newest_checkpoint(&ckpt, "embedding")
            .ok_or_else(|| anyhow::anyhow!("{}: no embedding checkpoint yet", ckpt.display()))?;
        if version > rec.embedding_version() {
            rec.set_embedding(&EmbeddingSnapshot {
                version,
                bytes: read(&path)?,
                model_loss: 0.0,
                decoder_loss: 0.0,
            })
            .map_err(anyhow::Error::msg)?;
            changed = true;
        }
    }
    let (version, path) = newest_checkpoint(&ckpt, "policy")
        .ok_or_else(|| anyhow::anyhow!("{}: no policy checkpoint yet", ckpt.display()))?;
    if rec.policy_version() != Some(version) {
        rec.set_policy(&PolicySnapshot {
            version,
            bytes: read(&path)?,
        })
        .map_err(anyhow::Error::msg)?;
        changed = true;
    }
    Ok(changed)
}

/// Follows a run directory: loads its newest checkpoints now and whenever newer ones appear.
async fn follow_run(rec: Arc<Recommender>, dir: PathBuf) {
    let mut waiting_said = false;
    loop {
        let (r, d) = (rec.clone(), dir.clone());
        match tokio::task::spawn_blocking(move || load_run(&r, &d)).await {
            Ok(Ok(true)) => tracing::info!(
                "recommender: weights of {} (policy v{:?}, embedding v{})",
                dir.display(),
                rec.policy_version(),
                rec.embedding_version()
            ),
            Ok(Ok(false)) => {}
            Ok(Err(e)) if !waiting_said => {
                tracing::warn!("recommender: waiting for checkpoints: {e:#}");
                waiting_said = true;
            }
            Ok(Err(e)) => tracing::debug!("recommender: {e:#}"),
            Err(e) => tracing::warn!("recommender: {e}"),
        }
        tokio::time::sleep(RUN_POLL).await;
    }
}

/// Serves `rec` on `listener` until `shutdown` resolves, following the weight sources.
pub async fn serve(
    rec: Arc<Recommender>,
    listener: TcpListener,
    sources: WeightSources,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let mut tasks = tokio::task::JoinSet::new();
    if let Some(dir) = sources.run.clone() {
        // the first load before serving, so a finished run answers from the first request
        let _ = load_run(&rec, &dir);
        tasks.spawn(follow_run(rec.clone(), dir));
    }
    if let Some(url) = sources.learner.clone() {
        let rec = rec.clone();
        tasks.spawn(async move {
            client::watch_policy(&url, 0, |event| {
                if let PolicyEvent::Snapshot(s) = &event {
                    match rec.set_policy(s) {
                        Ok(()) => tracing::debug!("recommender: policy v{}", s.version),
                        Err(e) => tracing::warn!("recommender: {e}"),
                    }
                }
                async { true }
            })
            .await;
        });
    }
    if let Some(url) = sources.embedder.clone() {
        let rec = rec.clone();
        tasks.spawn(async move {
            client::watch_embedding(&url, |s| {
                if let Err(e) = rec.set_embedding(&s) {
                    tracing::warn!("recommender: {e}");
                }
                async { true }
            })
            .await;
        });
    }
    let (health, health_service) = tonic_health::server::health_reporter();
    health
        .set_serving::<pb::recommender_server::RecommenderServer<RecommenderService>>()
        .await;
    let server = pb::recommender_server::RecommenderServer::new(RecommenderService::new(rec))
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES);
    let result = tonic::transport::Server::builder()
        .add_service(health_service)
        .add_service(net::reflection()?)
        .add_service(server)
        .serve_with_incoming_shutdown(net::incoming(listener), shutdown)
        .await;
    tasks.abort_all();
    result?;
    Ok(())
}

/// The recommender's command line.
#[derive(Debug, Clone, clap::Args)]
pub struct RecommenderArgs {
    /// Address to serve on (port 0: any free port; the first stdout line says which).
    #[arg(long, env = "JSAE_LISTEN", default_value = "127.0.0.1:50060")]
    pub listen: String,
    /// Learner URL to follow for policy snapshots (`http://host:port`).
    #[arg(long, env = "JSAE_LEARNER")]
    pub learner: Option<String>,
    /// Embedder URL to follow for embedding snapshots (needed by `--algo jsae` with
    /// `--learner`).
    #[arg(long, env = "JSAE_EMBEDDER")]
    pub embedder: Option<String>,
    /// A finished run directory: its config.toml and latest checkpoints are used.
    #[arg(long, env = "JSAE_RUN")]
    pub run: Option<PathBuf>,
    /// Algorithm of the policy [default: the run's or settings file's, else jsae].
    #[arg(long, value_enum, env = "JSAE_ALGO")]
    pub algo: Option<Algo>,
    /// Settings file (TOML, as a run's config.toml; `[environment.recommender]` picks the
    /// data).
    #[arg(long, env = "JSAE_CONFIG")]
    pub config: Option<PathBuf>,
    /// Session store directory: submitted sessions are appended there, and the n-gram
    /// model is rebuilt from it [default: the settings', else sessions are checked but not
    /// kept].
    #[arg(long, env = "JSAE_STORE_DIR")]
    pub store_dir: Option<PathBuf>,
    /// burn device [default: flex].
    #[arg(long, value_enum, env = "JSAE_DEVICE")]
    pub device: Option<DeviceKind>,
}

fn config_of(args: &RecommenderArgs) -> Result<TrainConfig, String> {
    let file = match (&args.config, &args.run) {
        (Some(f), _) => Some(f.clone()),
        (None, Some(run)) => Some(run.join("config.toml")),
        (None, None) => None,
    };
    let mut c = TrainConfig::from_layers(Some(EnvName::Recommender), args.algo, file.as_deref())
        .map_err(|e| e.to_string())?;
    if c.env != EnvName::Recommender {
        return Err(format!(
            "the settings are for --env {}, not recommender",
            c.env.as_str()
        ));
    }
    if let Some(dir) = &args.store_dir {
        c.environment.recommender.store_dir = dir.clone();
    }
    c.device = args.device.unwrap_or(c.device);
    c.validate().map_err(|e| e.to_string())?;
    if args.learner.is_none() && args.run.is_none() {
        return Err("give --learner URL (follow a run) or --run DIR (a finished run)".into());
    }
    if c.algo.uses_embedding() && args.learner.is_some() && args.embedder.is_none() {
        return Err(format!(
            "--embedder is required with --learner for --algo {}",
            c.algo.as_str()
        ));
    }
    Ok(c)
}

/// Runs the recommender service: exit 0 on SIGINT/SIGTERM, 2 for a bad configuration, 1 when
/// it fails. With `--run DIR` it waits for the run's config.toml (a run still starting).
pub fn main(args: RecommenderArgs) -> std::process::ExitCode {
    use std::process::ExitCode;
    net::init_logging();
    let runtime = match net::runtime() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("jsae recommender: {e}");
            return ExitCode::FAILURE;
        }
    };
    let result: Result<(), (u8, String)> = runtime.block_on(async {
        let fail = |e: &dyn std::fmt::Display| (1, format!("{e:#}"));
        let mut shutdown = Box::pin(net::shutdown_signal().map_err(|e| fail(&e))?);
        if let (Some(run), None) = (&args.run, &args.config) {
            let file = run.join("config.toml");
            if !file.exists() {
                tracing::info!("recommender: waiting for {}", file.display());
            }
            while !file.exists() {
                tokio::select! {
                    () = &mut shutdown => return Ok(()),
                    () = tokio::time::sleep(RUN_POLL) => {}
                }
            }
        }
        let config = config_of(&args).map_err(|e| (2, e))?;
        let rec = Recommender::new(&config, config.device).map_err(|e| (2, e.to_string()))?;
        if !rec.has_store() {
            tracing::warn!("recommender: no session store (--store-dir): sessions are not kept");
        }
        let sources = WeightSources {
            learner: args.learner.clone(),
            embedder: args.embedder.clone(),
            run: args.run.clone(),
        };
        let listener = net::bind(&args.listen).await.map_err(|e| fail(&e))?;
        let addr = listener.local_addr().map_err(|e| fail(&e))?;
        println!("jsae recommender listening on {addr}");
        serve(Arc::new(rec), listener, sources, shutdown)
            .await
            .map_err(|e| fail(&e))
    });
    runtime.shutdown_timeout(Duration::from_secs(2));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err((code, e)) => {
            eprintln!("jsae recommender: {e}");
            ExitCode::from(code)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn best_k_orders_by_score_then_index() {
        let mut v = vec![(0, 0.1), (1, 0.5), (2, 0.5), (3, 0.9), (4, -1.0)];
        best_k(&mut v, 3);
        assert_eq!(v, vec![(3, 0.9), (1, 0.5), (2, 0.5)]);
    }

    #[test]
    fn nearest_items_skip_free_slots_and_score_minus_distance() {
        // rows: (0,0) (3,4) (1,0) and a free slot (0.1, 0) that must not be answered
        let table = [0.0, 0.0, 3.0, 4.0, 1.0, 0.0, 0.1, 0.0];
        let got = nearest_items(&table, &[0.0, 0.0], 3, 3);
        assert_eq!(got, vec![(0, -0.0), (2, -1.0), (1, -5.0)]);
    }

    #[test]
    fn most_likely_is_the_softmax_of_the_filled_slots() {
        let got = most_likely(&[0.0, (2.0f32).ln(), 10.0], 2, 2);
        assert_eq!(got[0].0, 1);
        assert_eq!(got[1].0, 0);
        assert!((got[0].1 / got[1].1 - 2.0).abs() < 1e-5);
    }
}
