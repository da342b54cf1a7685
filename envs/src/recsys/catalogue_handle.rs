//! The catalogue alone, for a process that maps item ids to actions and needs no n-gram
//! model: the Recommender serving a learned policy, and the learner and embedder reading the
//! logged purchases ([`CatalogueHandle::logged_steps`]). It is the catalogue [`ModelHandle`]
//! makes from the same settings ([`first_catalogue`], then the store's sessions in the order
//! they were committed), made without the model's counts and without holding the data's
//! sessions: at a million items the model takes 7 GB at its peak, the catalogue about 100 MB.
//!
//! [`ModelHandle`]: super::ModelHandle

use std::sync::{Arc, Mutex, RwLock};

use jsae_env_spec::RecommenderConfig;
use jsae_spaces::StateBatch;

use super::data::for_each_training_session;
use super::model_handle::{first_catalogue, logged_steps_of, refresh_every, store_dir};
use super::ngram::Catalogue;
use super::{RecsysError, store};

/// The current catalogue of one set of settings, extended as the store's sessions bring new
/// items.
pub struct CatalogueHandle {
    config: RecommenderConfig,
    current: RwLock<Arc<Catalogue>>,
    /// The end of the store's log read so far.
    offset: Mutex<u64>,
}

impl std::fmt::Debug for CatalogueHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CatalogueHandle")
            .field("items", &self.current().len())
            .finish()
    }
}

impl CatalogueHandle {
    /// Makes the catalogue from the data (read one session at a time) and the store.
    pub fn load(config: &RecommenderConfig) -> Result<Self, RecsysError> {
        let catalogue = first_catalogue(config, |visit| {
            for_each_training_session(config, |s| visit(s))
        })?;
        let handle = Self {
            config: config.clone(),
            current: RwLock::new(Arc::new(catalogue)),
            offset: Mutex::new(0),
        };
        handle.refresh()?;
        Ok(handle)
    }

    /// The catalogue to use now.
    pub fn current(&self) -> Arc<Catalogue> {
        self.current
            .read()
            .map_or_else(|p| Arc::clone(p.get_ref()), |c| Arc::clone(&c))
    }

    /// The logged purchases as the environment's steps, as [`ModelHandle::logged_steps`]
    /// gives them: the data's sessions read again one at a time, then the store's read so far.
    ///
    /// # Errors
    /// When the data cannot be read (a store that cannot be read gives the data's steps
    /// alone, with a warning).
    pub fn logged_steps(&self, history: usize) -> Result<(StateBatch, Vec<u32>), RecsysError> {
        let catalogue = self.current();
        let until = *self.offset.lock().unwrap_or_else(|p| p.into_inner());
        let mut read = Ok(());
        let steps = logged_steps_of(&catalogue, history, |visit| {
            read = for_each_training_session(&self.config, |s| visit(s));
            if read.is_ok()
                && let Some(dir) = store_dir(&self.config)
                && let Err(e) = store::read_committed(dir, 0, until, |s, _| visit(&s))
            {
                tracing::warn!("recommender: logged steps without the rest of the store: {e}");
            }
        });
        read.map(|()| steps)
    }

    /// Reads the sessions committed to the store since the last call; their new items take
    /// free slots. Returns how many sessions were read.
    pub fn refresh(&self) -> Result<usize, RecsysError> {
        let Some(dir) = store_dir(&self.config) else {
            return Ok(0);
        };
        let mut offset = self.offset.lock().unwrap_or_else(|p| p.into_inner());
        let current = self.current();
        let free = current.capacity() - current.len();
        // the new items in the order they come, before any copy of the catalogue
        let (mut new, mut seen) = (Vec::new(), std::collections::HashSet::new());
        let (mut read, mut end) = (0, *offset);
        let result = store::read_committed(dir, *offset, u64::MAX, |s, at| {
            for p in &s.purchases {
                if new.len() < free
                    && current.slot(&p.item_id).is_none()
                    && seen.insert(p.item_id.clone())
                {
                    new.push(p.item_id.clone());
                }
            }
            read += 1;
            end = at;
        });
        // the sessions read before an error are not read again
        *offset = end;
        if !new.is_empty() {
            let mut grown = Catalogue::clone(&current);
            grown.add(new);
            *self.current.write().unwrap_or_else(|p| p.into_inner()) = Arc::new(grown);
        }
        result?;
        Ok(read)
    }
}

/// The catalogue of these settings, made now; with a session store, a thread extends it every
/// `refresh_seconds` while it is in use.
pub fn catalogue_handle(config: &RecommenderConfig) -> Result<Arc<CatalogueHandle>, RecsysError> {
    let handle = Arc::new(CatalogueHandle::load(config)?);
    if store_dir(config).is_some() {
        refresh_every(&handle, config, CatalogueHandle::refresh);
    }
    Ok(handle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recsys::model_handle::ModelHandle;
    use jsae_env_spec::SessionSource;

    #[test]
    fn the_catalogue_alone_is_the_models() {
        for source in [SessionSource::Synthetic, SessionSource::Catalogue] {
            let mut config = RecommenderConfig {
                source,
                top_n: 300,
                ..RecommenderConfig::default()
            };
            config.catalogue.items = 2_000;
            let model = ModelHandle::load(&config).expect("model");
            let alone = CatalogueHandle::load(&config).expect("catalogue");
            let (m, c) = (model.current(), alone.current());
            assert_eq!(m.catalogue(), &*c, "{source:?}");
            assert_eq!(c.len(), 300);
            assert_eq!(c.prefix_hash(300), m.catalogue().prefix_hash(300));
            let steps = alone.logged_steps(3).expect("steps");
            assert_eq!(steps, model.logged_steps(3), "{source:?}");
            assert!(!steps.1.is_empty());
        }
    }
}
