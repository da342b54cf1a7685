//! Offline evaluation the way recommender systems are judged: on the held-out sessions of the
//! data (`environment.recommender.holdout`, split before the catalogue and the n-gram model
//! are built, so the simulator never saw them), every purchase after a session's first is a
//! query: the state is the last `history` purchases before it (items outside the catalogue
//! dropped, as `Recommend` does), and a policy's `k` best items either hold the item bought
//! or not.
//!
//! - hit rate@k: the share of queries whose item is among the `k`;
//! - NDCG@k: the mean of `1 / log2(rank + 1)` (rank 1 the best) where it is, else 0; with one
//!   relevant item the ideal DCG is 1;
//! - coverage@k: the share of the catalogue recommended to anyone (how much the policy's
//!   answer depends on the state).
//!
//! Purchases of items outside the catalogue are not queries (no policy can recommend them);
//! they are counted. Uniformly random recommendations are scored by their expectation.

use jsae_envs::recsys::{NgramModel, Session};
use serde::Serialize;

use crate::scoring::Recommender;

/// Hit rate, NDCG and MRR of one policy at `k` (JSON keys `hr_at_K`, `ndcg_at_K`, `mrr_at_K`,
/// `coverage_at_K` beside `policy`).
#[derive(Debug, Clone, PartialEq)]
pub struct RankingMetrics {
    /// `learned`, `most-likely`, `item-knn`, `popular` or `random`.
    pub policy: String,
    /// Items recommended per query.
    pub k: usize,
    /// Share of queries whose purchased item was among the `k` recommended.
    pub hit_rate: f64,
    /// Mean NDCG@k.
    pub ndcg: f64,
    /// Mean reciprocal rank@k: `1 / rank` of the purchased item where it is among the `k`,
    /// else 0.
    pub mrr: f64,
    /// Catalogue coverage@k: the share of catalogue items in at least one query's `k` (1 for
    /// random recommendations over enough queries; a policy that ignores the state: k/n).
    pub coverage: f64,
}

impl Serialize for RankingMetrics {
    fn serialize<S: serde::Serializer>(&self, out: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let k = self.k;
        let mut map = out.serialize_map(Some(5))?;
        map.serialize_entry("policy", &self.policy)?;
        map.serialize_entry(&format!("hr_at_{k}"), &self.hit_rate)?;
        map.serialize_entry(&format!("ndcg_at_{k}"), &self.ndcg)?;
        map.serialize_entry(&format!("mrr_at_{k}"), &self.mrr)?;
        map.serialize_entry(&format!("coverage_at_{k}"), &self.coverage)?;
        map.end()
    }
}

/// The queries of held-out sessions against one model.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Queries {
    /// Held-out sessions.
    pub sessions: usize,
    /// Queries (purchases after the first of a session, of catalogue items).
    pub queries: usize,
    /// Purchases after the first whose item is outside the catalogue (not queries).
    pub outside_catalogue: usize,
    /// Queries scored: all of them, or an even subset ([`Queries::thin_to`]).
    pub scored: usize,
    /// `(state, purchased slot)` of every query scored.
    #[serde(skip)]
    pub pairs: Vec<(Vec<u32>, u32)>,
}

impl Queries {
    /// Keeps at most `most` of the queries, evenly spread: every `ceil(queries / most)`-th
    /// from the first (the reference policies score every item per query, which at 100,000
    /// items and more takes hours over every held-out purchase).
    pub fn thin_to(&mut self, most: usize) {
        let stride = self.pairs.len().div_ceil(most.max(1)).max(1);
        if stride > 1 {
            self.pairs = std::mem::take(&mut self.pairs)
                .into_iter()
                .step_by(stride)
                .collect();
        }
        self.scored = self.pairs.len();
    }
}

/// The queries of `sessions` under `model`, states made as `rec` makes them.
pub fn queries(rec: &Recommender, model: &NgramModel, sessions: &[Session]) -> Queries {
    let catalogue = model.catalogue();
    let mut out = Queries {
        sessions: sessions.len(),
        queries: 0,
        outside_catalogue: 0,
        scored: 0,
        pairs: Vec::new(),
    };
    for s in sessions {
        let mut known = Vec::new();
        for (t, p) in s.purchases.iter().enumerate() {
            let slot = catalogue.slot(&p.item_id);
            if t > 0 {
                match slot {
                    Some(target) => out.pairs.push((rec.state_after(catalogue, &known), target)),
                    None => out.outside_catalogue += 1,
                }
            }
            known.extend(slot);
        }
    }
    out.queries = out.pairs.len();
    out.scored = out.queries;
    out
}

