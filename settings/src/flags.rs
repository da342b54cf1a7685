//! The run flags every command that trains, serves or evaluates a run takes: `--env`,
//! `--algo`, `--seed`, `--config` and `--set`, with their environment variables. One struct,
//! flattened into each command's arguments, so they read the same everywhere.

use std::path::PathBuf;

use super::{Algo, ConfigError, DeviceKind, EnvName, TrainConfig};

/// `--env/--algo/--seed/--config/--set`.
#[derive(Debug, Clone, Default, PartialEq, Eq, clap::Args)]
pub struct RunFlags {
    /// Environment: gridworld, gridworld-discrete, slotmachine, half-cheetah, ant,
    /// recommender, or gym:ID for a Gymnasium environment stepped by Python workers (e.g.
    /// gym:CartPole-v1) [default: the settings file's, else gridworld-discrete].
    #[arg(long, env = "JSAE_ENV", value_name = "ENV")]
    pub env: Option<EnvArg>,
    /// Algorithm [default: the settings file's, else jsae].
    #[arg(long, value_enum, env = "JSAE_ALGO")]
    pub algo: Option<Algo>,
    /// Seed of everything [default: the settings file's, else 1].
    #[arg(long, env = "JSAE_SEED")]
    pub seed: Option<u64>,
    /// Settings file (TOML, the same keys as a run's config.toml; unknown keys are refused).
    #[arg(long, env = "JSAE_CONFIG")]
    pub config: Option<PathBuf>,
    /// Any setting, over the settings file: `--set ppo.lr=0.0005` (a dotted key of a
    /// settings file and a TOML value; repeat it for more). `jsae config` lists the keys.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

impl RunFlags {
    /// The settings these flags give: the defaults of the environment and algorithm, the
    /// settings file over them, then the seed. Not validated: a command sets its own flags
    /// first and then calls [`TrainConfig::validate`].
    pub fn layered(&self) -> Result<TrainConfig, ConfigError> {
        let mut sets = self.set.clone();
        if let Some(id) = self.env.as_ref().and_then(|e| e.gym_id.as_ref()) {
            // `--env gym:ID` is `environment.gym.id`, laid over the file like a --set
            sets.insert(0, format!("environment.gym.id={}", toml_string(id)));
        }
        let env = self.env.as_ref().map(|e| e.name);
        let mut c = TrainConfig::from_layers_with(env, self.algo, self.config.as_deref(), &sets)?;
        c.seed = self.seed.unwrap_or(c.seed);
        let named_here = self.env.as_ref().is_some_and(|e| e.gym_id.is_some());
        if c.env == EnvName::Gym && (c.environment.gym.observation.is_none() || named_here) {
            // a gym environment's spaces (and the defaults that follow them) come from the
            // environment itself; an id on the command line is asked again, whatever a
            // settings file says of another's
            if named_here {
                c.environment.gym.observation = None;
            }
            crate::complete_gym(&mut c).map_err(ConfigError::Invalid)?;
            let described = c.environment.gym.clone();
            let mut sets = sets;
            sets.push(format!(
                "environment.gym={}",
                toml::Value::try_from(&described)
                    .map_err(|e| ConfigError::Invalid(e.to_string()))?
            ));
            c = TrainConfig::from_layers_with(env, self.algo, self.config.as_deref(), &sets)?;
            c.seed = self.seed.unwrap_or(c.seed);
        }
        Ok(c)
    }

    /// As [`RunFlags::layered`], for a service process of a run: `--env` and `--seed` must
    /// be given (as flags or environment variables) unless a settings file is (a run's
    /// config.toml names them), so that the processes of one run cannot fall back to
    /// different defaults unnoticed.
    pub fn for_service(&self) -> Result<TrainConfig, ConfigError> {
        if self.config.is_none() && (self.env.is_none() || self.seed.is_none()) {
            return Err(ConfigError::Invalid(
                "a service needs --env and --seed (or --config FILE with the run's settings)"
                    .into(),
            ));
        }
        self.layered()
    }
}

/// `--env`'s help in a service process: needed there unless `--config` names it
/// ([`RunFlags::for_service`]).
pub const SERVICE_ENV_HELP: &str =
    "Environment (needed unless --config names it: every process of a run must agree)";
/// `--seed`'s help in a service process ([`RunFlags::for_service`]).
pub const SERVICE_SEED_HELP: &str =
    "Seed of everything (needed unless --config names it: every process of a run must agree)";

/// `--listen ADDR`: where a service serves.
#[derive(Debug, Clone, PartialEq, Eq, clap::Args)]
pub struct ListenFlag {
    /// Address to listen on (`host:port`; port 0 picks a free one, printed on stdout).
    #[arg(long, env = "JSAE_LISTEN")]
    pub listen: String,
}

/// `--embedder URL`: the embedder a process follows, where the run's representation has one.
#[derive(Debug, Clone, Default, PartialEq, Eq, clap::Args)]
pub struct EmbedderFlag {
    /// Embedder URL (`http://host:port`, `https://` with --tls-ca; needed by `--algo jsae`).
    #[arg(long, env = "JSAE_EMBEDDER")]
    pub embedder: Option<String>,
}

impl EmbedderFlag {
    /// The embedder to follow under `config`: none for a representation without an embedder,
    /// an error when it needs one and the flag is missing (or `check_url`, the process's
    /// TLS settings, refuses its URL).
    pub fn for_run(
        &self,
        config: &TrainConfig,
        check_url: impl FnOnce(&str, &str) -> Result<(), String>,
    ) -> Result<Option<String>, String> {
        match (
            config.algo.representation().needs_embedder(),
            &self.embedder,
        ) {
            (false, _) => Ok(None),
            (true, Some(url)) => {
                check_url("--embedder", url)?;
                Ok(Some(url.clone()))
            }
            (true, None) => Err(format!(
                "--embedder is required for --algo {}",
                config.algo.as_str()
            )),
        }
    }
}

/// The parser of a `--device` flag: `flex` or `ndarray`, listed in the help.
pub fn device_parser() -> impl clap::builder::TypedValueParser<Value = DeviceKind> {
    use clap::builder::TypedValueParser;
    let names = DeviceKind::ALL.map(DeviceKind::as_str);
    clap::builder::PossibleValuesParser::new(names).map(|name| name.parse().unwrap_or_default())
}

/// A `--env` value: a built-in environment's name, or `gym:ID`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EnvArg {
    /// The environment.
    pub name: EnvName,
    /// The Gymnasium id of `gym:ID`.
    pub gym_id: Option<String>,
}

impl From<EnvName> for EnvArg {
    fn from(name: EnvName) -> Self {
        Self { name, gym_id: None }
    }
}

impl std::str::FromStr for EnvArg {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(id) = s.strip_prefix("gym:") {
            if id.is_empty() || id.chars().any(|c| c.is_control() || c.is_whitespace()) {
                return Err(format!(
                    "gym:ID needs a Gymnasium id after the colon, not {id:?}"
                ));
            }
            return Ok(Self {
                name: EnvName::Gym,
                gym_id: Some(id.to_string()),
            });
        }
        <EnvName as clap::ValueEnum>::from_str(s, false)
            .map(Self::from)
            .map_err(|_| {
                let names: Vec<&str> = <EnvName as clap::ValueEnum>::value_variants()
                    .iter()
                    .map(|e| e.as_str())
                    .collect();
                format!(
                    "unknown environment {s:?}: one of {}, or gym:ID",
                    names.join(", ")
                )
            })
    }
}

/// `s` as a TOML string.
fn toml_string(s: &str) -> String {
    toml::Value::String(s.to_string()).to_string()
}
