//! The `jsae` subcommands and what each one runs.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Subcommand;
use jsae_settings::{EnvName, RunFlags};

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Train on this machine (embedder, learner and actors) and print the summary.
    Train(crate::train_command::TrainArgs),
    /// Print the settings of an environment and algorithm as a settings file, every key with
    /// its explanation above it: the defaults, with `--config` and `--set` laid over them
    /// (what `jsae train` with the same flags would run; feed it back with `--config`).
    Config {
        /// `--env/--algo/--seed/--config/--set`.
        #[command(flatten)]
        run: RunFlags,
    },
    /// Measure PPO update throughput and inference latency on both burn devices, and the
    /// services' ingest rates over loopback gRPC against in-process channels.
    Bench(jsae_bench::BenchArgs),
    /// Run an experiment grid (envs x algos x seeds x setting overrides, from a sweep file)
    /// into one results folder, N runs at a time; finished runs are skipped, so a stopped
    /// sweep goes on when started again. Then `jsae report` the folder.
    Sweep {
        /// The sweep file (TOML; docs/src/experiments.md).
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
    Plot(jsae_report::plot::PlotArgs),
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
    #[command(mut_arg("env", |a| a.help("Environment [default: recommender, the only one \
        it takes]")))]
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
    /// A recommender run judged offline: hit rate@k, NDCG@k, MRR@k and coverage@k on the
    /// held-out sessions and the simulated return, for the learned policy and each reference policy (JSON).
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

/// Runs a `jsae` subcommand.
pub fn run(command: Command) -> ExitCode {
    match command {
        Command::Embedder(args) => {
            return jsae_embedder::service::main(args, jsae_train::logs::logged_items);
        }
        Command::Learner(args) => {
            return jsae_learner::service::main(args, jsae_train::logs::logged_purchases);
        }
        Command::Actor(args) => return jsae_actor::service::main(args),
        Command::Recommender(args) => return jsae_recommender::main(args),
        Command::Health(args) => return crate::health::main(args),
        Command::Recommend(args) => return crate::recommender_client::main(args),
        Command::SubmitSessions(args) => return crate::recommender_client::submit_main(args),
        _ => {}
    }
    jsae_net::logging::init_logging();
    match command {
        Command::Train(args) => crate::train_command::main(&args),
        Command::Bench(args) => jsae_bench::main(args),
        Command::Config { run } => print_config(&run),
        Command::RecommenderBaseline { run, episodes } => recommender_baseline(run, episodes),
        Command::Sweep { file, jobs, out } => crate::experiments::sweep(&file, jobs, &out),
        Command::Eval(args) => crate::eval::main(&args),
        Command::RecordInfo { file } => record_info(&file),
        Command::RecommenderEval(args) => crate::recommender_eval::main(&args),
        Command::Report { dir, out } => {
            crate::experiments::report(&dir, out.as_deref().unwrap_or(&dir))
        }
        Command::Plot(args) => jsae_report::plot::main(&args),
        Command::EnvReplay { env, input, output } => env_replay(env, &input, &output),
        Command::Embedder(_)
        | Command::Learner(_)
        | Command::Actor(_)
        | Command::Recommender(_)
        | Command::Health(_)
        | Command::Recommend(_)
        | Command::SubmitSessions(_) => ExitCode::SUCCESS,
    }
}

/// `jsae config`: the settings the flags make, as a commented settings file.
fn print_config(run: &RunFlags) -> ExitCode {
    let text = run
        .layered()
        .and_then(|c| c.validate().map(|()| c))
        .map_err(|e| e.to_string())
        .and_then(|c| c.to_commented_toml().map_err(|e| e.to_string()));
    match text {
        Ok(text) => {
            print!("{text}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("jsae config: {e}");
            ExitCode::from(2)
        }
    }
}

/// `jsae recommender-baseline`: the reference recommenders' returns, one JSON line each.
fn recommender_baseline(run: RunFlags, episodes: usize) -> ExitCode {
    let run = RunFlags {
        env: Some(
            run.env
                .clone()
                .unwrap_or_else(|| EnvName::Recommender.into()),
        ),
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
    match jsae_recommender::baseline::baselines(&config, episodes.max(1), config.eval_seed()) {
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

/// `jsae record-info`: a recording's summary as JSON.
fn record_info(file: &std::path::Path) -> ExitCode {
    match jsae_record::summarize(file) {
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
    }
}

/// `jsae env-replay`: the Gymnasium parity check's replay of recorded actions.
fn env_replay(env: EnvName, input: &std::path::Path, output: &std::path::Path) -> ExitCode {
    let run = || -> Result<usize, String> {
        let reader = std::fs::File::open(input)
            .map(std::io::BufReader::new)
            .map_err(|e| format!("{}: {e}", input.display()))?;
        let writer = std::fs::File::create(output)
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
