//! `jsae-learner`: the learner service (`jsae.v1.Learner`, health, reflection), for runs that
//! learn from no logged purchases (`jsae learner` reads the recommender's).

fn main() -> std::process::ExitCode {
    jsae_learner::service::main(clap::Parser::parse(), jsae_learner::service::no_logs)
}
