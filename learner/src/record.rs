//! The run's result, `summary.json` (the metrics per update are `metrics`).

use std::path::PathBuf;

use jsae_proto::EvalReport;
use jsae_proto::run_dir::{RunDir, write_atomic};
use serde::{Deserialize, Serialize};

/// What identifies a run in its summary.
#[derive(Debug, Clone, PartialEq)]
pub struct RunMeta {
    /// Environment name.
    pub env: String,
    /// Algorithm name.
    pub algo: String,
    /// Seed.
    pub seed: u64,
    /// burn device.
    pub device: String,
}

/// `summary.json`, as CONTRACT.md specifies (and a few more fields).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Environment name.
    pub env: String,
    /// Algorithm name.
    pub algo: String,
    /// Seed.
    pub seed: u64,
    /// Env steps of all actors.
    pub env_steps: u64,
    /// Wall time of the run.
    pub wall_seconds: f64,
    /// `env_steps / wall_seconds`.
    pub steps_per_second: f64,
    /// Deterministic evaluation episodes.
    pub eval_episodes: usize,
    /// Their mean return.
    pub eval_return_mean: f64,
    /// Their return's standard deviation.
    pub eval_return_std: f64,
    /// Their success rate (null where the environment has no success notion).
    pub eval_success_rate: Option<f64>,
    /// Mean evaluation episode length.
    pub eval_length_mean: f64,
    /// Policy updates.
    pub learner_updates: u64,
    /// Mean policy lag of accepted fragments.
    pub policy_lag_mean: f64,
    /// Largest policy lag accepted.
    pub policy_lag_max: u64,
    /// Fragments dropped for lag.
    pub dropped_lag: u64,
    /// Fragments dropped for an outdated embedding.
    pub dropped_embedding: u64,
    /// Final policy version.
    pub policy_version: u64,
    /// Final embedding version (0 without embeddings).
    pub embedding_version: u64,
    /// burn device.
    pub device: String,
}

impl Summary {
    /// The summary of a finished run.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        meta: &RunMeta,
        env_steps: u64,
        wall_seconds: f64,
        eval: &EvalReport,
        updates: u64,
        lag: &crate::LagStats,
        dropped: (u64, u64),
        policy_version: u64,
    ) -> Self {
        let n = eval.episodes.len();
        let mean = eval.episodes.iter().map(|e| e.ret).sum::<f64>() / n.max(1) as f64;
        let var = eval
            .episodes
            .iter()
            .map(|e| (e.ret - mean).powi(2))
            .sum::<f64>()
            / n.max(1) as f64;
        let successes: Vec<bool> = eval.episodes.iter().filter_map(|e| e.success).collect();
        let success = (!successes.is_empty())
            .then(|| successes.iter().filter(|&&s| s).count() as f64 / successes.len() as f64);
        let length = eval
            .episodes
            .iter()
            .map(|e| f64::from(e.length))
            .sum::<f64>()
            / n.max(1) as f64;
        Self {
            env: meta.env.clone(),
            algo: meta.algo.clone(),
            seed: meta.seed,
            env_steps,
            wall_seconds,
            steps_per_second: env_steps as f64 / wall_seconds.max(1e-9),
            eval_episodes: n,
            eval_return_mean: mean,
            eval_return_std: var.sqrt(),
            eval_success_rate: success,
            eval_length_mean: length,
            learner_updates: updates,
            policy_lag_mean: lag.mean(),
            policy_lag_max: lag.max,
            dropped_lag: dropped.0,
            dropped_embedding: dropped.1,
            policy_version,
            embedding_version: eval.embedding_version,
            device: meta.device.clone(),
        }
    }

    /// Writes the run directory's `summary.json` (via a temporary file, so it is whole or
    /// absent).
    pub fn write(&self, dir: &RunDir) -> std::io::Result<PathBuf> {
        let path = dir.summary_json();
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        write_atomic(&path, (text + "\n").as_bytes())?;
        Ok(path)
    }
}
