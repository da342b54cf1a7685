//! Loading the sessions a run's settings name (REES46, Instacart, MovieLens, synthetic), and the
//! held-out split of them for offline evaluation. The model built from them and the session
//! store is `model_handle`'s.

use std::path::PathBuf;

use jsae_env_spec::{RecommenderConfig, SessionSource};

use super::large_catalogue::LargeCatalogue;
use super::sessions::{Session, id_hash};
use super::{RecsysError, instacart, movielens, rees46, synthetic};

/// The data file the settings name (the fetched Instacart sample by default).
pub fn data_path(config: &RecommenderConfig) -> PathBuf {
    match config.source {
        _ if !config.path.as_os_str().is_empty() => config.path.clone(),
        SessionSource::Instacart => instacart::default_path(),
        SessionSource::Movielens100k => movielens::default_path(),
        SessionSource::Rees46 | SessionSource::Synthetic | SessionSource::Catalogue => {
            config.path.clone()
        }
    }
}

/// Reads the sessions of the configured source (without the store).
pub fn load_sessions(config: &RecommenderConfig) -> Result<Vec<Session>, RecsysError> {
    let path = data_path(config);
    match config.source {
        SessionSource::Synthetic => Ok(synthetic::generate(&config.synthetic)),
        SessionSource::Catalogue => {
            let catalogue = LargeCatalogue::new(&config.catalogue)
                .map_err(|e| RecsysError::Data(format!("recommender.catalogue.{e}")))?;
            Ok((0..catalogue.sessions())
                .map(|s| catalogue.session_record(s))
                .collect())
        }
        SessionSource::Instacart if !path.exists() => Err(RecsysError::Data(format!(
            "the Instacart sample is not at {}: run scripts/setup-data.sh (cargo build does), \
             or set environment.recommender.path",
            path.display()
        ))),
        SessionSource::Instacart => instacart::read(&path),
        SessionSource::Movielens100k if !path.exists() => Err(RecsysError::Data(format!(
            "MovieLens-100K is not at {}: run scripts/setup-data.sh (cargo build does), \
             or set environment.recommender.path",
            path.display()
        ))),
        SessionSource::Movielens100k => movielens::read(&path),
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

/// Visits the sessions of the configured source that are not held out, one at a time: the
/// generated catalogue is made session by session and never held whole (20 million purchases
/// at a million items); the files are read whole first.
pub fn for_each_training_session(
    config: &RecommenderConfig,
    mut visit: impl FnMut(&Session),
) -> Result<(), RecsysError> {
    let mut keep = |s: &Session| {
        if !is_held_out(&s.session_id, config.holdout) {
            visit(s);
        }
    };
    if config.source == SessionSource::Catalogue {
        let catalogue = LargeCatalogue::new(&config.catalogue)
            .map_err(|e| RecsysError::Data(format!("recommender.catalogue.{e}")))?;
        (0..catalogue.sessions()).for_each(|s| keep(&catalogue.session_record(s)));
    } else {
        load_sessions(config)?.iter().for_each(keep);
    }
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
