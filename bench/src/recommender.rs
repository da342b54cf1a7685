//! `jsae bench --recommender`: `Recommend` latency (p50, p99) over loopback gRPC at a fixed
//! offered load (5,000 requests/s, open loop: each request leaves at its scheduled time
//! whether or not earlier ones were answered, and its latency counts from that time), and
//! latency and throughput at saturation (concurrency 64), for the JSAE and PPO policies over
//! the Instacart catalogue (835 items, k = 10), next to the same call in-process on one
//! thread. The weights are freshly initialised: a trained policy does the same arithmetic.

use std::sync::Arc;
use std::time::{Duration, Instant};

use jsae_agent::{EmbeddingModel, Policy, PolicyPrior, policy_shape};
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_wire::pb;
use jsae_wire::{EmbeddingSnapshot, PolicySnapshot};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use jsae_recommender::{Recommender, WeightSources, serve};

/// Requests in flight at once (saturation).
pub const CONCURRENCY: usize = 64;
/// Offered load of the fixed-rate measurement, requests per second.
pub const OFFERED_PER_S: f64 = 5_000.0;
/// Items asked for.
const K: u32 = 10;

/// What one algorithm measured.
#[derive(Debug, Clone, Copy)]
pub struct RecommendRates {
    /// The policy's algorithm.
    pub algo: Algo,
    /// Requests answered during the measurement.
    pub requests: usize,
    /// Median latency, milliseconds.
    pub p50_ms: f64,
    /// 99th percentile latency, milliseconds.
    pub p99_ms: f64,
    /// Answers per second over gRPC at concurrency 64.
    pub grpc_per_s: f64,
    /// Calls per second of `Recommender::recommend` in-process, one thread.
    pub in_process_per_s: f64,
    /// At the fixed offered load: requests sent, answered, median and 99th percentile
    /// latency (milliseconds).
    pub fixed: (usize, usize, f64, f64),
}

fn recommender(algo: Algo) -> anyhow::Result<(Arc<Recommender>, Vec<Vec<String>>)> {
    let config = TrainConfig::defaults(EnvName::Recommender, algo);
    config.validate()?;
    let rec = Recommender::new(
        &config,
        jsae_recommender::baseline::PolicyChoice::Learned,
        DeviceKind::Flex,
    )?;
    let (states, actions) = EnvName::Recommender.spaces(&config.environment);
    let device = DeviceKind::Flex.device();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (input, head) = policy_shape(&config, &states, &actions);
    let policy = Policy::new(&config.ppo, input, head, &mut rng, &device);
    rec.set_policy(&PolicySnapshot {
        version: 1,
        bytes: PolicyPrior::new(&config.ppo).encode(&policy)?,
    })
    .map_err(anyhow::Error::msg)?;
    if algo.representation().needs_embedder() {
        let model = EmbeddingModel::new(
            &config.embedding,
            algo.representation(),
            &states,
            &actions,
            &mut rng,
            &device,
        );
        rec.set_embedding(EmbeddingSnapshot::from_bytes(1, model.to_bytes()?))
            .map_err(anyhow::Error::msg)?;
    }
    // histories as users make them: three purchases drawn from the n-gram model
    let model = jsae_envs::recsys::model_handle(&config.environment.recommender)?.current();
    let histories = (0..1000)
        .map(|_| {
            let mut h = vec![model.sample_start(&mut rng)];
            for _ in 0..2 {
                let before = if h.len() >= 2 {
                    h[h.len() - 2]
                } else {
                    model.catalogue().none()
                };
                let next = model.sample_next(before, h[h.len() - 1], u32::MAX, &mut rng);
                h.push(next);
            }
            h.iter()
                .filter_map(|&s| model.catalogue().id(s).map(str::to_owned))
                .collect()
        })
        .collect();
    Ok((Arc::new(rec), histories))
}

