//! The metric families of each service, with their names and help texts. Integers are
//! gauges where the service already keeps the count (set from it: a restarted process or a
//! resumed run goes on from its own count), counters where the family counts events here.

use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

/// A gauge of real values.
type RealGauge = Gauge<f64, AtomicU64>;
/// One label.
type Label = [(&'static str, &'static str); 1];

fn gauge(v: u64) -> i64 {
    i64::try_from(v).unwrap_or(i64::MAX)
}

/// A rate (per second) of a growing count, measured over windows of at least a second.
#[derive(Debug, Clone, Default)]
struct Rate {
    gauge: RealGauge,
    last: Arc<Mutex<Option<(Instant, u64)>>>,
}

impl Rate {
    fn observe(&self, count: u64) {
        let now = Instant::now();
        let mut last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        match *last {
            Some((t, c)) if now.duration_since(t).as_secs_f64() >= 1.0 => {
                let dt = now.duration_since(t).as_secs_f64();
                self.gauge.set(count.saturating_sub(c) as f64 / dt);
                *last = Some((now, count));
            }
            Some(_) => {}
            None => *last = Some((now, count)),
        }
    }
}

/// What the learner thread knows after each message it handles.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LearnerSample {
    /// Env steps of the run so far.
    pub env_steps: u64,
    /// Updates done.
    pub updates: u64,
    /// The published policy version.
    pub policy_version: u64,
    /// The newest embedding version seen in a fragment.
    pub embedding_version: u64,
    /// Fragments dropped for policy lag and for an outdated embedding, so far.
    pub dropped: (u64, u64),
    /// Messages waiting in the learner thread's queue.
    pub queue_depth: usize,
}

/// The learner's families (`jsae_learner_*`).
#[derive(Debug, Clone, Default)]
pub struct LearnerMetrics {
    /// Env steps of all actors so far.
    pub env_steps: Gauge,
    steps_per_second: Rate,
    updates: Gauge,
    policy_version: Gauge,
    embedding_version: Gauge,
    policy_lag: RealGauge,
    queue_depth: Gauge,
    fragments: Counter,
    dropped: Family<Label, Gauge>,
    actors: Family<Label, Gauge>,
    actor_steps: Family<Vec<(&'static str, String)>, Counter>,
}

impl LearnerMetrics {
    /// Registers the families in `registry`.
    pub fn register(registry: &mut Registry) -> Self {
        let m = Self::default();
        let r = registry.sub_registry_with_prefix("jsae_learner");
        r.register(
            "env_steps",
            "Env steps of all actors so far",
            m.env_steps.clone(),
        );
        r.register(
            "env_steps_per_second",
            "Env steps per second over the last second or more",
            m.steps_per_second.gauge.clone(),
        );
        r.register("updates", "PPO updates done in the run", m.updates.clone());
        r.register(
            "policy_version",
            "The published policy version",
            m.policy_version.clone(),
        );
        r.register(
            "embedding_version",
            "The newest embedding version of the fragments",
            m.embedding_version.clone(),
        );
        r.register(
            "policy_lag",
            "Mean policy lag (versions) of the last update's batch",
            m.policy_lag.clone(),
        );
        r.register(
            "queue_depth",
            "Messages waiting for the learner thread",
            m.queue_depth.clone(),
        );
        r.register(
            "fragments",
            "Rollout fragments received",
            m.fragments.clone(),
        );
        r.register(
            "fragments_dropped",
            "Fragments dropped so far, by reason (lag, embedding)",
            m.dropped.clone(),
        );
        r.register(
            "actors",
            "Actors with an open policy stream (connected), and those of them in the batch \
             (present)",
            m.actors.clone(),
        );
        r.register(
            "actor_env_steps",
            "Env steps of the fragments received, by actor id",
            m.actor_steps.clone(),
        );
        m
    }

    /// Actors connected, and present in the batch.
    pub fn observe_actors(&self, (connected, present): (usize, usize)) {
        self.actors
            .get_or_create(&[("state", "connected")])
            .set(gauge(connected as u64));
        self.actors
            .get_or_create(&[("state", "present")])
            .set(gauge(present as u64));
    }

