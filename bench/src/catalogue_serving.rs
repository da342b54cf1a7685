//! The Recommender at catalogue scale, for `jsae bench --catalogue`: the real `jsae
//! recommender` process, started on a run directory this bench writes (the recommender JSAE's
//! settings over the generated catalogue; g the category stand-in, phi and the policy freshly
//! initialised: a trained model does the same arithmetic), then
//! 1. `Recommend` over loopback gRPC at a fixed offered load, open loop, and the process's
//!    resident memory;
//! 2. a second embedding written to the run directory and swapped in under the same load
//!    (the new index is built at the lowest priority while the old one answers): latency
//!    and memory until the answers carry the new version;
//! 3. a third embedding tagged with another catalogue, which must be refused.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use burn::module::Param;
use jsae_agent::{EmbeddingModel, Policy, PolicyPrior, policy_shape};
use jsae_envs::recsys::Catalogue;
use jsae_envs::recsys::CatalogueHandle;
use jsae_envs::recsys::large_catalogue::LargeCatalogue;
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_run_dir::{RunDir, Weights};
use jsae_settings::{Algo, EnvName, SessionSource, TrainConfig};
use jsae_wire::{CatalogueTag, pb};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::recommender::{Answer, open_loop, percentile, summary};

/// Offered load of the measurement, requests per second.
pub const OFFERED_RPS: f64 = 1_000.0;
/// Items asked for.
const K: u32 = 10;
/// The longest a swap may take before the bench gives up on it.
const SWAP_LIMIT: Duration = Duration::from_secs(900);

/// What the Recommender process measured at one size.
#[derive(Debug, Clone, Copy, Default)]
pub struct Serving {
    /// Seconds from the process's start to its first answer (the catalogue made, the
    /// snapshot read, f's index built).
    pub load_s: f64,
    /// Requests offered per second.
    pub offered_rps: f64,
    /// Requests answered, of those offered after the warm-up.
    pub answered: usize,
    /// Requests offered after the warm-up.
    pub sent: usize,
    /// Median latency, milliseconds (from each request's scheduled time).
    pub p50_ms: f64,
    /// 99th percentile latency, milliseconds.
    pub p99_ms: f64,
    /// The process's peak resident memory from its start through the measurement, MiB.
    pub rss_mib: f64,
    /// Its resident memory at the end of the measurement (serving, nothing being loaded), MiB.
    pub serving_rss_mib: f64,
    /// Seconds from the new embedding's file to the first answer that used it.
    pub swap_s: f64,
    /// Median latency while the new embedding was decoded and indexed, milliseconds.
    pub swap_p50_ms: f64,
    /// 99th percentile latency meanwhile, milliseconds.
    pub swap_p99_ms: f64,
    /// Requests answered meanwhile, and offered.
    pub swap_answered: (usize, usize),
    /// The process's peak resident memory through the swap (two embeddings held), MiB.
    pub swap_rss_mib: f64,
    /// Whether an embedding of another catalogue was refused (and the one in use kept).
    pub refused_other_catalogue: bool,
}

/// The recommender JSAE's settings over the generated catalogue of `items` items.
pub(crate) fn settings(items: u32) -> anyhow::Result<TrainConfig> {
    let mut config = TrainConfig::defaults(EnvName::Recommender, Algo::Jsae);
    let r = &mut config.environment.recommender;
    r.source = SessionSource::Catalogue;
    r.top_n = items;
    r.catalogue.items = items;
    // the random play before training must fit the replay (25 per item below
    // `sampled_softmax_from`); nothing here trains, but the Recommender validates the run
    config.embedding.replay_capacity = config
        .embedding
        .replay_capacity
        .max(config.pretrain_budget());
    config.env_steps = config.env_steps.max(config.pretrain_budget() as u64 + 1);
    config.validate()?;
    Ok(config)
}

