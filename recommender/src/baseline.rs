//! Reference policies for the recommender: the most popular item whatever the history (the
//! highest purchase share times value), item-kNN by co-visitation (the items bought near the
//! history's items in the data's sessions), and the myopic greedy rule that reads the n-gram
//! model itself (an upper reference a learned policy does not get to see). One home
//! for their scores: the returns here (scored like a run's evaluation, same episodes and
//! seeds, beside uniformly random recommendations), the service's `--policy`, and the offline
//! evaluation's rankings.

use jsae_settings::TrainConfig;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use jsae_envs::recsys::{NgramModel, RecommenderEnv, RecsysError};
use jsae_envs::{ActionRef, Env};

/// What a Recommender serves (`jsae recommender --policy`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum PolicyChoice {
    /// The run's policy (JSAE: nearest items to its action embedding; PPO: its softmax).
    #[default]
    Learned,
    /// The myopic greedy rule: the highest expected reward now under the n-gram model (the
    /// most likely next item where only an accepted recommendation pays and items have no
    /// prices; reads the simulator's model).
    MostLikely,
    /// The most popular item, whatever the history.
    Popular,
    /// Item-kNN: the items most often bought near the history's in the data's sessions.
    ItemKnn,
}

impl PolicyChoice {
    /// The reference policy chosen, None for the learned one.
    pub fn reference(self) -> Option<Reference> {
        match self {
            Self::Learned => None,
            Self::MostLikely => Some(Reference::MostLikely),
            Self::Popular => Some(Reference::Popular),
            Self::ItemKnn => Some(Reference::ItemKnn),
        }
    }
}

/// A policy that reads the n-gram model instead of learning.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reference {
    /// The highest purchase share times value, whatever the history.
    Popular,
    /// The highest expected reward now: the probability that the item is bought when
    /// recommended (boost and floor included) times its value, plus, where every purchase
    /// pays, the other items' (`NgramModel::expected_rewards`).
    MostLikely,
    /// The highest co-visitation similarity to the history (`NgramModel::covisit_scores`).
    ItemKnn,
}

impl Reference {
    /// Every reference policy, in the order reports list them.
    pub const ALL: [Self; 3] = [Self::Popular, Self::ItemKnn, Self::MostLikely];

    /// The name reports and `--policy` use.
    pub fn name(self) -> &'static str {
        match self {
            Self::Popular => "popular",
            Self::MostLikely => "most-likely",
            Self::ItemKnn => "item-knn",
        }
    }

    /// The policy `--policy` names this one.
    pub fn choice(self) -> PolicyChoice {
        match self {
            Self::Popular => PolicyChoice::Popular,
            Self::MostLikely => PolicyChoice::MostLikely,
            Self::ItemKnn => PolicyChoice::ItemKnn,
        }
    }

    /// The score of recommending each catalogue item (by slot) in `state` (the last
    /// purchases, oldest first, "none" slots included; at least two).
    pub fn scores(self, model: &NgramModel, state: &[u32]) -> Vec<f64> {
        match self {
            Self::Popular => (0..model.catalogue().len() as u32)
                .map(|a| model.popularity(a) * model.value(a))
                .collect(),
            Self::MostLikely => {
                let n = state.len();
                model.expected_rewards(state[n - 2], state[n - 1])
            }
            Self::ItemKnn => model.covisit_scores(state),
        }
    }

    /// The `k` best catalogue items in `state` as `(item, score)`, best first (ties: the
    /// lower slot first).
    pub fn rank(self, model: &NgramModel, state: &[u32], k: usize) -> Vec<(u32, f64)> {
        let mut all: Vec<(u32, f64)> = (0u32..).zip(self.scores(model, state)).collect();
        crate::ranking::best_k(&mut all, k, f64::total_cmp);
        all
    }

    /// The best item in `state`.
    pub fn best(self, model: &NgramModel, state: &[u32]) -> u32 {
        self.rank(model, state, 1).first().map_or(0, |b| b.0)
    }
}

/// Returns of one reference policy.
#[derive(Debug, Clone, Serialize)]
pub struct BaselineReturns {
    /// `random`, `popular`, `item-knn` or `most-likely`.
    pub policy: &'static str,
    /// Episodes run.
    pub episodes: usize,
    /// Mean return.
    pub return_mean: f64,
    /// Standard deviation of the returns.
    pub return_std: f64,
}

/// The returns of the policy `choose` over `episodes` episodes of `env` seeded with `seed`
/// (what every reference policy is scored with: the same episodes and seeds on one
/// environment; `choose` gets its own random stream).
pub fn returns(
    env: &mut RecommenderEnv,
    episodes: usize,
    seed: u64,
    policy: &'static str,
    mut choose: impl FnMut(&RecommenderEnv, &mut ChaCha8Rng) -> u32,
) -> BaselineReturns {
    let mut env_rng = ChaCha8Rng::seed_from_u64(seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED);
    let mut all = Vec::with_capacity(episodes);
    for _ in 0..episodes {
        env.reset(&mut env_rng);
        let mut ret = 0.0;
        loop {
            let a = choose(env, &mut rng);
            let step = env.step(ActionRef::Discrete(a));
            ret += step.reward;
            if step.terminated || step.truncated {
                break;
            }
        }
        all.push(ret);
    }
    let n = all.len().max(1) as f64;
    let mean = all.iter().sum::<f64>() / n;
    let var = all.iter().map(|r| (r - mean) * (r - mean)).sum::<f64>() / n;
    BaselineReturns {
        policy,
        episodes,
        return_mean: mean,
        return_std: var.sqrt(),
    }
}

/// Every reference policy over `episodes` episodes seeded with `seed` (a run's evaluation
/// uses `config.eval_seed()`).
pub fn baselines(
    config: &TrainConfig,
    episodes: usize,
    seed: u64,
) -> Result<Vec<BaselineReturns>, RecsysError> {
    let actions = config.environment.recommender.top_n;
    let mut env = RecommenderEnv::new(&config.environment)?;
    let random = returns(&mut env, episodes, seed, "random", |_, rng| {
        rng.random_range(0..actions)
    });
    let mut all = vec![random];
    for reference in Reference::ALL {
        all.push(returns(
            &mut env,
            episodes,
            seed,
            reference.name(),
            |env, _| reference.best(env.model(), env.history()),
        ));
    }
    Ok(all)
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_settings::{Algo, EnvName, SessionSource};

    #[test]
    fn reading_the_model_beats_random_and_both_repeat_for_a_seed() {
        let mut config = TrainConfig::defaults(EnvName::Recommender, Algo::Jsae);
        let r = &mut config.environment.recommender;
        r.source = SessionSource::Synthetic;
        r.top_n = 30;
        r.synthetic.items = 25;
        r.synthetic.sessions = 500;
        let first = baselines(&config, 200, 3).expect("runs");
        let again = baselines(&config, 200, 3).expect("runs");
        assert_eq!(first.len(), 4);
        for (a, b) in first.iter().zip(&again) {
            assert_eq!(a.return_mean, b.return_mean, "{}", a.policy);
        }
        let names: Vec<_> = first.iter().map(|b| b.policy).collect();
        assert_eq!(names, ["random", "popular", "item-knn", "most-likely"]);
        assert!(
            first[3].return_mean > 2.0 * first[0].return_mean,
            "{first:?}"
        );
    }
}
