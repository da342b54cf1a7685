//! `jsae recommender`: the command line, the settings it serves with, and the process's main.

use std::path::PathBuf;
use std::sync::Arc;

use jsae_net::security::{Security, SecurityFlags};
use jsae_net::{self as net, Failure};
use jsae_nn::DeviceKind;
use jsae_run_dir::RunDir;
use jsae_settings::{EmbedderFlag, EnvName, RunFlags, TrainConfig};

use crate::baseline::PolicyChoice;
use crate::grpc::serve;
use crate::scoring::Recommender;
use crate::sources::{RUN_POLL, WeightSources};

/// The recommender's command line.
#[derive(Debug, Clone, clap::Args)]
pub struct RecommenderArgs {
    /// Address to serve on (port 0: any free port; the first stdout line says which).
    #[arg(long, env = "JSAE_LISTEN", default_value = "127.0.0.1:50060")]
    pub listen: String,
    /// Learner URL to follow for policy snapshots (`http://host:port`, `https://` with
    /// --tls-ca).
    #[arg(long, env = "JSAE_LEARNER")]
    pub learner: Option<String>,
    /// `--embedder`: the embedder to follow with `--learner`.
    #[command(flatten)]
    pub embedder: EmbedderFlag,
    /// A finished run directory: its config.toml and latest checkpoints are used.
    #[arg(long, env = "JSAE_RUN")]
    pub run: Option<PathBuf>,
    /// `--env/--algo/--seed/--config` (the environment must be the recommender; the settings
    /// file's `[environment.recommender]` picks the data; `--run` gives its config.toml).
    #[command(flatten)]
    pub flags: RunFlags,
    /// Session store directory: submitted sessions are appended there, and the n-gram
    /// model is rebuilt from it [default: the settings', else sessions are checked but not
    /// kept].
    #[arg(long, env = "JSAE_STORE_DIR")]
    pub store_dir: Option<PathBuf>,
    /// What to serve: the run's policy, or a reference policy that reads the n-gram model
    /// (needs no run: `--env recommender` or `--config` give the data) for A/B tests.
    #[arg(long, value_enum, env = "JSAE_POLICY", default_value = "learned")]
    pub policy: PolicyChoice,
    /// burn device [default: flex].
    #[arg(long, env = "JSAE_DEVICE", value_parser = jsae_settings::device_parser())]
    pub device: Option<DeviceKind>,
    /// With `--run`: wait for a run directory that has no config.toml yet (a run still
    /// starting) instead of exiting with code 2.
    #[arg(long, env = "JSAE_WAIT")]
    pub wait: bool,
    /// `--metrics-listen`.
    #[command(flatten)]
    pub metrics: jsae_telemetry::MetricsFlag,
    /// `--auth-token-file`, `--tls-*`.
    #[command(flatten)]
    pub security: SecurityFlags,
}

impl RecommenderArgs {
    /// The settings file: `--config`, else the run directory's config.toml.
    fn settings_file(&self) -> Option<PathBuf> {
        match (&self.flags.config, &self.run) {
            (Some(f), _) => Some(f.clone()),
            (None, Some(run)) => Some(RunDir::new(run).config_toml()),
            (None, None) => None,
        }
    }
}

fn config_of(args: &RecommenderArgs, security: &Security) -> Result<TrainConfig, String> {
    let flags = RunFlags {
        env: Some(
            args.flags
                .env
                .clone()
                .unwrap_or_else(|| EnvName::Recommender.into()),
        ),
        config: args.settings_file(),
        ..args.flags.clone()
    };
    // a run of another environment has no recommender policy to serve
    if let (Some(run), None) = (&args.run, &args.flags.config) {
        let theirs = TrainConfig::from_layers(None, None, Some(&RunDir::new(run).config_toml()))
            .map_err(|e| e.to_string())?;
        if theirs.env != EnvName::Recommender {
            return Err(format!(
                "--run {}: a {} run, not a recommender run",
                run.display(),
                theirs.env.as_str()
            ));
        }
    }
    let mut c = flags.layered().map_err(|e| e.to_string())?;
    if c.env != EnvName::Recommender {
        return Err(format!(
            "the settings are for --env {}, not recommender",
            c.env.as_str()
        ));
    }
    if let Some(dir) = &args.store_dir {
        c.environment.recommender.store_dir = dir.clone();
    }
    c.device = args.device.unwrap_or(c.device);
    c.validate().map_err(|e| e.to_string())?;
    if args.policy.reference().is_some() {
        if args.learner.is_some() {
            return Err(format!(
                "--policy {} reads the n-gram model: it takes no --learner",
                args.policy.reference().map_or("", |r| r.name())
            ));
        }
        return Ok(c);
    }
    if args.learner.is_none() && args.run.is_none() {
        return Err(
            "give --learner URL (follow a run) or --run DIR (a finished run), or serve a \
             reference policy (--policy most-likely|item-knn|popular)"
                .into(),
        );
    }
    if let Some(url) = &args.learner {
        security.check_url("--learner", url)?;
        args.embedder
            .for_run(&c, |flag, url| security.check_url(flag, url))
            .map_err(|e| format!("{e} with --learner"))?;
    }
    Ok(c)
}

/// Runs the recommender service: exit 0 on SIGINT/SIGTERM, 2 for a bad configuration, 1 when
/// it fails. With `--run DIR --wait` it waits for the run's config.toml (a run still
/// starting); without `--wait` a directory without one is refused.
pub fn main(args: RecommenderArgs) -> std::process::ExitCode {
    let security = args.security.load().map(|s| (args, s));
    net::service_main(
        "jsae recommender",
        security,
        |(args, security), mut shutdown| async move {
            if let (Some(file), None) = (args.settings_file(), &args.flags.config) {
                if !file.exists() && !args.wait {
                    return Err(Failure::config(format!(
                        "--run: {} does not exist (not a run directory; --wait waits for a \
                         run still starting)",
                        file.display()
                    )));
                }
                if !file.exists() {
                    tracing::info!("recommender: waiting for {}", file.display());
                }
                while !file.exists() {
                    tokio::select! {
                        () = &mut shutdown => return Ok(()),
                        () = tokio::time::sleep(RUN_POLL) => {}
                    }
                }
            }
            let config = config_of(&args, &security).map_err(Failure::config)?;
            let rec =
                Recommender::new(&config, args.policy, config.device).map_err(Failure::config)?;
            if !rec.has_store() {
                tracing::warn!(
                    "recommender: no session store (--store-dir): sessions are not kept"
                );
            }
            let learned = args.policy == PolicyChoice::Learned;
            let sources = WeightSources {
                learner: args.learner.clone().filter(|_| learned),
                embedder: args.embedder.embedder.clone().filter(|_| learned),
                run: args.run.clone().filter(|_| learned),
            };
            let listener = net::bind(&args.listen).await?;
            let mut registry = jsae_telemetry::MetricsRegistry::default();
            let metrics = jsae_telemetry::RecommenderMetrics::register(&mut registry);
            jsae_telemetry::serve(&args.metrics, registry).await?;
            jsae_net::logging::announce_listening("jsae recommender", listener.local_addr()?);
            let rec = Arc::new(rec);
            Ok(serve(rec, listener, sources, metrics, security, shutdown).await?)
        },
        |()| {},
    )
}