/// An embedding snapshot's bytes: phi drawn from `seed`, g the category stand-in of each
/// slot's item (free slots: the stand-in of the item with the slot's number), tagged.
pub(crate) fn embedding_bytes(
    config: &TrainConfig,
    generated: &LargeCatalogue,
    catalogue: &Catalogue,
    seed: u64,
    tag: CatalogueTag,
) -> anyhow::Result<Vec<u8>> {
    let (states, actions) = EnvName::Recommender.spaces(&config.environment);
    let device = DeviceKind::Flex.device();
    let mut model = EmbeddingModel::new(
        &config.embedding,
        config.algo.representation(),
        &states,
        &actions,
        &mut ChaCha8Rng::seed_from_u64(seed),
        &device,
    );
    let d = config.embedding.action_dim;
    let stand_in = crate::catalogue::stand_in_embeddings(generated, d, seed);
    let n = catalogue.capacity();
    let mut table = Vec::with_capacity(n * d);
    for slot in 0..n as u32 {
        let item = catalogue
            .id(slot)
            .and_then(|id| id.strip_prefix("item-"))
            .and_then(|k| k.parse::<usize>().ok())
            .unwrap_or(slot as usize);
        table.extend_from_slice(&stand_in[item * d..(item + 1) * d]);
    }
    drop(stand_in);
    model.net_mut().g_table = Some(Param::from_tensor(jsae_nn::tensor2(table, n, d, &device)));
    let mut bytes = model.to_bytes()?;
    tag.append_to(&mut bytes);
    Ok(bytes)
}

/// A policy snapshot's bytes: the run's policy, freshly drawn.
pub(crate) fn policy_bytes(config: &TrainConfig) -> anyhow::Result<Vec<u8>> {
    let (states, actions) = EnvName::Recommender.spaces(&config.environment);
    let (input, head) = policy_shape(config, &states, &actions);
    let policy = Policy::new(
        &config.ppo,
        input,
        head,
        &mut ChaCha8Rng::seed_from_u64(1),
        &DeviceKind::Flex.device(),
    );
    Ok(PolicyPrior::new(&config.ppo).encode(&policy)?)
}

/// The peak (`VmHWM`) resident memory of process `pid`, MiB.
fn peak_rss_mib(pid: u32) -> f64 {
    status_mib(pid, "VmHWM:")
}

/// A memory line of process `pid`'s status (`VmHWM:`, `VmRSS:`), MiB.
fn status_mib(pid: u32, key: &str) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix(key))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// The `jsae recommender` process, stopped when dropped.
struct Process(Child);

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `jsae recommender --run DIR` on a free port; returns it and its URL.
fn start(run: &Path) -> anyhow::Result<(Process, String)> {
    let log = std::fs::File::create(run.join("recommender.log"))?;
    let mut child = Command::new(std::env::current_exe()?)
        .args(["recommender", "--listen", "127.0.0.1:0", "--run"])
        .arg(run)
        .env_remove("JSAE_METRICS_LISTEN")
        // the refusal is read from its log
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(log)
        .spawn()?;
    let out = child.stdout.take();
    let process = Process(child);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let Some(out) = out else { return };
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let line = rx
        .recv_timeout(Duration::from_secs(600))
        .map_err(|_| anyhow::anyhow!("the recommender did not report its address"))?;
    let addr = jsae_net::logging::announced_address(&line)
        .ok_or_else(|| anyhow::anyhow!("the recommender said {line:?}"))?;
    Ok((process, format!("http://{addr}")))
}

/// The embedding version of an answer to `history`, or why there was none (no answer
/// within 10 s: None).
fn answered_version(
    rt: &tokio::runtime::Runtime,
    url: &str,
    history: &[String],
) -> Option<Result<u64, String>> {
    rt.block_on(async {
        let ask = async {
            let mut client = pb::recommender_client::RecommenderClient::connect(url.to_owned())
                .await
                .ok()?;
            let request = pb::RecommendRequest {
                history: history.to_vec(),
                k: K,
            };
            Some(match client.recommend(request).await {
                Ok(answer) => Ok(answer.into_inner().embedding_version),
                Err(status) => Err(status.message().to_owned()),
            })
        };
        tokio::time::timeout(Duration::from_secs(10), ask)
            .await
            .ok()
            .flatten()
    })
}

/// Histories as users make them: the first three purchases of the first sessions.
fn histories(generated: &LargeCatalogue) -> Vec<Vec<String>> {
    (0..generated.sessions())
        .map(|s| generated.session(s))
        .filter(|s| !s.is_empty())
        .take(1_000)
        .map(|s| s.iter().take(3).map(|i| format!("item-{i}")).collect())
        .collect()
}

/// Measures the Recommender process at `items` items for `seconds` of steady load.
pub fn measure(items: u32, seconds: f64) -> anyhow::Result<Serving> {
    let root = std::env::temp_dir().join(format!("jsae-bench-serving-{}", std::process::id()));
    let measured = measure_in(&root, items, seconds);
    let _ = std::fs::remove_dir_all(&root);
    measured
}

