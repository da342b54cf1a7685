//! The `lookahead` targets of the logged pre-training (`embedding.recommender.logged_targets =
//! "lookahead"`): after each state, the item whose recommendation is expected to sell most
//! over this purchase and the next, planned on a model of the logs. The model is the logs'
//! interpolated n-gram estimate (Jelinek-Mercer: the items bought after the state's last
//! item and after its last two, each smoothed by one pseudo-purchase towards the items'
//! popularity, mixed half and half), and a recommendation lifts its item's purchase
//! probability `p` to `boost p / (1 + (boost - 1) p)`. The lift is not in the logs: it is
//! measured on the random-play pre-training transitions (bought recommendations against the
//! estimate's expectation of them), unless `lookahead_boost` fixes it. A purchase of the
//! recommended item is worth 1 (the logs carry no prices). After the recommendation, the
//! next state is valued by the estimate's most likely item there, so the target is the
//! count-greedy item unless steering the next purchase towards a context with a surer
//! continuation is worth more: the planning the greedy rule leaves out.

use std::collections::HashMap;

use jsae_wire::StateBatch;

/// The weight of the one-item context's estimate (the two-item context's: the rest).
const MIX: f32 = 0.5;
/// Pseudo-purchases spread by popularity at each context.
const SMOOTHING: f32 = 1.0;
/// The largest lift [`LookaheadEstimate::measure_boost`] reports.
const MAX_BOOST: f64 = 100.0;
/// The most next-state values kept (a row of `n` per last item; 64 MiB): past it the rows
/// are dropped and computed again as needed.
const MAX_CACHED_VALUES: usize = 1 << 24;

/// The items bought after a context and how often, by item.
type Bought = [(u32, f32)];

/// The logs' interpolated estimate over `n` items and the targets planned on it (cached per
/// state).
#[derive(Debug)]
pub struct LookaheadEstimate {
    n: usize,
    /// Each item's share of the logged purchases.
    popularity: Vec<f32>,
    /// The most bought item.
    popular: u32,
    /// Per last item (`n + 1` values, "none" last): the items bought after it, by item.
    after_one: Vec<Vec<(u32, f32)>>,
    /// Per (item before the last, last item): the same.
    after_two: HashMap<(u32, u32), Vec<(u32, f32)>>,
    /// The lift a recommendation gives its item.
    boost: f32,
    /// Per last item, per next item: the chance that the estimate's most likely item after
    /// the two is bought when recommended (rows computed as needed).
    next_value: HashMap<u32, Vec<f32>>,
    targets: HashMap<(u32, u32), u32>,
}

impl LookaheadEstimate {
    /// Counts the logged `states` (categorical, two factors or more: the last two are read)
    /// and the `items` bought after them (None otherwise).
    pub fn count(states: &StateBatch, items: &[u32], n: usize) -> Option<Self> {
        let StateBatch::Categorical { factors, data } = states else {
            return None;
        };
        let f = *factors;
        if f < 2 || n == 0 {
            return None;
        }
        let mut all = vec![0.0f32; n];
        let mut one: Vec<HashMap<u32, f32>> = vec![HashMap::new(); n + 1];
        let mut two: HashMap<(u32, u32), HashMap<u32, f32>> = HashMap::new();
        for (row, &item) in data.chunks_exact(f).zip(items) {
            let (a, b) = (row[f - 2].min(n as u32), row[f - 1].min(n as u32));
            all[item as usize] += 1.0;
            *one[b as usize].entry(item).or_default() += 1.0;
            *two.entry((a, b)).or_default().entry(item).or_default() += 1.0;
        }
        let total: f32 = all.iter().sum::<f32>().max(1.0);
        let popular = (0..n).max_by(|&i, &j| all[i].total_cmp(&all[j]).then(j.cmp(&i)));
        let sorted = |m: HashMap<u32, f32>| {
            let mut v: Vec<(u32, f32)> = m.into_iter().collect();
            v.sort_unstable_by_key(|e| e.0);
            v
        };
        Some(Self {
            n,
            popularity: all.iter().map(|&c| c / total).collect(),
            popular: popular.unwrap_or(0) as u32,
            after_one: one.into_iter().map(sorted).collect(),
            after_two: two.into_iter().map(|(k, m)| (k, sorted(m))).collect(),
            boost: 1.0,
            next_value: HashMap::new(),
            targets: HashMap::new(),
        })
    }

