//! The shared, refreshed n-gram model: one per process and settings (the environments of an
//! actor share it), built from the data's sessions and the session store's, and rebuilt every
//! `refresh_seconds` when a store is set. The store's sessions are read one at a time into
//! counts (`ngram_counts`), from the store's checkpoint (`model_checkpoint`) on: the model's
//! memory and start time follow the catalogue and its contexts, not the store's size.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex, OnceLock, RwLock, Weak};
use std::time::Duration;

use jsae_env_spec::RecommenderConfig;
use jsae_spaces::StateBatch;

use super::data::{load_sessions, split_sessions};
use super::ngram::{Catalogue, NgramModel};
use super::ngram_counts::NgramCounts;
use super::sessions::Session;
use super::{RecsysError, model_checkpoint, store};

/// What the model is rebuilt from: the store's sessions only as counts, never as sessions.
struct Refresh {
    /// The pinned catalogue, extended by the items of the store's sessions read so far.
    catalogue: Catalogue,
    /// The counts of the data's sessions (recounted when the catalogue grows).
    base_counts: NgramCounts,
    /// The counts of the store's sessions read so far.
    stored: NgramCounts,
    /// The end of the store's log read so far.
    offset: u64,
    /// Where the last checkpoint was written or read (`model_checkpoint`).
    checkpointed: u64,
}

impl Refresh {
    /// Reads the store's sessions after `offset`: each one extends the catalogue and is
    /// counted. Returns how many were read.
    fn read_store(&mut self, dir: &Path) -> Result<usize, RecsysError> {
        let (catalogue, stored) = (&mut self.catalogue, &mut self.stored);
        let (mut read, mut end) = (0, self.offset);
        let result = store::read_committed(dir, self.offset, u64::MAX, |s, at| {
            catalogue.extend(std::iter::once(&s));
            stored.add(catalogue, &s);
            read += 1;
            end = at;
        });
        // the sessions counted before an error are not read again
        self.offset = end;
        result?;
        Ok(read)
    }

