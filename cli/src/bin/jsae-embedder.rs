//! `jsae-embedder`: the embedder service (`jsae.v1.Embedder`, health, reflection), exactly as
//! `jsae embedder`.

fn main() -> std::process::ExitCode {
    jsae_cli::service_bin::main("jsae-embedder", jsae_cli::commands::Command::Embedder)
}
