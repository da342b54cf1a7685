//! The n-gram MDP of Shani et al.: the catalogue (the `top_n` most purchased items, one
//! action each), and purchase probabilities from 1-item and 2-item contexts, each smoothed
//! towards item popularity and mixed, with a boost on the recommended item. Everything is
//! sparse: counts of observed continuations per context, and one dense popularity table.

use std::collections::HashMap;

use jsae_env_spec::{RecommenderConfig, RewardOn};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

pub use super::catalogue::Catalogue;
use super::ngram_counts::{NgramCounts, pair};
use super::sessions::Session;

/// Counts of the items seen after one context, with a cumulative table for sampling.
#[derive(Debug, Clone, Default)]
struct Continuations {
    next: Vec<u32>,
    count: Vec<u32>,
    cum: Vec<u64>,
}

impl Continuations {
    fn from_map(map: &HashMap<u32, u32>) -> Self {
        let mut pairs: Vec<(u32, u32)> = map.iter().map(|(&k, &c)| (k, c)).collect();
        pairs.sort_unstable();
        let mut total = 0;
        let cum = pairs
            .iter()
            .map(|&(_, c)| {
                total += u64::from(c);
                total
            })
            .collect();
        Self {
            next: pairs.iter().map(|p| p.0).collect(),
            count: pairs.iter().map(|p| p.1).collect(),
            cum,
        }
    }

    fn total(&self) -> u64 {
        self.cum.last().copied().unwrap_or(0)
    }

    fn count_of(&self, item: u32) -> u64 {
        self.next
            .binary_search(&item)
            .map_or(0, |i| u64::from(self.count[i]))
    }

    fn sample(&self, rng: &mut ChaCha8Rng) -> u32 {
        let u = rng.random_range(0..self.total());
        self.next[self.cum.partition_point(|&c| c <= u)]
    }
}

/// The n-gram purchase model over a catalogue.
#[derive(Debug, Clone)]
pub struct NgramModel {
    catalogue: Catalogue,
    popularity: Continuations,
    start: Continuations,
    after_one: Vec<Continuations>,
    after_two: HashMap<u64, Continuations>,
    value: Vec<f64>,
    smoothing: f64,
    mix: f64,
    boost: f64,
    reward_on: RewardOn,
    sessions: usize,
}

