//! The `jsae` subcommands and what each one runs.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Subcommand};
use jsae_nn::DeviceKind;
use jsae_proto::run_dir::{RunDir, Weights};
use jsae_proto::settings::{EnvName, RunFlags, TrainConfig};

use crate::launch;
use crate::progress::Progress;
use crate::train::{RunOptions, train_one_process_with};

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Train on this machine (embedder, learner and actors) and print the summary.
    Train(TrainArgs),
    /// Measure PPO update throughput and inference latency on both burn devices, and the
    /// services' ingest rates over loopback gRPC against in-process channels.
    Bench {
        /// Fewer repetitions (a smoke run).
        #[arg(long)]
        quick: bool,
        /// Only the transport measurements.
        #[arg(long)]
        transport: bool,
        /// Only the PPO update: time per 2,048 samples for each policy head on the old
        /// (burn) and the new (fused) path, achieved GFLOP/s beside a GEMM peak measured in
        /// the same run.
        #[arg(long)]
        learner: bool,
        /// Only end-to-end HalfCheetah PPO env-steps/s with 1 and 2 actors (4 where there
        /// are cores) sharing one batch, beside raw env stepping measured in the same run.
        #[arg(long)]
        scaling: bool,
        /// Only the MuJoCo stepping measurements (HalfCheetah and Ant: raw mujoco-rs, our
        /// env, the actor with batched inference, Gymnasium).
        #[arg(long)]
        mujoco: bool,
        /// Only the Recommender service's latency (p50, p99) and throughput at concurrency
        /// 64 over loopback gRPC.
        #[arg(long)]
        recommender: bool,
        /// Environments per actor in the MuJoCo actor measurement.
        #[arg(long, default_value_t = 16)]
        envs: usize,
    },
    /// Run an experiment grid (envs x algos x seeds x setting overrides, from a sweep file)
    /// into one results folder, N runs at a time; finished runs are skipped, so a stopped
    /// sweep goes on when started again. Then `jsae report` the folder.
    Sweep {
        /// The sweep file (TOML; README: Experiments).
        file: PathBuf,
        /// Runs at a time [default: the machine's cores].
        #[arg(long)]
        jobs: Option<usize>,
        /// The results folder.
        #[arg(long)]
        out: PathBuf,
    },
    /// Summarise a results folder over seeds: mean with a 95% bootstrap interval, IQM, steps
    /// to the sweep's threshold, wall time; writes report.md, report.json and figures/.
    Report {
        /// The results folder (of `jsae sweep`).
        dir: PathBuf,
        /// Where report.md, report.json and figures/ go [default: DIR].
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Summarise a recording (`--record`): transitions per actor, episodes, versions, the
    /// run it came from (JSON).
    RecordInfo {
        /// The MCAP file.
        file: PathBuf,
    },
    /// Evaluate a run's newest checkpoints (or a given policy checkpoint) with the
    /// deterministic and the sampled policy; prints JSON.
    Eval(crate::eval::EvalArgs),
    /// Draw the plots of run directories as SVG and PNG (of runs the services wrote, for
    /// example by hand), and with several runs one figure of them all (mean and band).
    Plot(crate::plot::PlotArgs),
    /// Replay an initial state and actions through a MuJoCo environment (parity check).
    EnvReplay {
        /// half-cheetah or ant.
        #[arg(long, value_enum)]
        env: EnvName,
        /// JSON lines: `{"qpos": [...], "qvel": [...]}`, then `{"action": [...]}` per step.
        #[arg(long)]
        input: PathBuf,
        /// JSON lines written: `{"obs": [...], "reward": r, "terminated": b}` per step.
        #[arg(long)]
        output: PathBuf,
    },
    /// The embedder service (as `jsae-embedder`).
    Embedder(jsae_embedder::service::EmbedderArgs),
    /// The learner service (as `jsae-learner`).
    Learner(jsae_learner::service::LearnerArgs),
    /// An actor (as `jsae-actor`).
    Actor(jsae_actor::service::ActorArgs),
    /// Returns of reference recommenders (uniformly random, the most popular item, and the
    /// myopic most likely next item read from the n-gram model) under a run's evaluation
    /// protocol: the evaluation seed of a run with `--seed N`, the data of the settings
    /// file's `[environment.recommender]`.
    RecommenderBaseline {
        /// `--env/--algo/--seed/--config` (the environment must be the recommender; the
        /// settings file's `[environment.recommender]` picks the data; the evaluation seed of
        /// a run with this seed is used).
        #[command(flatten)]
        run: RunFlags,
        /// Episodes per policy.
        #[arg(long, default_value_t = 1000)]
        episodes: usize,
    },
    /// A recommender run judged offline: hit rate@k and NDCG@k on the held-out sessions and
    /// the simulated return, for the learned policy and each reference policy (JSON).
    RecommenderEval(crate::recommender_eval::RecommenderEvalArgs),
    /// Ask a service for its gRPC health (exit 0 when SERVING): container healthchecks.
    Health(crate::health::HealthArgs),
    /// Ask a Recommender for recommendations (prints the answer as JSON).
    Recommend(crate::recommender_client::AskArgs),
    /// Send sessions from a JSON-lines file to a Recommender's SubmitSessions (prints the
    /// summary as JSON; exit 1 when some were rejected).
    SubmitSessions(crate::recommender_client::SubmitArgs),
    /// The Recommender gRPC service: recommendations from a live run's or a finished run's
    /// policy, and session submission into the session store. The settings are `--config`,
    /// else the `--run` directory's config.toml; `--env`, if given, must be recommender;
    /// `--embedder` is needed with `--learner` for `--algo jsae`.
    Recommender(jsae_recommender::RecommenderArgs),
}

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// `--env/--algo/--seed/--config`.
    #[command(flatten)]
    pub run: RunFlags,
    /// Env steps of the whole run [default: the settings file's, else the environment's:
    /// 500000; 1000000 for half-cheetah and ant; 300000 for the recommender].
    #[arg(long, env = "JSAE_ENV_STEPS")]
    pub env_steps: Option<u64>,
    /// Actor workers [default: 1].
    #[arg(long, env = "JSAE_ACTORS")]
    pub actors: Option<usize>,
    /// Environments per actor [default: 16].
    #[arg(long, env = "JSAE_ENVS")]
    pub envs: Option<usize>,
    /// Run directory [default: runs/ENV-ALGO-seedN].
    #[arg(long, env = "JSAE_OUT")]
    pub out: Option<PathBuf>,
    /// burn device [default: flex].
    #[arg(long, value_enum, env = "JSAE_DEVICE")]
    pub device: Option<DeviceKind>,
    /// Deterministic evaluation episodes at the end [default: the settings file's, else 20;
    /// 200 for the recommender].
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
    let absolute =
        |p: &PathBuf| std::path::absolute(p).map_err(|e| format!("{}: {e}", p.display()));
    Ok(RunOptions {
        record: a.record.as_ref().map(absolute).transpose()?,
        pretrain_from: a.pretrain_from.as_ref().map(absolute).transpose()?,
        resume: a.resume.is_some(),
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
        let done = serde_json::from_str::<jsae_learner::Summary>(&text)
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
    c.init_source().map_err(|e| e.to_string())?;
    Ok(c)
}

/// Runs a `jsae` subcommand.
pub fn run(command: Command) -> ExitCode {
    match command {
        Command::Embedder(args) => return jsae_embedder::service::main(args),
        Command::Learner(args) => {
            return jsae_learner::service::main(args, jsae_recommender::logged_purchases);
        }
        Command::Actor(args) => return jsae_actor::service::main(args),
        Command::Recommender(args) => return jsae_recommender::main(args),
        Command::Health(args) => return crate::health::main(args),
        Command::Recommend(args) => return crate::recommender_client::main(args),
        Command::SubmitSessions(args) => return crate::recommender_client::submit_main(args),
        _ => {}
    }
    jsae_proto::logging::init_logging();
    match command {
        Command::Train(args) => {
            let built = build_config(&args)
                .and_then(|c| run_files(&args, &c).map(|files| (c, files)))
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
        Command::Bench {
            quick,
            transport,
            learner,
            scaling,
            mujoco,
            recommender,
            envs,
        } => {
            if scaling {
                print!("{}", crate::bench::scaling::run(quick));
                return ExitCode::SUCCESS;
            }
            if learner {
                print!("{}", crate::bench::learner::run(quick));
                return ExitCode::SUCCESS;
            }
            if recommender {
                print!("{}", crate::bench::recommender::run(quick));
                return ExitCode::SUCCESS;
            }
            if mujoco {
                print!("{}", crate::bench::mujoco::run(envs.max(1), quick));
                return ExitCode::SUCCESS;
            }
            if !transport {
                print!("{}", crate::bench::run(quick));
            }
            print!("{}", crate::bench::transport::run(quick));
            ExitCode::SUCCESS
        }
        Command::RecommenderBaseline { run, episodes } => {
            let run = RunFlags {
                env: Some(run.env.unwrap_or(EnvName::Recommender)),
                ..run
            };
            let config = run
                .layered()
                .and_then(|c| c.validate().map(|()| c))
                .map_err(|e| e.to_string());
            let config = match config {
                Ok(c) if c.env == EnvName::Recommender => c,
                Ok(c) => {
                    eprintln!(
                        "jsae recommender-baseline: the settings are for --env {}",
                        c.env.as_str()
                    );
                    return ExitCode::from(2);
                }
                Err(e) => {
                    eprintln!("jsae recommender-baseline: {e}");
                    return ExitCode::from(2);
                }
            };
            match jsae_recommender::baseline::baselines(
                &config,
                episodes.max(1),
                config.eval_seed(),
            ) {
                Ok(all) => {
                    for b in all {
                        println!("{}", serde_json::to_string(&b).unwrap_or_default());
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("jsae recommender-baseline: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::Sweep { file, jobs, out } => crate::experiments::sweep(&file, jobs, &out),
        Command::Eval(args) => crate::eval::main(&args),
        Command::RecordInfo { file } => match jsae_record::summarize(&file) {
            Ok(summary) => {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&summary).unwrap_or_default()
                );
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("jsae record-info: {e}");
                ExitCode::from(2)
            }
        },
        Command::RecommenderEval(args) => crate::recommender_eval::main(&args),
        Command::Report { dir, out } => {
            crate::experiments::report(&dir, out.as_deref().unwrap_or(&dir))
        }
        Command::Plot(args) => crate::plot::main(&args),
        Command::EnvReplay { env, input, output } => {
            let run = || -> Result<usize, String> {
                let reader = std::fs::File::open(&input)
                    .map(std::io::BufReader::new)
                    .map_err(|e| format!("{}: {e}", input.display()))?;
                let writer = std::fs::File::create(&output)
                    .map(std::io::BufWriter::new)
                    .map_err(|e| format!("{}: {e}", output.display()))?;
                crate::replay::replay(env, reader, writer).map_err(|e| e.to_string())
            };
            match run() {
                Ok(_) => ExitCode::SUCCESS,
                Err(reason) => {
                    eprintln!("jsae env-replay: {reason}");
                    ExitCode::from(2)
                }
            }
        }
        Command::Embedder(_)
        | Command::Learner(_)
        | Command::Actor(_)
        | Command::Recommender(_)
        | Command::Health(_)
        | Command::Recommend(_)
        | Command::SubmitSessions(_) => ExitCode::SUCCESS,
    }
}
