//! `jsae bench --learner`: the PPO update's time per 2,048-sample batch for each policy head
//! we train (the shapes of each environment's defaults), its achieved GFLOP/s, and a
//! single-thread GEMM peak measured on the same machine in the same run, so the ratio to the
//! machine's limit is read from one run.
//!
//! The batches are synthetic (random inputs, actions drawn from the head's space, random
//! rewards): the update's cost depends only on the shapes, not on the data. FLOPs are those of
//! the dense matrix products of the policy and critic MLPs, forward (2 per weight and sample)
//! and backward (4), over the epochs the update ran.

use std::time::Instant;

use jsae_learner::fused::{HostMinibatch, HostPolicy, LossConfig};
use jsae_learner::{Ingested, Learner, PolicyHead, policy_shape};
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_proto::settings::{Algo, EnvName, TrainConfig};
use jsae_proto::{ActionBatch, RolloutFragment};
use ndarray::Array2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Samples per measured update.
const BATCH: usize = 2048;
/// Steps per synthetic fragment.
const FRAGMENT: usize = 128;

/// One measured head.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnerBench {
    /// `env/algo`.
    pub case: String,
    /// Policy input width.
    pub input: usize,
    /// The head, as text.
    pub head: String,
    /// Minibatch size and epochs run.
    pub minibatch: usize,
    /// Epochs the update ran (the KL stop may end it early).
    pub epochs: usize,
    /// Milliseconds per update of 2,048 samples.
    pub update_ms: f64,
    /// Dense-product FLOPs per second achieved.
    pub gflops: f64,
}

/// Weights in the dense products of an MLP `input -> hidden.. -> output`.
fn mlp_weights(input: usize, hidden: &[usize], output: usize) -> usize {
    let mut sizes = vec![input];
    sizes.extend_from_slice(hidden);
    sizes.push(output);
    sizes.windows(2).map(|w| w[0] * w[1]).sum()
}

fn head_outputs(head: PolicyHead) -> (usize, String) {
    match head {
        PolicyHead::Gaussian { dim } => (dim, format!("gaussian {dim}")),
        PolicyHead::Categorical { n } => (n, format!("categorical {n}")),
    }
}

/// A fragment of random data for a policy of input `x_dim` and `head`.
fn fragment(x_dim: usize, head: PolicyHead, version: u64, rng: &mut ChaCha8Rng) -> RolloutFragment {
    let actions = match head {
        PolicyHead::Gaussian { dim } => ActionBatch::Continuous {
            dim,
            data: (0..FRAGMENT * dim)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect(),
        },
        PolicyHead::Categorical { n } => ActionBatch::Discrete(
            (0..FRAGMENT)
                .map(|_| rng.random_range(0..n as u32))
                .collect(),
        ),
    };
    RolloutFragment {
        actor_id: 0,
        env_index: 0,
        policy_version: version,
        embedding_version: 0,
        actor_env_steps: 0,
        x_dim,
        x: (0..FRAGMENT * x_dim)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect(),
        actions,
        logp: (0..FRAGMENT)
            .map(|_| rng.random_range(-3.0..-1.0))
            .collect(),
        rewards: (0..FRAGMENT).map(|_| rng.random_range(-1.0..1.0)).collect(),
        terminated: vec![false; FRAGMENT],
        truncated: vec![false; FRAGMENT],
        truncated_next_x: Vec::new(),
        last_next_x: (0..x_dim).map(|_| rng.random_range(-1.0..1.0)).collect(),
        episodes: Vec::new(),
    }
}

/// Times `updates` PPO updates of 2,048 synthetic samples under `env`/`algo`'s defaults.
pub fn bench_case(env: EnvName, algo: Algo, updates: usize) -> LearnerBench {
    let config = TrainConfig::defaults(env, algo);
    let (states, actions) = config.spaces();
    let (input, head) = policy_shape(&config, &states, &actions);
    let mut ppo = config.ppo.clone();
    ppo.batch_steps = BATCH;
    let mut learner = Learner::new(ppo.clone(), input, head, 1 << 40, 1, DeviceKind::Flex);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (mut elapsed, mut epochs) = (0.0, 0);
    for _ in 0..updates.max(1) {
        let batch: Vec<RolloutFragment> = (0..BATCH / FRAGMENT)
            .map(|_| fragment(input, head, learner.version(), &mut rng))
            .collect();
        let t = Instant::now();
        for f in batch {
            if let Ok(Ingested::Updated(report)) = learner.ingest(f) {
                epochs += report.metrics.epochs;
            }
        }
        elapsed += t.elapsed().as_secs_f64();
    }
    let n = updates.max(1);
    let (outputs, head_name) = head_outputs(head);
    let weights = mlp_weights(input, &ppo.hidden, outputs) + mlp_weights(input, &ppo.hidden, 1);
    let flops = 6.0 * weights as f64 * BATCH as f64 * epochs as f64;
    LearnerBench {
        case: format!("{}/{}", env.as_str(), algo.as_str()),
        input,
        head: head_name,
        minibatch: ppo.minibatch_size,
        epochs: epochs / n,
        update_ms: elapsed * 1e3 / n as f64,
        gflops: flops / elapsed / 1e9,
    }
}