    /// A fragment of `steps` env steps came from actor `actor`.
    pub fn observe_actor_steps(&self, actor: u64, steps: u64) {
        self.actor_steps
            .get_or_create(&vec![("actor", actor.to_string())])
            .inc_by(steps);
    }

    /// A fragment was handled; `sample` is the learner's state after it.
    pub fn observe_fragment(&self, sample: &LearnerSample) {
        self.fragments.inc();
        self.env_steps.set(gauge(sample.env_steps));
        self.steps_per_second.observe(sample.env_steps);
        self.updates.set(gauge(sample.updates));
        self.policy_version.set(gauge(sample.policy_version));
        self.embedding_version.set(gauge(sample.embedding_version));
        self.queue_depth.set(gauge(sample.queue_depth as u64));
        let (lag, embedding) = sample.dropped;
        self.dropped
            .get_or_create(&[("reason", "lag")])
            .set(gauge(lag));
        self.dropped
            .get_or_create(&[("reason", "embedding")])
            .set(gauge(embedding));
    }

    /// An update finished with this mean policy lag.
    pub fn observe_update(&self, policy_lag_mean: f64) {
        self.policy_lag.set(policy_lag_mean);
    }
}

/// The embedder's families (`jsae_embedder_*`).
#[derive(Debug, Clone, Default)]
pub struct EmbedderMetrics {
    transitions: Gauge,
    transitions_per_second: Rate,
    embedding_version: Gauge,
    model_loss: RealGauge,
    decoder_loss: RealGauge,
    queue_depth: Gauge,
    replay_len: Gauge,
}

/// What the embedder's training thread knows after each batch.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EmbedderSample {
    /// Transitions received so far.
    pub transitions: u64,
    /// The published embedding version.
    pub embedding_version: u64,
    /// Model and decoder loss of the last round.
    pub losses: (f32, f32),
    /// Batches waiting for the training thread.
    pub queue_depth: usize,
    /// Transitions in the replay buffer.
    pub replay_len: usize,
}

impl EmbedderMetrics {
    /// Registers the families in `registry`.
    pub fn register(registry: &mut Registry) -> Self {
        let m = Self::default();
        let r = registry.sub_registry_with_prefix("jsae_embedder");
        r.register("transitions", "Transitions received", m.transitions.clone());
        r.register(
            "transitions_per_second",
            "Transitions received per second over the last second or more",
            m.transitions_per_second.gauge.clone(),
        );
        r.register(
            "embedding_version",
            "The published embedding version (0: still pre-training)",
            m.embedding_version.clone(),
        );
        r.register(
            "model_loss",
            "Model loss of the last round",
            m.model_loss.clone(),
        );
        r.register(
            "decoder_loss",
            "Decoder loss of the last round",
            m.decoder_loss.clone(),
        );
        r.register(
            "queue_depth",
            "Transition batches waiting for the training thread",
            m.queue_depth.clone(),
        );
        r.register(
            "replay_len",
            "Transitions in the replay buffer",
            m.replay_len.clone(),
        );
        m
    }

    /// A batch was handled; `sample` is the trainer's state after it.
    pub fn observe_batch(&self, sample: &EmbedderSample) {
        self.transitions.set(gauge(sample.transitions));
        self.transitions_per_second.observe(sample.transitions);
        self.embedding_version.set(gauge(sample.embedding_version));
        self.model_loss.set(f64::from(sample.losses.0));
        self.decoder_loss.set(f64::from(sample.losses.1));
        self.queue_depth.set(gauge(sample.queue_depth as u64));
        self.replay_len.set(gauge(sample.replay_len as u64));
    }
}

/// An actor's families (`jsae_actor_*`).
#[derive(Debug, Clone, Default)]
pub struct ActorMetrics {
    env_steps: Gauge,
    steps_per_second: Rate,
    policy_version: Gauge,
    embedding_version: Gauge,
    fragments: Counter,
    queue_depth: Family<Label, Gauge>,
}

