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
//! - The state is the last `history` known items of the request (items outside the
//!   catalogue are ignored and counted), padded with "none" as at the start of an episode.
//! - A learned policy needs only the catalogue (ids to actions, [`CatalogueHandle`]): the
//!   n-gram model is built only for a reference policy (7 GB at its peak at a million items,
//!   where the catalogue takes about 100 MB). An embedding snapshot that names another
//!   catalogue ([`CatalogueTag`]) is refused with the reason, which `Recommend` then gives.

use std::sync::{Arc, Mutex, RwLock};

use jsae_agent::{SwapError, Weights};
use jsae_envs::recsys::sessions::MAX_ID_BYTES;
use jsae_envs::recsys::staging::{StagedSessions, StagingArea};
use jsae_envs::recsys::store::{CommitOutcome, SessionStore};
use jsae_envs::recsys::{
    Catalogue, CatalogueHandle, ModelHandle, NgramModel, RecsysError, catalogue_handle,
    model_handle,
};
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_settings::{EnvName, TrainConfig};
use jsae_wire::{
    CatalogueTag, EmbeddingSnapshot, PolicySnapshot, RpcError, StateBatch, StateSpace,
};

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

/// What maps item ids to actions: the n-gram model (a reference policy reads it) or the
/// catalogue alone (a learned policy).
enum Items {
    Model(Arc<ModelHandle>),
    Catalogue(Arc<CatalogueHandle>),
}

/// The items in use now, as [`Items`] holds them.
enum Current {
    Model(Arc<NgramModel>),
    Catalogue(Arc<Catalogue>),
}

impl Current {
    fn catalogue(&self) -> &Catalogue {
        match self {
            Self::Model(m) => m.catalogue(),
            Self::Catalogue(c) => c,
        }
    }

    fn model(&self) -> Option<&NgramModel> {
        match self {
            Self::Model(m) => Some(m),
            Self::Catalogue(_) => None,
        }
    }
}

/// An embedding refused for its catalogue.
struct Refusal {
    version: u64,
    why: String,
    /// The items the snapshot's catalogue held where ours held fewer: once it holds as many
    /// (the store's sessions read since), the version may be tried again.
    items: Option<u64>,
}

/// The recommender's core, without the transport.
pub struct Recommender {
    config: TrainConfig,
    policy: PolicyChoice,
    items: Items,
    states: StateSpace,
    /// The last embedding version refused (None once a newer one is in use).
    refused: Mutex<Option<Refusal>>,
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
    /// A recommender serving `policy` for a `recommender` run's settings (the data and the
    /// session store are the settings' `environment.recommender`; the n-gram model is built
    /// only for a reference policy, a learned one needs the catalogue alone).
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
        let items = match policy.reference() {
            Some(_) => Items::Model(model_handle(r)?),
            None => Items::Catalogue(catalogue_handle(r)?),
        };
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
            items,
            states,
            refused: Mutex::new(None),
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

    /// The n-gram model in use now (None for a learned policy: it reads the catalogue alone).
    pub fn model(&self) -> Option<Arc<NgramModel>> {
        match &self.items {
            Items::Model(m) => Some(m.current()),
            Items::Catalogue(_) => None,
        }
    }

    fn current(&self) -> Current {
        match &self.items {
            Items::Model(m) => Current::Model(m.current()),
            Items::Catalogue(c) => Current::Catalogue(c.current()),
        }
    }

