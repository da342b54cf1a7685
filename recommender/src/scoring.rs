//! The Recommender's core, without the transport: the weights in use (swapped in whole as new
//! versions arrive), `recommend` (the state from a purchase history, then JSAE's nearest items
//! to the policy's mean action embedding or PPO's most likely items) and the session store's
//! writer (`SubmitSessions` stages and commits through it: `crate::submit`).
//!
//! - JSAE: `x = phi(state)`, the policy's mean action embedding `e`, then the `k` items whose
//!   `g` rows are nearest to `e` (score: minus the distance). PPO: the `k` most likely items
//!   of the policy's softmax (score: the probability).
//! - A reference policy (`--policy most-likely|item-knn|popular`) ranks by its score instead
//!   ([`crate::baseline::Reference`]); it needs no weights.
//! - The state is the last `history` known items of the request (items outside the model's
//!   catalogue are ignored and counted), padded with "none" as at the start of an episode.

use std::sync::{Arc, Mutex, RwLock};

use jsae_agent::{SwapError, Weights};
use jsae_envs::recsys::sessions::MAX_ID_BYTES;
use jsae_envs::recsys::staging::{StagedSessions, StagingArea};
use jsae_envs::recsys::store::{CommitOutcome, SessionStore};
use jsae_envs::recsys::{ModelHandle, NgramModel, RecsysError, model_handle};
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_settings::{EnvName, TrainConfig};
use jsae_wire::{EmbeddingSnapshot, PolicySnapshot, RpcError, StateBatch, StateSpace};

use crate::baseline::PolicyChoice;
use crate::ranking::best_k;

/// Longest `history` a Recommend request may carry.
pub const MAX_HISTORY: usize = 1000;
/// One recommendation.
#[derive(Debug, Clone, PartialEq)]
pub struct Recommendation {
    /// `(item id, score)`, best first.
    pub items: Vec<(String, f32)>,
    /// The policy version used.
    pub policy_version: u64,
    /// The embedding version used (0 for PPO).
    pub embedding_version: u64,
    /// History entries outside the catalogue.
    pub unknown_items: u32,
}

/// Items ranked for one state, with the versions of the weights that ranked them.
#[derive(Debug, Clone, PartialEq)]
pub struct Ranking {
    /// `(catalogue slot, score)`, best first.
    pub items: Vec<(u32, f32)>,
    /// The policy version used (0 for a reference policy).
    pub policy_version: u64,
    /// The embedding version used (0 for PPO and the reference policies).
    pub embedding_version: u64,
}

/// The recommender's core, without the transport.
pub struct Recommender {
    config: TrainConfig,
    policy: PolicyChoice,
    model: Arc<ModelHandle>,
    states: StateSpace,
    /// The weights in use, replaced whole (readers keep the `Arc` they took).
    weights: RwLock<Arc<Weights>>,
    /// The session store's writer, and where calls stage their sessions.
    store: Option<(Mutex<SessionStore>, StagingArea)>,
}

impl std::fmt::Debug for Recommender {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let w = self.weights();
        f.debug_struct("Recommender")
            .field("algo", &self.config.algo)
            .field("policy", &self.policy)
            .field("policy_version", &w.policy_version())
            .field("embedding_version", &w.embedding_version())
            .finish()
    }
}

impl Recommender {
    /// A recommender serving `policy` for a `recommender` run's settings (the n-gram model's
    /// data and session store are the settings' `environment.recommender`).
    pub fn new(
        config: &TrainConfig,
        policy: PolicyChoice,
        device: DeviceKind,
    ) -> Result<Self, RecsysError> {
        if config.env != EnvName::Recommender {
            return Err(RecsysError::Data(format!(
                "the settings are for --env {}, not recommender",
                config.env.as_str()
            )));
        }
        let r = &config.environment.recommender;
        let model = model_handle(r)?;
        let (states, actions) = EnvName::Recommender.spaces(&config.environment);
        let store = if r.store_dir.as_os_str().is_empty() {
            None
        } else {
            let store = SessionStore::open(&r.store_dir)?;
            let staging = store.staging();
            Some((Mutex::new(store), staging))
        };
        let weights = Weights::new(config, &states, &actions, &device.device());
        Ok(Self {
            config: config.clone(),
            policy,
            model,
            states,
            weights: RwLock::new(Arc::new(weights)),
            store,
        })
    }

