//! `jsae`: the launcher and tools. `jsae train` runs a whole training on this machine (the
//! embedder, the learner and the actors as separate processes on loopback, or in one process
//! with `--one-process`) and prints its summary; `jsae bench` measures PPO updates and
//! inference on both devices. `jsae embedder|learner|actor|recommender` are the services
//! themselves (the `jsae-embedder`, `jsae-learner` and `jsae-actor` binaries are these
//! subcommands: `jsae_cli::service_bin`),
//! which is how `jsae train` starts them. The commands are `jsae_cli::commands`.

use clap::Parser;

#[derive(Parser, Debug)]
#[command(name = "jsae", version, about = "JSAE-RL launcher and tools")]
struct Cli {
    #[command(flatten)]
    log_format: jsae_cli::service_bin::LogFormatFlag,
    #[command(subcommand)]
    command: jsae_cli::commands::Command,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    cli.log_format.apply();
    jsae_cli::closed_pipe::run(|| jsae_cli::commands::run(cli.command))
}
