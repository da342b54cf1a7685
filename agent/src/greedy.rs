//! Deterministic (greedy) actions of a policy that acts in an action-embedding space over
//! discrete actions.
//!
//! The policy is a Gaussian N(mu(s), sigma^2) over E and f maps an embedding to the action
//! of the nearest g(a). The greedy action is f(mu) ([`GreedyDecode::Mean`], the default and
//! the paper's "mean action, then f": mu is the Gaussian's mode in E). The alternative,
//! [`GreedyDecode::Mode`], is the action the policy chooses most often: the probability of
//! a is the Gaussian's mass on a's Voronoi cell, which [`modal_action`] estimates from
//! [`SAMPLES`] fixed draws (common random numbers, the same for every state, so the greedy
//! policy is a function of the state): mu + sigma * z_k, each decoded by f; the action
//! decoded most often wins, a tie goes to the one decoded first, and the mean itself is the
//! first draw (z_0 = 0).
//!
//! Measured on the ten 2,048-action gridworld runs of `results/sweeps/gridworld-actions.toml`
//! (100 evaluation episodes each, `jsae eval --decode mean|mode`): the mean decode solved all
//! ten (and the ten 4,096-action runs); the mode got stuck on one of the ten (every episode
//! 150 steps, return -1.5): seed 1005 from 256 draws, seed 1001 from 4,096 (16 times the
//! cost). Equivalent actions (the same displacement) split the mass into cells of a few draws
//! each, so the estimate is noise. A greedy policy in the gridworld loops for good wherever
//! its one action at a state runs into a wall (the state does not change), which the sampled
//! policy escapes; evaluation reports both (docs/src/experiments/greedy-loops.md).

use std::collections::HashMap;

use crate::embedding::Embedding;
use jsae_wire::ActionBatch;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// How the deterministic evaluation turns the policy's Gaussian over E into one discrete
/// action.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GreedyDecode {
    /// f of the mean embedding (the paper's "mean action, then f").
    #[default]
    Mean,
    /// The most likely action ([`modal_action`]).
    Mode,
}

/// Draws per greedy action (the mean included).
pub const SAMPLES: usize = 4096;

/// The fixed standard-normal draws for `dim` dimensions, `[SAMPLES, dim]`, row 0 zero (the
/// same seed every call: common random numbers across states).
fn draws(dim: usize) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(0x6eed_7a11);
    let mut z = vec![0.0; dim];
    z.extend((dim..SAMPLES * dim).map(|_| -> f32 { StandardNormal.sample(&mut rng) }));
    z
}

/// The policy's most likely discrete action at mean embedding `mean` with per-dimension
/// standard deviations `std`, decoded by `embedding`'s f (see the module's note).
pub fn modal_action(embedding: &mut Embedding, mean: &[f32], std: &[f32]) -> Option<u32> {
    let dim = mean.len();
    let z = draws(dim);
    let points: Vec<f32> = z
        .chunks_exact(dim)
        .flat_map(|zk| zk.iter().zip(mean).zip(std).map(|((z, m), s)| m + s * z))
        .collect();
    let mut decoded = ActionBatch::Discrete(Vec::with_capacity(SAMPLES));
    embedding.decode(&points, &mut decoded);
    match decoded {
        ActionBatch::Discrete(actions) => most_frequent(&actions),
        ActionBatch::Continuous { .. } => None,
    }
}

/// The value that occurs most often; of equally frequent ones, the one that occurs first.
pub fn most_frequent(actions: &[u32]) -> Option<u32> {
    // (count, first position) per action.
    let mut tally: HashMap<u32, (usize, usize)> = HashMap::new();
    for (k, &a) in actions.iter().enumerate() {
        tally.entry(a).or_insert((0, k)).0 += 1;
    }
    tally
        .into_iter()
        .max_by(|(_, (c1, k1)), (_, (c2, k2))| c1.cmp(c2).then(k2.cmp(k1)))
        .map(|(a, _)| a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_most_frequent_wins_and_ties_go_to_the_first() {
        assert_eq!(most_frequent(&[7, 3, 3, 9, 3, 7]), Some(3));
        assert_eq!(most_frequent(&[7, 3, 3, 7]), Some(7));
        assert_eq!(most_frequent(&[5]), Some(5));
        assert_eq!(most_frequent(&[]), None);
    }

    #[test]
    fn the_draws_are_fixed_and_start_at_the_mean() {
        let z = draws(3);
        assert_eq!(z.len(), SAMPLES * 3);
        assert_eq!(&z[..3], &[0.0; 3]);
        assert_eq!(z, draws(3));
        let mean = z[3..].iter().sum::<f32>() / (z.len() - 3) as f32;
        let var = z[3..].iter().map(|v| v * v).sum::<f32>() / (z.len() - 3) as f32;
        assert!(mean.abs() < 0.15 && (var - 1.0).abs() < 0.2, "{mean} {var}");
    }
}
