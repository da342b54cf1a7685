//! Rollout fragments of random data for a policy's shapes: what benchmarks and tests feed a
//! learner when the update's cost or its equality across paths is measured, not learning.

use jsae_wire::{ActionBatch, RolloutFragment};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use jsae_agent::PolicyHead;

/// A fragment of `steps` random steps for inputs of width `x_dim` and `head`'s actions,
/// produced under policy `version`: inputs in [-3, 3), rewards in [-1, 1), behaviour
/// log-probabilities in [-4, -1), an episode terminated every 23 steps and one truncated
/// every 29 (with its bootstrap input).
pub fn fragment(
    x_dim: usize,
    head: PolicyHead,
    version: u64,
    steps: usize,
    rng: &mut ChaCha8Rng,
) -> RolloutFragment {
    let actions = match head {
        PolicyHead::Gaussian { dim } => ActionBatch::Continuous {
            dim,
            data: (0..steps * dim)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect(),
        },
        PolicyHead::Categorical { n } => {
            ActionBatch::Discrete((0..steps).map(|_| rng.random_range(0..n as u32)).collect())
        }
    };
    let truncated: Vec<bool> = (0..steps).map(|t| t % 29 == 28).collect();
    let cuts = truncated.iter().filter(|&&t| t).count();
    let mut uniform = |n: usize, lo: f32, hi: f32| -> Vec<f32> {
        (0..n).map(|_| rng.random_range(lo..hi)).collect()
    };
    RolloutFragment {
        actor_id: 0,
        env_index: 0,
        policy_version: version,
        embedding_version: 0,
        actor_env_steps: 0,
        x_dim,
        x: uniform(steps * x_dim, -3.0, 3.0),
        actions,
        logp: uniform(steps, -4.0, -1.0),
        rewards: uniform(steps, -1.0, 1.0),
        terminated: (0..steps).map(|t| t % 23 == 22).collect(),
        truncated,
        truncated_next_x: uniform(cuts * x_dim, -3.0, 3.0),
        last_next_x: uniform(x_dim, -3.0, 3.0),
        episodes: Vec::new(),
        actor_incarnation: 1,
        visit_keys: Vec::new(),
    }
}
