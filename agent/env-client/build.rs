//! Generates the gRPC client and messages from `proto/` with `protox`, a pure-Rust
//! protobuf compiler, so building needs no system `protoc`.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto_root = concat!(env!("CARGO_MANIFEST_DIR"), "/../../proto");
    let proto_file = format!("{proto_root}/million/env/v1/env.proto");
    println!("cargo:rerun-if-changed={proto_file}");
    let descriptors = protox::compile([proto_file.as_str()], [proto_root])?;
    tonic_prost_build::configure()
        .build_server(false)
        // Tensor payloads decode into `bytes::Bytes`, so observations can be sliced
        // and handed on without copying the payload.
        .bytes(".million.env.v1.Tensor.data")
        .compile_fds(descriptors)?;
    Ok(())
}
