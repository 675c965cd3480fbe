//! Generates the tonic/prost code of the benchmarks' own gRPC package, `terl.bench.v1`
//! (`proto/terl/bench/v1/*.proto` of this crate), kept out of the production contract that
//! crates/wire compiles. protoc comes from `protoc-bin-vendored`, so no system protoc is needed.

use std::{env, path::PathBuf};

const PROTOS: &[&str] = &["terl/bench/v1/bench.proto"];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto_root = PathBuf::from(env::var("CARGO_MANIFEST_DIR")?).join("proto");
    if env::var_os("PROTOC").is_none() {
        // Build scripts are single-threaded, so setting the variable for prost-build is sound.
        env::set_var("PROTOC", protoc_bin_vendored::protoc_bin_path()?);
    }
    let files: Vec<PathBuf> = PROTOS.iter().map(|p| proto_root.join(p)).collect();
    for file in &files {
        println!("cargo:rerun-if-changed={}", file.display());
    }
    println!("cargo:rerun-if-env-changed=PROTOC");
    tonic_prost_build::configure().compile_protos(&files, &[proto_root])?;
    Ok(())
}
