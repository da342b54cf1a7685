//! `jsae-learner`: the learner service (`jsae.v1.Learner`, health, reflection).

fn main() -> std::process::ExitCode {
    jsae_learner::service::main(clap::Parser::parse())
}