    /// Sets the lift a recommendation gives its item (the cached targets are dropped).
    pub fn set_boost(&mut self, boost: f64) {
        self.boost = boost.max(1.0) as f32;
        self.next_value.clear();
        self.targets.clear();
    }

    /// The lift in use.
    pub fn boost(&self) -> f64 {
        f64::from(self.boost)
    }

    /// The estimate after (`before`, `last`) into `out` (`[n]`).
    pub fn probs(&self, before: u32, last: u32, out: &mut [f32]) {
        let (one, two) = self.contexts(before, last);
        let (t1, t2) = (mass(one), mass(two));
        let shared = popularity_weight(t1, t2);
        for (o, &p) in out.iter_mut().zip(&self.popularity) {
            *o = shared * p;
        }
        for &(k, c) in one {
            out[k as usize] += MIX * c / (t1 + SMOOTHING);
        }
        for &(k, c) in two {
            out[k as usize] += (1.0 - MIX) * c / (t2 + SMOOTHING);
        }
    }

    fn contexts(&self, before: u32, last: u32) -> (&Bought, &Bought) {
        let (a, b) = (before.min(self.n as u32), last.min(self.n as u32));
        let one = self.after_one[b as usize].as_slice();
        let two = self.after_two.get(&(a, b)).map_or(&[][..], Vec::as_slice);
        (one, two)
    }

    /// The estimate's largest probability after (`before`, `last`): only items bought there
    /// and the most popular item can hold it (any other item's is its popularity share
    /// scaled alike, the most popular's at least as large).
    fn best_probability(&self, before: u32, last: u32) -> f32 {
        let (one, two) = self.contexts(before, last);
        let (t1, t2) = (mass(one), mass(two));
        let shared = popularity_weight(t1, t2);
        let p = |k: u32| {
            shared * self.popularity[k as usize]
                + MIX * count_of(one, k) / (t1 + SMOOTHING)
                + (1.0 - MIX) * count_of(two, k) / (t2 + SMOOTHING)
        };
        one.iter()
            .chain(two)
            .map(|e| p(e.0))
            .fold(p(self.popular), f32::max)
    }

    /// The chance that an item of probability `p` is bought when recommended.
    fn bought(&self, p: f32) -> f32 {
        self.boost * p / (1.0 + (self.boost - 1.0) * p)
    }

    /// The item to teach after the state `row` (its factors; the last two are read):
    /// the recommendation with the most expected purchases of recommended items over this
    /// step and the next, the next one the estimate's most likely item.
    pub fn target(&mut self, row: &[u32]) -> u32 {
        let (a, b) = (row[row.len() - 2], row[row.len() - 1]);
        if let Some(&t) = self.targets.get(&(a, b)) {
            return t;
        }
        let n = self.n;
        let mut p = vec![0.0; n];
        self.probs(a, b, &mut p);
        let b_key = b.min(n as u32);
        if !self.next_value.contains_key(&b_key) {
            if (self.next_value.len() + 1) * n > MAX_CACHED_VALUES {
                self.next_value.clear();
            }
            let row = (0..n as u32)
                .map(|k| self.bought(self.best_probability(b, k)))
                .collect();
            self.next_value.insert(b_key, row);
        }
        let next = &self.next_value[&b_key];
        let mean: f32 = p.iter().zip(next).map(|(p, v)| p * v).sum();
        let boost = self.boost;
        let value = |k: usize| {
            let (pk, vk) = (p[k], next[k]);
            (boost * pk * (1.0 + vk) + mean - pk * vk) / (1.0 + (boost - 1.0) * pk)
        };
        let best = (0..n)
            .max_by(|&i, &j| value(i).total_cmp(&value(j)).then(j.cmp(&i)))
            .unwrap_or(0) as u32;
        self.targets.insert((a, b), best);
        best
    }

