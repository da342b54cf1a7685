//! `jsae-embedder`: the embedder service (`jsae.v1.Embedder`, health, reflection).

fn main() -> std::process::ExitCode {
    jsae_embedder::service::main(clap::Parser::parse())
}
