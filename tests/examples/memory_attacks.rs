//! The memory attacks of issue 43 against running services, with their peak RSS: many idle
//! `WatchEmbedding` and `WatchPolicy` streams that never read, `Health.Watch` floods,
//! fragments with no step and a million episode statistics, tens of thousands of tiny empty
//! fragments, and sockets that never speak; a health `Check` every 200 ms throughout.
//! `scripts/memory-attacks.sh` starts a run and calls it; by hand:
//!   cargo run --release -p jsae-tests --example memory_attacks -- LEARNER_URL EMBEDDER_URL \
//!       LEARNER_PID EMBEDDER_PID
//! It prints one line per attack (accepted, refused, each service's RSS and peak, health
//! answers missed) and exits 1 if a peak passes 512 MB or a health check went unanswered.

use std::time::{Duration, Instant};

use jsae_wire::pb;
use tonic::transport::{Channel, Endpoint};
use tonic_health::pb::HealthCheckRequest;
use tonic_health::pb::health_client::HealthClient;

/// The peak RSS the issue allows every service.
const MAX_PEAK_MB: f64 = 512.0;

/// (current, peak) resident memory of a process, in MB.
fn rss_mb(pid: u32) -> (f64, f64) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let field = |name: &str| -> f64 {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|kb| kb.parse::<f64>().ok())
            .map_or(f64::NAN, |kb| kb / 1024.0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

async fn connect(url: &str) -> Option<Channel> {
    Endpoint::from_shared(url.to_string())
        .ok()?
        .connect_timeout(Duration::from_secs(5))
        .connect()
        .await
        .ok()
}

/// Streams held open (never read), with their connections.
type Held<T> = (Vec<T>, Vec<Channel>);

/// Opens `connections` x `per_connection` streams with `open`, holding those accepted
/// (never read) and their connections; returns them and the counts accepted and refused.
async fn hold_streams<T, F, Fut>(
    url: &str,
    connections: usize,
    per_connection: usize,
    open: F,
) -> (Held<T>, usize, usize)
where
    F: Fn(Channel) -> Fut,
    Fut: std::future::Future<Output = Result<T, tonic::Status>>,
{
    let (mut held, mut channels, mut refused) = (Vec::new(), Vec::new(), 0);
    for _ in 0..connections {
        let Some(channel) = connect(url).await else {
            refused += per_connection;
            continue;
        };
        for _ in 0..per_connection {
            match open(channel.clone()).await {
                Ok(stream) => held.push(stream),
                Err(_) => refused += 1,
            }
        }
        channels.push(channel);
    }
    let accepted = held.len();
    ((held, channels), accepted, refused)
}

/// A fragment with no step and `episodes` episode statistics.
fn empty_fragment(episodes: usize) -> pb::RolloutFragment {
    pb::RolloutFragment {
        actor_id: 1,
        x_dim: 1,
        actions: Some(pb::ActionBatch {
            kind: Some(pb::action_batch::Kind::Discrete(
                pb::DiscreteActions::default(),
            )),
        }),
        episodes: vec![
            pb::EpisodeStat {
                ret: 1.0,
                length: 1,
                success: None,
            };
            episodes
        ],
        ..Default::default()
    }
}

/// Pushes `messages` copies of `fragment` in one stream; the count the service accepted.
async fn push(url: &str, fragment: pb::RolloutFragment, messages: usize) -> Result<u64, String> {
    let channel = connect(url).await.ok_or("no connection")?;
    let mut client = pb::learner_client::LearnerClient::new(channel)
        .max_encoding_message_size(jsae_wire::MAX_MESSAGE_BYTES);
    let stream = tokio_stream::iter(std::iter::repeat_n(fragment, messages));
    client
        .push_fragments(stream)
        .await
        .map(|r| r.into_inner().accepted)
        .map_err(|s| format!("{:?}: {}", s.code(), s.message()))
}

/// Checks the health of both services every 200 ms; the checks unanswered within 2 s and
/// all the checks, counted as they go.
fn watch_health(
    urls: [String; 2],
) -> (
    std::sync::Arc<std::sync::atomic::AtomicU64>,
    std::sync::Arc<std::sync::atomic::AtomicU64>,
) {
    let missed = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let checks = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    for url in urls {
        let (missed, checks) = (missed.clone(), checks.clone());
        tokio::spawn(async move {
            loop {
                let answered = tokio::time::timeout(Duration::from_secs(2), async {
                    let channel = connect(&url).await?;
                    HealthClient::new(channel)
                        .check(HealthCheckRequest::default())
                        .await
                        .ok()
                })
                .await;
                checks.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if !matches!(answered, Ok(Some(_))) {
                    missed.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
        });
    }
    (missed, checks)
}

/// Idle streams held open: WatchEmbedding, WatchPolicy, then Health.Watch on both services;
/// `report` says how many each service took.
async fn idle_streams(learner: &str, embedder: &str, report: &impl Fn(&str, String)) {
    let (idle_embedding, accepted, refused) = hold_streams(embedder, 250, 8, |c| async move {
        pb::embedder_client::EmbedderClient::new(c)
            .watch_embedding(pb::WatchRequest::default())
            .await
    })
    .await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    report(
        "2,000 idle WatchEmbedding (250 conn. x 8)",
        format!("{accepted} open, {refused} refused"),
    );
    let (idle_policy, accepted, refused) = hold_streams(learner, 38, 8, |c| async move {
        pb::learner_client::LearnerClient::new(c)
            .watch_policy(pb::WatchRequest::default())
            .await
    })
    .await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    report(
        "304 idle WatchPolicy (38 conn. x 8)",
        format!("{accepted} open, {refused} refused"),
    );
    drop((idle_embedding, idle_policy));
    let mut health_watches = Vec::new();
    for url in [learner, embedder] {
        let (held, accepted, refused) = hold_streams(url, 1000, 2, |c| async move {
            HealthClient::new(c)
                .watch(HealthCheckRequest::default())
                .await
        })
        .await;
        report(
            "2,000 Health.Watch (1,000 conn. x 2)",
            format!("{accepted} open, {refused} refused"),
        );
        health_watches.push(held);
    }
    drop(health_watches);
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> std::process::ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [learner, embedder, learner_pid, embedder_pid] = args.as_slice() else {
        eprintln!("usage: memory_attacks LEARNER_URL EMBEDDER_URL LEARNER_PID EMBEDDER_PID");
        return std::process::ExitCode::from(2);
    };
    let pids: [(&str, u32); 2] = [
        ("learner", learner_pid.parse().unwrap_or(0)),
        ("embedder", embedder_pid.parse().unwrap_or(0)),
    ];
    let (missed, checks) = watch_health([learner.clone(), embedder.clone()]);
    let report = |attack: &str, outcome: String| {
        let memory: Vec<String> = pids
            .iter()
            .map(|(name, pid)| {
                let (now, peak) = rss_mb(*pid);
                format!("{name} RSS {now:.0} MB (peak {peak:.0})")
            })
            .collect();
        println!("{attack:<44} {outcome:<60} {}", memory.join(", "));
    };
    let started = Instant::now();
    report("before", String::new());

    idle_streams(learner, embedder, &report).await;
    let big = push(learner, empty_fragment(1_150_000), 40).await;
    report(
        "40 fragments, 0 steps, 1.15M episodes",
        format!("{big:?}").chars().take(60).collect(),
    );
    let tiny = push(learner, empty_fragment(0), 60_000).await;
    report(
        "60,000 fragments, 0 steps",
        format!("{tiny:?}").chars().take(60).collect(),
    );
    let mut silent = Vec::new();
    for url in [learner, embedder] {
        let addr = url.trim_start_matches("http://");
        for _ in 0..300 {
            if let Ok(s) = tokio::net::TcpStream::connect(addr).await {
                silent.push(s);
            }
        }
    }
    tokio::time::sleep(Duration::from_secs(2)).await;
    report(
        "300 silent sockets each",
        format!("{} connected", silent.len()),
    );
    drop(silent);
    let (missed, checks) = (
        missed.load(std::sync::atomic::Ordering::Relaxed),
        checks.load(std::sync::atomic::Ordering::Relaxed),
    );
    let peaks: Vec<f64> = pids.iter().map(|(_, pid)| rss_mb(*pid).1).collect();
    println!(
        "{:.0} s; health checks unanswered: {missed} of {checks}; peak RSS {:?} MB (at most {MAX_PEAK_MB})",
        started.elapsed().as_secs_f64(),
        peaks.iter().map(|p| p.round()).collect::<Vec<_>>()
    );
    if missed > 0 || peaks.iter().any(|&p| p.is_nan() || p > MAX_PEAK_MB) {
        return std::process::ExitCode::FAILURE;
    }
    std::process::ExitCode::SUCCESS
}
