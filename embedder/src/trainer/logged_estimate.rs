//! The counted targets of the logged pre-training (`embedding.recommender.logged_targets =
//! "counted"`): the next-purchase estimate counted from the logs (PPO's count prior,
//! [`jsae_agent::prior::CountPrior`]) after each logged state, a distribution over the items
//! in place of the one item bought there. A two-item context seen once then leans on what
//! follows its last item, as the simulator's smoothed model does, where the item bought
//! would teach the head that one purchase alone. States one purchase ahead
//! (`logged_ahead_share`) carry the estimate into contexts the logs never hold.

use jsae_agent::prior::CountPrior;
use jsae_wire::StateBatch;
use rand::Rng;

use super::logged::LoggedItems;

/// The counted estimate over `n` items, keyed by a categorical state's factors.
#[derive(Debug)]
pub struct CountedEstimate {
    prior: CountPrior,
    /// Items (actions).
    n: usize,
    /// Values per factor (columns of the prior's keys per factor).
    width: usize,
    /// Factors per state.
    factors: usize,
}

impl CountedEstimate {
    /// Counts the logs (None for real states, or fewer than two factors).
    pub fn count(logged: &LoggedItems, n: usize) -> Option<Self> {
        let StateBatch::Categorical { factors, data } = &logged.states else {
            return None;
        };
        let factors = *factors;
        if factors < 2 {
            return None;
        }
        // every factor's values are items or "none" (`n`): n + 1 columns each
        let width = n + 1;
        let x_dim = factors * width;
        let rows: Vec<(Vec<u32>, u32)> = data
            .chunks_exact(factors)
            .zip(&logged.items)
            .map(|(row, &item)| (columns(row, width), item))
            .collect();
        let prior = CountPrior::count(x_dim, n, rows.iter().map(|(c, k)| (c.as_slice(), *k)));
        Some(Self {
            prior,
            n,
            width,
            factors,
        })
    }

    /// Appends the estimate after the state `row` (its factors) to `out`: `n` probabilities.
    pub(super) fn push_probs(&self, row: &[u32], out: &mut Vec<f32>) {
        let start = out.len();
        out.resize(start + self.n, 0.0);
        let logits = &mut out[start..];
        self.prior.add_to(&columns(row, self.width), logits);
        let top = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let mut sum = 0.0;
        for l in logits.iter_mut() {
            *l = (*l - top).exp();
            sum += *l;
        }
        for l in logits.iter_mut() {
            *l /= sum;
        }
    }

    /// The estimate's most likely item after the state `row` (its factors): the
    /// `counted-best` target there.
    pub fn best_item(&self, row: &[u32]) -> u32 {
        let mut probs = Vec::with_capacity(self.n);
        self.push_probs(row, &mut probs);
        self.best_items(&probs)[0]
    }

    /// The most likely item of each estimate in `probs` (`[states, n]`).
    pub(super) fn best_items(&self, probs: &[f32]) -> Vec<u32> {
        probs
            .chunks_exact(self.n)
            .map(|row| {
                let best = (0..self.n).max_by(|&i, &j| row[i].total_cmp(&row[j]));
                best.unwrap_or(0) as u32
            })
            .collect()
    }

    /// The state one purchase after `row`, the item drawn from `probs` (the estimate after
    /// `row`): the factors shifted by one, the drawn item last.
    pub(super) fn ahead(&self, row: &[u32], probs: &[f32], rng: &mut impl Rng) -> Vec<u32> {
        let u: f32 = rng.random();
        let mut acc = 0.0;
        let mut drawn = self.n - 1;
        for (i, &p) in probs.iter().enumerate() {
            acc += p;
            if u < acc {
                drawn = i;
                break;
            }
        }
        let mut next = row[1..self.factors].to_vec();
        next.push(drawn as u32);
        next
    }
}

/// A state's factors as the prior's columns: factor `f`'s value `v` is column `f * width + v`
/// (ascending, as the prior reads them: the last two are the item before the last and the
/// last item).
fn columns(row: &[u32], width: usize) -> Vec<u32> {
    row.iter()
        .enumerate()
        .map(|(f, &v)| (f * width) as u32 + v)
        .collect()
}

