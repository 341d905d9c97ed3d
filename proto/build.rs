//! Compiles `proto/adp/v1/adp.proto` with protox (no system `protoc`) and generates the prost
//! messages and tonic services.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=proto/adp/v1/adp.proto");
    let fds = protox::compile(["adp/v1/adp.proto"], ["proto"])?;
    tonic_prost_build::configure().bytes(".adp.v1").compile_fds(fds)?;
    Ok(())
}
