//! `jsae-actor`: an actor process (steps environments, streams transitions and fragments,
//! follows the embedder's and the learner's snapshots), exactly as `jsae actor`.

fn main() -> std::process::ExitCode {
    jsae_cli::service_bin::main("jsae-actor", jsae_cli::commands::Command::Actor)
}
