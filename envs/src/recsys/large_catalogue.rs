//! Seeded sessions over a large catalogue (10^4 to 10^6 items) with the structure of real
//! shop logs: item popularity falls off like Zipf's law, items belong to categories of
//! uneven size, a session stays mostly inside the one to three categories it came for, and
//! each item has a few items it is bought with (co-purchase partners, most of them in its
//! own category).
//!
//! Sessions are item indices (item 0 is the most popular), generated one at a time from the
//! seed and the session's index, so nothing holds them all: a million items and two million
//! sessions take the tables below (about 40 bytes an item) and one session at a time.

pub use jsae_env_spec::LargeCatalogueConfig;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, LogNormal};
use serde::Serialize;

use super::sessions::{Purchase, Session};

/// Where the next purchase comes from, by share (the rest: popular items of the whole shop).
const FROM_PARTNER_OF_LAST: f64 = 0.45;
const FROM_PARTNER_OF_BEFORE: f64 = 0.10;
const FROM_SESSION_CATEGORY: f64 = 0.30;
/// Co-purchase partners per item: the first `PARTNERS - 1` in its category.
const PARTNERS: usize = 3;
/// Longest generated session.
const MAX_LEN: usize = 500;
/// Spread of the log-normal session length.
const LEN_SIGMA: f64 = 0.8;

/// A generated catalogue: its categories and partners, and the sessions it generates.
#[derive(Debug, Clone)]
pub struct LargeCatalogue {
    config: LargeCatalogueConfig,
    /// Cumulative popularity of every item (item 0 first).
    popularity_cum: Vec<f64>,
    /// `[items]`: each item's category.
    category: Vec<u32>,
    /// `[categories + 1]`: where each category's items start in `members`.
    category_start: Vec<u32>,
    /// Items by category, each category's in item order.
    members: Vec<u32>,
    /// `[items]`: cumulative popularity within the item's category, aligned with `members`.
    members_cum: Vec<f64>,
    /// `[items]`: each item's co-purchase partners.
    partners: Vec<[u32; PARTNERS]>,
    length: LogNormal<f64>,
}

fn pick(cum: &[f64], rng: &mut ChaCha8Rng) -> usize {
    let total = cum.last().copied().unwrap_or(0.0);
    let u = rng.random::<f64>() * total;
    cum.partition_point(|&c| c <= u).min(cum.len() - 1)
}

impl LargeCatalogue {
    /// Builds the catalogue's tables (categories, partners) from the seed.
    pub fn new(config: &LargeCatalogueConfig) -> Result<Self, String> {
        config.check()?;
        let n = config.items as usize;
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let mut total = 0.0;
        let popularity: Vec<f64> = (0..n)
            .map(|i| 1.0 / (i as f64 + 1.0).powf(config.zipf))
            .collect();
        let popularity_cum: Vec<f64> = popularity
            .iter()
            .map(|w| {
                total += w;
                total
            })
            .collect();
        // categories of uneven size: category c is drawn with weight 1 / (c + 10)
        let categories = n.div_ceil(config.items_per_category as usize).max(1);
        let mut csum = 0.0;
        let category_cum: Vec<f64> = (0..categories)
            .map(|c| {
                csum += 1.0 / (c as f64 + 10.0);
                csum
            })
            .collect();
        let category: Vec<u32> = (0..n)
            .map(|_| pick(&category_cum, &mut rng) as u32)
            .collect();
        let mut category_start = vec![0u32; categories + 1];
        for &c in &category {
            category_start[c as usize + 1] += 1;
        }
        for c in 0..categories {
            category_start[c + 1] += category_start[c];
        }
        let mut fill = category_start.clone();
        let mut members = vec![0u32; n];
        for (item, &c) in category.iter().enumerate() {
            members[fill[c as usize] as usize] = item as u32;
            fill[c as usize] += 1;
        }
        let mut members_cum = vec![0.0; n];
        for c in 0..categories {
            let (a, b) = (category_start[c] as usize, category_start[c + 1] as usize);
            let mut acc = 0.0;
            for k in a..b {
                acc += popularity[members[k] as usize];
                members_cum[k] = acc;
            }
        }
        let mut catalogue = Self {
            config: config.clone(),
            popularity_cum,
            category,
            category_start,
            members,
            members_cum,
            partners: Vec::new(),
            length: LogNormal::new(0.0, LEN_SIGMA).map_err(|e| e.to_string())?,
        };
        // E[exp(mu + sigma z)] = exp(mu + sigma^2 / 2); lengths are 1 + that, rounded down
        let mu = (config.mean_len - 0.5).max(0.5).ln() - LEN_SIGMA * LEN_SIGMA / 2.0;
        catalogue.length = LogNormal::new(mu, LEN_SIGMA).map_err(|e| e.to_string())?;
        catalogue.partners = (0..n)
            .map(|item| {
                let mut p = [0u32; PARTNERS];
                for slot in p.iter_mut().take(PARTNERS - 1) {
                    *slot = catalogue.popular_in(catalogue.category[item], &mut rng);
                }
                p[PARTNERS - 1] = catalogue.popular(&mut rng);
                p
            })
            .collect();
        Ok(catalogue)
    }

    /// The settings it was made from.
    pub fn config(&self) -> &LargeCatalogueConfig {
        &self.config
    }

    /// Distinct items.
    pub fn items(&self) -> usize {
        self.category.len()
    }

    /// Categories.
    pub fn categories(&self) -> usize {
        self.category_start.len() - 1
    }

    /// The category of `item`.
    pub fn category(&self, item: u32) -> u32 {
        self.category[item as usize]
    }

    /// Sessions it generates.
    pub fn sessions(&self) -> u64 {
        self.config.sessions()
    }

