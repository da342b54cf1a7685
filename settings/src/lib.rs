//! Every setting of a run, shared by the actor, the embedder and the learner so that each
//! service reads the same `config.toml` the same way: environment names and settings (and
//! the spaces they give), the embedding model's and PPO's settings, the device, and the run
//! configuration with its layering (defaults -> TOML file -> environment variables and
//! flags) and validation. The environments' own settings come from `jsae_env_spec` and the
//! device from `jsae_nn`; both are re-exported here, as a run's settings hold them.

#![forbid(unsafe_code)]

mod algo;
mod batch;
mod config_file;
mod docs;
mod embedding;
mod embedding_recommender;
mod env_defaults;
mod file_errors;
mod flags;
mod gym;
mod ppo;
mod ppo_recommender;
mod run;
mod sets;

pub use algo::{Algo, Representation};
pub use batch::share_envs;
pub use config_file::ConfigFile;
pub use embedding::EmbeddingConfig;
pub use embedding_recommender::{LoggedTargets, RecommenderEmbeddingConfig};
pub use flags::{
    EmbedderFlag, EnvArg, ListenFlag, RunFlags, SERVICE_ENV_HELP, SERVICE_SEED_HELP, device_parser,
};
pub use gym::{
    Description, PYTHON_ENV, cannot_start_python, complete_gym, describe, parse_description, python,
};
pub use jsae_env_spec::{
    EnvConfig, EnvName, GridworldConfig, GroupBy, GymConfig, GymSpace, LargeCatalogueConfig,
    MujocoConfig, Prices, RecommenderConfig, RewardOn, SessionSource, SlotmachineConfig, StartRule,
    SyntheticConfig, gridworld_action_motions, validate_env_config,
};
pub use jsae_nn::DeviceKind;
pub use ppo::{DEFAULT_MAX_ABS_REWARD, EMBEDDED_ENTROPY_LOG_STD_MAX, PpoConfig, UpdatePath};
pub use ppo_recommender::RecommenderPpoConfig;
pub use run::{ConfigError, ExplorationConfig, TrainConfig};
