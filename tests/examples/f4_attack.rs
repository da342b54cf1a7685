//! The F4 attack on `SubmitSessions` against a `jsae recommender` process, with the process's
//! peak resident memory (VmHWM of /proc/PID/status) after each step:
//!
//! 1. one call of 500 maximum-size sessions (10,000 purchases of 256-byte ids, about 2.8 MB
//!    each), cancelled half-way (the service refuses it at MAX_CALL_BYTES before that);
//! 2. a call within the limits, cancelled after 22 such sessions (a cancel is a reset of the
//!    stream before its end: the client resets it with a message over its own limit);
//! 3. MAX_CONCURRENT_CALLS calls of them at once, and one more;
//!
//! after which the store must hold what it held before. Then the store is filled with
//! `--store-mb` of such sessions in good calls, the process killed and started again: its
//! start time and memory, with the model's checkpoint and without it.
//!
//!   cargo run --release -p jsae-tests --example f4_attack -- attack [--jsae PATH]
//!
//! With `--jsae PATH` the service is `PATH recommender ...`; without, this example starts
//! itself as `f4_attack serve ...`, which is `jsae recommender`'s own main.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use clap::Parser;
use jsae_recommender::{MAX_CALL_BYTES, MAX_CONCURRENT_CALLS, MAX_REQUEST_BYTES, RecommenderArgs};
use jsae_wire::pb;
use tokio_stream::wrappers::ReceiverStream;

type Client = pb::recommender_client::RecommenderClient<tonic::transport::Channel>;

#[derive(Debug, Parser)]
enum Mode {
    /// Runs the attack against a service it starts.
    Attack(AttackArgs),
    /// `jsae recommender` itself (what `attack` starts without `--jsae`).
    Serve(Box<RecommenderArgs>),
}

#[derive(Debug, clap::Args)]
struct AttackArgs {
    /// A `jsae` binary to attack (`PATH recommender ...`) instead of this example's own.
    #[arg(long)]
    jsae: Option<PathBuf>,
    /// Sessions in the attack's call.
    #[arg(long, default_value_t = 500)]
    sessions: usize,
    /// MB of good sessions stored before the restarts (0: no restarts).
    #[arg(long, default_value_t = 440)]
    store_mb: u64,
    /// Keep the temporary directory (settings, store, the service's log).
    #[arg(long)]
    keep: bool,
}

const SETTINGS: &str = r#"
env = "recommender"
algo = "jsae"
[environment.recommender]
source = "synthetic"
top_n = 200
refresh_seconds = 1
[environment.recommender.synthetic]
items = 150
sessions = 2000
"#;

/// A maximum-size session: 10,000 purchases of items with 256-byte ids.
fn max_session(id: &str) -> pb::Session {
    pb::Session {
        session_id: id.into(),
        purchases: (0..10_000)
            .map(|k| {
                let mut item_id = format!("item-{}-", k % 1000);
                item_id.extend(std::iter::repeat_n('x', 256 - item_id.len()));
                pb::Purchase {
                    item_id,
                    price: 1.5,
                    time_unix_ms: k,
                }
            })
            .collect(),
    }
}

/// The service process and what it needs.
struct Service {
    child: Child,
    addr: String,
    started: Duration,
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Service {
    /// Starts the service on the settings and store in `dir`; returns once it listens.
    fn start(args: &AttackArgs, dir: &Path) -> Service {
        let mut command = match &args.jsae {
            Some(jsae) => {
                let mut c = Command::new(jsae);
                c.arg("recommender");
                c
            }
            None => {
                let mut c = Command::new(std::env::current_exe().expect("own path"));
                c.arg("serve");
                c
            }
        };
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.join("service.log"))
            .expect("log file");
        let started = Instant::now();
        let mut child = command
            .args(["--listen", "127.0.0.1:0", "--policy", "popular", "--config"])
            .arg(dir.join("settings.toml"))
            .arg("--store-dir")
            .arg(dir.join("store"))
            .env("RUST_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(log)
            .spawn()
            .expect("the service starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("the address line");
        let addr = line
            .trim()
            .rsplit(' ')
            .next()
            .unwrap_or_default()
            .to_owned();
        assert!(line.contains("listening on"), "the service said {line:?}");
        Service {
            child,
            addr: format!("http://{addr}"),
            started: started.elapsed(),
        }
    }

    /// `(VmRSS, VmHWM)` in MB.
    fn memory(&self) -> (f64, f64) {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id()))
            .unwrap_or_default();
        let field = |name: &str| {
            status
                .lines()
                .find_map(|l| l.strip_prefix(name))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
                .map_or(f64::NAN, |kb| kb / 1024.0)
        };
        (field("VmRSS:"), field("VmHWM:"))
    }

    fn report(&self, step: &str) {
        let (rss, hwm) = self.memory();
        println!("{step:<58} RSS {rss:7.1} MB   peak (VmHWM) {hwm:7.1} MB");
    }

    /// A client that encodes messages up to the service's limit and fails on larger ones.
    async fn client(&self) -> Client {
        Client::connect(self.addr.clone())
            .await
            .expect("connects")
            .max_encoding_message_size(MAX_REQUEST_BYTES)
    }
}

/// The store's log and commit record.
fn store_state(dir: &Path) -> (u64, String) {
    let store = dir.join("store");
    (
        std::fs::metadata(store.join("sessions.jsonl")).map_or(0, |m| m.len()),
        std::fs::read_to_string(store.join("commit.json")).unwrap_or_default(),
    )
}

