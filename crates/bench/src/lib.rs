//! The benchmarks of terl, out of the library crates they measure: each module drives a library
//! only through its public API and returns a serialisable report (`terl bench ...` prints them
//! as JSON).
//!
//! - [`env`](mod@env): env steps/s per task against the bare physics of the same model (`terl-sim`);
//! - [`memory`]: RSS per Meta-World environment and the `mjData` arena they use (`terl-sim`);
//! - [`sac`]: SAC update throughput, achieved GFLOP/s against faer's GEMM rate, inference
//!   latency (`terl-rl`);
//! - [`tep`]: the same for the TEP update, and planner latency;
//! - [`transport`]: transitions/s through iceoryx2 shared memory and Zenoh, also split in two
//!   halves for a measurement between hosts (`terl-transport`);
//! - [`grpc`]: the transition stream over gRPC and the weight broadcast's latency
//!   (`terl-wire`), with the benchmarks' own gRPC package [`pb`] (`terl.bench.v1`, not part of
//!   the production contract);
//! - [`args`]: the clap arguments shared by `terl bench` and this crate's examples.

#![warn(missing_docs)]

pub mod args;
pub mod env;
pub mod grpc;
pub mod memory;
pub mod sac;
pub mod tep;
pub mod transport;

/// Generated prost messages and tonic client/server for package `terl.bench.v1`.
pub mod pb {
    #![allow(
        missing_docs,
        missing_debug_implementations,
        clippy::all,
        clippy::pedantic
    )]
    tonic::include_proto!("terl.bench.v1");
}
