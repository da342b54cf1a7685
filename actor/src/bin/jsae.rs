//! `jsae`: the launcher and tools. `jsae train` runs a whole training on this machine (the
//! embedder, the learner and the actors as separate processes on loopback, or in one process
//! with `--one-process`) and prints its summary; `jsae bench` measures PPO updates and
//! inference on both devices. `jsae embedder|learner|actor` are the services themselves (the
//! same as the `jsae-embedder`, `jsae-learner` and `jsae-actor` binaries), which is how
//! `jsae train` starts them.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use jsae_actor::envs::EnvName;
use jsae_actor::launch;
use jsae_actor::progress::Progress;
use jsae_actor::{Algo, TrainConfig, train_one_process};
use jsae_embedder::nn::DeviceKind;

#[derive(Parser, Debug)]
#[command(name = "jsae", version, about = "JSAE-RL launcher and tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
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
    /// Draw the plots of a run directory (one the services wrote, for example by hand).
    Plot {
        /// The run directory (holding config.toml and metrics.csv).
        #[arg(long)]
        out: PathBuf,
    },
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
    /// Returns of reference recommenders (uniformly random, and the myopic most likely
    /// next item read from the n-gram model) under a run's evaluation protocol.
    RecommenderBaseline {
        /// Settings file (`[environment.recommender]` picks the data).
        #[arg(long, env = "JSAE_CONFIG")]
        config: Option<PathBuf>,
        /// Episodes per policy.
        #[arg(long, default_value_t = 1000)]
        episodes: usize,
        /// Seed (the evaluation seed of a run with this seed is used).
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Ask a service for its gRPC health (exit 0 when SERVING): container healthchecks.
    Health(jsae_actor::health::HealthArgs),
    /// Ask a Recommender for recommendations (prints the answer as JSON).
    Recommend(jsae_actor::recsys::client::AskArgs),
    /// Send sessions from a JSON-lines file to a Recommender's SubmitSessions (prints the
    /// summary as JSON; exit 1 when some were rejected).
    SubmitSessions(jsae_actor::recsys::client::SubmitArgs),
    /// The Recommender gRPC service: recommendations from a live run's or a finished run's
    /// policy, and session submission into the session store.
    Recommender(jsae_actor::recsys::service::RecommenderArgs),
}

#[derive(Args, Debug)]
struct TrainArgs {
    /// Environment [default: gridworld-discrete].
    #[arg(long, value_enum, env = "JSAE_ENV")]
    env: Option<EnvName>,
    /// Algorithm [default: jsae].
    #[arg(long, value_enum, env = "JSAE_ALGO")]
    algo: Option<Algo>,
    /// Seed [default: 1].
    #[arg(long, env = "JSAE_SEED")]
    seed: Option<u64>,
    /// Env steps of the whole run [default: 500000].
    #[arg(long, env = "JSAE_ENV_STEPS")]
    env_steps: Option<u64>,
    /// Actor workers [default: 1].
    #[arg(long, env = "JSAE_ACTORS")]
    actors: Option<usize>,
    /// Environments per actor [default: 16].
    #[arg(long, env = "JSAE_ENVS")]
    envs: Option<usize>,
    /// Run directory [default: runs/ENV-ALGO-seedN].
    #[arg(long, env = "JSAE_OUT")]
    out: Option<PathBuf>,
    /// TOML file with any settings (see config.toml of a run for every key).
    #[arg(long, env = "JSAE_CONFIG")]
    config: Option<PathBuf>,
    /// burn device [default: flex].
    #[arg(long, value_enum, env = "JSAE_DEVICE")]
    device: Option<DeviceKind>,
    /// Deterministic evaluation episodes at the end [default: 20].
    #[arg(long, env = "JSAE_EVAL_EPISODES")]
    eval_episodes: Option<usize>,
    /// Run every component in this process, in lockstep (deterministic for a seed) instead
    /// of as separate service processes talking gRPC over loopback.
    #[arg(long)]
    one_process: bool,
    /// No progress output.
    #[arg(long)]
    quiet: bool,
}

