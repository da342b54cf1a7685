//! `jsae-actor`: an actor process (steps environments, streams transitions and fragments,
//! follows the embedder's and the learner's snapshots).

fn main() -> std::process::ExitCode {
    jsae_actor::main(clap::Parser::parse())
}
