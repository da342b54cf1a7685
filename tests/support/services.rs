//! The services harness: embedder, learner and actors started from their libraries on free
//! loopback ports (as the processes start them), and the messages and checks the service
//! tests share.

use std::path::Path;
use std::time::Duration;

use jsae_actor::service::{ActorOptions, ActorReport};
use jsae_embedder::service::EmbedderOptions;
use jsae_learner::service::LearnerOptions;
use jsae_net::security::Security;
use jsae_run_dir::RunDir;
use jsae_run_dir::{MetricsTable, Summary};
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_wire::pb;
use jsae_wire::{ActionBatch, RolloutFragment, StateBatch, TransitionBatch};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tonic::Code;

use crate::{small_config, temp_dir};

/// A service started from its library on a free loopback port.
#[derive(Debug)]
pub struct Service<T> {
    /// Its URL (`http://127.0.0.1:PORT`).
    pub url: String,
    /// Sends its shutdown signal.
    pub stop: Option<oneshot::Sender<()>>,
    /// The serving task.
    pub handle: JoinHandle<anyhow::Result<T>>,
}

impl<T> Service<T> {
    /// Sends the shutdown signal and waits for the service to return.
    pub async fn stop(mut self) -> anyhow::Result<T> {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        self.handle.await.expect("service task")
    }

    /// Waits (at most 240 s) for the service to return by itself.
    pub async fn join(self) -> anyhow::Result<T> {
        tokio::time::timeout(Duration::from_secs(240), self.handle)
            .await
            .expect("finishes in time")
            .expect("service task")
    }
}

pub fn stop_signal() -> (
    oneshot::Sender<()>,
    impl Future<Output = ()> + Send + 'static,
) {
    let (tx, rx) = oneshot::channel::<()>();
    (tx, async move {
        let _ = rx.await;
    })
}

pub async fn bind() -> (TcpListener, String) {
    bind_for(&Security::default()).await
}

/// A free loopback port and its URL for clients with `security` (`https://` with TLS).
pub async fn bind_for(security: &Security) -> (TcpListener, String) {
    let l = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let url = format!("{}://{}", security.scheme(), l.local_addr().expect("addr"));
    (l, url)
}

pub async fn start_embedder(config: &TrainConfig) -> Service<()> {
    // the logged purchases, where the settings ask, as `jsae embedder` reads them
    let logged = jsae_train::logs::logged_items(config).expect("logs read");
    let options = EmbedderOptions {
        logged: logged.map(std::sync::Arc::new),
        ..EmbedderOptions::default()
    };
    start_embedder_with(config, options).await
}

pub async fn start_embedder_with(config: &TrainConfig, options: EmbedderOptions) -> Service<()> {
    let (listener, url) = bind_for(&options.security).await;
    let (stop, signal) = stop_signal();
    let config = config.clone();
    let handle = tokio::spawn(jsae_embedder::service::serve(
        config, listener, options, signal,
    ));
    Service {
        url,
        stop: Some(stop),
        handle,
    }
}

pub async fn start_learner_on(
    config: &TrainConfig,
    listener: TcpListener,
    url: String,
    embedder: Option<String>,
) -> Service<Option<Summary>> {
    start_learner_secured(config, listener, url, embedder, Security::default()).await
}

/// [`start_learner_on`] with `security` in front of it and towards the embedder.
pub async fn start_learner_secured(
    config: &TrainConfig,
    listener: TcpListener,
    url: String,
    embedder: Option<String>,
    security: Security,
) -> Service<Option<Summary>> {
    let (stop, signal) = stop_signal();
    let options = LearnerOptions {
        embedder,
        logged: jsae_train::logs::logged_purchases(config)
            .expect("the logged purchases")
            .map(std::sync::Arc::new),
        resume: false,
        metrics: Default::default(),
        security,
    };
    let handle = tokio::spawn(jsae_learner::service::serve(
        config.clone(),
        listener,
        options,
        signal,
    ));
    Service {
        url,
        stop: Some(stop),
        handle,
    }
}