impl NgramModel {
    /// Counts the purchases of `sessions` (restricted to catalogue items, in order) under
    /// the settings of `config`. Fails when no session buys a catalogue item.
    pub fn build<'a>(
        catalogue: Catalogue,
        sessions: impl Iterator<Item = &'a Session>,
        config: &RecommenderConfig,
    ) -> Option<Self> {
        let mut counts = NgramCounts::new(catalogue.capacity());
        for s in sessions {
            counts.add(&catalogue, s);
        }
        Self::from_counts(catalogue, &[&counts], config)
    }

    /// The model of the sum of `parts` (counts over `catalogue`'s slots, e.g. the data's and
    /// the session store's) under the settings of `config`. Fails when nothing was bought.
    pub fn from_counts(
        catalogue: Catalogue,
        parts: &[&NgramCounts],
        config: &RecommenderConfig,
    ) -> Option<Self> {
        let mut sum = NgramCounts::new(catalogue.capacity());
        for part in parts {
            sum.add_counts(part);
        }
        if sum.popularity.is_empty() {
            return None;
        }
        let value = sum
            .price_sum
            .iter()
            .zip(&sum.price_n)
            .map(|(&s, &c)| if c > 0 { s / f64::from(c) } else { 1.0 })
            .collect();
        Some(Self {
            catalogue,
            popularity: Continuations::from_map(&sum.popularity),
            start: Continuations::from_map(&sum.start),
            after_one: sum.after_one.iter().map(Continuations::from_map).collect(),
            after_two: sum
                .after_two
                .iter()
                .map(|(&k, m)| (k, Continuations::from_map(m)))
                .collect(),
            value,
            smoothing: config.smoothing,
            mix: config.mix,
            boost: config.boost,
            reward_on: config.reward_on,
            sessions: sum.sessions(),
        })
    }

    /// The catalogue.
    pub fn catalogue(&self) -> &Catalogue {
        &self.catalogue
    }

    /// Sessions that bought at least one catalogue item.
    pub fn sessions(&self) -> usize {
        self.sessions
    }

    /// Distinct 2-item contexts seen (the model's size).
    pub fn contexts(&self) -> usize {
        self.after_two.len()
    }

    /// The reward value of an item: its mean price, or 1 where no price is known.
    pub fn value(&self, item: u32) -> f64 {
        self.value.get(item as usize).copied().unwrap_or(0.0)
    }

    /// The item's share of all purchases (P(item) with no context).
    pub fn popularity(&self, item: u32) -> f64 {
        self.popularity.count_of(item) as f64 / self.popularity.total() as f64
    }

    fn after_one(&self, last: u32) -> Option<&Continuations> {
        self.after_one.get(last as usize)
    }

    fn after_two(&self, before: u32, last: u32) -> Option<&Continuations> {
        self.after_two.get(&pair(before, last))
    }

    /// Smoothed P(item | context): `(count + smoothing * popularity) / (total + smoothing)`.
    fn smoothed(&self, context: Option<&Continuations>, item: u32) -> f64 {
        let pop = self.popularity(item);
        let (count, total) = context.map_or((0, 0), |c| (c.count_of(item), c.total()));
        (count as f64 + self.smoothing * pop) / (total as f64 + self.smoothing)
    }

    fn sample_smoothed(&self, context: Option<&Continuations>, rng: &mut ChaCha8Rng) -> u32 {
        let total = context.map_or(0, Continuations::total) as f64;
        match context {
            Some(c) if rng.random::<f64>() * (total + self.smoothing) < total => c.sample(rng),
            _ => self.popularity.sample(rng),
        }
    }

    /// P(next = item | the last two purchases `before`, `last`), without a recommendation.
    pub fn probability(&self, before: u32, last: u32, item: u32) -> f64 {
        self.mix * self.smoothed(self.after_one(last), item)
            + (1.0 - self.mix) * self.smoothed(self.after_two(before, last), item)
    }

    /// P(next = item | before, last, the recommendation): the recommended item's
    /// probability multiplied by the boost, then renormalised.
    pub fn probability_recommended(&self, before: u32, last: u32, rec: u32, item: u32) -> f64 {
        let p_rec = self.probability(before, last, rec);
        let z = 1.0 + (self.boost - 1.0) * p_rec;
        let p = self.probability(before, last, item);
        if item == rec {
            self.boost * p / z
        } else {
            p / z
        }
    }

    /// Samples the next purchase after `before`, `last` when `rec` is recommended.
    pub fn sample_next(&self, before: u32, last: u32, rec: u32, rng: &mut ChaCha8Rng) -> u32 {
        let p_rec = self.probability(before, last, rec);
        let q = self.boost * p_rec / (1.0 + (self.boost - 1.0) * p_rec);
        if rng.random::<f64>() < q {
            return rec;
        }
        // the rest of the mass is the unboosted distribution without `rec`
        for _ in 0..10_000 {
            let item = if rng.random::<f64>() < self.mix {
                self.sample_smoothed(self.after_one(last), rng)
            } else {
                self.sample_smoothed(self.after_two(before, last), rng)
            };
            if item != rec {
                return item;
            }
        }
        rec
    }

    /// Samples a first purchase.
    pub fn sample_start(&self, rng: &mut ChaCha8Rng) -> u32 {
        self.start.sample(rng)
    }

    /// The reward of a step that recommended `rec` and saw `bought` purchased.
    pub fn reward(&self, rec: u32, bought: u32) -> f64 {
        match self.reward_on {
            RewardOn::Any => self.value(bought),
            RewardOn::Accepted if rec == bought => self.value(bought),
            RewardOn::Accepted => 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recsys::Purchase;
    use rand::SeedableRng;

    fn sessions(seqs: &[&[&str]]) -> Vec<Session> {
        seqs.iter()
            .enumerate()
            .map(|(i, items)| Session {
                session_id: format!("s{i}"),
                purchases: items
                    .iter()
                    .map(|&id| Purchase {
                        item_id: id.into(),
                        price: if id == "a" { 10.0 } else { 0.0 },
                        time_unix_ms: 0,
                    })
                    .collect(),
            })
            .collect()
    }

    #[test]
    fn the_catalogue_ranks_by_purchases_and_new_items_take_free_slots_only() {
        let s = sessions(&[&["a", "b", "a"], &["c", "a", "b"], &["d"]]);
        let mut c = Catalogue::most_purchased(s.iter(), 3);
        assert_eq!(
            (c.id(0), c.id(1), c.id(2)),
            (Some("a"), Some("b"), Some("c"))
        );
        assert_eq!((c.slot("d"), c.none()), (None, 3));
        assert_eq!(c.extend(sessions(&[&["e"]]).iter()), 0, "full");
        let mut c = Catalogue::most_purchased(s.iter(), 5);
        assert_eq!(c.len(), 4);
        assert_eq!(c.extend(sessions(&[&["a", "f", "g"]]).iter()), 1);
        assert_eq!(
            (c.slot("a"), c.slot("f"), c.slot("g")),
            (Some(0), Some(4), None)
        );
        let json = serde_json::to_string(&c).expect("serialises");
        let mut back: Catalogue = serde_json::from_str(&json).expect("parses");
        back.reindex();
        assert_eq!(back, c);
    }

    #[test]
    fn probabilities_sum_to_one_and_sampling_follows_them_with_the_boost() {
        let s = sessions(&[
            &["a", "b", "c", "a", "b", "d"],
            &["b", "c", "c"],
            &["a", "b", "c"],
            &["d", "a", "b"],
        ]);
        let config = RecommenderConfig {
            top_n: 5,
            boost: 4.0,
            ..RecommenderConfig::default()
        };
        let cat = Catalogue::most_purchased(s.iter(), 5);
        let model = NgramModel::build(cat, s.iter(), &config).expect("builds");
        let c = model.catalogue().clone();
        let (a, b) = (c.slot("a").expect("a"), c.slot("b").expect("b"));
        let items = c.len() as u32;
        for rec in 0..items {
            let total: f64 = (0..5)
                .map(|j| model.probability_recommended(a, b, rec, j))
                .sum();
            assert!((total - 1.0).abs() < 1e-12, "{total}");
        }
        assert_eq!(
            model.probability(a, b, 4),
            0.0,
            "a free slot is never bought"
        );
        let rec = c.slot("d").expect("d");
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let draws = 200_000;
        let mut seen = [0u32; 5];
        for _ in 0..draws {
            seen[model.sample_next(a, b, rec, &mut rng) as usize] += 1;
        }
        for j in 0..5 {
            let expected = model.probability_recommended(a, b, rec, j);
            let got = f64::from(seen[j as usize]) / f64::from(draws);
            assert!(
                (got - expected).abs() < 0.005,
                "item {j}: {got} vs {expected}"
            );
        }
        assert!(
            model.probability_recommended(a, b, rec, rec) > 2.0 * model.probability(a, b, rec),
            "the boost raises the recommended item"
        );
        // "a" has a price, the others are worth 1; only an accepted recommendation pays
        assert_eq!(
            (model.reward(a, a), model.reward(a, b), model.reward(b, b)),
            (10.0, 0.0, 1.0)
        );
    }
}