/// Microseconds of the host loss and gradient (`jsae_learner::fused`) for one minibatch of
/// `env`/`algo`'s default shapes and minibatch size (no optimiser step).
pub fn host_loss_grad_us(env: EnvName, algo: Algo, repeats: usize) -> f64 {
    let config = TrainConfig::defaults(env, algo);
    let (states, actions) = config.spaces();
    let (input, head) = policy_shape(&config, &states, &actions);
    let device = DeviceKind::Flex.train_device();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let policy = jsae_learner::Policy::new(&config.ppo, input, head, &mut rng, &device);
    let host = HostPolicy::from_policy(&policy);
    let b = config.ppo.minibatch_size;
    let f = fragment(input, head, 0, &mut rng);
    let rows = b.min(FRAGMENT);
    let x = Array2::from_shape_vec((rows, input), f.x[..rows * input].to_vec())
        .unwrap_or_else(|_| Array2::zeros((rows, input)));
    let (continuous, discrete) = match &f.actions {
        ActionBatch::Continuous { dim, data } => (&data[..rows * dim], &[][..]),
        ActionBatch::Discrete(a) => (&[][..], &a[..rows]),
    };
    let mb = HostMinibatch {
        x: x.view(),
        continuous,
        discrete,
        old_logp: &f.logp[..rows],
        adv: &f.rewards[..rows],
        returns: &f.rewards[..rows],
        old_values: &f.logp[..rows],
    };
    let cfg = LossConfig {
        clip: config.ppo.clip as f32,
        clip_value_loss: config.ppo.clip_value_loss,
        ent_coef: config.ppo.ent_coef as f32,
        vf_coef: config.ppo.vf_coef as f32,
    };
    let mut sink = host.loss_and_grads(&mb, cfg).0.total;
    let t = Instant::now();
    for _ in 0..repeats.max(1) {
        sink += host.loss_and_grads(&mb, cfg).0.total;
    }
    std::hint::black_box(sink);
    t.elapsed().as_secs_f64() * 1e6 / repeats.max(1) as f64
}

/// Single-thread GEMM throughput in GFLOP/s on `n x n` matrices (matrixmultiply, through
/// ndarray): the machine's practical limit for dense products on one core.
pub fn gemm_peak(n: usize, repeats: usize) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let a = Array2::from_shape_fn((n, n), |_| rng.random_range(-1.0f32..1.0));
    let b = Array2::from_shape_fn((n, n), |_| rng.random_range(-1.0f32..1.0));
    let mut sink = a.dot(&b)[[0, 0]];
    let t = Instant::now();
    for _ in 0..repeats.max(1) {
        sink += a.dot(&b)[[0, 0]];
    }
    let s = t.elapsed().as_secs_f64();
    std::hint::black_box(sink);
    2.0 * (n as f64).powi(3) * repeats.max(1) as f64 / s / 1e9
}

/// The heads measured: each environment's default shapes for plain PPO and for JSAE.
pub const CASES: [(EnvName, Algo); 7] = [
    (EnvName::HalfCheetah, Algo::Ppo),
    (EnvName::HalfCheetah, Algo::Jsae),
    (EnvName::GridworldDiscrete, Algo::Ppo),
    (EnvName::GridworldDiscrete, Algo::Jsae),
    (EnvName::Slotmachine, Algo::Ppo),
    (EnvName::Recommender, Algo::Ppo),
    (EnvName::Recommender, Algo::Jsae),
];

/// Runs every case and formats the table.
pub fn run(quick: bool) -> String {
    let updates = if quick { 1 } else { 3 };
    let peak = gemm_peak(512, if quick { 4 } else { 40 });
    let mut out = format!(
        "PPO update, {BATCH} samples, burn (flex), one process; GEMM peak {peak:.1} GFLOP/s \
         (512x512 f32, one thread, this run)\n"
    );
    out.push_str(&format!(
        "{:<26} {:>6} {:>17} {:>5} {:>6} {:>10} {:>8} {:>8} {:>12} {:>12}\n",
        "case",
        "input",
        "head",
        "mb",
        "epochs",
        "ms/update",
        "GFLOP/s",
        "/peak",
        "burn us/mb",
        "host lg us"
    ));
    for (env, algo) in CASES {
        let b = bench_case(env, algo, updates);
        let steps = (BATCH.div_ceil(b.minibatch) * b.epochs.max(1)) as f64;
        let host = host_loss_grad_us(env, algo, if quick { 5 } else { 200 });
        out.push_str(&format!(
            "{:<26} {:>6} {:>17} {:>5} {:>6} {:>10.1} {:>8.2} {:>8.3} {:>12.0} {:>12.0}\n",
            b.case,
            b.input,
            b.head,
            b.minibatch,
            b.epochs,
            b.update_ms,
            b.gflops,
            b.gflops / peak,
            b.update_ms * 1e3 / steps,
            host
        ));
    }
    out.push_str(
        "burn us/mb: a whole minibatch step of the update (forward, backward, clip, Adam); \
         host lg us: the loss and every gradient on the host (jsae_learner::fused), no \
         optimiser step yet\n",
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mlp_weights_counts_every_dense_product() {
        assert_eq!(mlp_weights(17, &[64, 64], 6), 17 * 64 + 64 * 64 + 64 * 6);
        assert_eq!(mlp_weights(3, &[], 2), 6);
    }

    #[test]
    fn a_quick_case_runs_its_epochs_and_reports_a_rate() {
        let b = bench_case(EnvName::GridworldDiscrete, Algo::Jsae, 1);
        assert!(
            b.epochs >= 1 && b.update_ms > 0.0 && b.gflops > 0.0,
            "{b:?}"
        );
        assert!(gemm_peak(64, 2) > 0.0);
        assert!(host_loss_grad_us(EnvName::HalfCheetah, Algo::Ppo, 2) > 0.0);
    }
}
