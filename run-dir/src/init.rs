//! `--init-from RUN`: the finished run a new run warm-starts from, read and checked before
//! anything starts.

use std::path::{Path, PathBuf};

use jsae_settings::{ConfigError, TrainConfig};

use crate::{RunDir, Weights};

/// A source run's settings and newest weights.
#[derive(Debug, Clone)]
pub struct InitSource {
    /// The run directory.
    pub dir: PathBuf,
    /// Its settings (its config.toml).
    pub config: TrainConfig,
    /// Its newest policy checkpoint's bytes.
    pub policy: Vec<u8>,
    /// Its newest embedding checkpoint's bytes (runs with an embedder).
    pub embedding: Option<Vec<u8>>,
}

fn invalid(dir: &Path, why: impl std::fmt::Display) -> ConfigError {
    ConfigError::Invalid(format!("--init-from {}: {why}", dir.display()))
}

fn newest(dir: &RunDir, kind: Weights, what: &str) -> Result<Vec<u8>, ConfigError> {
    let checkpoints = dir.checkpoints();
    let (_, path) = checkpoints
        .newest(kind)
        .ok_or_else(|| invalid(dir.path(), format!("no {what} checkpoint")))?;
    crate::read_weights(&path).map_err(|e| invalid(dir.path(), format!("{}: {e}", path.display())))
}

/// The run named by `run.init_from`, if any: the same environment and algorithm with the
/// same embedding widths (so phi, T and the policy can carry over), with its checkpoints.
pub fn init_source(run: &TrainConfig) -> Result<Option<InitSource>, ConfigError> {
    let Some(path) = &run.init_from else {
        return Ok(None);
    };
    let dir = RunDir::new(path);
    let config = TrainConfig::from_layers(None, None, Some(&dir.config_toml()))
        .map_err(|e| invalid(path, e))?;
    if (config.env, config.algo) != (run.env, run.algo) {
        return Err(invalid(
            path,
            format!(
                "a {} {} run; this run is {} {}",
                config.env.as_str(),
                config.algo.as_str(),
                run.env.as_str(),
                run.algo.as_str()
            ),
        ));
    }
    let widths = |c: &TrainConfig| {
        (
            c.embedding.state_dim,
            c.embedding.action_dim,
            c.embedding.policy_input_dim(),
            c.ppo.recommender.mean_at_next_item,
        )
    };
    if widths(&config) != widths(run) {
        return Err(invalid(
            path,
            format!(
                "embedding widths (state_dim, action_dim, the policy's input, \
                 ppo.recommender.mean_at_next_item) {:?}; this run's are {:?}",
                widths(&config),
                widths(run)
            ),
        ));
    }
    let policy = newest(&dir, Weights::Policy, "policy")?;
    let embedding = if run.algo.representation().needs_embedder() {
        Some(newest(&dir, Weights::Embedding, "embedding")?)
    } else {
        None
    };
    Ok(Some(InitSource {
        dir: path.clone(),
        config,
        policy,
        embedding,
    }))
}
