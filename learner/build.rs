//! Compiles the official ONNX schema (`proto/onnx.proto`) into Rust types with prost, without
//! a system `protoc`: protox parses the file into a descriptor set, prost-build generates the
//! code into `OUT_DIR/onnx.rs`.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=proto/onnx.proto");
    let descriptors = protox::compile(["onnx.proto"], ["proto"])?;
    prost_build::Config::new().compile_fds(descriptors)?;
    Ok(())
}