/// Hit rate@k, NDCG@k and MRR@k of the policy `rec` serves over `queries`.
pub fn score(
    rec: &Recommender,
    model: &NgramModel,
    queries: &Queries,
    k: usize,
    name: &str,
) -> Result<RankingMetrics, jsae_wire::RpcError> {
    let (mut hits, mut gain, mut reciprocal) = (0usize, 0.0, 0.0);
    let mut shown = vec![false; model.catalogue().len()];
    for (state, target) in &queries.pairs {
        let ranking = rec.rank(model, state, k)?;
        for (a, _) in &ranking.items {
            if let Some(s) = shown.get_mut(*a as usize) {
                *s = true;
            }
        }
        if let Some(i) = ranking.items.iter().position(|(a, _)| a == target) {
            hits += 1;
            gain += 1.0 / ((i + 2) as f64).log2();
            reciprocal += 1.0 / (i + 1) as f64;
        }
    }
    let n = queries.pairs.len().max(1) as f64;
    Ok(RankingMetrics {
        policy: name.to_owned(),
        k,
        hit_rate: hits as f64 / n,
        ndcg: gain / n,
        mrr: reciprocal / n,
        coverage: shown.iter().filter(|&&s| s).count() as f64 / shown.len().max(1) as f64,
    })
}

/// The expected hit rate@k, NDCG@k and MRR@k of `k` distinct items drawn uniformly from `items`.
pub fn random_expectation(items: usize, k: usize) -> RankingMetrics {
    let asked = k;
    let k = k.min(items);
    let per_rank = 1.0 / items.max(1) as f64;
    RankingMetrics {
        policy: "random".into(),
        k: asked,
        hit_rate: k as f64 * per_rank,
        ndcg: (0..k).map(|i| per_rank / ((i + 2) as f64).log2()).sum(),
        mrr: (0..k).map(|i| per_rank / (i + 1) as f64).sum(),
        coverage: 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::baseline::PolicyChoice;
    use jsae_envs::recsys::held_out_sessions;
    use jsae_settings::{Algo, EnvName, SessionSource, TrainConfig};

    #[test]
    fn reading_the_model_ranks_held_out_purchases_better_than_popularity_and_chance() {
        let mut config = TrainConfig::defaults(EnvName::Recommender, Algo::Ppo);
        let r = &mut config.environment.recommender;
        r.source = SessionSource::Synthetic;
        r.top_n = 60;
        r.holdout = 0.2;
        r.synthetic.items = 50;
        r.synthetic.sessions = 1000;
        let held = held_out_sessions(&config.environment.recommender).expect("sessions");
        let rec = |choice| Recommender::new(&config, choice, config.device).expect("builds");
        let (likely, popular) = (rec(PolicyChoice::MostLikely), rec(PolicyChoice::Popular));
        let knn = rec(PolicyChoice::ItemKnn);
        let model = likely.model().expect("a reference policy reads the model");
        let q = queries(&likely, &model, &held);
        assert!(q.queries > 1000, "{q:?}");
        assert_eq!(q.outside_catalogue, 0, "every item is in the catalogue");
        let a = score(&likely, &model, &q, 10, "most-likely").expect("ranks");
        let b = score(&popular, &model, &q, 10, "popular").expect("ranks");
        let c = random_expectation(model.catalogue().len(), 10);
        let d = score(&knn, &model, &q, 10, "item-knn").expect("ranks");
        assert!(
            d.hit_rate > b.hit_rate && d.coverage > b.coverage,
            "the history's neighbours beat the one popular list: {d:?} {b:?}"
        );
        assert!(
            a.hit_rate > b.hit_rate && b.hit_rate > c.hit_rate,
            "{a:?} {b:?} {c:?}"
        );
        for m in [&a, &b, &c] {
            assert!(
                m.ndcg > 0.0 && m.ndcg < m.hit_rate && m.hit_rate <= 1.0,
                "{m:?}"
            );
            // a hit at rank 1 counts 1 in both, lower ones less in MRR than in NDCG
            assert!(m.mrr > 0.0 && m.mrr <= m.ndcg, "{m:?}");
        }
        let items = model.catalogue().len() as f64;
        assert!(
            (b.coverage - 10.0 / items).abs() < 1e-12,
            "popular ignores the state"
        );
        assert!(a.coverage > b.coverage, "{a:?}");
        // the learned policy has no weights yet: UNAVAILABLE, not a made-up ranking
        let learned = rec(PolicyChoice::Learned);
        assert!(score(&learned, &model, &q, 10, "learned").is_err());
    }

    #[test]
    fn random_recommendations_hit_k_in_n() {
        let r = random_expectation(100, 10);
        assert!((r.hit_rate - 0.1).abs() < 1e-12);
        // every rank equally likely: the mean of the discounts over the first k ranks, times k/n
        let mean: f64 = (0..10).map(|i| 1.0 / ((i + 2) as f64).log2()).sum::<f64>() / 10.0;
        assert!((r.ndcg - 0.1 * mean).abs() < 1e-12);
        let harmonic: f64 = (1..=10).map(|i| 1.0 / f64::from(i)).sum();
        assert!((r.mrr - 0.01 * harmonic).abs() < 1e-12);
        assert_eq!(random_expectation(5, 10).hit_rate, 1.0);
        let json = serde_json::to_value(&r).expect("serialises");
        assert_eq!(json["policy"], "random");
        assert!(
            (json["hr_at_10"].as_f64().expect("hr") - 0.1).abs() < 1e-12,
            "{json}"
        );
        for key in ["ndcg_at_10", "mrr_at_10", "coverage_at_10"] {
            assert!(json[key].is_f64(), "{key}: {json}");
        }
    }
}