    /// The targets of every state of a categorical batch.
    pub fn targets_of(&mut self, states: &StateBatch) -> Vec<u32> {
        let StateBatch::Categorical { factors, data } = states else {
            unreachable!("lookahead targets only for categorical states")
        };
        data.chunks_exact(*factors)
            .map(|row| self.target(row))
            .collect()
    }

    /// The lift under which the estimate expects as many bought recommendations as the
    /// random-play `states` (categorical), `actions` and `bought` items (the next states'
    /// last) hold; None when none was bought.
    pub fn measure_boost(
        &self,
        states: &StateBatch,
        actions: &[u32],
        bought: &[u32],
    ) -> Option<f64> {
        let StateBatch::Categorical { factors, data } = states else {
            return None;
        };
        let f = *factors;
        let mut p = vec![0.0; self.n];
        let mut chances = Vec::with_capacity(actions.len());
        let mut hits = 0usize;
        for ((row, &a), &k) in data.chunks_exact(f).zip(actions).zip(bought) {
            if a as usize >= self.n {
                continue;
            }
            self.probs(row[f - 2], row[f - 1], &mut p);
            chances.push(f64::from(p[a as usize]));
            hits += usize::from(a == k);
        }
        if hits == 0 {
            return None;
        }
        let expected =
            |b: f64| -> f64 { chances.iter().map(|&p| b * p / (1.0 + (b - 1.0) * p)).sum() };
        if expected(1.0) >= hits as f64 {
            return Some(1.0);
        }
        if expected(MAX_BOOST) <= hits as f64 {
            return Some(MAX_BOOST);
        }
        // expected purchases rise with the lift: bisect
        let (mut lo, mut hi) = (1.0, MAX_BOOST);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if expected(mid) < hits as f64 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Some(0.5 * (lo + hi))
    }
}

/// The weight popularity gets in a context whose two levels saw `t1` and `t2` purchases.
fn popularity_weight(t1: f32, t2: f32) -> f32 {
    MIX * SMOOTHING / (t1 + SMOOTHING) + (1.0 - MIX) * SMOOTHING / (t2 + SMOOTHING)
}

fn mass(items: &Bought) -> f32 {
    items.iter().map(|e| e.1).sum()
}

