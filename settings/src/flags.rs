//! The run flags every command that trains, serves or evaluates a run takes: `--env`,
//! `--algo`, `--seed` and `--config`, with their environment variables. One struct,
//! flattened into each command's arguments, so they read the same everywhere.

use std::path::PathBuf;

use super::{Algo, ConfigError, DeviceKind, EnvName, TrainConfig};

/// `--env/--algo/--seed/--config`.
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
}

impl RunFlags {
    /// The settings these flags give: the defaults of the environment and algorithm, the
    /// settings file over them, then the seed. Not validated: a command sets its own flags
    /// first and then calls [`TrainConfig::validate`].
    pub fn layered(&self) -> Result<TrainConfig, ConfigError> {
        let mut c = TrainConfig::from_layers(self.env, self.algo, self.config.as_deref())?;
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