    /// Why `tag`'s catalogue is not the one served (None: it is). A catalogue that holds
    /// fewer items than the tag is read again first (the store may have sessions not read yet).
    fn catalogue_mismatch(&self, tag: &CatalogueTag) -> Option<String> {
        let check = |c: &Catalogue| {
            let ours = c.prefix_hash(tag.items as usize);
            tag.mismatch(c.capacity() as u64, c.len() as u64, ours)
        };
        let why = check(self.current().catalogue())?;
        if self.current().catalogue().len() < tag.items as usize {
            let refreshed = match &self.items {
                Items::Model(m) => m.refresh(),
                Items::Catalogue(c) => c.refresh(),
            };
            if refreshed.is_ok() {
                return check(self.current().catalogue());
            }
        }
        Some(why)
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

    /// The last embedding version refused for its catalogue, while it stays refused: a
    /// followed run directory does not read its file again. None once a newer one is in use,
    /// or once the catalogue holds as many items as the refused one did.
    pub fn refused_embedding(&self) -> Option<u64> {
        let refused = self.refused.lock().unwrap_or_else(|p| p.into_inner());
        let r = refused.as_ref()?;
        let held = self.current().catalogue().len() as u64;
        match r.items {
            Some(items) if held >= items => None,
            _ => Some(r.version),
        }
    }

    /// Swaps in a newer embedding snapshot (given up: its bytes are decoded without a copy).
    pub fn set_embedding(&self, snapshot: EmbeddingSnapshot) -> Result<(), String> {
        let current = self.weights();
        if snapshot.version <= current.embedding_version() {
            return Ok(());
        }
        if let (Some(tag), _) = CatalogueTag::split(&snapshot.bytes)
            && let Some(why) = self.catalogue_mismatch(&tag)
        {
            let why = format!("embedding version {} refused: {why}", snapshot.version);
            tracing::error!("recommender: {why}");
            let held = self.current().catalogue().len() as u64;
            *self.refused.lock().unwrap_or_else(|p| p.into_inner()) = Some(Refusal {
                version: snapshot.version,
                why: why.clone(),
                items: (held < tag.items).then_some(tag.items),
            });
            return Err(why);
        }
        // decoded once, outside the swap's retries: f's index is built here (minutes at a
        // million items), and a policy swapped in meanwhile must not start it again; while an
        // embedding is served, by one thread at the lowest priority, so the calls keep a core
        let version = snapshot.version;
        let decoded = if current.embedding().is_some() {
            at_low_priority(|| current.decode_owned_embedding(snapshot, 1))
        } else {
            current.decode_owned_embedding(snapshot, 0)
        }
        .map_err(|e| e.to_string())?;
        self.swap(|w| Ok(w.install_embedding(decoded.clone())))?;
        let mut refused = self.refused.lock().unwrap_or_else(|p| p.into_inner());
        if refused.as_ref().is_some_and(|r| r.version <= version) {
            *refused = None;
        }
        Ok(())
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
        let current = self.current();
        let catalogue = current.catalogue();
        let items = catalogue.len();
        if k == 0 || k as usize > items {
            return Err(bad(format!(
                "k must be in 1..={items} (the catalogue's size), got {k}"
            )));
        }
        let known: Vec<u32> = history.iter().filter_map(|h| catalogue.slot(h)).collect();
        let unknown_items = (history.len() - known.len()) as u32;
        let state = self.state_after(catalogue, &known);
        let ranking = self.ranking(catalogue, current.model(), &state, k as usize)?;
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
    pub fn state_after(&self, catalogue: &Catalogue, known: &[u32]) -> Vec<u32> {
        let n = self.config.environment.recommender.history as usize;
        let mut state = vec![catalogue.none(); n];
        let tail = &known[known.len().saturating_sub(n)..];
        state[n - tail.len()..].copy_from_slice(tail);
        state
    }

    /// The `k` best catalogue items of `model` in `state` (from [`Self::state_after`]) under
    /// the policy served.
    pub fn rank(&self, model: &NgramModel, state: &[u32], k: usize) -> Result<Ranking, RpcError> {
        self.ranking(model.catalogue(), Some(model), state, k)
    }

    /// [`Self::rank`] over `catalogue`; a reference policy reads `model`.
    fn ranking(
        &self,
        catalogue: &Catalogue,
        model: Option<&NgramModel>,
        state: &[u32],
        k: usize,
    ) -> Result<Ranking, RpcError> {
        let items = catalogue.len();
        if let Some(reference) = self.policy.reference() {
            let model = model.ok_or_else(|| {
                RpcError::Internal("a reference policy without the n-gram model".into())
            })?;
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
                let refused = self.refused.lock().unwrap_or_else(|p| p.into_inner());
                return Err(RpcError::Unavailable(match refused.as_ref() {
                    Some(r) => format!("no embedding: {}", r.why),
                    None => "no embedding yet: waiting for the embedder's first snapshot".into(),
                }));
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

/// The tag of `catalogue` as a recommender embedding's snapshot carries it.
pub fn catalogue_tag(catalogue: &Catalogue) -> CatalogueTag {
    CatalogueTag {
        items: catalogue.len() as u64,
        capacity: catalogue.capacity() as u64,
        prefix_hash: catalogue.prefix_hash(catalogue.len()).unwrap_or_default(),
    }
}

/// Runs `work` on a thread of the lowest CPU priority (nice 19; the threads it starts, such as
/// the index build's, inherit it) and waits for it.
fn at_low_priority<T: Send>(work: impl FnOnce() -> T + Send) -> T {
    // rayon's pool, if the work starts it, would keep the priority for good
    let _ = rayon::current_num_threads();
    std::thread::scope(|s| {
        s.spawn(|| {
            #[cfg(target_os = "linux")]
            if let Err(e) = rustix::process::setpriority_process(Some(rustix::thread::gettid()), 19)
            {
                tracing::debug!("recommender: no lower priority for the decode: {e}");
            }
            work()
        })
        .join()
        .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
    })
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
#[path = "scoring_tests.rs"]
mod tests;
