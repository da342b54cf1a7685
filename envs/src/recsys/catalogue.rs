//! The recommender's catalogue: the items that are actions, each in a fixed slot.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::sessions::{Session, bytes_hash};

/// The items that are actions: slot `k` is action `k`; slot `capacity` stands for "none"
/// in a state (history shorter than the state). Slots past `len()` are free: new items take
/// them in the order they are first seen, and existing items never move.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Catalogue {
    capacity: usize,
    ids: Vec<String>,
    #[serde(skip)]
    index: HashMap<String, u32>,
}

impl Catalogue {
    /// The `capacity` most purchased items of `sessions` (ties: smaller id first).
    pub fn most_purchased<'a>(
        sessions: impl Iterator<Item = &'a Session>,
        capacity: usize,
    ) -> Self {
        let mut counts: HashMap<&str, u64> = HashMap::new();
        for s in sessions {
            for p in &s.purchases {
                *counts.entry(p.item_id.as_str()).or_insert(0) += 1;
            }
        }
        Self::top(counts, capacity)
    }

    /// The `capacity` items with the most purchases in `counts` (ties: smaller id first).
    pub fn top<S: AsRef<str>>(counts: impl IntoIterator<Item = (S, u64)>, capacity: usize) -> Self {
        let mut ranked: Vec<(S, u64)> = counts.into_iter().collect();
        ranked.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.as_ref().cmp(b.0.as_ref())));
        ranked.truncate(capacity);
        Self::from_ids(
            capacity,
            ranked
                .into_iter()
                .map(|(id, _)| id.as_ref().to_owned())
                .collect(),
        )
    }

    /// A catalogue holding `ids` in this order.
    pub fn from_ids(capacity: usize, ids: Vec<String>) -> Self {
        let mut c = Self {
            capacity,
            ids,
            index: HashMap::new(),
        };
        c.reindex();
        c
    }

    /// Rebuilds the id index (after deserialising).
    pub fn reindex(&mut self) {
        self.index = self
            .ids
            .iter()
            .enumerate()
            .map(|(i, id)| (id.clone(), i as u32))
            .collect();
    }

    /// Gives free slots to items of `sessions` not in the catalogue yet, in order of first
    /// appearance; returns how many were added.
    pub fn extend<'a>(&mut self, sessions: impl Iterator<Item = &'a Session>) -> usize {
        let before = self.ids.len();
        for s in sessions {
            for p in &s.purchases {
                if self.ids.len() >= self.capacity {
                    return self.ids.len() - before;
                }
                if !self.index.contains_key(&p.item_id) {
                    self.index.insert(p.item_id.clone(), self.ids.len() as u32);
                    self.ids.push(p.item_id.clone());
                }
            }
        }
        self.ids.len() - before
    }

    /// A hash of the capacity and the ids of slots `0..n` in slot order (None when fewer
    /// than `n` are held): two catalogues that agree on it map those items to the same
    /// actions. Stable across machines and versions ([`bytes_hash`]).
    pub fn prefix_hash(&self, n: usize) -> Option<u64> {
        let ids = self.ids.get(..n)?;
        let mut h = bytes_hash(&(self.capacity as u64).to_le_bytes());
        let mut buf = Vec::new();
        for id in ids {
            buf.clear();
            buf.extend_from_slice(&h.to_le_bytes());
            buf.extend_from_slice(id.as_bytes());
            h = bytes_hash(&buf);
        }
        Some(h)
    }

    /// Gives free slots to `ids` (new to the catalogue, distinct) in this order, as far as
    /// free slots go; returns how many were added.
    pub fn add(&mut self, ids: Vec<String>) -> usize {
        let before = self.ids.len();
        for id in ids {
            if self.ids.len() >= self.capacity {
                break;
            }
            if !self.index.contains_key(&id) {
                self.index.insert(id.clone(), self.ids.len() as u32);
                self.ids.push(id);
            }
        }
        self.ids.len() - before
    }

    /// Items held.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// Whether no item is held.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// Slots (actions), free ones included.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The state value standing for "no item".
    pub fn none(&self) -> u32 {
        self.capacity as u32
    }

    /// The slot of an item id.
    pub fn slot(&self, id: &str) -> Option<u32> {
        self.index.get(id).copied()
    }

    /// The item id of a slot (None for a free slot).
    pub fn id(&self, slot: u32) -> Option<&str> {
        self.ids.get(slot as usize).map(String::as_str)
    }
}
