//! The run's result, `summary.json` (the metrics per update are `metrics`).

use std::path::PathBuf;

use jsae_wire::EvalReport;

use crate::{RunDir, Scalar, write_atomic};
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

/// `summary.json`, as docs/src/method/training.md describes it.
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
    /// Mean return of as many evaluation episodes with sampled actions, from the same start
    /// states (null when not run).
    #[serde(default)]
    pub eval_stochastic_return_mean: Option<f64>,
    /// Their success rate.
    #[serde(default)]
    pub eval_stochastic_success_rate: Option<f64>,
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
    /// The git revision the program was built from ("unknown" outside a checkout).
    #[serde(default)]
    pub git_commit: String,
    /// When the run started, seconds since the Unix epoch.
    #[serde(default)]
    pub started_unix_s: u64,
    /// The command that started the run, as typed (`jsae train ...`).
    #[serde(default)]
    pub command_line: Vec<String>,
}

/// The environment variable `jsae train` hands its own command line to the services in
/// (JSON array), so the learner's summary names what the user typed.
pub const COMMAND_LINE_ENV: &str = "JSAE_COMMAND_LINE";

/// The command that started the run: [`COMMAND_LINE_ENV`] if set, else this process's own.
fn command_line() -> Vec<String> {
    std::env::var(COMMAND_LINE_ENV)
        .ok()
        .and_then(|json| serde_json::from_str(&json).ok())
        .unwrap_or_else(|| std::env::args().collect())
}

/// `x` rounded to `digits` decimals, for reading.
fn rounded(x: f64, digits: i32) -> f64 {
    let scale = 10f64.powi(digits);
    (x * scale).round() / scale
}

/// Return, success and length statistics of some evaluation episodes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EvalStats {
    /// Episodes.
    pub episodes: usize,
    /// Mean return.
    pub return_mean: f64,
    /// The returns' standard deviation.
    pub return_std: f64,
    /// Success rate (None where the environment has no success notion).
    pub success_rate: Option<f64>,
    /// Mean episode length.
    pub length_mean: f64,
}

impl EvalStats {
    /// The statistics of `episodes`.
    pub fn of(episodes: &[jsae_wire::EpisodeStat]) -> Self {
        let n = episodes.len().max(1) as f64;
        let mean = episodes.iter().map(|e| e.ret).sum::<f64>() / n;
        let var = episodes.iter().map(|e| (e.ret - mean).powi(2)).sum::<f64>() / n;
        let successes: Vec<bool> = episodes.iter().filter_map(|e| e.success).collect();
        let success_rate = (!successes.is_empty())
            .then(|| successes.iter().filter(|&&s| s).count() as f64 / successes.len() as f64);
        Self {
            episodes: episodes.len(),
            return_mean: mean,
            return_std: var.sqrt(),
            success_rate,
            length_mean: episodes.iter().map(|e| f64::from(e.length)).sum::<f64>() / n,
        }
    }
}

impl Summary {
    /// The evaluation's numbers as named scalars (TensorBoard's `eval/` tags).
    pub fn eval_scalars(&self) -> Vec<Scalar> {
        vec![
            ("return_mean", Some(self.eval_return_mean)),
            ("return_std", Some(self.eval_return_std)),
            ("success_rate", self.eval_success_rate),
            ("length_mean", Some(self.eval_length_mean)),
            ("stochastic_return_mean", self.eval_stochastic_return_mean),
            ("stochastic_success_rate", self.eval_stochastic_success_rate),
        ]
    }

    /// The summary of a finished run; `lag` is the accepted fragments' mean and largest
    /// policy lag, `dropped` those dropped for lag and for an outdated embedding.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        meta: &RunMeta,
        env_steps: u64,
        wall_seconds: f64,
        eval: &EvalReport,
        updates: u64,
        lag: (f64, u64),
        dropped: (u64, u64),
        policy_version: u64,
    ) -> Self {
        let det = EvalStats::of(&eval.episodes);
        let stoch = (!eval.stochastic.is_empty()).then(|| EvalStats::of(&eval.stochastic));
        Self {
            env: meta.env.clone(),
            algo: meta.algo.clone(),
            seed: meta.seed,
            env_steps,
            wall_seconds: rounded(wall_seconds, 3),
            steps_per_second: rounded(env_steps as f64 / wall_seconds.max(1e-9), 1),
            eval_episodes: eval.episodes.len(),
            eval_return_mean: det.return_mean,
            eval_return_std: det.return_std,
            eval_success_rate: det.success_rate,
            eval_length_mean: det.length_mean,
            eval_stochastic_return_mean: stoch.as_ref().map(|s| s.return_mean),
            eval_stochastic_success_rate: stoch.and_then(|s| s.success_rate),
            learner_updates: updates,
            policy_lag_mean: lag.0,
            policy_lag_max: lag.1,
            dropped_lag: dropped.0,
            dropped_embedding: dropped.1,
            policy_version,
            embedding_version: eval.embedding_version,
            device: meta.device.clone(),
            git_commit: env!("JSAE_GIT_COMMIT").to_string(),
            started_unix_s: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64() - wall_seconds)
                .max(0.0) as u64,
            command_line: command_line(),
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
