//! What the next-purchase signal can teach within a budget of env steps, with no function
//! approximation: a learner that counts, from its own play, which item was bought after each
//! 2-item context and after each last item, and recommends the most counted one: the pair's
//! once the pair has been seen `m` times, else the last item's, else the most bought item.
//! It acts greedily on its counts while it learns (its recommendations bias what is bought,
//! as they bias the data PPO's next-purchase loss reads), then is frozen and scored under
//! `recommender-baseline`'s protocol, beside the rule that reads the true model. A variant
//! weighs a purchase of the recommended item by 1 / boost, undoing the simulator's boost;
//! another smooths a pair's counts towards its last item's (an interpolated n-gram). Two
//! more first count the logged purchases the model is built from (what
//! `ppo.recommender.logged_pretrain_epochs` trains on): with no play at all, and before playing.
//!
//! Unlike `context_value`'s learner, which knows a pair's true continuation after `k`
//! visits, this one has only the purchases it saw: the most likely item out of 835 must be
//! told apart from a handful of draws.
//!
//!   cargo run --release -p jsae-research --example counting_learner [SEED] [BUDGET]

use std::collections::HashMap;
use std::hash::Hash;

use jsae_envs::recsys::RecommenderEnv;
use jsae_envs::{ActionRef, Env};
use jsae_recommender::baseline::{Reference, returns};
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_wire::StateBatch;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Counts of the items bought after each key, with the most counted item kept current.
struct Counts<K> {
    by_key: HashMap<K, Counted>,
}

#[derive(Default)]
struct Counted {
    items: HashMap<u32, f64>,
    total: u32,
    best: (u32, f64),
}

impl<K: Hash + Eq> Counts<K> {
    fn new() -> Self {
        Self {
            by_key: HashMap::new(),
        }
    }

    fn add(&mut self, key: K, item: u32, weight: f64) {
        let c = self.by_key.entry(key).or_default();
        let n = c.items.entry(item).or_insert(0.0);
        *n += weight;
        c.total += 1;
        if *n > c.best.1 {
            c.best = (item, *n);
        }
    }

    /// The most counted item after `key`, if it has been seen at least `min` times.
    fn best(&self, key: &K, min: u32) -> Option<u32> {
        self.by_key
            .get(key)
            .filter(|c| c.total >= min.max(1))
            .map(|c| c.best.0)
    }
}

struct Learner {
    pairs: Counts<(u32, u32)>,
    last: Counts<u32>,
    all: Counts<()>,
    min_pair: u32,
    /// The weight of a purchase of the recommended item: 1, or 1 / boost, which undoes the
    /// simulator's boost (the counts then estimate the model's own continuation).
    accepted_weight: f64,
    /// 0: the pair's counts alone once it has been seen `min_pair` times. Above 0: the pair's
    /// counts plus this many pseudo-purchases spread as the last item's counts are (an
    /// interpolated n-gram estimate: a pair seen once leans on its last item).
    smoothing: f64,
}

impl Learner {
    fn choose(&self, h: &[u32]) -> u32 {
        let n = h.len();
        if self.smoothing > 0.0
            && let Some(best) = self.smoothed(h)
        {
            return best;
        }
        self.pairs
            .best(&(h[n - 2], h[n - 1]), self.min_pair)
            .or_else(|| self.last.best(&h[n - 1], 1))
            .or_else(|| self.all.best(&(), 1))
            .unwrap_or(0)
    }

    /// The best item under the pair's counts plus `smoothing` times the last item's shares:
    /// one of the pair's items or the last item's best.
    fn smoothed(&self, h: &[u32]) -> Option<u32> {
        let n = h.len();
        let pair = self.pairs.by_key.get(&(h[n - 2], h[n - 1]))?;
        let last = self.last.by_key.get(&h[n - 1])?;
        let mass: f64 = last.items.values().sum();
        let share = |i: u32| last.items.get(&i).copied().unwrap_or(0.0) / mass;
        let score = |i: u32| pair.items.get(&i).copied().unwrap_or(0.0) + self.smoothing * share(i);
        pair.items
            .keys()
            .copied()
            .chain([last.best.0])
            .max_by(|&a, &b| score(a).total_cmp(&score(b)).then(b.cmp(&a)))
    }

    fn observe(&mut self, h: &[u32], recommended: u32, bought: u32) {
        let n = h.len();
        let w = if bought == recommended {
            self.accepted_weight
        } else {
            1.0
        };
        self.pairs.add((h[n - 2], h[n - 1]), bought, w);
        self.last.add(h[n - 1], bought, w);
        self.all.add((), bought, w);
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let mut config = TrainConfig::defaults(EnvName::Recommender, Algo::Ppo);
    config.seed = args.next().map_or(Ok(1001), |s| s.parse())?;
    let budget: usize = args.next().map_or(Ok(2_000_000), |s| s.parse())?;
    let mut env = RecommenderEnv::new(&config.environment)?;
    let episodes = 2000;
    let model = RecommenderEnv::new(&config.environment)?;
    let rule = returns(&mut env, episodes, config.eval_seed(), "", |env, _| {
        Reference::MostLikely.best(model.model(), env.history())
    });
    println!(
        "the most likely item under the true model: return {:.3} ({episodes} episodes)",
        rule.return_mean
    );
    let boost = config.environment.recommender.boost;
    // (pair used after, weight of an accepted purchase, smoothing, counts from the logs
    // first, env steps played)
    let variants = [
        (1, 1.0, 0.0, false, budget),
        (3, 1.0, 0.0, false, budget),
        (5, 1.0, 0.0, false, budget),
        (3, 1.0 / boost, 0.0, false, budget),
        (1, 1.0 / boost, 1.0, false, budget),
        (1, 1.0 / boost, 3.0, false, budget),
        (1, 1.0, 0.0, true, 0),
        (1, 1.0 / boost, 0.0, true, budget),
    ];
    let (logged_states, logged_next) = env.logged_steps();
    for (min_pair, accepted_weight, smoothing, from_logs, play) in variants {
        let mut learner = Learner {
            pairs: Counts::new(),
            last: Counts::new(),
            all: Counts::new(),
            min_pair,
            accepted_weight,
            smoothing,
        };
        if let StateBatch::Categorical { factors, data } = &logged_states
            && from_logs
        {
            // a logged purchase followed no recommendation: it counts 1
            for (h, &bought) in data.chunks_exact(*factors).zip(&logged_next) {
                learner.observe(h, u32::MAX, bought);
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let mut steps = 0;
        while steps < play {
            env.reset(&mut rng);
            loop {
                let before = env.history().to_vec();
                let action = learner.choose(&before);
                let step = env.step(ActionRef::Discrete(action));
                steps += 1;
                let bought = *env.history().last().expect("a history");
                learner.observe(&before, action, bought);
                if step.terminated || step.truncated {
                    break;
                }
            }
        }
        let r = returns(&mut env, episodes, config.eval_seed(), "", |env, _| {
            learner.choose(env.history())
        });
        println!(
            "counting learner, pair used after {min_pair} sightings, accepted purchases weighted \
             {accepted_weight:.2}, smoothing {smoothing}, logs counted first: {from_logs}, \
             {steps} steps: return {:.3} (std {:.3}, {episodes} episodes; {} pairs seen)",
            r.return_mean,
            r.return_std,
            learner.pairs.by_key.len()
        );
    }
    Ok(())
}