/// The `q` quantile of sorted values (nearest rank), NaN when there are none.
pub(crate) fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Measures one algorithm for `seconds` (after a one-second warm-up).
pub fn measure(algo: Algo, seconds: f64) -> anyhow::Result<RecommendRates> {
    let (rec, histories) = recommender(algo)?;
    let histories = Arc::new(histories);

    // in-process, one thread
    let started = Instant::now();
    let mut calls = 0usize;
    while started.elapsed().as_secs_f64() < seconds.min(3.0) {
        rec.recommend(&histories[calls % histories.len()], K)?;
        calls += 1;
    }
    let in_process_per_s = calls as f64 / started.elapsed().as_secs_f64();

    let server_rt = jsae_net::runtime()?;
    let listener = server_rt.block_on(jsae_net::bind("127.0.0.1:0"))?;
    let url = format!("http://{}", listener.local_addr()?);
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server = server_rt.spawn(serve(
        rec.clone(),
        listener,
        WeightSources::default(),
        Default::default(),
        Default::default(),
        async move {
            let _ = stop_rx.await;
        },
    ));
    let client_rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let fixed = open_loop(
        &client_rt,
        &url,
        &histories,
        (seconds.min(5.0), 0.5),
        OFFERED_PER_S,
        K,
    )
    .map(|answers| summary(&answers));
    let result = client_rt.block_on(async {
        let channel = tonic::transport::Endpoint::from_shared(url)?
            .tcp_nodelay(true)
            .connect()
            .await?;
        let warm_until = Instant::now() + Duration::from_secs(1);
        let end = warm_until + Duration::from_secs_f64(seconds);
        let mut tasks = tokio::task::JoinSet::new();
        for t in 0..CONCURRENCY {
            let mut client = pb::recommender_client::RecommenderClient::new(channel.clone());
            let histories = histories.clone();
            tasks.spawn(async move {
                let mut latencies = Vec::new();
                let mut i = t * 7;
                loop {
                    let sent = Instant::now();
                    if sent >= end {
                        break;
                    }
                    let request = pb::RecommendRequest {
                        history: histories[i % histories.len()].clone(),
                        k: K,
                    };
                    client.recommend(request).await?;
                    if sent >= warm_until {
                        latencies.push(sent.elapsed().as_secs_f64() * 1000.0);
                    }
                    i += 1;
                }
                Ok::<_, tonic::Status>(latencies)
            });
        }
        let mut all = Vec::new();
        while let Some(done) = tasks.join_next().await {
            all.extend(done??);
        }
        Ok::<_, anyhow::Error>(all)
    });
    let _ = stop_tx.send(());
    let _ = server_rt.block_on(server);
    let (sent, answered, fixed) = fixed?;
    let mut latencies = result?;
    latencies.sort_by(f64::total_cmp);
    Ok(RecommendRates {
        algo,
        requests: latencies.len(),
        p50_ms: percentile(&latencies, 0.50),
        p99_ms: percentile(&latencies, 0.99),
        grpc_per_s: latencies.len() as f64 / seconds,
        in_process_per_s,
        fixed: (
            sent,
            answered,
            percentile(&fixed, 0.50),
            percentile(&fixed, 0.99),
        ),
    })
}

/// One request of an open-loop load.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Answer {
    /// When it was due to leave.
    pub due: Instant,
    /// Milliseconds from then to its answer (infinite: failed, or not answered in time).
    pub ms: f64,
    /// The embedding version of the answer (0: none).
    pub embedding_version: u64,
}

/// Requests offered, requests answered and every latency (ms, sorted) of `answers`.
pub(crate) fn summary(answers: &[Answer]) -> (usize, usize, Vec<f64>) {
    let mut ms: Vec<f64> = answers.iter().map(|a| a.ms).collect();
    ms.sort_by(f64::total_cmp);
    let answered = ms.iter().filter(|m| m.is_finite()).count();
    (answers.len(), answered, ms)
}

/// Open-loop load of `per_s` requests a second for `seconds`, after `warm_s` seconds of the
/// same load whose requests are not returned, each asking for `k` items: a pacing thread
/// releases each request at its scheduled time (sleeping in between), the runtime sends it
/// on one shared HTTP/2 channel; the latency of each request counts from its scheduled
/// time, and one that fails or is not answered within 5 s of the last release counts as
/// infinitely late.
pub(crate) fn open_loop(
    rt: &tokio::runtime::Runtime,
    url: &str,
    histories: &Arc<Vec<Vec<String>>>,
    (seconds, warm_s): (f64, f64),
    per_s: f64,
    k: u32,
) -> anyhow::Result<Vec<Answer>> {
    let channel = rt.block_on(
        tonic::transport::Endpoint::from_shared(url.to_owned())?
            .tcp_nodelay(true)
            .connect(),
    )?;
    let interval = Duration::from_secs_f64(1.0 / per_s);
    let warm = (per_s * warm_s) as usize;
    let total = warm + (per_s * seconds) as usize;
    let start = Instant::now() + Duration::from_millis(10);
    let mut calls = Vec::with_capacity(total);
    for i in 0..total {
        let due = start + interval.mul_f64(i as f64);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        let mut client = pb::recommender_client::RecommenderClient::new(channel.clone());
        let request = pb::RecommendRequest {
            history: histories[i % histories.len()].clone(),
            k,
        };
        calls.push((
            due,
            rt.spawn(async move {
                let answer = client.recommend(request).await.ok()?;
                Some((
                    due.elapsed().as_secs_f64() * 1000.0,
                    answer.into_inner().embedding_version,
                ))
            }),
        ));
    }
    let measured = calls.split_off(warm);
    Ok(rt.block_on(async {
        let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
        let mut all = Vec::with_capacity(measured.len());
        for (due, call) in measured {
            let answer = tokio::time::timeout_at(deadline, call).await;
            let (ms, embedding_version) = answer
                .ok()
                .and_then(Result::ok)
                .flatten()
                .unwrap_or((f64::INFINITY, 0));
            all.push(Answer {
                due,
                ms,
                embedding_version,
            });
        }
        all
    }))
}

