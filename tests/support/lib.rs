//! Helpers shared by the workspace integration tests.

#![forbid(unsafe_code)]

pub mod raw_grpc;
pub mod services;

use std::path::PathBuf;

use jsae_run_dir::MetricsTable;
use jsae_run_dir::RunDir;
use jsae_settings::{Algo, EnvName, TrainConfig};

/// The workspace root.
pub fn repo_root() -> PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the tests crate lives in the workspace")
        .to_path_buf()
}

/// The test venv's python (scripts/setup-python.sh creates it on first use).
pub fn venv_python() -> PathBuf {
    let out = std::process::Command::new(repo_root().join("scripts/setup-python.sh"))
        .output()
        .expect("scripts/setup-python.sh runs");
    assert!(
        out.status.success(),
        "scripts/setup-python.sh failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

/// A fresh, empty directory under the system temp dir for one test.
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("jsae-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("temp dir {}: {e}", dir.display()));
    dir
}

/// A configuration small enough for a test: a short run with a small pre-training set.
pub fn small_config(env: EnvName, algo: Algo, seed: u64, out: PathBuf) -> TrainConfig {
    let mut c = TrainConfig::defaults(env, algo);
    c.seed = seed;
    c.env_steps = 16_384;
    c.envs_per_actor = 8;
    c.rollout_len = 64;
    c.eval_episodes = 3;
    c.embedding.pretrain_transitions = 4_096;
    c.embedding.pretrain_per_action = 0;
    c.embedding.pretrain_epochs = 3;
    c.ppo.epochs = 2;
    // one pass over the recommender's logged purchases where the defaults pre-train
    c.ppo.recommender.logged_pretrain_epochs = c.ppo.recommender.logged_pretrain_epochs.min(1);
    let items = &mut c.embedding.recommender;
    items.logged_pretrain_epochs = items.logged_pretrain_epochs.min(1);
    if items.pair_buckets > 0 {
        // the recommender's JSAE: its structure, smaller
        items.pair_buckets = 4_096;
        (c.embedding.state_dim, c.embedding.action_dim) = (16, 16);
    }
    c.out = out;
    c
}

/// `summary.json` without the fields that measure time.
pub fn summary_without_timing(dir: &std::path::Path) -> serde_json::Value {
    let text =
        std::fs::read_to_string(RunDir::new(dir).summary_json()).expect("summary.json written");
    let mut v: serde_json::Value = serde_json::from_str(&text).expect("summary.json is JSON");
    if let Some(map) = v.as_object_mut() {
        map.remove("wall_seconds");
        map.remove("steps_per_second");
        map.remove("started_unix_s");
    }
    v
}

/// `metrics.csv` without its `wall_seconds` column, one string per row.
pub fn metrics_without_timing(dir: &std::path::Path) -> Vec<String> {
    let table = MetricsTable::read(&RunDir::new(dir).metrics_csv()).expect("metrics.csv read");
    let columns: Vec<&String> = table
        .columns()
        .iter()
        .filter(|c| *c != "wall_seconds")
        .collect();
    let values: Vec<Vec<Option<f64>>> = columns.iter().map(|c| table.column(c)).collect();
    (0..table.len())
        .map(|row| {
            values
                .iter()
                .map(|col| col[row].map(|v| v.to_string()).unwrap_or_default())
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}
