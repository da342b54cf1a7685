//! `jsae bench`: PPO update throughput and batch-1 / batch-64 inference latency on both
//! burn devices, measured in one run so the ratios between them are meaningful; the
//! PPO update per head against the GEMM peak (`learner`), transport (`transport`), MuJoCo
//! stepping (`mujoco`), Recommender (`recommender`), catalogue scale (`catalogue`) and
//! end-to-end actor scaling (`scaling`) benchmarks are the submodules.

pub mod catalogue;
pub mod catalogue_acting;
pub mod catalogue_embedder;
pub mod catalogue_serving;
pub mod learner;
pub mod mujoco;
pub mod recommender;
pub mod scaling;
pub mod transport;

use std::time::Instant;

use jsae_embedder::EmbedderTrainer;
use jsae_learner::{Ingested, Learner};
use jsae_nn::{BurnDevice, DeviceKind};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use jsae_agent::policy_shape;
use jsae_envs::EnvName;
use jsae_settings::{Algo, TrainConfig};

use jsae_actor::worker::ActorWorker;

/// Measurements on one device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceBench {
    /// The device.
    pub device: DeviceKind,
    /// PPO update throughput: samples processed per second (samples x epochs / time).
    pub update_samples_per_s: f64,
    /// Milliseconds per PPO update of one batch.
    pub update_ms: f64,
    /// Inference `phi -> pi_i (sample) -> f` for one state, microseconds.
    pub infer_batch1_us: f64,
    /// Inference `phi -> pi_i (sample) -> f` for 64 states, microseconds.
    pub infer_batch64_us: f64,
    /// A whole actor step of 1 environment (inference, env step, bookkeeping), microseconds.
    pub act_batch1_us: f64,
    /// A whole actor step of 64 environments, microseconds.
    pub act_batch64_us: f64,
}

