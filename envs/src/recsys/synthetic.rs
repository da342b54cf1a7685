//! Seeded synthetic sessions with the shape of real ones and an n-gram structure a policy
//! can use: item popularity falls off like Zipf's law, each item has three likely
//! successors, and a session sometimes follows the item before last (2-gram structure).

use jsae_env_spec::SyntheticConfig;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::sessions::{Purchase, Session};

/// Generates `config.sessions` sessions over `config.items` items (`item-0`, ...), with
/// prices and increasing times.
pub fn generate(config: &SyntheticConfig) -> Vec<Session> {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let n = config.items as usize;
    // Zipf(1) popularity as a cumulative table
    let mut cum = Vec::with_capacity(n);
    let mut total = 0.0;
    for i in 0..n {
        total += 1.0 / (i as f64 + 1.0);
        cum.push(total);
    }
    let popular = |rng: &mut ChaCha8Rng| {
        let u = rng.random::<f64>() * total;
        cum.partition_point(|&c| c < u).min(n - 1)
    };
    let successors: Vec<[usize; 3]> = (0..n)
        .map(|_| [popular(&mut rng), popular(&mut rng), rng.random_range(0..n)])
        .collect();
    let prices: Vec<f64> = (0..n)
        .map(|_| (rng.random_range(100..20_000) as f64) / 100.0)
        .collect();
    let mut time = 1_569_888_000_000_i64;
    (0..config.sessions)
        .map(|s| {
            // lengths 1, 2, ... with mean `mean_len` (geometric)
            let stop = 1.0 / config.mean_len;
            let mut items = vec![popular(&mut rng)];
            while rng.random::<f64>() >= stop && items.len() < 200 {
                let last = items[items.len() - 1];
                let u = rng.random::<f64>();
                let next = if u < 0.6 {
                    successors[last][rng.random_range(0..3)]
                } else if u < 0.8 && items.len() >= 2 {
                    successors[items[items.len() - 2]][0]
                } else {
                    popular(&mut rng)
                };
                items.push(next);
            }
            Session {
                session_id: format!("synthetic-{s}"),
                purchases: items
                    .into_iter()
                    .map(|i| {
                        time += rng.random_range(1_000..600_000);
                        Purchase {
                            item_id: format!("item-{i}"),
                            price: prices[i],
                            time_unix_ms: time,
                        }
                    })
                    .collect(),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_generator_is_seeded_and_has_the_asked_shape() {
        let config = SyntheticConfig {
            items: 50,
            sessions: 400,
            mean_len: 5.0,
            seed: 3,
        };
        let a = generate(&config);
        assert_eq!(a, generate(&config), "same seed, same sessions");
        assert_ne!(
            a,
            generate(&SyntheticConfig {
                seed: 4,
                ..config.clone()
            })
        );
        assert_eq!(a.len(), 400);
        let purchases: usize = a.iter().map(|s| s.purchases.len()).sum();
        let mean = purchases as f64 / 400.0;
        assert!((3.5..6.5).contains(&mean), "mean length {mean}");
        for s in &a {
            super::super::sessions::check_session(s).expect("well formed");
        }
    }
}
