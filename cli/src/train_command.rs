//! `jsae train`: its arguments, the settings and the run directory they give (a fresh run's
//! directory claimed, a stopped run's settings for `--resume`), and the run itself, in this
//! process or as service processes.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use jsae_net::security::SecurityFlags;
use jsae_nn::DeviceKind;
use jsae_run_dir::{RunDir, Weights};
use jsae_settings::{RunFlags, TrainConfig};

use jsae_train::launch;
use jsae_train::progress::Progress;
use jsae_train::{RunOptions, train_one_process_with};

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// `--env/--algo/--seed/--config`.
    #[command(flatten)]
    pub run: RunFlags,
    /// Env steps of the whole run [default: the settings file's, else the environment and
    /// algorithm's: `jsae config --env E --algo A` prints them all].
    #[arg(long, env = "JSAE_ENV_STEPS")]
    pub env_steps: Option<u64>,
    /// Actor workers [default: the settings file's, else 1].
    #[arg(long, env = "JSAE_ACTORS")]
    pub actors: Option<usize>,
    /// Environments per actor [default: the settings file's, else the environment and
    /// algorithm's (`envs_per_actor` in `jsae config`)].
    #[arg(long, env = "JSAE_ENVS")]
    pub envs: Option<usize>,
    /// Run directory [default: runs/ENV-ALGO-seedN].
    #[arg(long, env = "JSAE_OUT")]
    pub out: Option<PathBuf>,
    /// burn device [default: flex].
    #[arg(long, env = "JSAE_DEVICE", value_parser = jsae_settings::device_parser())]
    pub device: Option<DeviceKind>,
    /// Deterministic evaluation episodes at the end [default: the settings file's, else the
    /// environment's (`eval_episodes` in `jsae config`)].
    #[arg(long, env = "JSAE_EVAL_EPISODES")]
    pub eval_episodes: Option<usize>,
    /// Run every component in this process, in lockstep (deterministic for a seed) instead
    /// of as separate service processes talking gRPC over loopback.
    #[arg(long)]
    pub one_process: bool,
    /// A finished run (same env and algorithm, same embedding widths) to warm-start from:
    /// its policy and the embedding parts whose shapes match (phi, T; g only with the same
    /// action count).
    #[arg(long, env = "JSAE_INIT_FROM")]
    pub init_from: Option<PathBuf>,
    /// Record every transition the actors step into this MCAP file (protobuf messages with
    /// their schema inside; replaced if it exists). With several actors as separate
    /// processes, actor K writes STEM-actor-K.mcap beside it.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// Pre-train the embedding (phi, g, T, f) on the first transitions of this recording
    /// instead of fresh random play (jsae, ae and ra).
    #[arg(long, value_name = "FILE.mcap")]
    pub pretrain_from: Option<PathBuf>,
    /// Continue the stopped (or finished, with a larger --env-steps) run in DIR from its
    /// config.toml and its latest checkpoints; metrics.csv and the step count go on.
    #[arg(long, value_name = "DIR")]
    pub resume: Option<PathBuf>,
    /// Start a fresh run in a directory that holds one: remove the old run's files first
    /// (config, metrics, summary, checkpoints, logs, TensorBoard files, plots; nothing else).
    #[arg(long)]
    pub force: bool,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
    /// `--auth-token-file`, `--tls-*`: handed to the service processes (with
    /// `--one-process` nothing travels over the network and they are not read).
    #[command(flatten)]
    pub security: SecurityFlags,
}

/// The files `jsae train` records into and pre-trains from, checked before anything runs.
fn run_files(a: &TrainArgs, config: &TrainConfig) -> Result<RunOptions, String> {
    if let Some(path) = &a.pretrain_from {
        if !config.algo.representation().needs_embedder() {
            return Err(format!(
                "--pretrain-from: --algo {} trains no embedding",
                config.algo.as_str()
            ));
        }
        if !path.is_file() {
            return Err(format!("--pretrain-from {}: no such file", path.display()));
        }
    }
    if !config.one_process {
        launch::check_security(&a.security).map_err(|e| e.to_string())?;
    }
    let absolute =
        |p: &PathBuf| std::path::absolute(p).map_err(|e| format!("{}: {e}", p.display()));
    Ok(RunOptions {
        record: a.record.as_ref().map(absolute).transpose()?,
        pretrain_from: a.pretrain_from.as_ref().map(absolute).transpose()?,
        resume: a.resume.is_some(),
        security: a.security.clone(),
    })
}

/// A fresh run's directory: refused when it holds anything unless `force`, which removes the
/// old run's files (checked last, so a mistyped flag never costs an old run).
fn claim_run_dir(config: &TrainConfig, force: bool) -> Result<(), String> {
    let run = RunDir::new(&config.out);
    if !run.is_occupied() {
        return Ok(());
    }
    if !force {
        return Err(format!(
            "{} is not empty (an earlier run?); pass --force to replace that run, --resume {} \
             to continue it, or another --out",
            config.out.display(),
            config.out.display()
        ));
    }
    run.clear_run()
        .map_err(|e| format!("--force: cannot clear {}: {e}", config.out.display()))
}