    fn popular(&self, rng: &mut ChaCha8Rng) -> u32 {
        pick(&self.popularity_cum, rng) as u32
    }

    fn popular_in(&self, category: u32, rng: &mut ChaCha8Rng) -> u32 {
        let (a, b) = (
            self.category_start[category as usize] as usize,
            self.category_start[category as usize + 1] as usize,
        );
        if a == b {
            return self.popular(rng);
        }
        self.members[a + pick(&self.members_cum[a..b], rng)]
    }

    /// Session `index`'s items, oldest first: the same for the same seed and index on every
    /// machine, whatever else was generated before.
    pub fn session(&self, index: u64) -> Vec<u32> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.config.seed);
        rng.set_stream(index.wrapping_add(1));
        let len = (1 + self.length.sample(&mut rng) as usize).min(MAX_LEN);
        // the one to three categories the session came for, each that of a popular item
        let wanted =
            1 + usize::from(rng.random::<f64>() < 0.4) + usize::from(rng.random::<f64>() < 0.15);
        let interests: Vec<u32> = (0..wanted)
            .map(|_| self.category(self.popular(&mut rng)))
            .collect();
        let mut items = Vec::with_capacity(len);
        items.push(self.popular_in(interests[0], &mut rng));
        while items.len() < len {
            let last = items[items.len() - 1] as usize;
            let u = rng.random::<f64>();
            let next = if u < FROM_PARTNER_OF_LAST {
                self.partners[last][rng.random_range(0..PARTNERS)]
            } else if u < FROM_PARTNER_OF_LAST + FROM_PARTNER_OF_BEFORE && items.len() >= 2 {
                self.partners[items[items.len() - 2] as usize][0]
            } else if u < FROM_PARTNER_OF_LAST + FROM_PARTNER_OF_BEFORE + FROM_SESSION_CATEGORY {
                let c = interests[rng.random_range(0..interests.len())];
                self.popular_in(c, &mut rng)
            } else {
                self.popular(&mut rng)
            };
            items.push(next);
        }
        items
    }

    /// Session `index` as the sessions the recommender reads (`item-N` ids, no prices,
    /// a minute apart): for the catalogue sizes the string-keyed model holds.
    pub fn session_record(&self, index: u64) -> Session {
        Session {
            session_id: format!("catalogue-{index}"),
            purchases: self
                .session(index)
                .into_iter()
                .enumerate()
                .map(|(k, item)| Purchase {
                    item_id: format!("item-{item}"),
                    price: 0.0,
                    time_unix_ms: (index as i64) * 86_400_000 + k as i64 * 60_000,
                })
                .collect(),
        }
    }
}

/// OTTO's train split as published (items, sessions, events): the real shop data this
/// generator is compared with.
pub const OTTO_ITEMS: u64 = 1_855_603;
/// OTTO's train sessions.
pub const OTTO_SESSIONS: u64 = 12_899_779;
/// OTTO's train events (clicks, carts and orders).
pub const OTTO_EVENTS: u64 = 216_716_096;

/// What a generated catalogue's sessions look like, counted over all of them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CatalogueStats {
    /// Distinct items in the catalogue.
    pub items: u64,
    /// Categories.
    pub categories: u64,
    /// Sessions.
    pub sessions: u64,
    /// Purchases over all sessions.
    pub events: u64,
    /// Mean purchases per session.
    pub events_per_session: f64,
    /// Median purchases per session.
    pub median_session_len: u64,
    /// 90th percentile of purchases per session.
    pub p90_session_len: u64,
    /// Sessions per item.
    pub sessions_per_item: f64,
    /// Share of the items bought at least once.
    pub items_bought_share: f64,
    /// Share of purchases that go to the most popular 1% of items.
    pub top_1pct_share: f64,
    /// Share of consecutive purchases within one category.
    pub same_category_share: f64,
}

impl LargeCatalogue {
    /// Counts [`CatalogueStats`] over every session (a pass of the generator).
    pub fn stats(&self) -> CatalogueStats {
        let n = self.items();
        let mut bought = vec![0u32; n];
        let mut lengths = vec![0u64; MAX_LEN + 1];
        let (mut events, mut pairs, mut same) = (0u64, 0u64, 0u64);
        for s in 0..self.sessions() {
            let items = self.session(s);
            lengths[items.len()] += 1;
            events += items.len() as u64;
            for w in items.windows(2) {
                pairs += 1;
                same += u64::from(self.category(w[0]) == self.category(w[1]));
            }
            for i in items {
                bought[i as usize] = bought[i as usize].saturating_add(1);
            }
        }
        let sessions = self.sessions();
        let quantile = |q: f64| {
            let target = (q * sessions as f64).ceil() as u64;
            let mut acc = 0;
            lengths
                .iter()
                .position(|&c| {
                    acc += c;
                    acc >= target.max(1)
                })
                .unwrap_or(0) as u64
        };
        let mut sorted = bought.clone();
        sorted.sort_unstable_by(|a, b| b.cmp(a));
        let top: u64 = sorted[..n.div_ceil(100)]
            .iter()
            .map(|&c| u64::from(c))
            .sum();
        let ratio = |a: u64, b: u64| if b == 0 { 0.0 } else { a as f64 / b as f64 };
        CatalogueStats {
            items: n as u64,
            categories: self.categories() as u64,
            sessions,
            events,
            events_per_session: ratio(events, sessions),
            median_session_len: quantile(0.5),
            p90_session_len: quantile(0.9),
            sessions_per_item: ratio(sessions, n as u64),
            items_bought_share: ratio(bought.iter().filter(|&&c| c > 0).count() as u64, n as u64),
            top_1pct_share: ratio(top, events),
            same_category_share: ratio(same, pairs),
        }
    }
}

#[cfg(test)]
#[path = "large_catalogue_tests.rs"]
mod tests;
