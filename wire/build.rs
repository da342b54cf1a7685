//! Compiles `proto/jsae.proto` with protox (no protoc needed) and keeps the encoded file
//! descriptor set beside the generated code, for server reflection.

use prost::Message;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo::rerun-if-changed=proto/jsae.proto");
    let fds = protox::compile(["proto/jsae.proto"], ["proto"])?;
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out.join("jsae.fds"), fds.encode_to_vec())?;
    tonic_prost_build::configure()
        .codec_path("crate::codec::StrictCodec")
        .compile_fds(fds)?;
    Ok(())
}