fn build_config(a: &TrainArgs) -> Result<TrainConfig, String> {
    let mut c =
        TrainConfig::from_layers(a.env, a.algo, a.config.as_deref()).map_err(|e| e.to_string())?;
    c.seed = a.seed.unwrap_or(c.seed);
    c.env_steps = a.env_steps.unwrap_or(c.env_steps);
    c.actors = a.actors.unwrap_or(c.actors);
    c.envs_per_actor = a.envs.unwrap_or(c.envs_per_actor);
    c.device = a.device.unwrap_or(c.device);
    c.eval_episodes = a.eval_episodes.unwrap_or(c.eval_episodes);
    c.one_process |= a.one_process;
    if let Some(out) = &a.out {
        c.out = out.clone();
    }
    if c.out.as_os_str().is_empty() {
        c.out = PathBuf::from(format!(
            "runs/{}-{}-seed{}",
            c.env.as_str(),
            c.algo.as_str(),
            c.seed
        ));
    }
    c.validate().map_err(|e| e.to_string())?;
    Ok(c)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Embedder(args) => return jsae_embedder::service::main(args),
        Command::Learner(args) => return jsae_learner::service::main(args),
        Command::Actor(args) => return jsae_actor::service::main(args),
        Command::Recommender(args) => return jsae_actor::recsys::service::main(args),
        Command::Health(args) => return jsae_actor::health::main(args),
        Command::Recommend(args) => return jsae_actor::recsys::client::main(args),
        Command::SubmitSessions(args) => return jsae_actor::recsys::client::submit_main(args),
        _ => {}
    }
    jsae_proto::net::init_logging();
    match cli.command {
        Command::Train(args) => {
            let config = match build_config(&args) {
                Ok(c) => c,
                Err(reason) => {
                    eprintln!("jsae train: {reason}");
                    return ExitCode::from(2);
                }
            };
            let mut progress = Progress::new(config.env_steps, args.quiet);
            let outcome = if config.one_process {
                train_one_process(&config, &mut progress)
            } else {
                launch::current_exe()
                    .and_then(|exe| launch::train_processes(&config, &exe, &mut progress))
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
            mujoco,
            recommender,
            envs,
        } => {
            if recommender {
                print!("{}", jsae_actor::bench_recommender::run(quick));
                return ExitCode::SUCCESS;
            }
            if mujoco {
                print!("{}", jsae_actor::bench_mujoco::run(envs.max(1), quick));
                return ExitCode::SUCCESS;
            }
            if !transport {
                print!("{}", jsae_actor::bench::run(quick));
            }
            print!("{}", jsae_actor::bench_transport::run(quick));
            ExitCode::SUCCESS
        }
        Command::RecommenderBaseline {
            config,
            episodes,
            seed,
        } => {
            let config =
                TrainConfig::from_layers(Some(EnvName::Recommender), None, config.as_deref())
                    .map_err(|e| e.to_string())
                    .and_then(|mut c| {
                        c.seed = seed;
                        c.validate().map(|()| c).map_err(|e| e.to_string())
                    });
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
            match jsae_actor::recsys::baseline::baselines(
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
        Command::Plot { out } => {
            let config = match TrainConfig::from_layers(None, None, Some(&out.join("config.toml")))
            {
                Ok(c) => c,
                Err(e) => {
                    eprintln!("jsae plot: {e}");
                    return ExitCode::from(2);
                }
            };
            match jsae_actor::plot::plot_run_dir(&out, &config) {
                Ok(paths) => {
                    for p in paths {
                        println!("plot: {}", p.display());
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("jsae plot: {}: {e}", out.display());
                    ExitCode::FAILURE
                }
            }
        }
        Command::EnvReplay { env, input, output } => {
            let run = || -> Result<usize, String> {
                let reader = std::fs::File::open(&input)
                    .map(std::io::BufReader::new)
                    .map_err(|e| format!("{}: {e}", input.display()))?;
                let writer = std::fs::File::create(&output)
                    .map(std::io::BufWriter::new)
                    .map_err(|e| format!("{}: {e}", output.display()))?;
                jsae_actor::replay::replay(env, reader, writer).map_err(|e| e.to_string())
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
