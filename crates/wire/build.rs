//! Generates the tonic/prost code for `proto/terl/v1/*.proto` and the encoded file descriptor set
//! that the reflection services serve. protoc comes from `protoc-bin-vendored`, so no system
//! protoc is needed.

use std::{env, path::PathBuf};

const PROTOS: &[&str] = &[
    "terl/v1/common.proto",
    "terl/v1/status.proto",
    "terl/v1/learner.proto",
    "terl/v1/selector.proto",
    "terl/v1/dataset.proto",
];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto_root = PathBuf::from(env::var("CARGO_MANIFEST_DIR")?).join("../../proto");
    let out_dir = PathBuf::from(env::var("OUT_DIR")?);
    if env::var_os("PROTOC").is_none() {
        // Build scripts are single-threaded, so setting the variable for prost-build is sound.
        env::set_var("PROTOC", protoc_bin_vendored::protoc_bin_path()?);
    }
    let files: Vec<PathBuf> = PROTOS.iter().map(|p| proto_root.join(p)).collect();
    for file in &files {
        println!("cargo:rerun-if-changed={}", file.display());
    }
    println!("cargo:rerun-if-env-changed=PROTOC");
    tonic_prost_build::configure()
        // Tensor data as `bytes::Bytes`: one encoded weight version is shared by every
        // subscriber stream without copying the payload per subscriber.
        .bytes(".terl.v1.Tensor.data")
        .file_descriptor_set_path(out_dir.join("terl_v1_descriptor.bin"))
        .compile_protos(&files, &[proto_root])?;
    Ok(())
}