/// One call streaming `count` maximum-size sessions named `prefix-N`, given up after
/// `cancel_after` of them were sent (when the service has not answered before); says how it
/// ended.
async fn call(client: &Client, prefix: &str, count: usize, cancel_after: usize) -> String {
    let (tx, rx) = tokio::sync::mpsc::channel(2);
    let mut client = client.clone();
    let mut call =
        tokio::spawn(async move { client.submit_sessions(ReceiverStream::new(rx)).await });
    let mut sent = 0;
    for i in 0..count {
        if sent == cancel_after {
            // a cancel is a reset of the stream before its end: this client resets it by
            // failing to encode a message over its own limit (dropping the tonic call would
            // end the stream cleanly first, which commits it)
            let mut reset = max_session("reset");
            reset.purchases.extend(max_session("reset").purchases);
            let _ = tx.send(reset).await;
            let ended = answered_after(call.await, sent);
            return format!("cancelled (stream reset by the client): {ended}");
        }
        let session = max_session(&format!("{prefix}-{i}"));
        tokio::select! {
            answered = &mut call => return answered_after(answered, sent),
            result = tx.send(session) => if result.is_err() { break },
        }
        sent += 1;
    }
    drop(tx);
    answered_after(call.await, sent)
}

fn answered_after(
    answered: Result<
        Result<tonic::Response<pb::SubmitSummary>, tonic::Status>,
        tokio::task::JoinError,
    >,
    sent: usize,
) -> String {
    match answered {
        Ok(Ok(summary)) => format!("stored after {sent} sessions: {:?}", summary.into_inner()),
        Ok(Err(status)) => format!(
            "answered {:?} after {sent} sessions: {}",
            status.code(),
            status.message()
        ),
        Err(e) => format!("{e}"),
    }
}

async fn attack(args: AttackArgs) {
    let dir = std::env::temp_dir().join(format!("jsae-f4-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    std::fs::write(dir.join("settings.toml"), SETTINGS).expect("settings");
    let service = Service::start(&args, &dir);
    println!("service {} (pid {})", service.addr, service.child.id());
    service.report("started");
    let client = service.client().await;
    let before = store_state(&dir);

    let n = args.sessions;
    let ended = call(&client, "f4", n, n / 2).await;
    println!("1. one call of {n} maximum-size sessions, cancelled half-way: {ended}");
    service.report("   after it");
    let within = (MAX_CALL_BYTES / 3_000_000) as usize;
    let ended = call(&client, "within", within + 10, within).await;
    println!("2. a call cancelled after {within} maximum-size sessions: {ended}");
    service.report("   after it");
    let calls: Vec<_> = (0..=MAX_CONCURRENT_CALLS)
        .map(|c| {
            let client = client.clone();
            tokio::spawn(async move { call(&client, &format!("c{c}"), 40, 40).await })
        })
        .collect();
    for (c, ended) in calls.into_iter().enumerate() {
        println!(
            "3. concurrent call {c}: {}",
            ended.await.unwrap_or_else(|e| e.to_string())
        );
    }
    service.report("   after them");
    // the service deletes a cancelled call's staging file when it notices the cancel
    tokio::time::sleep(Duration::from_millis(500)).await;
    let after = store_state(&dir);
    println!(
        "store before the attack: {} bytes, after: {} bytes ({})",
        before.0,
        after.0,
        if before == after {
            "unchanged"
        } else {
            "CHANGED"
        }
    );

    if args.store_mb > 0 {
        fill_and_restart(&args, &dir, service, &client).await;
    }
    if args.keep {
        println!("kept {}", dir.display());
    } else {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Stores `--store-mb` of maximum-size sessions in good calls, then kills the service and
/// starts it again, with the model's checkpoint and without it.
async fn fill_and_restart(args: &AttackArgs, dir: &Path, service: Service, client: &Client) {
    let per_call = (MAX_CALL_BYTES / 2_900_000) as usize;
    let mut c = 0;
    while store_state(dir).0 < args.store_mb * 1_000_000 {
        let sessions: Vec<_> = (0..per_call)
            .map(|i| max_session(&format!("fill-{c}-{i}")))
            .collect();
        let mut client = client.clone();
        client
            .submit_sessions(tokio_stream::iter(sessions))
            .await
            .expect("a good call is stored");
        c += 1;
    }
    let (bytes, _) = store_state(dir);
    println!(
        "filled the store: {:.0} MB in {c} calls",
        bytes as f64 / 1e6
    );
    // the service's model reads the new sessions at its next refresh and checkpoints them
    let checkpoint = dir.join("store/model_counts.json");
    let deadline = Instant::now() + Duration::from_secs(120);
    while Instant::now() < deadline {
        let at = std::fs::read(&checkpoint)
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .and_then(|v| v["log_bytes"].as_u64())
            .unwrap_or(0);
        if at + 16 * 1024 * 1024 >= bytes {
            break;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    service.report("   after filling it (and refreshing the model)");
    drop(service);
    let again = Service::start(args, dir);
    println!(
        "restart with a {:.0} MB store (checkpoint): listening after {:.2} s",
        bytes as f64 / 1e6,
        again.started.as_secs_f64()
    );
    again.report("   after the restart");
    drop(again);
    let _ = std::fs::remove_file(&checkpoint);
    let again = Service::start(args, dir);
    println!(
        "restart without the checkpoint: listening after {:.2} s",
        again.started.as_secs_f64()
    );
    again.report("   after the restart");
}

fn main() -> std::process::ExitCode {
    match Mode::parse() {
        Mode::Serve(args) => jsae_recommender::main(*args),
        Mode::Attack(args) => {
            tokio::runtime::Builder::new_multi_thread()
                .enable_all()
                .build()
                .expect("runtime")
                .block_on(attack(args));
            std::process::ExitCode::SUCCESS
        }
    }
}