/// Times `phi -> pi_i -> f` on `batch` random states with the worker's current weights.
fn time_inference(worker: &ActorWorker, batch: usize, repeats: usize, device: DeviceKind) -> f64 {
    let (Some(embedding), Some(policy)) = (worker.embedding(), worker.policy()) else {
        return f64::NAN;
    };
    let mut embedding = embedding.clone();
    let policy = policy.for_inference(&device.device());
    let n = match worker.state_space() {
        jsae_wire::StateSpace::Categorical { sizes } => sizes[0] as u32,
        jsae_wire::StateSpace::Real { .. } => 1,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let states = jsae_wire::StateBatch::Categorical {
        factors: 1,
        data: (0..batch).map(|_| rng.random_range(0..n)).collect(),
    };
    let head = policy.head().action_space();
    let (mut x, mut logp) = (Vec::new(), Vec::new());
    let mut e = jsae_wire::ActionBatch::empty(&head);
    let mut a = jsae_wire::ActionBatch::empty(worker.action_space());
    let mut once = |x: &mut Vec<f32>,
                    logp: &mut Vec<f32>,
                    e: &mut jsae_wire::ActionBatch,
                    a: &mut jsae_wire::ActionBatch| {
        e.clear();
        a.clear();
        logp.clear();
        embedding.embed_states(&states, x);
        policy.act(x, None, false, &mut rng, e, logp);
        if let jsae_wire::ActionBatch::Continuous { data, .. } = &*e {
            embedding.decode(data, a);
        }
    };
    for _ in 0..10 {
        once(&mut x, &mut logp, &mut e, &mut a);
    }
    let t = Instant::now();
    for _ in 0..repeats {
        once(&mut x, &mut logp, &mut e, &mut a);
    }
    t.elapsed().as_secs_f64() * 1e6 / repeats as f64
}

pub(crate) fn trained_worker(config: &TrainConfig, envs: usize, device: DeviceKind) -> ActorWorker {
    let mut c = config.clone();
    c.envs_per_actor = envs;
    let mut worker = ActorWorker::new(&c, 0, device).expect("benchmark environments need no data");
    let (s, a) = (worker.state_space().clone(), worker.action_space().clone());
    let mut emb = EmbedderTrainer::new(
        c.embedding.clone(),
        c.algo.representation(),
        &s,
        &a,
        c.seed,
        device,
    );
    let rollout = worker.collect(c.pretrain_budget().div_ceil(envs));
    let _ = emb.ingest(&rollout.transitions);
    if let Ok(Some(snap)) = emb.poll() {
        let _ = worker.set_embedding(&snap);
    }
    let (input, head) = policy_shape(&c, &s, &a);
    let learner = Learner::new(c.ppo.clone(), input, head, 1, c.seed, device);
    if let Ok(snap) = learner.snapshot() {
        let _ = worker.set_policy(&snap);
    }
    worker
}

fn time_collect(worker: &mut ActorWorker, envs: usize, repeats: usize) -> f64 {
    worker.collect(8);
    let t = Instant::now();
    worker.collect(repeats);
    let _ = envs;
    t.elapsed().as_secs_f64() * 1e6 / repeats as f64
}

/// gridworld-discrete with JSAE (512 actions) in the layout the performance pages' figures for it were
/// measured with: one actor's 16 environments, a batch of 2,048 (the run's default has since
/// become a shared batch of 64 environments).
pub(crate) fn gridworld_as_measured() -> TrainConfig {
    let mut c = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
    (c.envs_per_actor, c.batch_envs) = (16, None);
    c
}

/// Runs the benchmark on one device (gridworld-discrete, JSAE, 512 actions).
pub fn bench_device(device: DeviceKind, quick: bool) -> DeviceBench {
    let mut config = gridworld_as_measured();
    config.embedding.pretrain_transitions = 2_000;
    config.embedding.pretrain_per_action = 0;
    config.embedding.pretrain_epochs = 2;
    let repeats = if quick { 200 } else { 2_000 };
    let mut w1 = trained_worker(&config, 1, device);
    let infer_batch1_us = time_inference(&w1, 1, repeats, device);
    let infer_batch64_us = time_inference(&w1, 64, repeats / 4, device);
    let act_batch1_us = time_collect(&mut w1, 1, repeats);
    let mut w64 = trained_worker(&config, 64, device);
    let act_batch64_us = time_collect(&mut w64, 64, repeats / 10);

    // PPO update on a synthetic batch of the default size.
    let batch = config.round_steps();
    let (input, head) = policy_shape(&config, w1.state_space(), w1.action_space());
    let mut ppo = config.ppo.clone();
    ppo.batch_steps = batch;
    // the device comparison is burn's: the fused update runs on the host whatever the device
    ppo.update = jsae_settings::UpdatePath::Burn;
    let mut learner = Learner::new(ppo.clone(), input, head, 10 * batch as u64, 1, device);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut w = w64;
    let updates = if quick { 1 } else { 3 };
    let mut elapsed = 0.0;
    for _ in 0..updates {
        let mut fragments = Vec::new();
        while fragments
            .iter()
            .map(|f: &jsae_wire::RolloutFragment| f.len())
            .sum::<usize>()
            < batch
        {
            fragments.extend(w.collect(config.rollout_len).fragments);
        }
        for f in &mut fragments {
            f.policy_version = learner.version();
            f.rewards
                .iter_mut()
                .for_each(|r| *r += rng.random_range(-0.01..0.01));
        }
        let t = Instant::now();
        for f in fragments {
            if let Ok(Ingested::Updated(_)) = learner.ingest(f) {
                break;
            }
        }
        elapsed += t.elapsed().as_secs_f64();
    }
    let update_s = elapsed / updates as f64;
    DeviceBench {
        device,
        update_samples_per_s: (batch * ppo.epochs) as f64 / update_s,
        update_ms: update_s * 1e3,
        infer_batch1_us,
        infer_batch64_us,
        act_batch1_us,
        act_batch64_us,
    }
}

/// Runs the benchmark on both devices and formats the table with flex/ndarray ratios.
pub fn run(quick: bool) -> String {
    let flex = bench_device(DeviceKind::Flex, quick);
    let nd = bench_device(DeviceKind::Ndarray, quick);
    let mut out = String::new();
    out.push_str("gridworld-discrete, jsae, 512 actions, x 8-d, e 2-d, policy 64x64, batch 2048, 10 epochs of minibatch 256\n");
    out.push_str(&format!(
        "{:<34} {:>12} {:>12} {:>16}\n",
        "measure", "flex", "ndarray", "ndarray / flex"
    ));
    let rows = [
        (
            "PPO update (samples/s, higher=better)",
            flex.update_samples_per_s,
            nd.update_samples_per_s,
        ),
        ("PPO update (ms per batch)", flex.update_ms, nd.update_ms),
        (
            "inference, batch 1 (us)",
            flex.infer_batch1_us,
            nd.infer_batch1_us,
        ),
        (
            "inference, batch 64 (us)",
            flex.infer_batch64_us,
            nd.infer_batch64_us,
        ),
        ("act step, 1 env (us)", flex.act_batch1_us, nd.act_batch1_us),
        (
            "act step, 64 envs (us)",
            flex.act_batch64_us,
            nd.act_batch64_us,
        ),
    ];
    for (name, f, n) in rows {
        out.push_str(&format!("{name:<34} {f:>12.1} {n:>12.1} {:>16.2}\n", n / f));
    }
    out.push_str("(inference = phi, pi_i sample, nearest-neighbour f; act step = that plus env steps and bookkeeping)\n");
    out
}

/// `jsae bench`'s flags.
#[derive(clap::Args, Debug, Clone)]
pub struct BenchArgs {
    /// Fewer repetitions (a smoke run).
    #[arg(long)]
    pub quick: bool,
    /// Only the transport measurements.
    #[arg(long)]
    pub transport: bool,
    /// Only the PPO update: time per 2,048 samples for each policy head on the old
    /// (burn) and the new (fused) path, achieved GFLOP/s beside a GEMM peak measured in
    /// the same run.
    #[arg(long)]
    pub learner: bool,
    /// Only the actor ladder: end-to-end HalfCheetah PPO env-steps/s as separate
    /// processes with each count of `--actors` (the batch one rollout of every actor),
    /// beside raw env stepping and the learner's own limit measured in the same run.
    #[arg(long)]
    pub scaling: bool,
    /// The ladder's actor counts, e.g. `1,2,4,8` [default: 1, 2, 4, ... up to the cores].
    #[arg(long, value_delimiter = ',', requires = "scaling")]
    pub actors: Vec<usize>,
    /// Stepping threads of every actor in the ladder [default: 0, the run's rule: the
    /// cores less one, over the actors].
    #[arg(long, default_value_t = 0, requires = "scaling")]
    pub step_threads: usize,
    /// Only the MuJoCo stepping measurements (HalfCheetah and Ant: raw mujoco-rs, our
    /// env, the actor with batched inference, Gymnasium).
    #[arg(long)]
    pub mujoco: bool,
    /// Only the Recommender service's latency (p50, p99) and throughput at concurrency
    /// 64 over loopback gRPC.
    #[arg(long)]
    pub recommender: bool,
    /// Environments per actor in the MuJoCo actor measurement.
    #[arg(long, default_value_t = 16)]
    pub envs: usize,
    /// Only the catalogue-scale measurements: generated catalogues of `--items` items, f by
    /// approximate nearest neighbour against the exact scan.
    #[arg(long)]
    pub catalogue: bool,
    /// The catalogue sizes [default: 10000, 100000, 1000000].
    #[arg(long, value_delimiter = ',', requires = "catalogue")]
    pub items: Vec<u32>,
    /// One JSON object per catalogue size and line, instead of a table.
    #[arg(long, requires = "catalogue")]
    pub json: bool,
}

/// Runs `jsae bench`: the measurements its flags ask for, printed as they are made.
pub fn main(args: BenchArgs) -> std::process::ExitCode {
    use std::process::ExitCode;
    let BenchArgs {
        quick,
        transport,
        learner,
        scaling,
        actors,
        step_threads,
        mujoco,
        recommender,
        envs,
        catalogue,
        items,
        json,
    } = args;
    if catalogue {
        let sizes = if items.is_empty() {
            crate::catalogue::DEFAULT_ITEMS.to_vec()
        } else {
            items
        };
        return match crate::catalogue::run(&sizes, json, quick) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("jsae bench --catalogue: {e:#}");
                ExitCode::FAILURE
            }
        };
    }
    if scaling {
        if actors.contains(&0) {
            eprintln!("--actors: every count must be at least 1");
            return ExitCode::from(2);
        }
        let ladder = if actors.is_empty() {
            crate::scaling::default_ladder()
        } else {
            actors
        };
        print!("{}", crate::scaling::run(&ladder, step_threads, quick));
        return ExitCode::SUCCESS;
    }
    if learner {
        print!("{}", crate::learner::run(quick));
        return ExitCode::SUCCESS;
    }
    if recommender {
        print!("{}", crate::recommender::run(quick));
        return ExitCode::SUCCESS;
    }
    if mujoco {
        print!("{}", crate::mujoco::run(envs.max(1), quick));
        return ExitCode::SUCCESS;
    }
    if !transport {
        print!("{}", crate::run(quick));
    }
    print!("{}", crate::transport::run(quick));
    ExitCode::SUCCESS
}