    /// Writes a checkpoint when the store grew enough since the last one; a failure only
    /// costs the next start a longer read.
    fn checkpoint_if_due(&mut self, dir: &Path) {
        if self.offset < self.checkpointed + model_checkpoint::CHECKPOINT_EVERY_BYTES {
            return;
        }
        match model_checkpoint::save(dir, self.offset, &self.catalogue, &self.stored) {
            Ok(()) => self.checkpointed = self.offset,
            Err(e) => tracing::warn!("recommender: checkpoint of the store's counts: {e}"),
        }
    }
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

pub(super) fn store_dir(config: &RecommenderConfig) -> Option<&Path> {
    (!config.store_dir.as_os_str().is_empty()).then_some(config.store_dir.as_path())
}

/// The catalogue of a store: made once from the data and the store's sessions, then kept
/// in `STORE/catalogue.json` so every process that shares the store maps items to the same
/// actions (whoever comes first writes it; the write is atomic and never replaces one).
fn pinned_catalogue(
    dir: &Path,
    capacity: usize,
    make: impl FnOnce() -> Result<Catalogue, RecsysError>,
) -> Result<Catalogue, RecsysError> {
    let path = dir.join("catalogue.json");
    let io = |path: &Path| {
        let path = path.to_owned();
        move |source| RecsysError::Io { path, source }
    };
    if !path.exists() {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let tmp = dir.join(format!("catalogue.json.{}.tmp", std::process::id()));
        let json = serde_json::to_vec(&make()?).map_err(|e| RecsysError::Data(e.to_string()))?;
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

/// The items purchased in the sessions `visit` passes on, and how often.
fn purchase_counts(
    visit: impl FnOnce(&mut dyn FnMut(&Session)) -> Result<(), RecsysError>,
) -> Result<HashMap<String, u64>, RecsysError> {
    let mut counts: HashMap<String, u64> = HashMap::new();
    visit(&mut |s: &Session| {
        for p in &s.purchases {
            match counts.get_mut(p.item_id.as_str()) {
                Some(c) => *c += 1,
                None => {
                    counts.insert(p.item_id.clone(), 1);
                }
            }
        }
    })?;
    Ok(counts)
}

/// The catalogue the settings start from, before the store's sessions extend it: with a
/// store, its pinned `catalogue.json` (made the first time from the `top_n` most purchased
/// items of the data and the store's sessions); without, the data's `top_n` most purchased
/// items. `base` visits the data's sessions that are not held out. [`ModelHandle`] and
/// [`CatalogueHandle`](super::catalogue_handle::CatalogueHandle) both start here, so a
/// process that holds only the catalogue maps items to the same actions.
pub(super) fn first_catalogue(
    config: &RecommenderConfig,
    base: impl FnOnce(&mut dyn FnMut(&Session)) -> Result<(), RecsysError>,
) -> Result<Catalogue, RecsysError> {
    let capacity = config.top_n as usize;
    match store_dir(config) {
        Some(dir) => pinned_catalogue(dir, capacity, || {
            let counts = purchase_counts(|visit| {
                base(&mut *visit)?;
                store::read_committed(dir, 0, u64::MAX, |s, _| visit(&s)).map(|_| ())
            })?;
            Ok(Catalogue::top(counts, capacity))
        }),
        None => Ok(Catalogue::top(purchase_counts(base)?, capacity)),
    }
}

/// The counts of `sessions` over `catalogue`.
fn counts_of(catalogue: &Catalogue, sessions: &[Session]) -> NgramCounts {
    let mut counts = NgramCounts::new(catalogue.capacity());
    sessions.iter().for_each(|s| counts.add(catalogue, s));
    counts
}

impl ModelHandle {
    /// Reads the data (without its held-out sessions) and the store, makes the catalogue and
    /// builds the model. The store is read from its checkpoint on (`model_checkpoint`), one
    /// session at a time, into counts: neither its size nor its sessions stay in memory.
    pub fn load(config: &RecommenderConfig) -> Result<Self, RecsysError> {
        let (base, held_out) = split_sessions(load_sessions(config)?, config);
        let capacity = config.top_n as usize;
        let mut refresh = Refresh {
            catalogue: first_catalogue(config, |visit| {
                base.iter().for_each(visit);
                Ok(())
            })?,
            base_counts: NgramCounts::new(capacity),
            stored: NgramCounts::new(capacity),
            offset: 0,
            checkpointed: 0,
        };
        if let Some(dir) = store_dir(config) {
            if let Some(c) = model_checkpoint::load(dir, &refresh.catalogue) {
                (refresh.catalogue, refresh.stored) = (c.catalogue, c.counts);
                (refresh.offset, refresh.checkpointed) = (c.log_bytes, c.log_bytes);
            }
            refresh.read_store(dir)?;
            refresh.checkpoint_if_due(dir);
        }
        refresh.base_counts = counts_of(&refresh.catalogue, &base);
        if refresh.catalogue.len() < capacity {
            tracing::warn!(
                "recommender: the data has {} distinct items, fewer than top_n = {capacity}; \
                 the other actions are free slots for items submitted later",
                refresh.catalogue.len()
            );
        }
        let model = NgramModel::from_counts(
            refresh.catalogue.clone(),
            &[&refresh.base_counts, &refresh.stored],
            config,
        )
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
            refresh: Mutex::new(refresh),
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
    /// the store's, read again one at a time), as the environment's steps: for every
    /// catalogue purchase after a session's first, the state before it (the session's last
    /// `history` catalogue purchases, "none" where there are fewer, as an episode starts) and
    /// the item bought. Purchases outside the catalogue are passed over, as the model passes
    /// over them. A store that cannot be read gives the data's steps alone (with a warning).
    pub fn logged_steps(&self, history: usize) -> (StateBatch, Vec<u32>) {
        let model = self.current();
        let until = self
            .refresh
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .offset;
        logged_steps_of(model.catalogue(), history, |visit| {
            self.base.iter().for_each(&mut *visit);
            if let Some(dir) = store_dir(&self.config)
                && let Err(e) = store::read_committed(dir, 0, until, |s, _| visit(&s))
            {
                tracing::warn!("recommender: logged steps without the rest of the store: {e}");
            }
        })
    }

    /// Reads sessions added to the store since the last call and, if there are any,
    /// rebuilds the model with them (new items take free slots). Returns how many were new.
    pub fn refresh(&self) -> Result<usize, RecsysError> {
        let Some(dir) = store_dir(&self.config) else {
            return Ok(0);
        };
        let mut r = self.refresh.lock().unwrap_or_else(|p| p.into_inner());
        let items = r.catalogue.len();
        let new = r.read_store(dir)?;
        if new == 0 {
            return Ok(0);
        }
        let added = r.catalogue.len() - items;
        if added > 0 {
            // a data item outside the catalogue may have joined it
            r.base_counts = counts_of(&r.catalogue, &self.base);
        }
        r.checkpoint_if_due(dir);
        let model = NgramModel::from_counts(
            r.catalogue.clone(),
            &[&r.base_counts, &r.stored],
            &self.config,
        )
        .ok_or_else(|| RecsysError::Data("no session buys anything".into()))?;
        tracing::info!(
            "recommender: {new} new sessions from the store ({added} new items); model rebuilt"
        );
        *self.current.write().unwrap_or_else(|p| p.into_inner()) = Arc::new(model);
        Ok(new)
    }

    /// Writes the checkpoint of the store's counts read so far now (it is otherwise written
    /// every [`model_checkpoint::CHECKPOINT_EVERY_BYTES`] of new store).
    pub fn checkpoint(&self) -> Result<(), RecsysError> {
        let Some(dir) = store_dir(&self.config) else {
            return Ok(());
        };
        let mut r = self.refresh.lock().unwrap_or_else(|p| p.into_inner());
        model_checkpoint::save(dir, r.offset, &r.catalogue, &r.stored)?;
        r.checkpointed = r.offset;
        Ok(())
    }
}

/// The environment's steps in the sessions `sessions` visits: for every `catalogue` purchase
/// after a session's first, the state before it (the session's last `history` catalogue
/// purchases, "none" where there are fewer, as an episode starts) and the item bought.
/// Purchases outside the catalogue are passed over, as the model passes over them.
pub(super) fn logged_steps_of(
    catalogue: &Catalogue,
    history: usize,
    sessions: impl FnOnce(&mut dyn FnMut(&Session)),
) -> (StateBatch, Vec<u32>) {
    let (mut states, mut next) = (Vec::new(), Vec::new());
    let mut window = vec![catalogue.none(); history.max(1)];
    sessions(&mut |s: &Session| {
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
    });
    let states = StateBatch::Categorical {
        factors: history.max(1),
        data: states,
    };
    (states, next)
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
        refresh_every(&handle, config, ModelHandle::refresh);
    }
    Ok(handle)
}

/// Starts a thread that calls `refresh` on `handle` every `refresh_seconds` while anything
/// else holds it (a failure is logged and tried again next time).
pub(super) fn refresh_every<T: Send + Sync + 'static>(
    handle: &Arc<T>,
    config: &RecommenderConfig,
    refresh: fn(&T) -> Result<usize, RecsysError>,
) {
    let weak = Arc::downgrade(handle);
    let every = Duration::from_secs(config.refresh_seconds);
    let spawned = std::thread::Builder::new()
        .name("recsys-refresh".into())
        .spawn(move || {
            loop {
                std::thread::sleep(every);
                let Some(handle) = weak.upgrade() else { return };
                if let Err(e) = refresh(&handle) {
                    tracing::warn!("recommender: refreshing from the store: {e}");
                }
            }
        });
    if let Err(e) = spawned {
        tracing::warn!("recommender: no refresh thread: {e}");
    }
}

#[cfg(test)]
#[path = "model_handle_tests.rs"]
mod tests;
