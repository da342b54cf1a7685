//! `jsae bench --learner`: the PPO update's time per 2,048-sample batch for each policy head
//! we train (the shapes of each environment's defaults) on the old path (burn's autodiff)
//! and the new one (the fused host update, `ppo.update = "fused"`), the new path's achieved
//! GFLOP/s, and a single-thread GEMM peak measured on the same machine in the same run, so
//! the speed-up and the ratio to the machine's limit are read from one run.
//!
//! The batches are synthetic (random inputs, one-hot where plain PPO reads categorical
//! states, actions drawn from the head's space, random rewards): the update's cost depends
//! only on the shapes and on that sparsity. FLOPs are those of the matrix products of the
//! policy and critic MLPs, forward (2 per weight and sample) and backward (4), over the epochs
//! the update ran; a one-hot input row counts one weight row per factor (what the fused
//! path multiplies; burn's multiplies the zeros too).

use std::time::Instant;

use jsae_agent::{PolicyHead, policy_shape};
use jsae_learner::{Ingested, Learner, UpdatePath};
use jsae_nn::DeviceKind;
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_wire::{RolloutFragment, StateSpace};
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
    /// Samples per update.
    pub batch: usize,
    /// Milliseconds per update (of `batch` samples).
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

/// Rewrites `x` (rows of `sizes.sum()` values) as one one-hot per factor.
fn one_hot_rows(x: &mut [f32], sizes: &[usize], rng: &mut ChaCha8Rng) {
    let width: usize = sizes.iter().sum();
    for row in x.chunks_mut(width.max(1)) {
        row.fill(0.0);
        let mut offset = 0;
        for &n in sizes {
            row[offset + rng.random_range(0..n.max(1))] = 1.0;
            offset += n;
        }
    }
}

/// Times `updates` PPO updates of 2,048 synthetic samples under `env`/`algo`'s defaults on
/// the given update path, after one untimed warm-up update.
pub fn bench_case(env: EnvName, algo: Algo, updates: usize, path: UpdatePath) -> LearnerBench {
    bench_batch(env, algo, updates, path, BATCH, None)
}

/// [`bench_case`] with batches of `batch` samples (whole fragments of 128 steps): what the
/// learner does per update when `batch / 2048` actors of 16 environments feed it, so
/// `batch / update_ms` is the most env steps per second it can take in (gRPC decoding and
/// the checkpoint left out). `minibatches`: `ppo.minibatches` (None: the defaults' size).
pub fn bench_batch(
    env: EnvName,
    algo: Algo,
    updates: usize,
    path: UpdatePath,
    batch: usize,
    minibatches: Option<usize>,
) -> LearnerBench {
    let batch = batch.div_ceil(FRAGMENT).max(1) * FRAGMENT;
    let config = TrainConfig::defaults(env, algo);
    let (states, actions) = config.spaces();
    let (input, head) = policy_shape(&config, &states, &actions);
    let mut ppo = config.ppo.clone();
    ppo.batch_steps = batch;
    ppo.update = path;
    ppo.minibatches = minibatches.or(ppo.minibatches);
    // plain PPO on categorical states reads them one-hot, as the actors encode them
    let one_hot = match &states {
        StateSpace::Categorical { sizes }
            if !config.algo.representation().embeds_states()
                && sizes.iter().sum::<usize>() == input =>
        {
            Some(sizes.clone())
        }
        _ => None,
    };
    let (elapsed, epochs) =
        time_updates(&ppo, input, head, one_hot.as_deref(), batch, updates, true);
    let n = updates.max(1);
    let (outputs, head_name) = head_outputs(head);
    // the products done: a one-hot input row multiplies one weight row per factor
    let read = one_hot.as_ref().map_or(input, Vec::len);
    let weights = mlp_weights(read, &ppo.hidden, outputs) + mlp_weights(read, &ppo.hidden, 1);
    let flops = 6.0 * weights as f64 * batch as f64 * epochs as f64;
    LearnerBench {
        case: format!("{}/{}", env.as_str(), algo.as_str()),
        input,
        head: head_name,
        minibatch: ppo.minibatch_len(batch),
        epochs: epochs / n,
        batch,
        update_ms: elapsed * 1e3 / n as f64,
        gflops: flops / elapsed / 1e9,
    }
}

/// Seconds spent in `updates` PPO updates of `batch` synthetic samples (whole fragments) of
/// a fresh learner with these settings and shape, and the epochs they ran; with `warm_up`,
/// after one untimed update (buffers, the allocator's pages and the optimiser's state are
/// set up there, and every later update reuses them). `one_hot`: the factor sizes of a
/// one-hot input.
pub fn time_updates(
    ppo: &jsae_settings::PpoConfig,
    input: usize,
    head: PolicyHead,
    one_hot: Option<&[usize]>,
    batch: usize,
    updates: usize,
    warm_up: bool,
) -> (f64, usize) {
    let mut learner = Learner::new(ppo.clone(), input, head, 1 << 40, 1, DeviceKind::Flex);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (mut elapsed, mut epochs) = (0.0, 0);
    // one update first, untimed: buffers, the allocator's pages and the optimiser's state
    // are set up there, and every later update reuses them
    for round in 0..updates.max(1) + usize::from(warm_up) {
        let timed = !(warm_up && round == 0);
        let fragments: Vec<RolloutFragment> = (0..batch / FRAGMENT)
            .map(|_| {
                let mut f = jsae_learner::synthetic::fragment(
                    input,
                    head,
                    learner.version(),
                    FRAGMENT,
                    &mut rng,
                );
                if let Some(sizes) = one_hot {
                    one_hot_rows(&mut f.x, sizes, &mut rng);
                    one_hot_rows(&mut f.truncated_next_x, sizes, &mut rng);
                    one_hot_rows(&mut f.last_next_x, sizes, &mut rng);
                }
                f
            })
            .collect();
        let t = Instant::now();
        for f in fragments {
            if let Ok(Ingested::Updated(report)) = learner.ingest(f)
                && timed
            {
                epochs += report.metrics.epochs;
            }
        }
        if timed {
            elapsed += t.elapsed().as_secs_f64();
        }
    }
    (elapsed, epochs)
}

