//! The model handle's tests: the store's sessions reshape the model at a refresh, counted
//! exactly as a build from all the sessions would; a restart starts from the checkpoint;
//! the logged steps.

use std::path::PathBuf;

use super::*;
use crate::recsys::store::SessionStore;
use crate::recsys::{Purchase, Session};
use jsae_env_spec::{SessionSource, SyntheticConfig};

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

/// A fresh store directory `jsae-NAME-PID` and the settings of a synthetic source of 25
/// items and `sessions` sessions, its `top_n` most popular items kept.
fn synthetic_store(name: &str, top_n: u32, sessions: u32) -> (PathBuf, RecommenderConfig) {
    let dir = std::env::temp_dir().join(format!("jsae-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let config = RecommenderConfig {
        source: SessionSource::Synthetic,
        top_n,
        store_dir: dir.clone(),
        synthetic: SyntheticConfig {
            items: 25,
            sessions,
            ..SyntheticConfig::default()
        },
        ..RecommenderConfig::default()
    };
    (dir, config)
}

#[test]
fn sessions_added_to_the_store_reshape_the_model_at_the_next_refresh() {
    let (dir, config) = synthetic_store("refresh", 30, 500);
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
    let (dir, mut config) = synthetic_store("logged", 25, 300);
    config.holdout = 0.2;
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

/// Asserts that two models give every transition the same probability.
fn assert_same_model(got: &NgramModel, want: &NgramModel) {
    assert_eq!(got.catalogue(), want.catalogue());
    assert_eq!(
        (got.sessions(), got.contexts()),
        (want.sessions(), want.contexts())
    );
    let c = got.catalogue();
    for before in 0..=c.none() {
        for last in 0..c.capacity() as u32 {
            for item in 0..c.capacity() as u32 {
                let (g, w) = (
                    got.probability(before, last, item),
                    want.probability(before, last, item),
                );
                assert!((g - w).abs() < 1e-12, "{before} {last} {item}: {g} vs {w}");
            }
        }
    }
    for item in 0..c.capacity() as u32 {
        assert_eq!(got.value(item), want.value(item));
    }
}

#[test]
fn a_restart_counts_the_store_from_its_checkpoint_as_a_build_from_every_session_would() {
    let (dir, config) = synthetic_store("checkpoint", 30, 300);
    let handle = ModelHandle::load(&config).expect("loads");
    let catalogue = handle.current().catalogue().clone();
    let (a, b) = (
        catalogue.id(0).expect("filled").to_owned(),
        catalogue.id(1).expect("filled").to_owned(),
    );
    let mut store = SessionStore::open(&dir).expect("store");
    let mut stored: Vec<Session> = (0..200)
        .map(|i| session(&format!("s{i}"), &[&a, &b, &a, &format!("new-{}", i % 3)]))
        .collect();
    store.append(&stored).expect("appends");
    handle.refresh().expect("refreshes");
    let base = split_sessions(load_sessions(&config).expect("data"), &config).0;
    let rebuilt = |stored: &[Session]| {
        let mut c = catalogue.clone();
        c.extend(stored.iter());
        NgramModel::build(c, base.iter().chain(stored), &config).expect("builds")
    };
    assert_same_model(&handle.current(), &rebuilt(&stored));

    handle.checkpoint().expect("checkpoint");
    let more: Vec<Session> = (0..20)
        .map(|i| session(&format!("t{i}"), &[&b, "newer", &b]))
        .collect();
    store.append(&more).expect("appends");
    stored.extend(more);
    drop(store);
    // the first stored line is overwritten (same length): only a restart that starts from
    // the checkpoint still counts it
    let log = crate::recsys::store::sessions_file(&dir);
    let mut text = std::fs::read(&log).expect("log");
    let first = text.iter().position(|&c| c == b'\n').expect("a line");
    text[..first].fill(b' ');
    std::fs::write(&log, &text).expect("log");
    let again = ModelHandle::load(&config).expect("reloads");
    assert_same_model(&again.current(), &rebuilt(&stored));
    // without the checkpoint the damaged line is skipped
    std::fs::remove_file(model_checkpoint::checkpoint_file(&dir)).expect("removed");
    let whole = ModelHandle::load(&config).expect("reloads");
    assert_eq!(whole.current().sessions() + 1, again.current().sessions());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_catalogue_alone_follows_the_store_as_the_model_does() {
    use crate::recsys::CatalogueHandle;
    let (dir, config) = synthetic_store("catalogue-alone", 30, 400);
    let alone = CatalogueHandle::load(&config).expect("the catalogue");
    let model = ModelHandle::load(&config).expect("the model");
    assert_eq!(&*alone.current(), model.current().catalogue());
    let a = alone.current().id(0).expect("filled").to_owned();
    let mut store = SessionStore::open(&dir).expect("store");
    store
        .append(&[
            session("n1", &[&a, "new-1", "new-2"]),
            session("n2", &["new-2", "new-3", &a]),
        ])
        .expect("appends");
    assert_eq!(alone.refresh().expect("reads the store"), 2);
    assert_eq!(alone.refresh().expect("nothing new"), 0);
    model.refresh().expect("refreshes");
    assert_eq!(&*alone.current(), model.current().catalogue());
    assert_eq!(alone.current().slot("new-3"), Some(27));
    // a restart reads the pinned catalogue and the store again: the same slots
    drop(store);
    let again = CatalogueHandle::load(&config).expect("reloads");
    assert_eq!(&*again.current(), &*alone.current());
    // more new items than free slots: the first ones take the slots left
    let mut store = SessionStore::open(&dir).expect("store");
    let many: Vec<String> = (0..10).map(|i| format!("more-{i}")).collect();
    let refs: Vec<&str> = many.iter().map(String::as_str).collect();
    store.append(&[session("n3", &refs)]).expect("appends");
    alone.refresh().expect("reads the store");
    model.refresh().expect("refreshes");
    assert_eq!(alone.current().len(), 30);
    assert_eq!(&*alone.current(), model.current().catalogue());
    let _ = std::fs::remove_dir_all(&dir);
}
