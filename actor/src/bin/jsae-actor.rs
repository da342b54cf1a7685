//! `jsae-actor`: an actor process (steps environments, streams transitions and fragments,
//! follows the embedder's and the learner's snapshots).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(
    name = "jsae-actor",
    version,
    about = "JSAE-RL actor: steps environments, streams transitions and fragments"
)]
struct Cli {
    #[command(flatten)]
    args: jsae_actor::service::ActorArgs,
}

fn main() -> std::process::ExitCode {
    jsae_actor::service::main(Cli::parse().args)
}
