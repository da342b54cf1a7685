//! The n-gram MDP of Shani et al.: the catalogue (the `top_n` most purchased items, one
//! action each), and purchase probabilities from 1-item and 2-item contexts, each smoothed
//! towards item popularity and mixed, with a boost on the recommended item. Everything is
//! sparse: counts of observed continuations per context, and one dense popularity table.

use std::collections::HashMap;

use jsae_env_spec::{Prices, RecommenderConfig, RewardOn};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

pub use super::catalogue::Catalogue;
use super::ngram_counts::{NgramCounts, pair};
use super::sessions::{Session, bytes_hash};

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
    /// `[capacity]`: each slot's share of all purchases (`popularity` read densely: the
    /// greedy rule asks it of every item at every step).
    popularity_share: Vec<f64>,
    start: Continuations,
    after_one: Vec<Continuations>,
    after_two: HashMap<u64, Continuations>,
    value: Vec<f64>,
    smoothing: f64,
    mix: f64,
    boost: f64,
    floor: f64,
    reward_on: RewardOn,
    sessions: usize,
    covisit: HashMap<u32, Continuations>,
}

/// A price for an item the data has none for: log-normal with median 1 and sigma 0.75,
/// drawn from the hash of its id (the same on every machine and in every version).
fn synthetic_price(id: &str) -> f64 {
    let h = bytes_hash(id.as_bytes());
    // two uniforms in (0, 1) from the hash's halves, then Box-Muller
    let u1 = ((h >> 32) as f64 + 0.5) / 4_294_967_296.0;
    let u2 = ((h & 0xffff_ffff) as f64 + 0.5) / 4_294_967_296.0;
    let z = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
    (0.75 * z).exp()
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
        let total: u64 = sum.popularity.values().map(|&c| u64::from(c)).sum();
        let mut popularity_share = vec![0.0; catalogue.capacity()];
        for (&item, &c) in &sum.popularity {
            if let Some(x) = popularity_share.get_mut(item as usize) {
                *x = f64::from(c) / total as f64;
            }
        }
        let value = sum
            .price_sum
            .iter()
            .zip(&sum.price_n)
            .enumerate()
            .map(|(slot, (&s, &c))| match (c, config.prices) {
                (1.., _) => s / f64::from(c),
                (0, Prices::Synthetic) => catalogue.id(slot as u32).map_or(1.0, synthetic_price),
                (0, Prices::Data) => 1.0,
            })
            .collect();
        Some(Self {
            catalogue,
            popularity: Continuations::from_map(&sum.popularity),
            popularity_share,
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
            floor: config.recommend_floor,
            reward_on: config.reward_on,
            sessions: sum.sessions(),
            covisit: sum
                .covisit
                .iter()
                .map(|(&k, m)| (k, Continuations::from_map(m)))
                .collect(),
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
        self.popularity_share
            .get(item as usize)
            .copied()
            .unwrap_or(0.0)
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

    /// The recommended item's share of the mass before renormalising, and the normaliser:
    /// its probability `p` becomes `boost * p + floor`, so the mass is `1 + (boost - 1) p +
    /// floor`. A slot no item holds yet gets no floor: nothing there can be bought.
    fn boosted(&self, rec: u32, p_rec: f64) -> (f64, f64) {
        let floor = if (rec as usize) < self.catalogue.len() {
            self.floor
        } else {
            0.0
        };
        let raised = self.boost * p_rec + floor;
        (raised, 1.0 + (self.boost - 1.0) * p_rec + floor)
    }

    /// P(next = item | before, last, the recommendation): the recommended item's
    /// probability multiplied by the boost, the floor added, then renormalised.
    pub fn probability_recommended(&self, before: u32, last: u32, rec: u32, item: u32) -> f64 {
        let (raised, z) = self.boosted(rec, self.probability(before, last, rec));
        if item == rec {
            raised / z
        } else {
            self.probability(before, last, item) / z
        }
    }

    /// The expected reward of recommending each catalogue item (by slot) after `before`,
    /// `last`: what the myopic greedy policy maximises.
    pub fn expected_rewards(&self, before: u32, last: u32) -> Vec<f64> {
        let n = self.catalogue.len() as u32;
        let p: Vec<f64> = (0..n).map(|j| self.probability(before, last, j)).collect();
        // every purchase's value, before the recommendation moves the mass
        let all: f64 = match self.reward_on {
            RewardOn::Any => (0..n).map(|j| p[j as usize] * self.value(j)).sum(),
            RewardOn::Accepted => 0.0,
        };
        (0..n)
            .map(|a| {
                let (p_a, v_a) = (p[a as usize], self.value(a));
                let (raised, z) = self.boosted(a, p_a);
                match self.reward_on {
                    RewardOn::Accepted => raised * v_a / z,
                    RewardOn::Any => (all - p_a * v_a + raised * v_a) / z,
                }
            })
            .collect()
    }

    /// Item-kNN by co-visitation: each catalogue item's (by slot) summed co-visit rate
    /// `c(h, i) / n_h` with the items `h` of `state` (oldest first, "none" slots skipped),
    /// the last weighted 1, the one before 1/2, and so on; items bought within
    /// `COVISIT_WINDOW` purchases of each other in a session are the co-visits `c`, `n` the
    /// purchases. Popularity, a millionth of a rate, breaks ties. (The cosine
    /// `c(h, i) / sqrt(n_h n_i)` ranked the held-out purchases worse on both data sets:
    /// docs/src/recommender/data.md.)
    pub fn covisit_scores(&self, state: &[u32]) -> Vec<f64> {
        let n = self.catalogue.len();
        let top = (0..n as u32)
            .map(|i| self.popularity(i))
            .fold(0.0, f64::max)
            .max(f64::MIN_POSITIVE);
        let mut score: Vec<f64> = (0..n as u32)
            .map(|i| 1e-6 * self.popularity(i) / top)
            .collect();
        let purchases = |h: u32| self.popularity.count_of(h) as f64;
        for (back, &h) in state.iter().rev().enumerate() {
            let Some(near) = self.covisit.get(&h) else {
                continue;
            };
            let weight = 1.0 / (back + 1) as f64;
            for (&i, &c) in near.next.iter().zip(&near.count) {
                if let Some(s) = score.get_mut(i as usize) {
                    *s += weight * f64::from(c) / purchases(h).max(1.0);
                }
            }
        }
        score
    }

    /// Samples the next purchase after `before`, `last` when `rec` is recommended.
    pub fn sample_next(&self, before: u32, last: u32, rec: u32, rng: &mut ChaCha8Rng) -> u32 {
        let (raised, z) = self.boosted(rec, self.probability(before, last, rec));
        if rng.random::<f64>() < raised / z {
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

    /// Samples a catalogue item uniformly.
    pub fn sample_uniform(&self, rng: &mut ChaCha8Rng) -> u32 {
        rng.random_range(0..self.catalogue.len() as u32)
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

    #[test]
    fn the_floor_and_the_expected_rewards_follow_the_sampled_purchases() {
        let s = sessions(&[
            &["a", "b", "c", "a", "b", "d"],
            &["b", "c", "c"],
            &["a", "b", "c"],
            &["d", "a", "b"],
        ]);
        for reward_on in [RewardOn::Accepted, RewardOn::Any] {
            let config = RecommenderConfig {
                top_n: 4,
                boost: 2.0,
                recommend_floor: 0.05,
                reward_on,
                prices: Prices::Synthetic,
                ..RecommenderConfig::default()
            };
            let cat = Catalogue::most_purchased(s.iter(), 4);
            let model = NgramModel::build(cat, s.iter(), &config).expect("builds");
            let c = model.catalogue().clone();
            let (a, b) = (c.slot("a").expect("a"), c.slot("b").expect("b"));
            // "a" has its data price; the others a synthetic one, not 1
            assert_eq!(model.value(a), 10.0);
            assert!(model.value(b) > 0.0 && model.value(b) != 1.0);
            let expected = model.expected_rewards(a, b);
            let mut rng = ChaCha8Rng::seed_from_u64(9);
            for rec in 0..4 {
                let total: f64 = (0..4)
                    .map(|j| model.probability_recommended(a, b, rec, j))
                    .sum();
                assert!((total - 1.0).abs() < 1e-12, "{total}");
                // every recommendation is bought at least floor / (1 + boost - 1 + floor)
                assert!(model.probability_recommended(a, b, rec, rec) > 0.05 / 2.05);
                let draws = 100_000;
                let got: f64 = (0..draws)
                    .map(|_| model.reward(rec, model.sample_next(a, b, rec, &mut rng)))
                    .sum::<f64>()
                    / f64::from(draws);
                let want = expected[rec as usize];
                assert!(
                    (got - want).abs() < 0.02 * want.max(1.0),
                    "{reward_on:?} rec {rec}: {got} vs {want}"
                );
            }
            // a slot no item holds gets no floor: it is never bought
            let wide = RecommenderConfig {
                top_n: 6,
                ..config.clone()
            };
            let cat = Catalogue::most_purchased(s.iter(), 6);
            let model = NgramModel::build(cat, s.iter(), &wide).expect("builds");
            assert_eq!(model.catalogue().len(), 4);
            assert_eq!(model.probability_recommended(a, b, 5, 5), 0.0);
            assert!((0..1000).all(|_| model.sample_next(a, b, 5, &mut rng) != 5));
        }
    }

    #[test]
    fn item_knn_scores_the_items_bought_near_the_history() {
        let s = sessions(&[
            &["a", "b", "x"],
            &["a", "b"],
            &["c", "d"],
            &["c", "d"],
            &["d"],
        ]);
        let config = RecommenderConfig {
            top_n: 5,
            ..RecommenderConfig::default()
        };
        let cat = Catalogue::most_purchased(s.iter(), 5);
        let model = NgramModel::build(cat, s.iter(), &config).expect("builds");
        let c = model.catalogue().clone();
        let slot = |id| c.slot(id).expect("in the catalogue");
        let none = c.none();
        let best = |state: &[u32]| {
            let scores = model.covisit_scores(state);
            (0..scores.len())
                .max_by(|&i, &j| scores[i].total_cmp(&scores[j]))
                .map(|i| i as u32)
        };
        assert_eq!(best(&[none, slot("c")]), Some(slot("d")));
        assert_eq!(best(&[none, slot("a")]), Some(slot("b")));
        // the last item weighs more than the one before it
        assert_eq!(best(&[slot("a"), slot("c")]), Some(slot("d")));
        // nothing known: popularity decides ("d" is bought three times)
        assert_eq!(best(&[none, none]), Some(slot("d")));
    }
}