pub async fn start_learner(
    config: &TrainConfig,
    embedder: Option<String>,
) -> Service<Option<Summary>> {
    let (listener, url) = bind().await;
    start_learner_on(config, listener, url, embedder).await
}

pub fn start_actor(
    config: &TrainConfig,
    id: u64,
    embedder: Option<&str>,
    learner: &str,
) -> Service<ActorReport> {
    start_actor_secured(config, id, embedder, learner, Security::default())
}

/// [`start_actor`] with `security` towards the embedder and the learner.
pub fn start_actor_secured(
    config: &TrainConfig,
    id: u64,
    embedder: Option<&str>,
    learner: &str,
    security: Security,
) -> Service<ActorReport> {
    let (stop, signal) = stop_signal();
    let options = ActorOptions {
        env_host: None,
        id,
        embedder: embedder.map(String::from),
        learner: learner.to_string(),
        record: None,
        metrics: Default::default(),
        security,
    };
    let handle = tokio::spawn(jsae_actor::service::run(config.clone(), options, signal));
    Service {
        url: String::new(),
        stop: Some(stop),
        handle,
    }
}

pub fn config(env: EnvName, algo: Algo, name: &str) -> TrainConfig {
    let mut c = small_config(env, algo, 3, temp_dir(name));
    c.envs_per_actor = 4;
    c.rollout_len = 32;
    c.embedding.pretrain_transitions = 1_024;
    c.embedding.pretrain_per_action = 0;
    c.embedding.pretrain_epochs = 2;
    c.embedding.update_every = 2_048;
    c.embedding.update_steps = 5;
    c.policy_wait_ms = 500;
    c
}

/// Rows of a run directory's metrics.csv so far (0 before it exists).
pub fn metrics_rows(out: &Path) -> usize {
    MetricsTable::read(&RunDir::new(out).metrics_csv()).map_or(0, |t| t.len())
}

