//! What the n-gram model is made of: counts of purchases over catalogue slots (item
//! popularity, first purchases, the item after each 1-item and 2-item context, price sums,
//! the items bought near each other for item-kNN).
//! Counts add up, so the model's owner keeps them per source (the data, the session store),
//! adds a session at a time as the store grows, and never holds the sessions themselves; the
//! store's counts are also what its checkpoint saves (`model_checkpoint`).

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::catalogue::Catalogue;
use super::sessions::Session;

/// The key of a 2-item context `(before, last)`.
pub(super) fn pair(a: u32, b: u32) -> u64 {
    (u64::from(a) << 32) | u64::from(b)
}

/// Purchase counts over the slots of a catalogue of `capacity` slots (slot `capacity` is
/// "none", the context before a session's first purchase).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NgramCounts {
    capacity: usize,
    /// Purchases of each item.
    pub(super) popularity: HashMap<u32, u32>,
    /// First (catalogue) purchases of sessions.
    pub(super) start: HashMap<u32, u32>,
    /// `[capacity]`: the items bought after each item.
    pub(super) after_one: Vec<HashMap<u32, u32>>,
    /// The items bought after each 2-item context ([`pair`]; "none" before a second item).
    pub(super) after_two: HashMap<u64, HashMap<u32, u32>>,
    /// `[capacity]`: the sum of the positive prices paid for each item.
    pub(super) price_sum: Vec<f64>,
    /// `[capacity]`: how many positive prices were paid for each item.
    pub(super) price_n: Vec<u32>,
    /// Sessions that bought at least one catalogue item.
    pub(super) sessions: usize,
    /// Co-visitation: for each item, the items bought within [`COVISIT_WINDOW`] purchases of
    /// it in the same session, either side (itself included where bought again), each
    /// pair of positions once. Required: a store checkpoint saved before it existed fails to
    /// read, so the store's whole log is read again and its co-visits counted.
    pub(super) covisit: HashMap<u32, HashMap<u32, u32>>,
}

/// How many purchases apart two purchases of a session may be and still count as visited
/// together (item-kNN's co-visitation).
pub const COVISIT_WINDOW: usize = 5;

fn bump(map: &mut HashMap<u32, u32>, key: u32, by: u32) {
    let c = map.entry(key).or_insert(0);
    *c = c.saturating_add(by);
}

fn bump_all(into: &mut HashMap<u32, u32>, from: &HashMap<u32, u32>) {
    for (&k, &c) in from {
        bump(into, k, c);
    }
}