/// What the stepping thread knows after each rollout.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ActorSample {
    /// This actor's env steps.
    pub env_steps: u64,
    /// The policy and embedding versions it acts with.
    pub versions: (u64, u64),
    /// Transition batches and fragments waiting to be sent.
    pub queued: (usize, usize),
    /// Fragments this rollout queued (one per environment; none during random play).
    pub fragments: u64,
}

impl ActorMetrics {
    /// Registers the families in `registry`.
    pub fn register(registry: &mut Registry) -> Self {
        let m = Self::default();
        let r = registry.sub_registry_with_prefix("jsae_actor");
        r.register("env_steps", "Env steps of this actor", m.env_steps.clone());
        r.register(
            "env_steps_per_second",
            "Env steps per second over the last second or more",
            m.steps_per_second.gauge.clone(),
        );
        r.register(
            "policy_version",
            "The policy version acted with",
            m.policy_version.clone(),
        );
        r.register(
            "embedding_version",
            "The embedding version acted with",
            m.embedding_version.clone(),
        );
        r.register(
            "fragments",
            "Rollout fragments collected",
            m.fragments.clone(),
        );
        r.register(
            "queue_depth",
            "Messages waiting to be sent, by queue (transitions, fragments)",
            m.queue_depth.clone(),
        );
        m
    }

    /// A rollout was collected and queued.
    pub fn observe_rollout(&self, sample: &ActorSample) {
        self.fragments.inc_by(sample.fragments);
        self.env_steps.set(gauge(sample.env_steps));
        self.steps_per_second.observe(sample.env_steps);
        self.policy_version.set(gauge(sample.versions.0));
        self.embedding_version.set(gauge(sample.versions.1));
        let (transitions, fragments) = sample.queued;
        for (queue, depth) in [("transitions", transitions), ("fragments", fragments)] {
            self.queue_depth
                .get_or_create(&[("queue", queue)])
                .set(gauge(depth as u64));
        }
    }
}

/// The Recommender's families (`jsae_recommender_*`).
#[derive(Debug, Clone)]
pub struct RecommenderMetrics {
    latency: Histogram,
    requests: Family<[(&'static str, &'static str); 2], Counter>,
    sessions: Family<Label, Counter>,
    policy_version: Gauge,
}

impl Default for RecommenderMetrics {
    fn default() -> Self {
        Self {
            // 50 us to about 1.6 s
            latency: Histogram::new(exponential_buckets(5e-5, 2.0, 16)),
            requests: Family::default(),
            sessions: Family::default(),
            policy_version: Gauge::default(),
        }
    }
}

impl RecommenderMetrics {
    /// Registers the families in `registry`.
    pub fn register(registry: &mut Registry) -> Self {
        let m = Self::default();
        let r = registry.sub_registry_with_prefix("jsae_recommender");
        r.register(
            "recommend_seconds",
            "Time to answer a Recommend call",
            m.latency.clone(),
        );
        r.register(
            "requests",
            "Calls answered, by rpc and status code",
            m.requests.clone(),
        );
        r.register(
            "sessions",
            "Submitted sessions, by outcome (accepted, rejected)",
            m.sessions.clone(),
        );
        r.register(
            "policy_version",
            "The policy version of the last answer",
            m.policy_version.clone(),
        );
        m
    }

    /// A Recommend call took `seconds` and ended with `code` (`ok`, `invalid_argument`, ...)
    /// under `policy_version` where it was answered.
    pub fn observe_recommend(&self, seconds: f64, code: &'static str, policy_version: Option<u64>) {
        self.latency.observe(seconds);
        self.requests
            .get_or_create(&[("rpc", "recommend"), ("code", code)])
            .inc();
        if let Some(v) = policy_version {
            self.policy_version.set(gauge(v));
        }
    }

    /// A SubmitSessions call ended with `code`, having accepted and rejected these sessions.
    pub fn observe_submit(&self, code: &'static str, accepted: u64, rejected: u64) {
        self.requests
            .get_or_create(&[("rpc", "submit_sessions"), ("code", code)])
            .inc();
        self.sessions
            .get_or_create(&[("outcome", "accepted")])
            .inc_by(accepted);
        self.sessions
            .get_or_create(&[("outcome", "rejected")])
            .inc_by(rejected);
    }
}
