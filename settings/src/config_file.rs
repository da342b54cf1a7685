//! A settings file as read: every key optional, laid over the defaults by
//! [`crate::TrainConfig::from_layers`].

use std::path::PathBuf;

use serde::Deserialize;

use super::{Algo, DeviceKind, EnvName};

/// A partial configuration as read from a file: whatever it sets overrides the defaults.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfigFile {
    /// See [`TrainConfig`].
    pub env: Option<EnvName>,
    /// See [`TrainConfig`].
    pub algo: Option<Algo>,
    /// See [`TrainConfig`].
    pub seed: Option<u64>,
    /// See [`TrainConfig`].
    pub env_steps: Option<u64>,
    /// See [`TrainConfig`].
    pub actors: Option<usize>,
    /// See [`TrainConfig`].
    pub envs_per_actor: Option<usize>,
    /// See [`TrainConfig`].
    pub batch_envs: Option<usize>,
    /// See [`TrainConfig`].
    pub step_threads: Option<usize>,
    /// See [`TrainConfig`].
    pub rollout_len: Option<usize>,
    /// See [`TrainConfig`].
    pub rollouts_per_policy: Option<usize>,
    /// See [`TrainConfig`].
    pub policy_wait_ms: Option<u64>,
    /// See [`TrainConfig`].
    pub device: Option<DeviceKind>,
    /// See [`TrainConfig`].
    pub eval_episodes: Option<usize>,
    /// Written into config.toml by older versions and ignored: the run directory is
    /// `--out`'s (or the default), never the settings'.
    #[serde(rename = "out")]
    pub _ignored_out: Option<toml::Value>,
    /// See [`TrainConfig`].
    pub one_process: Option<bool>,
    /// See [`TrainConfig`].
    pub init_from: Option<PathBuf>,
    /// Environment settings (tables `[environment.gridworld]`, `[environment.slotmachine]`).
    pub environment: Option<toml::Value>,
    /// Embedding settings (`[embedding]`).
    pub embedding: Option<toml::Value>,
    /// PPO settings (`[ppo]`).
    pub ppo: Option<toml::Value>,
    /// Exploration bonus settings (`[exploration]`).
    pub exploration: Option<toml::Value>,
}