/// A single-thread GEMM kernel the bench can time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kernel {
    /// The fused update's own product ([`jsae_nn::host::product`]: the `gemm` crate, AVX-512
    /// where the CPU has it).
    Host,
    /// ndarray's product (matrixmultiply, AVX2 at most): the kernel the fused update used first.
    Ndarray,
}

/// Single-thread GEMM throughput in GFLOP/s on `n x n` matrices: with [`Kernel::Host`], the
/// practical limit for the fused update's dense products on one core.
pub fn gemm_peak(kernel: Kernel, n: usize, repeats: usize) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let a = Array2::from_shape_fn((n, n), |_| rng.random_range(-1.0f32..1.0));
    let b = Array2::from_shape_fn((n, n), |_| rng.random_range(-1.0f32..1.0));
    let mut c = Array2::zeros((n, n));
    let product = |c: &mut Array2<f32>| match kernel {
        Kernel::Host => jsae_nn::host::product(a.view(), b.view(), c.view_mut()),
        Kernel::Ndarray => ndarray::linalg::general_mat_mul(1.0, &a, &b, 0.0, c),
    };
    product(&mut c);
    let mut sink = c[[0, 0]];
    let t = Instant::now();
    for _ in 0..repeats.max(1) {
        product(&mut c);
        sink += c[[0, 0]];
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

/// Runs every case on both update paths and formats the table.
pub fn run(quick: bool) -> String {
    let updates = if quick { 1 } else { 5 };
    let repeats = if quick { 4 } else { 40 };
    let peak = gemm_peak(Kernel::Host, 512, repeats);
    let ndarray_peak = gemm_peak(Kernel::Ndarray, 512, repeats);
    // the fused update shares its work between rayon's threads
    let threads = rayon::current_num_threads().max(1);
    let limit = peak * threads as f64;
    let mut out = format!(
        "PPO update, {BATCH} samples, one process; old: burn autodiff (flex, its products on the \
         gemm crate too), new: fused host \
         update on rayon's {threads} threads (minibatch rows, actor and critic halves, wide \
         products, softmax rows and Adam split between them); GEMM peak {peak:.1} \
         GFLOP/s (512x512 f32, one thread, this run, the fused update's kernel: the gemm crate; \
         ndarray's matrixmultiply {ndarray_peak:.1}), limit {limit:.1} ({threads} threads)\n"
    );
    out.push_str(&format!(
        "{:<26} {:>6} {:>17} {:>4} {:>7} {:>9} {:>9} {:>8} {:>8} {:>6} {:>8} {:>7}\n",
        "case",
        "input",
        "head",
        "mb",
        "epochs",
        "old ms",
        "new ms",
        "speedup",
        "GFLOP/s",
        "/limit",
        "us/mb",
        "bound"
    ));
    for (env, algo) in CASES {
        let old = bench_case(env, algo, updates, UpdatePath::Burn);
        let new = bench_case(env, algo, updates, UpdatePath::Fused);
        let steps = (BATCH.div_ceil(new.minibatch) * new.epochs.max(1)) as f64;
        out.push_str(&format!(
            "{:<26} {:>6} {:>17} {:>4} {:>7} {:>9.1} {:>9.1} {:>7.1}x {:>8.2} {:>6.3} {:>8.0} {:>6.1}x\n",
            new.case,
            new.input,
            new.head,
            new.minibatch,
            format!("{}/{}", old.epochs, new.epochs),
            old.update_ms,
            new.update_ms,
            old.update_ms / new.update_ms,
            new.gflops,
            new.gflops / limit,
            new.update_ms * 1e3 / steps,
            // the products alone at the limit take new_ms * (GFLOP/s / limit)
            old.update_ms / (new.update_ms * new.gflops / limit),
        ));
    }
    out.push_str(
        "ms: one whole update (GAE, every minibatch step: forward, backward, clip, Adam); \
         epochs: old/new (the KL stop may end one early); GFLOP/s and /limit: the new path's \
         dense products, and their share of the GEMM peak times the threads; us/mb: the new \
         path per minibatch step; bound: the largest speed-up the new path's products allow \
         (old ms over their time at the limit)\n",
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
    fn a_quick_case_runs_its_epochs_on_both_paths_and_reports_a_rate() {
        for path in [UpdatePath::Burn, UpdatePath::Fused] {
            let b = bench_case(EnvName::GridworldDiscrete, Algo::Jsae, 1, path);
            assert!(
                b.epochs >= 1 && b.update_ms > 0.0 && b.gflops > 0.0,
                "{path:?}: {b:?}"
            );
        }
        for kernel in [Kernel::Host, Kernel::Ndarray] {
            assert!(gemm_peak(kernel, 64, 2) > 0.0);
        }
    }
}
