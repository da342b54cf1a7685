//! `jsae-actor`: the actor service. Its command line is fixed by CONTRACT.md; serving over
//! gRPC arrives with the services issue, until then `jsae train` runs actors in-process.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use jsae_actor::envs::EnvName;

#[derive(Parser, Debug)]
#[command(
    name = "jsae-actor",
    version,
    about = "JSAE-RL actor: steps environments, streams transitions and fragments"
)]
struct Cli {
    /// Embedder URL.
    #[arg(long, env = "JSAE_EMBEDDER")]
    embedder: String,
    /// Learner URL.
    #[arg(long, env = "JSAE_LEARNER")]
    learner: String,
    /// Environment.
    #[arg(long, value_enum, env = "JSAE_ENV")]
    env: EnvName,
    /// Seed.
    #[arg(long, env = "JSAE_SEED")]
    seed: u64,
    /// Environments stepped together.
    #[arg(long, env = "JSAE_ENVS", default_value_t = 16)]
    envs: usize,
    /// Settings file.
    #[arg(long, env = "JSAE_CONFIG")]
    config: Option<PathBuf>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    eprintln!(
        "jsae-actor: the gRPC transport is not available yet; `jsae train --env {}` runs actors in-process",
        cli.env.as_str()
    );
    ExitCode::FAILURE
}
