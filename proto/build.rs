//! Compiles `proto/*.proto` with protox (pure Rust), so the build needs no system `protoc`.
//! The file descriptor set is written next to the generated code for the coordinator's
//! server reflection (`FILE_DESCRIPTOR_SET`).
use prost::Message as _;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=proto");
    let fds = protox::compile(["tessera.proto"], ["proto"])?;
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out.join("tessera_descriptor.bin"), fds.encode_to_vec())?;
    // `bytes::Bytes`, so that cloning an update shares its encoded pixels and preview.
    tonic_prost_build::configure()
        .bytes(".tessera.v1.FramebufferUpdate.pixels")
        .bytes(".tessera.v1.FramebufferUpdate.preview")
        .compile_fds(fds)?;
    Ok(())
}