/// The settings `jsae train --resume DIR` goes on with: DIR's config.toml, with another
/// --env-steps, --device or --eval-episodes where given; flags that would make it another
/// run are refused. A finished run is reopened only for more env steps than it took.
fn resume_config(a: &TrainArgs, dir: &std::path::Path) -> Result<TrainConfig, String> {
    // (a flag's environment variable counts as the flag: the message names both)
    let other_run = [
        ("--env (or JSAE_ENV)", a.run.env.is_some()),
        ("--algo (or JSAE_ALGO)", a.run.algo.is_some()),
        ("--seed (or JSAE_SEED)", a.run.seed.is_some()),
        ("--config (or JSAE_CONFIG)", a.run.config.is_some()),
        ("--actors (or JSAE_ACTORS)", a.actors.is_some()),
        ("--envs (or JSAE_ENVS)", a.envs.is_some()),
        ("--out (or JSAE_OUT)", a.out.is_some()),
        ("--init-from (or JSAE_INIT_FROM)", a.init_from.is_some()),
        ("--pretrain-from", a.pretrain_from.is_some()),
        ("--force", a.force),
    ];
    if let Some((flag, _)) = other_run.iter().find(|(_, given)| *given) {
        return Err(format!(
            "--resume goes on with the run's own settings ({}); {flag} cannot change them",
            dir.display()
        ));
    }
    let run = RunDir::new(dir);
    if !run.config_toml().is_file() {
        return Err(format!(
            "--resume {}: no config.toml there, so no run to resume",
            dir.display()
        ));
    }
    let mut c = TrainConfig::from_layers(None, None, Some(&run.config_toml()))
        .map_err(|e| e.to_string())?;
    // a run's config.toml names `batch_envs` only where it was set: one without it ran with
    // the growing batch (runs from before the gridworld's shared default have none), so it
    // goes on with it rather than taking today's default
    let text = std::fs::read_to_string(run.config_toml()).map_err(|e| e.to_string())?;
    if text
        .parse::<toml::Table>()
        .is_ok_and(|t| !t.contains_key("batch_envs"))
    {
        c.batch_envs = None;
    }
    c.out = dir.to_path_buf();
    c.env_steps = a.env_steps.unwrap_or(c.env_steps);
    c.device = a.device.unwrap_or(c.device);
    c.eval_episodes = a.eval_episodes.unwrap_or(c.eval_episodes);
    c.one_process |= a.one_process;
    c.validate().map_err(|e| e.to_string())?;
    if run.checkpoints().read_latest(Weights::Policy).is_none() {
        return Err(format!(
            "--resume {}: no policy checkpoint ({}) to go on from",
            dir.display(),
            run.checkpoints().latest(Weights::Policy).display()
        ));
    }
    if let Ok(text) = std::fs::read_to_string(run.summary_json()) {
        let done = serde_json::from_str::<jsae_run_dir::Summary>(&text)
            .map(|s| s.env_steps)
            .map_err(|e| format!("{}: {e}", run.summary_json().display()))?;
        if c.env_steps <= done {
            return Err(format!(
                "--resume {}: the run finished at {done} env steps; pass a larger --env-steps \
                 to train on",
                dir.display()
            ));
        }
        std::fs::remove_file(run.summary_json())
            .map_err(|e| format!("{}: {e}", run.summary_json().display()))?;
    }
    Ok(c)
}

/// The settings `jsae train` runs with: the run flags' layers, then the other flags.
fn build_config(a: &TrainArgs) -> Result<TrainConfig, String> {
    if let Some(dir) = &a.resume {
        return resume_config(a, dir);
    }
    let mut c = a.run.layered().map_err(|e| e.to_string())?;
    c.env_steps = a.env_steps.unwrap_or(c.env_steps);
    c.actors = a.actors.unwrap_or(c.actors);
    c.envs_per_actor = a.envs.unwrap_or(c.envs_per_actor);
    c.device = a.device.unwrap_or(c.device);
    c.eval_episodes = a.eval_episodes.unwrap_or(c.eval_episodes);
    c.one_process |= a.one_process;
    if let Some(run) = &a.init_from {
        c.init_from = Some(run.clone());
    }
    if let Some(out) = &a.out {
        c.out = out.clone();
    }
    if c.out.as_os_str().is_empty() {
        c.out = RunDir::default_path(c.env, c.algo, c.seed);
    }
    c.validate().map_err(|e| e.to_string())?;
    // the warm start's run is read and checked before any service starts
    jsae_run_dir::init_source(&c).map_err(|e| e.to_string())?;
    Ok(c)
}

/// Runs `jsae train`: exit 0 with the summary printed, 2 for bad input, 1 when the run fails.
pub fn main(args: &TrainArgs) -> ExitCode {
    let built = build_config(args)
        .and_then(|c| run_files(args, &c).map(|files| (c, files)))
        .and_then(|(c, files)| {
            if !files.resume {
                claim_run_dir(&c, args.force)?;
            }
            Ok((c, files))
        });
    let (config, files) = match built {
        Ok(c) => c,
        Err(reason) => {
            eprintln!("jsae train: {reason}");
            return ExitCode::from(2);
        }
    };
    let mut progress = Progress::new(config.env_steps, args.quiet);
    let outcome = if config.one_process {
        train_one_process_with(&config, &files, &mut progress)
    } else {
        launch::current_exe()
            .and_then(|exe| launch::train_processes(&config, &files, &exe, &mut progress))
    };
    match outcome {
        Ok(outcome) => {
            let json = serde_json::to_string_pretty(&outcome.summary).unwrap_or_default();
            println!("{json}");
            println!("run directory: {}", outcome.dir.display());
            for p in &outcome.plots {
                println!("plot: {}", p.display());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("jsae train: {e}");
            ExitCode::FAILURE
        }
    }
}
