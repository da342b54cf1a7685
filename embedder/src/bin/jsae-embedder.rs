//! `jsae-embedder`: the embedder service (`jsae.v1.Embedder`, health, reflection).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(
    name = "jsae-embedder",
    version,
    about = "JSAE-RL embedder: trains phi/g/T/f on raw transitions and publishes snapshots"
)]
struct Cli {
    #[command(flatten)]
    args: jsae_embedder::service::EmbedderArgs,
}

fn main() -> std::process::ExitCode {
    jsae_embedder::service::main(Cli::parse().args)
}