pub(crate) fn rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// The n-gram model at catalogue scale: seconds to build it from synthetic sessions over
/// `items` items, its resident memory (MiB), and environment steps per second on it.
pub fn model_scale(items: u32, sessions: u32) -> anyhow::Result<(u64, f64, f64, usize, f64)> {
    use jsae_envs::recsys::{Catalogue, NgramModel};
    let config = jsae_settings::RecommenderConfig {
        top_n: items,
        synthetic: jsae_settings::SyntheticConfig {
            items,
            sessions,
            mean_len: 8.0,
            seed: 7,
        },
        ..Default::default()
    };
    let data = jsae_envs::recsys::synthetic::generate(&config.synthetic);
    let purchases = data.iter().map(|s| s.purchases.len() as u64).sum();
    let before = rss_mib();
    let started = Instant::now();
    let catalogue = Catalogue::most_purchased(data.iter(), items as usize);
    let model = NgramModel::build(catalogue, data.iter(), &config)
        .ok_or_else(|| anyhow::anyhow!("no purchases"))?;
    let build_s = started.elapsed().as_secs_f64();
    let mib = rss_mib() - before;
    drop(data);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (mut before, mut last) = (model.catalogue().none(), model.sample_start(&mut rng));
    let started = Instant::now();
    let steps = 1_000_000;
    for t in 0..steps {
        let rec = (t * 7919 % items as usize) as u32;
        let next = model.sample_next(before, last, rec, &mut rng);
        (before, last) = (last, next);
    }
    let per_s = steps as f64 / started.elapsed().as_secs_f64();
    Ok((purchases, build_s, mib, model.contexts(), per_s))
}

/// The report `jsae bench --recommender` prints.
pub fn run(quick: bool) -> String {
    let seconds = if quick { 2.0 } else { 10.0 };
    let mut out = format!(
        "n-gram model at scale (synthetic sessions)\n{:>8} {:>10} {:>9} {:>9} {:>10} {:>12}\n",
        "items", "purchases", "build s", "RSS MiB", "contexts", "env steps/s"
    );
    let scales: &[(u32, u32)] = if quick {
        &[(10_000, 20_000)]
    } else {
        &[(10_000, 100_000), (100_000, 500_000)]
    };
    for &(items, sessions) in scales {
        match model_scale(items, sessions) {
            Ok((purchases, build_s, mib, contexts, per_s)) => out.push_str(&format!(
                "{items:>8} {purchases:>10} {build_s:>9.2} {mib:>9.0} {contexts:>10} {per_s:>12.0}\n"
            )),
            Err(e) => out.push_str(&format!("{items} items: failed: {e:#}\n")),
        }
    }
    let mut fixed = format!(
        "Recommend over loopback gRPC at a fixed offered load of {OFFERED_PER_S:.0} requests/s \
         (open loop), k = {K}, Instacart catalogue (835 items)\n{:<6} {:>9} {:>9} {:>9} {:>9}\n",
        "algo", "sent", "answered", "p50 ms", "p99 ms"
    );
    out.push_str(&format!(
        "Recommend over loopback gRPC, {CONCURRENCY} requests in flight, k = {K}, Instacart \
         catalogue (835 items), {seconds} s per policy\n{:<6} {:>9} {:>9} {:>9} {:>12} {:>15} {:>12}\n",
        "algo", "requests", "p50 ms", "p99 ms", "answers/s", "in-proc 1thr/s", "gRPC/in-proc"
    ));
    for algo in [Algo::Jsae, Algo::Ppo] {
        match measure(algo, seconds) {
            Ok(r) => {
                out.push_str(&format!(
                    "{:<6} {:>9} {:>9.3} {:>9.3} {:>12.0} {:>15.0} {:>12.2}\n",
                    r.algo.as_str(),
                    r.requests,
                    r.p50_ms,
                    r.p99_ms,
                    r.grpc_per_s,
                    r.in_process_per_s,
                    r.grpc_per_s / r.in_process_per_s
                ));
                let (sent, answered, p50, p99) = r.fixed;
                fixed.push_str(&format!(
                    "{:<6} {sent:>9} {answered:>9} {p50:>9.3} {p99:>9.3}\n",
                    r.algo.as_str()
                ));
            }
            Err(e) => out.push_str(&format!("{}: failed: {e:#}\n", algo.as_str())),
        }
    }
    out.push_str(&fixed);
    out
}
