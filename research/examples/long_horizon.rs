//! The long-horizon recommender (`environment.recommender.leave_on_miss`, synthetic prices
//! unless a settings file says otherwise): how far the myopic greedy rule is from a policy
//! that plans. The greedy rule recommends the item with the highest expected reward now,
//! `q(a) v(a)` (`q`: the chance it is bought when recommended, `v`: its price). After a miss
//! the user leaves with probability `l(a) = min(1, L v(a))`, so to a policy whose later
//! purchases are worth `V` a recommendation is worth `q(a) v(a) - (1 - q(a)) l(a) V`. The
//! hand policy ranks by that with `V` from a grid; `V = 0` is the greedy rule. Also
//! printed: the most likely item (`q` alone), popular and item-kNN, all under
//! `recommender-baseline`'s protocol (2,000 episodes, the run's evaluation seed).
//!
//!   cargo run --release -p jsae-research --example long_horizon [SEED] [LEAVE] [EPISODE_LEN] [SETTINGS.toml]

use jsae_envs::recsys::RecommenderEnv;
use jsae_recommender::baseline::{Reference, returns};
use jsae_settings::{Algo, EnvName, Prices, TrainConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let arg = |i: usize| std::env::args().nth(i);
    let mut config = match arg(4) {
        Some(file) => {
            let mut c = TrainConfig::from_layers(None, None, Some(std::path::Path::new(&file)))?;
            c.env = EnvName::Recommender;
            c
        }
        None => {
            let mut c = TrainConfig::defaults(EnvName::Recommender, Algo::Ppo);
            c.environment.recommender.prices = Prices::Synthetic;
            c
        }
    };
    config.seed = arg(1).map_or(Ok(1001), |s| s.parse())?;
    let r = &mut config.environment.recommender;
    r.leave_on_miss = arg(2).map_or(Ok(0.1), |s| s.parse())?;
    r.episode_len = arg(3).map_or(Ok(r.episode_len), |s| s.parse())?;
    let leave = r.leave_on_miss;
    println!(
        "leave_on_miss {leave}, episode_len {}, prices {:?}, seed {}",
        r.episode_len, r.prices, config.seed
    );
    let mut env = RecommenderEnv::new(&config.environment)?;
    let model_env = RecommenderEnv::new(&config.environment)?;
    let model = model_env.model();
    let items = model.catalogue().len() as u32;
    let (episodes, seed) = (2000, config.eval_seed());
    for reference in Reference::ALL {
        let r = returns(&mut env, episodes, seed, "", |env, _| {
            reference.best(model, env.history())
        });
        println!("{:>24}: {:.3}", reference.name(), r.return_mean);
    }
    let bought_if_recommended = |h: &[u32], a: u32| {
        let (before, last) = (h[h.len() - 2], h[h.len() - 1]);
        model.probability_recommended(before, last, a, a)
    };
    let r = returns(&mut env, episodes, seed, "", |env, _| {
        let h = env.history();
        (0..items)
            .max_by(|&x, &y| {
                bought_if_recommended(h, x)
                    .total_cmp(&bought_if_recommended(h, y))
                    .then(y.cmp(&x))
            })
            .unwrap_or(0)
    });
    println!("{:>24}: {:.3}", "most likely (q alone)", r.return_mean);
    for later in [0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0] {
        let r = returns(&mut env, episodes, seed, "", |env, _| {
            let h = env.history();
            let worth = |a: u32| {
                let q = bought_if_recommended(h, a);
                q * model.value(a) - (1.0 - q) * env.leave_probability(a) * later
            };
            (0..items)
                .max_by(|&x, &y| worth(x).total_cmp(&worth(y)).then(y.cmp(&x)))
                .unwrap_or(0)
        });
        println!("{:>24}: {:.3}", format!("hand, V = {later}"), r.return_mean);
    }
    Ok(())
}
