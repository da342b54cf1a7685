//! Loading the sessions a run's settings name, and the shared, refreshed n-gram model: one
//! per process and settings (the environments of an actor share it), rebuilt from the data
//! and the session store every `refresh_seconds` when a store is set.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock, RwLock, Weak};
use std::time::Duration;

use jsae_proto::StateBatch;
use jsae_proto::settings::{RecommenderConfig, SessionSource};

use super::ngram::{Catalogue, NgramModel};
use super::sessions::{Session, id_hash};
use super::{RecsysError, instacart, rees46, store, synthetic};

/// The data file the settings name (the fetched Instacart sample by default).
pub fn data_path(config: &RecommenderConfig) -> PathBuf {
    if config.path.as_os_str().is_empty() && config.source == SessionSource::Instacart {
        instacart::default_path()
    } else {
        config.path.clone()
    }
}

/// Reads the sessions of the configured source (without the store).
pub fn load_sessions(config: &RecommenderConfig) -> Result<Vec<Session>, RecsysError> {
    let path = data_path(config);
    match config.source {
        SessionSource::Synthetic => Ok(synthetic::generate(&config.synthetic)),
        SessionSource::Instacart if !path.exists() => Err(RecsysError::Data(format!(
            "the Instacart sample is not at {}: run scripts/setup-data.sh (cargo build does), \
             or set environment.recommender.path",
            path.display()
        ))),
        SessionSource::Instacart => instacart::read(&path),
        SessionSource::Rees46 => {
            let (sessions, stats) = rees46::read(&path, config.group_by)?;
            tracing::info!(
                "{}: {} rows, {} purchases in {} sessions ({} duplicates, {} malformed skipped)",
                path.display(),
                stats.rows,
                stats.purchases,
                sessions.len(),
                stats.duplicates,
                stats.malformed
            );
            Ok(sessions)
        }
    }
}

/// Whether a session of the data is held out for offline evaluation: the [`id_hash`] of its
/// id, as a share of the hash range, below `share`. The same ids give the same split on
/// every machine and whatever the order of the file.
pub fn is_held_out(session_id: &str, share: f64) -> bool {
    (id_hash(session_id) as f64) < share * (u64::MAX as f64)
}

/// The data's sessions split into (training, held out) by [`is_held_out`] with the settings'
/// `holdout`.
pub fn split_sessions(
    sessions: Vec<Session>,
    config: &RecommenderConfig,
) -> (Vec<Session>, Vec<Session>) {
    sessions
        .into_iter()
        .partition(|s| !is_held_out(&s.session_id, config.holdout))
}

/// The held-out sessions of the settings' data (none when `holdout` is 0).
pub fn held_out_sessions(config: &RecommenderConfig) -> Result<Vec<Session>, RecsysError> {
    Ok(split_sessions(load_sessions(config)?, config).1)
}

struct Refresh {
    catalogue: Catalogue,
    stored: Vec<Session>,
    offset: u64,
}

/// The current n-gram model of one set of settings, and what rebuilds it.
pub struct ModelHandle {
    config: RecommenderConfig,
    base: Vec<Session>,
    refresh: Mutex<Refresh>,
    current: RwLock<Arc<NgramModel>>,
}

impl std::fmt::Debug for ModelHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ModelHandle")
            .field("base_sessions", &self.base.len())
            .field("items", &self.current().catalogue().len())
            .finish()
    }
}

fn store_dir(config: &RecommenderConfig) -> Option<&Path> {
    (!config.store_dir.as_os_str().is_empty()).then_some(config.store_dir.as_path())
}