impl NgramCounts {
    /// No purchases yet, over a catalogue of `capacity` slots.
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity,
            popularity: HashMap::new(),
            start: HashMap::new(),
            after_one: vec![HashMap::new(); capacity],
            after_two: HashMap::new(),
            price_sum: vec![0.0; capacity],
            price_n: vec![0; capacity],
            sessions: 0,
            covisit: HashMap::new(),
        }
    }

    /// Slots of the catalogue these counts are over.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Sessions that bought at least one catalogue item.
    pub fn sessions(&self) -> usize {
        self.sessions
    }

    /// Counts the purchases of `session` that are catalogue items, in order (the others are
    /// passed over, as if they were not there).
    pub fn add(&mut self, catalogue: &Catalogue, session: &Session) {
        debug_assert_eq!(catalogue.capacity(), self.capacity);
        let none = catalogue.none();
        let seq: Vec<u32> = session
            .purchases
            .iter()
            .filter_map(|p| {
                let k = catalogue.slot(&p.item_id)?;
                // a price no session may carry now (stored before the bound) is not counted
                if p.price > 0.0 && super::sessions::valid_price(p.price) {
                    self.price_sum[k as usize] += p.price;
                    self.price_n[k as usize] = self.price_n[k as usize].saturating_add(1);
                }
                Some(k)
            })
            .collect();
        let Some(&first) = seq.first() else { return };
        self.sessions += 1;
        bump(&mut self.start, first, 1);
        for (t, &item) in seq.iter().enumerate() {
            bump(&mut self.popularity, item, 1);
            if t >= 1 {
                let before = if t >= 2 { seq[t - 2] } else { none };
                bump(&mut self.after_one[seq[t - 1] as usize], item, 1);
                bump(
                    self.after_two.entry(pair(before, seq[t - 1])).or_default(),
                    item,
                    1,
                );
            }
            for &other in seq.iter().skip(t + 1).take(COVISIT_WINDOW) {
                bump(self.covisit.entry(item).or_default(), other, 1);
                if other != item {
                    bump(self.covisit.entry(other).or_default(), item, 1);
                }
            }
        }
    }

    /// Adds `other`'s counts (over a catalogue of the same capacity) to these.
    pub fn add_counts(&mut self, other: &NgramCounts) {
        debug_assert_eq!(other.capacity, self.capacity);
        bump_all(&mut self.popularity, &other.popularity);
        bump_all(&mut self.start, &other.start);
        for (into, from) in self.after_one.iter_mut().zip(&other.after_one) {
            bump_all(into, from);
        }
        for (&k, from) in &other.after_two {
            bump_all(self.after_two.entry(k).or_default(), from);
        }
        for (into, from) in self.price_sum.iter_mut().zip(&other.price_sum) {
            *into += from;
        }
        for (into, from) in self.price_n.iter_mut().zip(&other.price_n) {
            *into = into.saturating_add(*from);
        }
        self.sessions += other.sessions;
        for (&k, from) in &other.covisit {
            bump_all(self.covisit.entry(k).or_default(), from);
        }
    }

    /// Whether the counts have the shape of a catalogue of `capacity` slots (a checkpoint read
    /// back from disk is checked before use).
    pub fn fits(&self, capacity: usize) -> bool {
        self.capacity == capacity
            && self.after_one.len() == capacity
            && self.price_sum.len() == capacity
            && self.price_n.len() == capacity
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recsys::Purchase;

    fn session(id: &str, items: &[&str]) -> Session {
        Session {
            session_id: id.into(),
            purchases: items
                .iter()
                .map(|&item| Purchase {
                    item_id: item.into(),
                    price: 2.0,
                    time_unix_ms: 0,
                })
                .collect(),
        }
    }

    #[test]
    fn counts_of_two_parts_add_up_to_the_counts_of_the_whole() {
        let all = [
            session("a", &["x", "y", "z", "x"]),
            session("b", &["y", "outside", "x"]),
            session("c", &["outside"]),
        ];
        let catalogue = Catalogue::from_ids(4, vec!["x".into(), "y".into(), "z".into()]);
        let mut whole = NgramCounts::new(4);
        all.iter().for_each(|s| whole.add(&catalogue, s));
        let (mut first, mut second) = (NgramCounts::new(4), NgramCounts::new(4));
        first.add(&catalogue, &all[0]);
        all[1..].iter().for_each(|s| second.add(&catalogue, s));
        first.add_counts(&second);
        assert_eq!(first, whole);
        // "c" buys nothing in the catalogue; "outside" is passed over in "b"
        assert_eq!(whole.sessions(), 2);
        assert_eq!(whole.after_one[1].get(&0), Some(&1), "y then x in b");
        assert_eq!(
            whole.after_two.get(&pair(4, 1)).and_then(|m| m.get(&0)),
            Some(&1)
        );
        assert_eq!(whole.price_n, vec![3, 2, 1, 0]);
        // a: x y z x: x and y once apart, x and x three apart, both ways for a pair
        let covisit = |a: u32, b: u32| whole.covisit.get(&a).and_then(|m| m.get(&b)).copied();
        assert_eq!(covisit(0, 0), Some(1));
        assert_eq!(
            (covisit(0, 1), covisit(1, 0)),
            (Some(3), Some(3)),
            "x-y twice in a, once in b"
        );
        assert_eq!((covisit(2, 0), covisit(0, 2)), (Some(2), Some(2)));
        // counts written before co-visitation existed do not read (the store's log is read
        // again instead, co-visits and all)
        let mut old = serde_json::to_value(&whole).expect("serialises");
        let back: NgramCounts = serde_json::from_value(old.clone()).expect("reads");
        assert!(back.fits(4) && back.covisit == whole.covisit);
        old.as_object_mut().expect("a map").remove("covisit");
        assert!(serde_json::from_value::<NgramCounts>(old).is_err());
    }
}
