//! Compiles `proto/*.proto` with protox (pure Rust), so the build needs no system `protoc`.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=proto");
    let fds = protox::compile(["tessera.proto"], ["proto"])?;
    // A `bytes::Bytes`, so that cloning an update shares its encoded pixels.
    tonic_prost_build::configure().bytes(".tessera.v1.FramebufferUpdate.pixels").compile_fds(fds)?;
    Ok(())
}
