//! The session store's tests: commits all or nothing, uncommitted bytes never read and cut at
//! open, duplicates by `session_id` across calls and restarts, stores from before commit
//! records.

use super::*;
use crate::recsys::Purchase;

fn temp_store(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("jsae-store-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn s(id: &str) -> Session {
    Session {
        session_id: id.into(),
        purchases: vec![Purchase {
            item_id: "x".into(),
            price: 2.5,
            time_unix_ms: 7,
        }],
    }
}

fn read_all(dir: &Path, offset: u64) -> (Vec<Session>, u64) {
    let mut got = Vec::new();
    let end = read_committed(dir, offset, u64::MAX, |s, _| got.push(s)).expect("reads");
    (got, end)
}

fn append_bytes(path: &Path, bytes: &[u8]) {
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(path)
        .expect("open");
    f.write_all(bytes).expect("write");
}

#[test]
fn committed_sessions_are_read_once_and_an_uncommitted_tail_never() {
    let dir = temp_store("tail");
    let mut store = SessionStore::open(&dir).expect("opens");
    let outcome = store.append(&[s("a"), s("b")]).expect("appends");
    assert_eq!((outcome.stored, outcome.purchases), (2, 2));
    let (got, offset) = read_all(&dir, 0);
    assert_eq!(got, vec![s("a"), s("b")]);
    let c_hash = store.ids().hash("c");
    drop(store);
    // a crash in the middle of a commit: whole lines, and a torn one, past the commit point
    let line = serde_json::to_string(&s("c")).expect("json");
    append_bytes(
        &sessions_file(&dir),
        format!("{line}\n{{\"session_id\":\"d\",\"pu").as_bytes(),
    );
    append_bytes(&index_file(&dir), &c_hash.to_le_bytes());
    assert_eq!(read_all(&dir, offset), (vec![], offset), "not committed");
    let mut store = SessionStore::open(&dir).expect("reopens");
    assert_eq!(
        std::fs::metadata(sessions_file(&dir)).expect("log").len(),
        offset,
        "cut at open"
    );
    assert!(!store.ids().contains("c"), "the index is cut too");
    assert_eq!(store.append(&[s("c")]).expect("appends").stored, 1);
    let (got, _) = read_all(&dir, offset);
    assert_eq!(got, vec![s("c")]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_staged_call_that_is_dropped_stores_nothing_and_leaves_no_file() {
    let dir = temp_store("dropped");
    let mut store = SessionStore::open(&dir).expect("opens");
    store.append(&[s("kept")]).expect("appends");
    let before = std::fs::read(sessions_file(&dir)).expect("log");
    let mut staged = store.stage().expect("stages");
    for i in 0..100 {
        assert_eq!(
            staged.push(&s(&format!("gone-{i}"))).expect("staged"),
            Staged::New
        );
    }
    let path = staged.path().to_owned();
    assert!(path.exists() && staged.bytes() > 0);
    drop(staged);
    assert!(!path.exists(), "the staging file is deleted");
    assert_eq!(std::fs::read(sessions_file(&dir)).expect("log"), before);
    assert_eq!(read_all(&dir, 0).0, vec![s("kept")]);
    // a staging file left by a crash is deleted when the writer opens the store
    let mut staged = store.stage().expect("stages");
    staged.push(&s("crashed")).expect("staged");
    let left = staged.path().to_owned();
    std::mem::forget(staged);
    drop(store);
    assert!(left.exists());
    let store = SessionStore::open(&dir).expect("reopens");
    assert!(!left.exists(), "staging is emptied at open");
    assert_eq!(store.ids().len(), 1);
    assert_eq!(read_all(&dir, 0).0, vec![s("kept")]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_session_id_is_stored_once_across_calls_and_restarts() {
    let dir = temp_store("dedup");
    let mut store = SessionStore::open(&dir).expect("opens");
    let first = store.append(&[s("a"), s("b"), s("a")]).expect("appends");
    assert_eq!(
        (first.stored, first.duplicates),
        (2, 1),
        "a twice in one call"
    );
    // two calls staging the same id: the first to commit stores it
    let (mut one, mut two) = (store.stage().expect("one"), store.stage().expect("two"));
    assert_eq!(one.push(&s("c")).expect("staged"), Staged::New);
    assert_eq!(two.push(&s("c")).expect("staged"), Staged::New);
    assert_eq!(two.push(&s("b")).expect("stored"), Staged::Duplicate);
    assert_eq!(store.commit(one).expect("commits").stored, 1);
    let late = store.commit(two).expect("commits");
    assert_eq!((late.stored, late.duplicates), (0, 1));
    drop(store);
    let mut store = SessionStore::open(&dir).expect("reopens");
    let again = store.append(&[s("a"), s("c"), s("d")]).expect("appends");
    assert_eq!(
        (again.stored, again.duplicates),
        (1, 2),
        "the index survives"
    );
    drop(store);
    // a lost index is rebuilt from the log
    std::fs::remove_file(index_file(&dir)).expect("removed");
    let mut store = SessionStore::open(&dir).expect("reopens");
    assert_eq!(store.ids().len(), 4);
    assert_eq!(store.append(&[s("d")]).expect("appends").duplicates, 1);
    let ids: Vec<String> = read_all(&dir, 0)
        .0
        .into_iter()
        .map(|s| s.session_id)
        .collect();
    assert_eq!(ids, ["a", "b", "c", "d"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_store_from_before_commit_records_is_read_whole_and_indexed_at_open() {
    let dir = temp_store("legacy");
    std::fs::create_dir_all(&dir).expect("dir");
    let lines = [s("old-1"), s("old-2")]
        .iter()
        .map(|s| serde_json::to_string(s).expect("json") + "\n")
        .collect::<String>();
    std::fs::write(sessions_file(&dir), format!("{lines}{{\"torn")).expect("log");
    assert_eq!(read_all(&dir, 0).0, vec![s("old-1"), s("old-2")]);
    let mut store = SessionStore::open(&dir).expect("opens");
    assert_eq!(
        store.committed(),
        CommitRecord {
            log_bytes: lines.len() as u64,
            sessions: 2
        }
    );
    assert_eq!(
        store
            .append(&[s("old-2"), s("new")])
            .expect("appends")
            .stored,
        1
    );
    let ids: Vec<String> = read_all(&dir, 0)
        .0
        .into_iter()
        .map(|s| s.session_id)
        .collect();
    assert_eq!(ids, ["old-1", "old-2", "new"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ids_are_hashed_with_the_stores_own_secret_key_kept_across_reopens() {
    let (a, b) = (temp_store("key-a"), temp_store("key-b"));
    let mut store_a = SessionStore::open(&a).expect("opens");
    let store_b = SessionStore::open(&b).expect("opens");
    // another store, another key: what collides in one says nothing of the other
    let ids: Vec<String> = (0..16).map(|i| format!("user-{i}")).collect();
    let hashes =
        |store: &SessionStore| -> Vec<u64> { ids.iter().map(|i| store.ids().hash(i)).collect() };
    assert_ne!(hashes(&store_a), hashes(&store_b));
    assert_ne!(
        store_a.ids().hash("user-0"),
        crate::recsys::sessions::id_hash("user-0"),
        "not the public hash"
    );
    assert_eq!(
        store_a.append(&[s("a"), s("b")]).expect("appends").stored,
        2
    );
    let before = hashes(&store_a);
    drop(store_a);
    let store_a = SessionStore::open(&a).expect("reopens");
    assert_eq!(hashes(&store_a), before, "the key is kept");
    assert!(store_a.ids().contains("a") && !store_a.ids().contains("c"));
    drop(store_a);
    // a store from before the key: one is drawn and the index rebuilt with it
    std::fs::remove_file(a.join("id_key")).expect("removed");
    let mut store_a = SessionStore::open(&a).expect("reopens without a key");
    assert_ne!(hashes(&store_a), before, "a new key");
    assert!(store_a.ids().contains("a") && store_a.ids().contains("b"));
    assert_eq!(store_a.append(&[s("a")]).expect("appends").duplicates, 1);
    drop(store_a);
    // a damaged key is refused, naming the file
    std::fs::write(a.join("id_key"), "not a key").expect("written");
    let refused = SessionStore::open(&a).expect_err("a damaged key");
    assert!(refused.to_string().contains("id_key"), "{refused}");
    drop(store_b);
    for dir in [a, b] {
        let _ = std::fs::remove_dir_all(&dir);
    }
}