    fn weights(&self) -> Arc<Weights> {
        self.weights
            .read()
            .map_or_else(|p| Arc::clone(p.get_ref()), |w| Arc::clone(&w))
    }

    /// Applies `swap` to a copy of the weights in use (decoding the snapshot with no lock
    /// held, so `Recommend` calls go on meanwhile) and puts the copy in their place when it
    /// changed them and nothing else was swapped in since.
    fn swap(&self, swap: impl Fn(&mut Weights) -> Result<bool, SwapError>) -> Result<(), String> {
        loop {
            let current = self.weights();
            let mut next = Weights::clone(&current);
            if !swap(&mut next).map_err(|e| e.to_string())? {
                return Ok(());
            }
            let mut slot = self.weights.write().unwrap_or_else(|p| p.into_inner());
            if Arc::ptr_eq(&slot, &current) {
                *slot = Arc::new(next);
                return Ok(());
            }
            // another swap won the race: apply this one to its result
        }
    }

    /// The settings served.
    pub fn config(&self) -> &TrainConfig {
        &self.config
    }

    /// The policy served.
    pub fn policy(&self) -> PolicyChoice {
        self.policy
    }

    /// The n-gram model in use now.
    pub fn model(&self) -> Arc<NgramModel> {
        self.model.current()
    }

    /// The policy version in use (None before the first).
    pub fn policy_version(&self) -> Option<u64> {
        self.weights().policy_version()
    }

    /// The embedding version in use (0: none).
    pub fn embedding_version(&self) -> u64 {
        self.weights().embedding_version()
    }

    /// Swaps in a policy snapshot (any other version than the one in use).
    pub fn set_policy(&self, snapshot: &PolicySnapshot) -> Result<(), String> {
        self.swap(|w| w.set_policy(snapshot))
    }

    /// Swaps in a newer embedding snapshot.
    pub fn set_embedding(&self, snapshot: &EmbeddingSnapshot) -> Result<(), String> {
        let current = self.weights();
        if snapshot.version <= current.embedding_version() {
            return Ok(());
        }
        // decoded once, outside the swap's retries: f's index is built here (minutes at a
        // million items), and a policy swapped in meanwhile must not start it again
        let decoded = current
            .decode_embedding(snapshot)
            .map_err(|e| e.to_string())?;
        self.swap(|w| Ok(w.install_embedding(decoded.clone())))
    }

    /// The `k` best items after `history` (item ids, oldest first).
    pub fn recommend(&self, history: &[String], k: u32) -> Result<Recommendation, RpcError> {
        let bad = RpcError::InvalidArgument;
        if history.is_empty() {
            return Err(bad("history is empty: give at least one item id".into()));
        }
        if history.len() > MAX_HISTORY {
            return Err(bad(format!(
                "history holds {} items, more than the limit of {MAX_HISTORY}",
                history.len()
            )));
        }
        if let Some(i) = history
            .iter()
            .position(|h| h.is_empty() || h.len() > MAX_ID_BYTES)
        {
            return Err(bad(format!(
                "history[{i}] is empty or longer than {MAX_ID_BYTES} bytes"
            )));
        }
        let model = self.model.current();
        let catalogue = model.catalogue();
        let items = catalogue.len();
        if k == 0 || k as usize > items {
            return Err(bad(format!(
                "k must be in 1..={items} (the catalogue's size), got {k}"
            )));
        }
        let known: Vec<u32> = history.iter().filter_map(|h| catalogue.slot(h)).collect();
        let unknown_items = (history.len() - known.len()) as u32;
        let state = self.state_after(&model, &known);
        let ranking = self.rank(&model, &state, k as usize)?;
        Ok(Recommendation {
            items: ranking
                .items
                .into_iter()
                .filter_map(|(slot, score)| catalogue.id(slot).map(|id| (id.to_owned(), score)))
                .collect(),
            policy_version: ranking.policy_version,
            embedding_version: ranking.embedding_version,
            unknown_items,
        })
    }

