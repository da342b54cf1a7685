//! `jsae-learner`: the learner service (`jsae.v1.Learner`, health, reflection), exactly as
//! `jsae learner`.

fn main() -> std::process::ExitCode {
    jsae_cli::service_bin::main("jsae-learner", jsae_cli::commands::Command::Learner)
}
