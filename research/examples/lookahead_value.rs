//! How much the greedy rule leaves to planning: with the true model, the most likely next
//! item against a policy that looks one purchase further. It scores a recommendation by its
//! expected reward now plus the expected reward of the greedy rule after the purchase it
//! leads to (every item's probability under the boosted model, and the rule's value in each
//! resulting context, computed exactly and cached per context). Both are played under
//! `recommender-baseline`'s protocol. A small gap says the recommender is nearly a
//! contextual bandit: what a recommendation does to later states is worth little.
//! Then the same lookahead planned on the logs alone, as JSAE's `lookahead` targets plan it
//! (`jsae_embedder::LookaheadEstimate`: the logs' interpolated estimate, an assumed lift),
//! played under the same protocol at lifts 1 (greedy on the estimate), 2, 3 and 4: what the
//! head would return if it learnt those targets exactly.
//!
//!   cargo run --release -p jsae-research --example lookahead_value [SEED] [movielens100k]

use std::collections::HashMap;

use jsae_envs::recsys::{NgramModel, RecommenderEnv};
use jsae_recommender::baseline::{Reference, returns};
use jsae_settings::{Algo, EnvName, TrainConfig};

/// The greedy rule's expected reward in a context, cached.
struct OneStep<'a> {
    model: &'a NgramModel,
    boost: f64,
    value: HashMap<(u32, u32), f64>,
}

impl OneStep<'_> {
    fn get(&mut self, before: u32, last: u32) -> f64 {
        let (model, boost) = (self.model, self.boost);
        *self.value.entry((before, last)).or_insert_with(|| {
            let best = Reference::MostLikely.best(model, &[before, last]);
            let p = model.probability(before, last, best);
            boost * p / (1.0 + (boost - 1.0) * p) * model.value(best)
        })
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut config = TrainConfig::defaults(EnvName::Recommender, Algo::Ppo);
    config.seed = std::env::args().nth(1).map_or(Ok(1001), |s| s.parse())?;
    if std::env::args().nth(2).as_deref() == Some("movielens100k") {
        config.environment.recommender.source = jsae_settings::SessionSource::Movielens100k;
    }
    let mut env = RecommenderEnv::new(&config.environment)?;
    let model_env = RecommenderEnv::new(&config.environment)?;
    let model = model_env.model();
    let boost = config.environment.recommender.boost;
    let items = model.catalogue().len() as u32;
    let episodes = 2000;
    let rule = returns(&mut env, episodes, config.eval_seed(), "", |env, _| {
        Reference::MostLikely.best(model, env.history())
    });
    println!("most likely item: {:.3}", rule.return_mean);
    let mut v1 = OneStep {
        model,
        boost,
        value: HashMap::new(),
    };
    let r = returns(&mut env, episodes, config.eval_seed(), "", |env, _| {
        let h = env.history();
        let (a, b) = (h[h.len() - 2], h[h.len() - 1]);
        let p: Vec<f64> = (0..items).map(|j| model.probability(a, b, j)).collect();
        let next: Vec<f64> = (0..items).map(|j| v1.get(b, j)).collect();
        let mean: f64 = p.iter().zip(&next).map(|(p, v)| p * v).sum();
        (0..items)
            .max_by(|&x, &y| {
                let q = |k: u32| {
                    let pk = p[k as usize];
                    (boost * pk * (model.value(k) + next[k as usize]) + mean
                        - pk * next[k as usize])
                        / (1.0 + (boost - 1.0) * pk)
                };
                q(x).total_cmp(&q(y)).then(y.cmp(&x))
            })
            .unwrap_or(0)
    });
    println!(
        "two-step lookahead: {:.3} ({} contexts valued)",
        r.return_mean,
        v1.value.len()
    );
    let (states, bought) = env.logged_steps();
    let mut plan = jsae_embedder::LookaheadEstimate::count(&states, &bought, items as usize)
        .ok_or("the logs' states are not two items")?;
    for boost in [1.0, 2.0, 3.0, 4.0] {
        plan.set_boost(boost);
        let r = returns(&mut env, episodes, config.eval_seed(), "", |env, _| {
            plan.target(env.history())
        });
        println!(
            "lookahead on the logs' estimate, lift {boost}: {:.3}",
            r.return_mean
        );
    }
    Ok(())
}