/// A minibatch of the counted pre-training: the logged states `rows` of `logged` and, for
/// `ahead` of them drawn at random, the state one purchase later; every state's estimate.
pub(super) struct CountedBatch {
    /// The states.
    pub states: StateBatch,
    /// Their estimates, `[states, n]` row-major.
    pub probs: Vec<f32>,
}

impl CountedEstimate {
    /// The minibatch of logged `rows` and `ahead` states one purchase after random ones of
    /// them.
    pub(super) fn batch(
        &self,
        logged: &LoggedItems,
        rows: &[usize],
        ahead: usize,
        rng: &mut impl Rng,
    ) -> CountedBatch {
        let StateBatch::Categorical { data, .. } = &logged.states else {
            unreachable!("counted only for categorical states")
        };
        let f = self.factors;
        let mut states = Vec::with_capacity((rows.len() + ahead) * f);
        let mut probs = Vec::with_capacity((rows.len() + ahead) * self.n);
        for &r in rows {
            let row = &data[r * f..(r + 1) * f];
            states.extend_from_slice(row);
            self.push_probs(row, &mut probs);
        }
        for _ in 0..ahead {
            let k = rng.random_range(0..rows.len());
            let row = states[k * f..(k + 1) * f].to_vec();
            let next = self.ahead(&row, &probs[k * self.n..(k + 1) * self.n], rng);
            states.extend_from_slice(&next);
            self.push_probs(&next, &mut probs);
        }
        CountedBatch {
            states: StateBatch::Categorical {
                factors: f,
                data: states,
            },
            probs,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// Four items; after (0, 1) item 2 was bought three times, after (3, 1) item 3 once.
    fn logs() -> LoggedItems {
        LoggedItems {
            states: StateBatch::Categorical {
                factors: 2,
                data: vec![0, 1, 0, 1, 0, 1, 3, 1],
            },
            items: vec![2, 2, 2, 3],
            catalogue: None,
        }
    }

    #[test]
    fn the_estimate_is_a_smoothed_distribution_over_the_items() {
        let e = CountedEstimate::count(&logs(), 4).expect("categorical");
        let mut p = Vec::new();
        e.push_probs(&[0, 1], &mut p);
        e.push_probs(&[3, 1], &mut p);
        e.push_probs(&[2, 1], &mut p); // a pair the logs never hold: the last item's
        for row in p.chunks_exact(4) {
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{row:?}");
            assert!(row.iter().all(|&q| q > 0.0), "{row:?}");
        }
        let best = |row: &[f32]| (0..4).max_by(|&i, &j| row[i].total_cmp(&row[j]));
        assert_eq!(best(&p[0..4]), Some(2));
        // seen once: (1 + last item's estimate) / 2 for item 3, the rest the last item's
        // estimate halved, which leans on item 2 (3 of the 4 purchases after item 1)
        assert!(p[4 + 3] > 0.5 && p[4 + 2] > 0.3, "{:?}", &p[4..8]);
        assert_eq!(best(&p[8..12]), Some(2), "{:?}", &p[8..12]);
        assert_eq!(e.best_items(&p), vec![2, 3, 2]);
    }

    #[test]
    fn states_ahead_shift_the_context_by_the_drawn_item() {
        let e = CountedEstimate::count(&logs(), 4).expect("categorical");
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let batch = e.batch(&logs(), &[0, 3], 200, &mut rng);
        let StateBatch::Categorical { data, .. } = &batch.states else {
            panic!("categorical")
        };
        assert_eq!(data.len(), 2 * 202);
        assert_eq!(batch.probs.len(), 4 * 202);
        assert_eq!(&data[..4], &[0, 1, 3, 1]);
        let ahead = &data[4..];
        assert!(ahead.chunks_exact(2).all(|s| s[0] == 1 && s[1] < 4));
        // mostly item 2 after item 1
        let twos = ahead.chunks_exact(2).filter(|s| s[1] == 2).count();
        assert!(twos > 80, "{twos} of 200");
    }
}