/// The catalogue of a store: made once from the data and the store's sessions, then kept
/// in `STORE/catalogue.json` so every process that shares the store maps items to the same
/// actions (whoever comes first writes it; the write is atomic and never replaces one).
fn pinned_catalogue(
    dir: &Path,
    capacity: usize,
    make: impl FnOnce() -> Catalogue,
) -> Result<Catalogue, RecsysError> {
    let path = dir.join("catalogue.json");
    let io = |path: &Path| {
        let path = path.to_owned();
        move |source| RecsysError::Io { path, source }
    };
    if !path.exists() {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let tmp = dir.join(format!("catalogue.json.{}.tmp", std::process::id()));
        let json = serde_json::to_vec(&make()).map_err(|e| RecsysError::Data(e.to_string()))?;
        std::fs::write(&tmp, json).map_err(io(&tmp))?;
        let linked = std::fs::hard_link(&tmp, &path);
        let _ = std::fs::remove_file(&tmp);
        match linked {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(io(&path)(e)),
        }
    }
    let text = std::fs::read(&path).map_err(io(&path))?;
    let mut catalogue: Catalogue =
        serde_json::from_slice(&text).map_err(|e| RecsysError::Parse {
            path: path.clone(),
            line: 1,
            reason: e.to_string(),
        })?;
    catalogue.reindex();
    if catalogue.capacity() != capacity {
        return Err(RecsysError::Data(format!(
            "{} was made for top_n = {}, the settings say {capacity}: use another store_dir",
            path.display(),
            catalogue.capacity()
        )));
    }
    Ok(catalogue)
}

impl ModelHandle {
    /// Reads the data (without its held-out sessions) and the store, makes the catalogue and
    /// builds the model.
    pub fn load(config: &RecommenderConfig) -> Result<Self, RecsysError> {
        let (base, held_out) = split_sessions(load_sessions(config)?, config);
        let capacity = config.top_n as usize;
        let (stored, offset) = match store_dir(config) {
            Some(dir) => store::read_since(dir, 0)?,
            None => (Vec::new(), 0),
        };
        let rank = || Catalogue::most_purchased(base.iter().chain(&stored), capacity);
        let mut catalogue = match store_dir(config) {
            Some(dir) => pinned_catalogue(dir, capacity, rank)?,
            None => rank(),
        };
        catalogue.extend(stored.iter());
        if catalogue.len() < capacity {
            tracing::warn!(
                "recommender: the data has {} distinct items, fewer than top_n = {capacity}; \
                 the other actions are free slots for items submitted later",
                catalogue.len()
            );
        }
        let model = NgramModel::build(catalogue.clone(), base.iter().chain(&stored), config)
            .ok_or_else(|| RecsysError::Data("no session buys anything".into()))?;
        tracing::info!(
            "recommender: {} sessions ({} more held out), {} items, {} two-item contexts",
            model.sessions(),
            held_out.len(),
            model.catalogue().len(),
            model.contexts()
        );
        Ok(Self {
            config: config.clone(),
            base,
            refresh: Mutex::new(Refresh {
                catalogue,
                stored,
                offset,
            }),
            current: RwLock::new(Arc::new(model)),
        })
    }

    /// The model to use now.
    pub fn current(&self) -> Arc<NgramModel> {
        self.current
            .read()
            .map_or_else(|p| Arc::clone(p.get_ref()), |m| Arc::clone(&m))
    }

    /// The purchases the model is built from (the data without its held-out sessions, and
    /// the store's), as the environment's steps: for every catalogue purchase after a
    /// session's first, the state before it (the session's last `history` catalogue
    /// purchases, "none" where there are fewer, as an episode starts) and the item bought.
    /// Purchases outside the catalogue are passed over, as the model passes over them.
    pub fn logged_steps(&self, history: usize) -> (StateBatch, Vec<u32>) {
        let model = self.current();
        let catalogue = model.catalogue();
        let r = self.refresh.lock().unwrap_or_else(|p| p.into_inner());
        let (mut states, mut next) = (Vec::new(), Vec::new());
        let mut window = vec![catalogue.none(); history.max(1)];
        for s in self.base.iter().chain(&r.stored) {
            window.fill(catalogue.none());
            let mut first = true;
            for k in s
                .purchases
                .iter()
                .filter_map(|p| catalogue.slot(&p.item_id))
            {
                if !first {
                    states.extend_from_slice(&window);
                    next.push(k);
                }
                first = false;
                window.rotate_left(1);
                if let Some(last) = window.last_mut() {
                    *last = k;
                }
            }
        }
        let states = StateBatch::Categorical {
            factors: window.len(),
            data: states,
        };
        (states, next)
    }

