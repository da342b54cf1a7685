//! Every setting of a run, shared by the actor, the embedder and the learner so that each
//! service reads the same `config.toml` the same way: environment names and settings (and
//! the spaces they give), the embedding model's and PPO's settings, the device, and the run
//! configuration with its layering (defaults -> TOML file -> environment variables and
//! flags) and validation.

mod algo;
mod batch;
mod device;
mod embedding;
mod envs;
mod file_errors;
mod flags;
mod init;
mod ppo;
mod run;

pub use algo::{Algo, Representation};
pub use batch::share_envs;
pub use device::DeviceKind;
pub use embedding::EmbeddingConfig;
pub use envs::{
    EnvConfig, EnvName, GridworldConfig, GroupBy, MujocoConfig, RecommenderConfig, RewardOn,
    SessionSource, SlotmachineConfig, SyntheticConfig, gridworld_action_motions,
    validate_env_config,
};
pub use flags::{EmbedderFlag, ListenFlag, RunFlags};
pub use init::InitSource;
pub use ppo::{DEFAULT_MAX_ABS_REWARD, EMBEDDED_ENTROPY_LOG_STD_MAX, PpoConfig, UpdatePath};
pub use run::{ConfigError, ConfigFile, ExplorationConfig, TrainConfig};
