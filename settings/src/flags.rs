//! The run flags every command that trains, serves or evaluates a run takes: `--env`,
//! `--algo`, `--seed`, `--config` and `--set`, with their environment variables. One struct,
//! flattened into each command's arguments, so they read the same everywhere.

use std::path::PathBuf;

use super::{Algo, ConfigError, DeviceKind, EnvName, TrainConfig};

/// `--env/--algo/--seed/--config/--set`.
#[derive(Debug, Clone, Default, PartialEq, Eq, clap::Args)]
pub struct RunFlags {
    /// Environment [default: the settings file's, else gridworld-discrete].
    #[arg(long, value_enum, env = "JSAE_ENV")]
    pub env: Option<EnvName>,
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
        let mut c =
            TrainConfig::from_layers_with(self.env, self.algo, self.config.as_deref(), &self.set)?;
        c.seed = self.seed.unwrap_or(c.seed);
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