    /// Reads sessions added to the store since the last call and, if there are any,
    /// rebuilds the model with them (new items take free slots). Returns how many were new.
    pub fn refresh(&self) -> Result<usize, RecsysError> {
        let Some(dir) = store_dir(&self.config) else {
            return Ok(0);
        };
        let mut r = self.refresh.lock().unwrap_or_else(|p| p.into_inner());
        let (new, offset) = store::read_since(dir, r.offset)?;
        r.offset = offset;
        if new.is_empty() {
            return Ok(0);
        }
        let added = r.catalogue.extend(new.iter());
        r.stored.extend(new.iter().cloned());
        let model = NgramModel::build(
            r.catalogue.clone(),
            self.base.iter().chain(&r.stored),
            &self.config,
        )
        .ok_or_else(|| RecsysError::Data("no session buys anything".into()))?;
        tracing::info!(
            "recommender: {} new sessions from the store ({added} new items); model rebuilt",
            new.len()
        );
        *self.current.write().unwrap_or_else(|p| p.into_inner()) = Arc::new(model);
        Ok(new.len())
    }
}

/// The process's model for these settings, loaded on first use. With a session store, a
/// thread refreshes it every `refresh_seconds` while the model is in use.
pub fn model_handle(config: &RecommenderConfig) -> Result<Arc<ModelHandle>, RecsysError> {
    static CACHE: OnceLock<Mutex<HashMap<String, Weak<ModelHandle>>>> = OnceLock::new();
    let key = serde_json::to_string(config).unwrap_or_default();
    let mut cache = CACHE
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|p| p.into_inner());
    if let Some(handle) = cache.get(&key).and_then(Weak::upgrade) {
        return Ok(handle);
    }
    let handle = Arc::new(ModelHandle::load(config)?);
    cache.insert(key, Arc::downgrade(&handle));
    if store_dir(config).is_some() {
        let weak = Arc::downgrade(&handle);
        let every = Duration::from_secs(config.refresh_seconds);
        let spawned = std::thread::Builder::new()
            .name("recsys-refresh".into())
            .spawn(move || {
                loop {
                    std::thread::sleep(every);
                    let Some(handle) = weak.upgrade() else { return };
                    if let Err(e) = handle.refresh() {
                        tracing::warn!("recommender: refreshing from the store: {e}");
                    }
                }
            });
        if let Err(e) = spawned {
            tracing::warn!("recommender: no refresh thread: {e}");
        }
    }
    Ok(handle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recsys::store::SessionStore;
    use crate::recsys::{Purchase, Session};
    use jsae_proto::settings::SyntheticConfig;

    fn session(id: &str, items: &[&str]) -> Session {
        Session {
            session_id: id.into(),
            purchases: items
                .iter()
                .enumerate()
                .map(|(t, i)| Purchase {
                    item_id: (*i).into(),
                    price: 5.0,
                    time_unix_ms: t as i64,
                })
                .collect(),
        }
    }

    #[test]
    fn the_held_out_split_is_stable_and_has_about_the_asked_share() {
        let config = RecommenderConfig {
            source: SessionSource::Synthetic,
            holdout: 0.2,
            ..RecommenderConfig::default()
        };
        let sessions = load_sessions(&config).expect("generated");
        let (train, held) = split_sessions(sessions.clone(), &config);
        assert_eq!(train.len() + held.len(), sessions.len());
        let share = held.len() as f64 / sessions.len() as f64;
        assert!((0.18..0.22).contains(&share), "{share}");
        let mut reversed = sessions;
        reversed.reverse();
        let (_, again) = split_sessions(reversed, &config);
        let ids = |v: &[Session]| {
            let mut ids: Vec<String> = v.iter().map(|s| s.session_id.clone()).collect();
            ids.sort();
            ids
        };
        assert_eq!(
            ids(&held),
            ids(&again),
            "the order of the file does not matter"
        );
        assert!(held.iter().all(|s| is_held_out(&s.session_id, 0.2)));
        assert!(!is_held_out("any", 0.0));
        // ids that differ only at the end (Instacart's `user-N`) split too
        let users = (0..1000)
            .filter(|u| is_held_out(&format!("user-{u}"), 0.1))
            .count();
        assert!((70..130).contains(&users), "{users}");
    }

    #[test]
    fn sessions_added_to_the_store_reshape_the_model_at_the_next_refresh() {
        let dir = std::env::temp_dir().join(format!("jsae-refresh-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let config = RecommenderConfig {
            source: SessionSource::Synthetic,
            top_n: 30,
            store_dir: dir.clone(),
            synthetic: SyntheticConfig {
                items: 25,
                sessions: 500,
                ..SyntheticConfig::default()
            },
            ..RecommenderConfig::default()
        };
        let handle = ModelHandle::load(&config).expect("loads");
        let before = handle.current();
        assert_eq!(before.catalogue().len(), 25);
        let (a, b) = (
            before.catalogue().id(0).expect("filled").to_owned(),
            before.catalogue().id(1).expect("filled").to_owned(),
        );
        let (sa, sb) = (0, 1);
        let p_before = before.probability(sa, sb, sa);

        // many sessions buy a, b, a again; one brings a new item
        let mut store = SessionStore::open(&dir).expect("store");
        let mut sessions: Vec<Session> = (0..300)
            .map(|i| session(&format!("s{i}"), &[&a, &b, &a]))
            .collect();
        sessions.push(session("new", &[&a, "fresh-item"]));
        store.append(&sessions).expect("appends");
        assert_eq!(handle.refresh().expect("refreshes"), 301);
        assert_eq!(handle.refresh().expect("nothing new"), 0);
        let after = handle.current();
        let p_after = after.probability(sa, sb, sa);
        assert!(p_after > p_before + 0.2, "{p_before} -> {p_after}");
        let fresh = after
            .catalogue()
            .slot("fresh-item")
            .expect("the new item joined");
        assert!((25..30).contains(&fresh));
        // the catalogue is pinned: another process sees the same slots
        drop(store);
        let again = ModelHandle::load(&config).expect("reloads");
        assert_eq!(again.current().catalogue().slot(&a), Some(sa));
        assert_eq!(again.current().catalogue().slot("fresh-item"), Some(fresh));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn logged_steps_are_every_purchase_after_the_first_with_the_state_before_it() {
        let dir = std::env::temp_dir().join(format!("jsae-logged-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let config = RecommenderConfig {
            source: SessionSource::Synthetic,
            top_n: 25,
            holdout: 0.2,
            store_dir: dir.clone(),
            synthetic: SyntheticConfig {
                items: 25,
                sessions: 300,
                ..SyntheticConfig::default()
            },
            ..RecommenderConfig::default()
        };
        let base = ModelHandle::load(&config).expect("loads");
        let catalogue = base.current().catalogue().clone();
        let (a, b, c) = (
            catalogue.id(0).expect("filled").to_owned(),
            catalogue.id(1).expect("filled").to_owned(),
            catalogue.id(2).expect("filled").to_owned(),
        );
        // a stored session with an item outside the (full) catalogue, which is passed over
        let mut store = SessionStore::open(&dir).expect("store");
        store
            .append(&[session("stored", &[&a, &b, "not-an-item", &c])])
            .expect("appends");
        drop(store);
        let handle = ModelHandle::load(&config).expect("reloads");
        let (states, next) = handle.logged_steps(2);
        let StateBatch::Categorical { factors: 2, data } = &states else {
            panic!("two factors: {states:?}")
        };
        let none = catalogue.none();
        let n = next.len();
        assert_eq!(&data[2 * (n - 2)..], &[none, 0, 0, 1]);
        assert_eq!(&next[n - 2..], &[1, 2]);
        // the training sessions' purchases after their first, the held-out ones never
        let (train, held) = split_sessions(load_sessions(&config).expect("generated"), &config);
        assert!(!held.is_empty());
        let expected: usize = train
            .iter()
            .map(|s| {
                let bought = s.purchases.iter();
                let kept = bought.filter(|p| catalogue.slot(&p.item_id).is_some());
                kept.count().saturating_sub(1)
            })
            .sum();
        assert_eq!(n, expected + 2);
        // every state is a context the model counted
        let contexts: std::collections::HashSet<(u32, u32)> =
            data.chunks_exact(2).map(|w| (w[0], w[1])).collect();
        assert_eq!(contexts.len(), handle.current().contexts());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