pub async fn wait_for_rows(out: &Path, rows: usize) {
    for _ in 0..2400 {
        if metrics_rows(out) >= rows {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("the learner did not reach {rows} updates");
}

pub async fn channel(url: &str) -> tonic::transport::Channel {
    tonic::transport::Channel::from_shared(url.to_string())
        .expect("url")
        .connect()
        .await
        .expect("connect")
}

pub fn increasing(v: &[u64]) -> bool {
    v.windows(2).all(|w| w[0] < w[1])
}

pub fn fragment(x_dim: usize, n: usize) -> RolloutFragment {
    RolloutFragment {
        actor_id: 9,
        env_index: 0,
        policy_version: 0,
        embedding_version: 0,
        actor_env_steps: n as u64,
        x_dim,
        x: vec![0.5; n * x_dim],
        actions: ActionBatch::Discrete(vec![1; n]),
        logp: vec![-6.0; n],
        rewards: vec![-0.01; n],
        terminated: vec![false; n],
        truncated: vec![false; n],
        truncated_next_x: vec![],
        last_next_x: vec![0.5; x_dim],
        episodes: vec![],
        actor_incarnation: 1,
        visit_keys: Vec::new(),
    }
}

pub async fn push_fragments(
    url: &str,
    msgs: Vec<pb::RolloutFragment>,
) -> Result<u64, tonic::Status> {
    let mut client = pb::learner_client::LearnerClient::connect(url.to_string())
        .await
        .expect("connect")
        .max_encoding_message_size(64 << 20);
    client
        .push_fragments(tokio_stream::iter(msgs))
        .await
        .map(|r| r.into_inner().accepted)
}

/// Pushes `msgs` to the learner at `url`, which must accept every one.
pub async fn push_all(url: &str, msgs: Vec<pb::RolloutFragment>) {
    let n = msgs.len() as u64;
    assert_eq!(push_fragments(url, msgs).await.expect("accepted"), n);
}

/// Pushes 512 transitions to the embedder at `url` (whose pre-training takes 512) and waits
/// for its first embedding, version 1.
pub async fn pretrain_to_version_one(url: &str) {
    let mut client = pb::embedder_client::EmbedderClient::connect(url.to_string())
        .await
        .expect("connect");
    let batches = vec![pb::TransitionBatch::from(transitions(512, -0.01))];
    client
        .push_transitions(tokio_stream::iter(batches))
        .await
        .expect("accepted");
    assert_eq!(first_embedding_version(url).await, 1);
}

pub fn transitions(n: usize, reward: f32) -> TransitionBatch {
    TransitionBatch {
        actor_id: 9,
        states: StateBatch::Real {
            dim: 2,
            data: vec![0.3; 2 * n],
        },
        actions: ActionBatch::Discrete((0..n as u32).map(|i| i % 512).collect()),
        rewards: vec![reward; n],
        next_states: StateBatch::Real {
            dim: 2,
            data: vec![0.31; 2 * n],
        },
        terminated: vec![false; n],
    }
}

pub fn assert_refused(r: Result<u64, tonic::Status>, code: Code, words: &str) {
    match r {
        Ok(n) => panic!("accepted {n} messages, expected {code:?}"),
        Err(s) => {
            assert_eq!(s.code(), code, "{}", s.message());
            assert!(
                s.message().contains(words),
                "{:?} lacks {words:?}",
                s.message()
            );
        }
    }
}

pub async fn first_embedding_version(url: &str) -> u64 {
    let mut client = pb::embedder_client::EmbedderClient::connect(url.to_string())
        .await
        .expect("connect");
    let mut watch = client
        .watch_embedding(pb::WatchRequest::default())
        .await
        .expect("watch")
        .into_inner();
    tokio::time::timeout(Duration::from_secs(60), watch.message())
        .await
        .expect("a snapshot in time")
        .expect("stream")
        .expect("a chunk")
        .version
}

/// A well-formed fragment of `steps` random steps for `config`'s learner (its input width
/// and action head), from `actor` in `incarnation`, claiming `claim` env steps, under policy
/// version 0 and embedding version `embedding`.
pub fn claimed_fragment(
    config: &TrainConfig,
    actor: u64,
    incarnation: u64,
    claim: u64,
    steps: usize,
    embedding: u64,
) -> pb::RolloutFragment {
    use rand::SeedableRng;
    let learner = jsae_learner::Learner::for_run(config);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(claim ^ actor ^ incarnation);
    let x_dim = learner.policy().input_dim();
    let mut f = jsae_learner::synthetic::fragment(x_dim, learner.head(), 0, steps, &mut rng);
    f.actor_id = actor;
    f.actor_incarnation = incarnation;
    f.actor_env_steps = claim;
    f.embedding_version = embedding;
    f.into()
}

/// The learner's policy stream as actor `actor_id` sees it.
pub async fn watch_policy(url: &str, actor_id: u64) -> tonic::Streaming<pb::PolicyEvent> {
    let mut client = pb::learner_client::LearnerClient::connect(url.to_string())
        .await
        .expect("connect")
        .max_decoding_message_size(jsae_wire::MAX_MESSAGE_BYTES);
    client
        .watch_policy(pb::WatchRequest {
            actor_id,
            evaluates: true,
            ..Default::default()
        })
        .await
        .expect("watch")
        .into_inner()
}

/// The next event of a policy stream (at most 60 s away).
pub async fn next_event(stream: &mut tonic::Streaming<pb::PolicyEvent>) -> pb::policy_event::Event {
    tokio::time::timeout(Duration::from_secs(60), stream.message())
        .await
        .expect("an event in time")
        .expect("the stream")
        .and_then(|e| e.event)
        .expect("an event")
}

/// Reads a policy stream until the last chunk of a snapshot of at least `version`; an
/// evaluation request on the way is returned instead.
pub async fn until_snapshot(
    stream: &mut tonic::Streaming<pb::PolicyEvent>,
    version: u64,
) -> Result<u64, pb::EvalRequest> {
    use pb::policy_event::Event;
    loop {
        match next_event(stream).await {
            Event::Chunk(c) if c.last && c.version >= version => return Ok(c.version),
            Event::Evaluate(request) => return Err(request),
            _ => {}
        }
    }
}
