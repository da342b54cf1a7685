//! `jsae-learner`: the learner service. Its command line is fixed by CONTRACT.md; serving
//! over gRPC arrives with the services issue, until then `jsae train` runs it in-process.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;

#[derive(Parser, Debug)]
#[command(
    name = "jsae-learner",
    version,
    about = "JSAE-RL learner: PPO on embedded tuples, publishes policy snapshots"
)]
struct Cli {
    /// Address to listen on.
    #[arg(long, env = "JSAE_LISTEN")]
    listen: String,
    /// Embedder URL.
    #[arg(long, env = "JSAE_EMBEDDER")]
    embedder: String,
    /// Environment.
    #[arg(long, env = "JSAE_ENV")]
    env: String,
    /// Algorithm.
    #[arg(long, env = "JSAE_ALGO")]
    algo: String,
    /// Seed.
    #[arg(long, env = "JSAE_SEED")]
    seed: u64,
    /// Env steps of the run.
    #[arg(long, env = "JSAE_ENV_STEPS")]
    env_steps: u64,
    /// Run directory.
    #[arg(long, env = "JSAE_OUT")]
    out: PathBuf,
    /// Settings file.
    #[arg(long, env = "JSAE_CONFIG")]
    config: Option<PathBuf>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    eprintln!(
        "jsae-learner: the gRPC transport is not available yet; `jsae train --env {}` runs the learner in-process",
        cli.env
    );
    ExitCode::FAILURE
}
