//! `jsae-embedder`: the embedder service. Its command line is fixed by CONTRACT.md; serving
//! over gRPC arrives with the services issue, until then `jsae train` runs it in-process.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;

#[derive(Parser, Debug)]
#[command(
    name = "jsae-embedder",
    version,
    about = "JSAE-RL embedder: trains phi/g/T/f and publishes snapshots"
)]
struct Cli {
    /// Address to listen on.
    #[arg(long, env = "JSAE_LISTEN")]
    listen: String,
    /// Environment.
    #[arg(long, env = "JSAE_ENV")]
    env: String,
    /// Algorithm.
    #[arg(long, env = "JSAE_ALGO")]
    algo: String,
    /// Seed.
    #[arg(long, env = "JSAE_SEED")]
    seed: u64,
    /// Settings file.
    #[arg(long, env = "JSAE_CONFIG")]
    config: Option<PathBuf>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    eprintln!(
        "jsae-embedder: the gRPC transport is not available yet; `jsae train --env {}` runs the embedder in-process",
        cli.env
    );
    ExitCode::FAILURE
}
