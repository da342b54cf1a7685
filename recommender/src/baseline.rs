//! Reference policies for the recommender, scored like a run's evaluation (same episodes,
//! same seeds): uniformly random recommendations, the most popular item whatever the history
//! (the highest purchase share times value), and the myopic "most likely next item" that reads
//! the n-gram model itself (an upper reference a learned policy does not get to see).

use jsae_proto::settings::TrainConfig;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use jsae_envs::recsys::RecommenderEnv;
use jsae_envs::recsys::RecsysError;
use jsae_envs::{ActionRef, Env};

/// Returns of one reference policy.
#[derive(Debug, Clone, Serialize)]
pub struct BaselineReturns {
    /// `random`, `popular` or `most-likely`.
    pub policy: &'static str,
    /// Episodes run.
    pub episodes: usize,
    /// Mean return.
    pub return_mean: f64,
    /// Standard deviation of the returns.
    pub return_std: f64,
}

/// Every policy runs on the same environment (one model load), from the same seeds.
fn returns(
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

/// The catalogue item with the highest `score` (the lowest slot on ties).
fn best(env: &RecommenderEnv, score: impl Fn(u32) -> f64) -> u32 {
    (0..env.model().catalogue().len() as u32)
        .map(|a| (a, score(a)))
        .fold((0, f64::NEG_INFINITY), |b, c| if c.1 > b.1 { c } else { b })
        .0
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
    let popular = returns(&mut env, episodes, seed, "popular", |env, _| {
        let model = env.model();
        best(env, |a| model.popularity(a) * model.value(a))
    });
    let greedy = returns(&mut env, episodes, seed, "most-likely", |env, _| {
        let model = env.model();
        let h = env.history();
        let (before, last) = (h[h.len() - 2], h[h.len() - 1]);
        best(env, |a| model.probability(before, last, a) * model.value(a))
    });
    Ok(vec![random, popular, greedy])
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_proto::settings::{Algo, EnvName, SessionSource};

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
        assert_eq!(first.len(), 3);
        for (a, b) in first.iter().zip(&again) {
            assert_eq!(a.return_mean, b.return_mean, "{}", a.policy);
        }
        let names: Vec<_> = first.iter().map(|b| b.policy).collect();
        assert_eq!(names, ["random", "popular", "most-likely"]);
        assert!(
            first[2].return_mean > 2.0 * first[0].return_mean,
            "{first:?}"
        );
    }
}