    /// The state after purchases of catalogue slots (oldest first): the last `history` of
    /// them, padded with "none" in front as at the start of an episode.
    pub fn state_after(&self, model: &NgramModel, known: &[u32]) -> Vec<u32> {
        let n = self.config.environment.recommender.history as usize;
        let mut state = vec![model.catalogue().none(); n];
        let tail = &known[known.len().saturating_sub(n)..];
        state[n - tail.len()..].copy_from_slice(tail);
        state
    }

    /// The `k` best catalogue items of `model` in `state` (from [`Self::state_after`]) under
    /// the policy served.
    pub fn rank(&self, model: &NgramModel, state: &[u32], k: usize) -> Result<Ranking, RpcError> {
        let items = model.catalogue().len();
        if let Some(reference) = self.policy.reference() {
            return Ok(Ranking {
                items: reference
                    .rank(model, state, k)
                    .into_iter()
                    .map(|(a, score)| (a, score as f32))
                    .collect(),
                policy_version: 0,
                embedding_version: 0,
            });
        }
        let weights = self.weights();
        let Some((policy_version, policy)) = weights.policy() else {
            return Err(RpcError::Unavailable(
                "no policy yet: waiting for the learner's first snapshot".into(),
            ));
        };
        let batch = StateBatch::Categorical {
            factors: state.len(),
            data: state.to_vec(),
        };
        let mut x = Vec::new();
        if self.config.algo.representation().decodes_actions() {
            let (Some(embedding), Some(nearest)) = (
                weights.embedding(),
                weights.embedding().and_then(|e| e.nearest()),
            ) else {
                return Err(RpcError::Unavailable(
                    "no embedding yet: waiting for the embedder's first snapshot".into(),
                ));
            };
            embedding.embed_states(&batch, &mut x);
            let e = policy.head_outputs(&x, weights.prior());
            // score: minus the Euclidean distance, nearest first
            let nearest = nearest.k_nearest(&e, k, items);
            Ok(Ranking {
                items: nearest.into_iter().map(|(a, d)| (a, -d)).collect(),
                policy_version,
                embedding_version: embedding.version(),
            })
        } else {
            batch.write_features(&self.states, &mut x);
            let logits = policy.head_outputs(&x, weights.prior());
            Ok(Ranking {
                items: most_likely(&logits, items, k),
                policy_version,
                embedding_version: 0,
            })
        }
    }

    /// A staging file for one SubmitSessions call (None without a store: nothing is kept).
    pub(crate) fn stage(&self) -> Result<Option<StagedSessions>, RpcError> {
        self.store
            .as_ref()
            .map(|(_, staging)| staging.stage())
            .transpose()
            .map_err(|e| RpcError::Internal(format!("session store: {e}")))
    }

    /// Commits a call's staged sessions to the store, all or none (this waits for the disk
    /// and for other calls' commits: call it off the async threads).
    pub(crate) fn commit(&self, staged: StagedSessions) -> Result<CommitOutcome, RpcError> {
        let Some((store, _)) = &self.store else {
            return Ok(CommitOutcome::default());
        };
        store
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .commit(staged)
            .map_err(|e| RpcError::Internal(format!("session store: {e}")))
    }

    /// Whether sessions are kept (a session store is configured).
    pub fn has_store(&self) -> bool {
        self.store.is_some()
    }
}

/// The `k` most likely of the first `items` actions under `logits`, as `(action, p)`.
fn most_likely(logits: &[f32], items: usize, k: usize) -> Vec<(u32, f32)> {
    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let z: f32 = logits.iter().map(|l| (l - max).exp()).sum();
    let mut all: Vec<(u32, f32)> = logits
        .iter()
        .take(items)
        .enumerate()
        .map(|(a, &l)| (a as u32, (l - max).exp() / z))
        .collect();
    best_k(&mut all, k, f32::total_cmp);
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn most_likely_is_the_softmax_of_the_filled_slots() {
        let got = most_likely(&[0.0, (2.0f32).ln(), 10.0], 2, 2);
        assert_eq!(got[0].0, 1);
        assert_eq!(got[1].0, 0);
        assert!((got[0].1 / got[1].1 - 2.0).abs() < 1e-5);
    }
}