fn measure_in(root: &Path, items: u32, seconds: f64) -> anyhow::Result<Serving> {
    let config = settings(items)?;
    let run = RunDir::new(root);
    std::fs::create_dir_all(root)?;
    run.write_config(&config)?;
    let generated = LargeCatalogue::new(&config.environment.recommender.catalogue)
        .map_err(anyhow::Error::msg)?;
    let catalogue = CatalogueHandle::load(&config.environment.recommender)?.current();
    let tag = jsae_recommender::catalogue_tag(&catalogue);
    let checkpoints = run.checkpoints();
    std::fs::create_dir_all(checkpoints.path())?;
    let write_embedding = |version: u64, tag: CatalogueTag| -> anyhow::Result<()> {
        let bytes = embedding_bytes(&config, &generated, &catalogue, version, tag)?;
        checkpoints.write_versioned(Weights::Embedding, version, &bytes)?;
        Ok(())
    };
    write_embedding(1, tag)?;
    checkpoints.write_versioned(Weights::Policy, 1, &policy_bytes(&config)?)?;
    let histories = Arc::new(histories(&generated));
    let probe = histories[0].clone();

    let started = Instant::now();
    let (mut process, url) = start(root)?;
    let pid = process.0.id();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    loop {
        match answered_version(&rt, &url, &probe) {
            Some(Ok(1)) => break,
            Some(Err(why)) if why.contains("refused") => anyhow::bail!("the recommender: {why}"),
            _ => {}
        }
        if let Some(status) = process.0.try_wait()? {
            anyhow::bail!(
                "the recommender exited ({status}): see {}",
                log(root).display()
            );
        }
        if started.elapsed() > SWAP_LIMIT {
            anyhow::bail!(
                "no answer after {SWAP_LIMIT:?}: see {}",
                log(root).display()
            );
        }
        std::thread::sleep(Duration::from_millis(250));
    }
    let load_s = started.elapsed().as_secs_f64();
    let steady = open_loop(&rt, &url, &histories, (seconds, 0.5), OFFERED_RPS, K)?;
    let (sent, answered, latencies) = summary(&steady);
    let (rss_mib, serving_rss_mib) = (peak_rss_mib(pid), status_mib(pid, "VmRSS:"));

    // a new embedding under the same load, in windows of 5 s (the load goes on across them)
    // until an answer uses it: the requests due before that answer's are the swap's
    write_embedding(2, tag)?;
    let written = Instant::now();
    let mut during: Vec<Answer> = Vec::new();
    let swapped = loop {
        let window = open_loop(&rt, &url, &histories, (5.0, 0.0), OFFERED_RPS, K)?;
        let first_new = window.iter().position(|a| a.embedding_version == 2);
        during.extend(&window[..first_new.unwrap_or(window.len())]);
        if let Some(i) = first_new {
            break window[i].due;
        }
        if let Some(status) = process.0.try_wait()? {
            anyhow::bail!(
                "the recommender exited ({status}): see {}",
                log(root).display()
            );
        }
        if written.elapsed() > SWAP_LIMIT {
            anyhow::bail!("the new embedding was not in use after {SWAP_LIMIT:?}");
        }
    };
    let swap_s = swapped.duration_since(written).as_secs_f64();
    let (swap_sent, swap_answered, swap_latencies) = summary(&during);
    let swap_rss_mib = peak_rss_mib(pid);

    // an embedding of another catalogue: refused, version 2 goes on answering
    let other = CatalogueTag {
        prefix_hash: tag.prefix_hash ^ 1,
        ..tag
    };
    write_embedding(3, other)?;
    // the run directory is read every 3 s
    std::thread::sleep(Duration::from_secs(10));
    let refused_other_catalogue = matches!(answered_version(&rt, &url, &probe), Some(Ok(2)))
        && std::fs::read_to_string(log(root))
            .is_ok_and(|l| l.contains("embedding version 3 refused"));
    drop(process);
    Ok(Serving {
        load_s,
        offered_rps: OFFERED_RPS,
        answered,
        sent,
        p50_ms: percentile(&latencies, 0.5),
        p99_ms: percentile(&latencies, 0.99),
        rss_mib,
        serving_rss_mib,
        swap_s,
        swap_p50_ms: percentile(&swap_latencies, 0.5),
        swap_p99_ms: percentile(&swap_latencies, 0.99),
        swap_answered: (swap_answered, swap_sent),
        swap_rss_mib,
        refused_other_catalogue,
    })
}

fn log(root: &Path) -> PathBuf {
    root.join("recommender.log")
}