fn count_of(items: &Bought, k: u32) -> f32 {
    items
        .binary_search_by_key(&k, |e| e.0)
        .map_or(0.0, |i| items[i].1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Four items. After item 1, item 2 is bought three times in four; after item 2 only
    /// ever item 3, after item 3 nothing was logged (popularity).
    fn logs() -> (StateBatch, Vec<u32>) {
        let data = vec![0, 1, 0, 1, 0, 1, 3, 1, 1, 2, 1, 2, 1, 2, 1, 2];
        let items = vec![2, 2, 2, 3, 3, 3, 3, 3];
        (StateBatch::Categorical { factors: 2, data }, items)
    }

    #[test]
    fn the_estimate_mixes_both_contexts_smoothed_towards_popularity() {
        let (s, i) = logs();
        let e = LookaheadEstimate::count(&s, &i, 4).expect("categorical");
        let mut p = vec![0.0; 4];
        e.probs(0, 1, &mut p);
        assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{p:?}");
        // after item 1: 3 of 4 item 2 (+ 3/8 popularity share / 5); after (0, 1): 3 of 3
        let pop2 = 3.0 / 8.0;
        let want = 0.5 * (3.0 + pop2) / 5.0 + 0.5 * (3.0 + pop2) / 4.0;
        assert!((p[2] - want).abs() < 1e-5, "{} against {want}", p[2]);
        e.probs(3, 3, &mut p); // nothing logged: popularity
        assert!((p[3] - 5.0 / 8.0).abs() < 1e-5, "{p:?}");
        assert!((e.best_probability(3, 3) - 5.0 / 8.0).abs() < 1e-5);
        e.probs(2, 1, &mut p);
        assert!((e.best_probability(2, 1) - p[2]).abs() < 1e-6, "{p:?}");
    }

    /// Random logs over `n` items: purchases that follow the last item loosely.
    fn random_logs(n: u32, steps: usize) -> (StateBatch, Vec<u32>) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (mut data, mut items) = (Vec::new(), Vec::new());
        let (mut a, mut b) = (n, rng.random_range(0..n));
        for _ in 0..steps {
            let k = if rng.random::<f32>() < 0.6 {
                (b * 7 + rng.random_range(0..3)) % n
            } else {
                rng.random_range(0..n)
            };
            data.extend_from_slice(&[a, b]);
            items.push(k);
            (a, b) = (b, k);
        }
        (StateBatch::Categorical { factors: 2, data }, items)
    }

    /// The expected purchases of recommended items over two steps, enumerated: the next
    /// purchase `j` with its lifted chance, then the most likely item after (b, j).
    fn enumerated(e: &LookaheadEstimate, a: u32, b: u32, k: usize) -> f32 {
        let n = e.n;
        let (mut p, mut q) = (vec![0.0; n], vec![0.0; n]);
        e.probs(a, b, &mut p);
        let z = 1.0 + (e.boost - 1.0) * p[k];
        let mut value = e.boost * p[k] / z;
        for (j, &pj) in p.iter().enumerate() {
            let chance = if j == k { e.boost * pj } else { pj } / z;
            e.probs(b, j as u32, &mut q);
            let best = q.iter().copied().fold(0.0, f32::max);
            value += chance * e.bought(best);
        }
        value
    }

    #[test]
    fn the_target_is_the_best_recommendation_over_two_purchases() {
        let (s, i) = random_logs(12, 400);
        let mut e = LookaheadEstimate::count(&s, &i, 12).expect("categorical");
        e.set_boost(3.0);
        let mut differs = 0;
        let mut p = vec![0.0; 12];
        for (a, b) in (0..13).flat_map(|a| (0..12).map(move |b| (a, b))) {
            let t = e.target(&[a, b]) as usize;
            let values: Vec<f32> = (0..12).map(|k| enumerated(&e, a, b, k)).collect();
            let top = values.iter().copied().fold(f32::MIN, f32::max);
            assert!(values[t] >= top - 1e-5, "({a}, {b}): {t} in {values:?}");
            e.probs(a, b, &mut p);
            let greedy = (0..12).max_by(|&x, &y| p[x].total_cmp(&p[y]).then(y.cmp(&x)));
            differs += usize::from(greedy != Some(t));
        }
        assert!(differs > 0, "planning never changed the greedy item");
        // without a lift a recommendation changes nothing after it: the most likely item
        e.set_boost(1.0);
        for (a, b) in [(12, 3), (4, 5), (0, 1)] {
            e.probs(a, b, &mut p);
            let greedy = (0..12).max_by(|&x, &y| p[x].total_cmp(&p[y]).then(y.cmp(&x)));
            assert_eq!(Some(e.target(&[a, b]) as usize), greedy);
        }
        assert_eq!(e.targets_of(&s).len(), 400);
    }

    #[test]
    fn the_lift_is_measured_from_bought_recommendations() {
        let (s, i) = logs();
        let e = LookaheadEstimate::count(&s, &i, 4).expect("categorical");
        let mut p = vec![0.0; 4];
        e.probs(0, 1, &mut p);
        // 1,000 recommendations of item 2 after (0, 1), bought as a lift of 2 says
        let b = 2.0 * f64::from(p[2]) / (1.0 + f64::from(p[2]));
        let hits = (1000.0 * b).round() as usize;
        let states = StateBatch::Categorical {
            factors: 2,
            data: [0, 1].repeat(1000),
        };
        let actions = vec![2; 1000];
        let bought: Vec<u32> = (0..1000).map(|t| if t < hits { 2 } else { 0 }).collect();
        let measured = e.measure_boost(&states, &actions, &bought).expect("bought");
        assert!((measured - 2.0).abs() < 0.02, "{measured}");
        assert_eq!(e.measure_boost(&states, &actions, &[0; 1000]), None);
    }
}
