//! `jsae`: the launcher and tools. `jsae train` runs a whole training on this machine (the
//! embedder, the learner and the actors as separate processes on loopback, or in one process
//! with `--one-process`) and prints its summary; `jsae bench` measures PPO updates and
//! inference on both devices. `jsae embedder|learner|actor|recommender` are the services
//! themselves (the same as the `jsae-embedder`, `jsae-learner` and `jsae-actor` binaries),
//! which is how `jsae train` starts them. The commands are `jsae_cli::commands`.

use clap::Parser;

#[derive(Parser, Debug)]
#[command(name = "jsae", version, about = "JSAE-RL launcher and tools")]
struct Cli {
    /// Log lines as text (coloured only on a terminal) or JSON objects, one per line; the
    /// services `jsae train` starts log the same way [default: $JSAE_LOG_FORMAT, else text].
    #[arg(long, global = true, value_enum)]
    log_format: Option<jsae_net::logging::LogFormat>,
    #[command(subcommand)]
    command: jsae_cli::commands::Command,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    if let Some(format) = cli.log_format {
        jsae_net::logging::choose_log_format(format);
    }
    jsae_cli::closed_pipe::run(|| jsae_cli::commands::run(cli.command))
}
