//! `jsae-learner`: the learner service (`jsae.v1.Learner`, health, reflection).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(
    name = "jsae-learner",
    version,
    about = "JSAE-RL learner: PPO on embedded tuples, publishes policy snapshots, ends the run"
)]
struct Cli {
    #[command(flatten)]
    args: jsae_learner::service::LearnerArgs,
}

fn main() -> std::process::ExitCode {
    jsae_learner::service::main(Cli::parse().args)
}
