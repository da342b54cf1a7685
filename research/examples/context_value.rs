//! What each context of the n-gram model is worth to the greedy rule, and how much of it a
//! learner could know within a budget of env steps.
//!
//! First, the most likely next item read from the last item alone (the 1-item context,
//! `mix = 1`), from the 2-item context alone (`mix = 0`), and from the model as the simulator
//! mixes them (the reference policy `most-likely`), each played on the default simulator
//! under `recommender-baseline`'s protocol. A policy that scores items by the last purchase
//! plus a term per older purchase (an additive model) can reach about the first; the gap to
//! the others is the 2-item contexts' own continuations, told apart pair by pair.
//!
//! Then a tabular learner that knows the whole model but may use a 2-item context's
//! continuation only after it has visited that context `k` times (before: the last item's),
//! playing `budget` env steps; printed: its return over the last 1,000 episodes, and the
//! share of those episodes' steps in contexts visited fewer than `k` times. No learner that
//! needs `k` visits per context can do better within the budget.
//!
//!   cargo run --release -p jsae-research --example context_value [SEED] [BUDGET]

use std::collections::HashMap;

use jsae_envs::recsys::{NgramModel, RecommenderEnv};
use jsae_envs::{ActionRef, Env};
use jsae_recommender::baseline::{Reference, returns};
use jsae_settings::{Algo, EnvName, TrainConfig};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The most likely next item per context, computed once per context.
struct Greedy<'a> {
    model: &'a NgramModel,
    best: HashMap<(u32, u32), u32>,
}

impl Greedy<'_> {
    fn best(&mut self, history: &[u32]) -> u32 {
        let n = history.len();
        let model = self.model;
        *self
            .best
            .entry((history[n - 2], history[n - 1]))
            .or_insert_with(|| Reference::MostLikely.best(model, history))
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let mut config = TrainConfig::defaults(EnvName::Recommender, Algo::Ppo);
    config.seed = args.next().map_or(Ok(1001), |s| s.parse())?;
    let budget: usize = args.next().map_or(Ok(2_000_000), |s| s.parse())?;
    let mut env = RecommenderEnv::new(&config.environment)?;
    let scorer = |mix: f64| {
        let mut scoring = config.environment.clone();
        scoring.recommender.mix = mix;
        RecommenderEnv::new(&scoring)
    };
    let (last_only, pair_only) = (scorer(1.0)?, scorer(0.0)?);
    let mixed = RecommenderEnv::new(&config.environment)?;
    let episodes = 2000;
    for (name, scoring) in [
        ("last item only (mix 1)", &last_only),
        ("two-item context only (mix 0)", &pair_only),
        ("as simulated (most-likely)", &mixed),
    ] {
        let mut greedy = Greedy {
            model: scoring.model(),
            best: HashMap::new(),
        };
        let r = returns(&mut env, episodes, config.eval_seed(), "", |env, _| {
            greedy.best(env.history())
        });
        println!(
            "greedy on the {name}: return {:.3} (std {:.3}, {episodes} episodes)",
            r.return_mean, r.return_std
        );
    }
    for k in [1, 5, 20, 50] {
        let mut fallback = Greedy {
            model: last_only.model(),
            best: HashMap::new(),
        };
        let mut known = Greedy {
            model: mixed.model(),
            best: HashMap::new(),
        };
        let mut visits: HashMap<(u32, u32), u32> = HashMap::new();
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let episodes = budget / 20;
        let (mut tail_return, mut tail_steps, mut tail_unknown) = (0.0, 0, 0);
        for episode in 0..episodes {
            env.reset(&mut rng);
            let tail = episode + 1000 >= episodes;
            loop {
                let h = env.history();
                let context = (h[h.len() - 2], h[h.len() - 1]);
                let seen = visits.entry(context).or_insert(0);
                *seen += 1;
                let action = if *seen > k {
                    known.best(h)
                } else {
                    fallback.best(h)
                };
                if tail {
                    tail_steps += 1;
                    tail_unknown += usize::from(*seen <= k);
                }
                let step = env.step(ActionRef::Discrete(action));
                if tail {
                    tail_return += step.reward;
                }
                if step.terminated || step.truncated {
                    break;
                }
            }
        }
        println!(
            "a learner needing {k} visits per 2-item context, after {budget} steps: return {:.3} \
             over the last 1,000 episodes, {:.1}% of their steps in contexts not yet known \
             ({} contexts visited)",
            tail_return / 1000.0,
            100.0 * tail_unknown as f64 / tail_steps.max(1) as f64,
            visits.len()
        );
    }
    Ok(())
}
