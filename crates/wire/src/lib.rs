//! The gRPC wire contract of terl: code generated from `proto/terl/v1/*.proto`, the domain types
//! the rest of the workspace uses instead, and the edge between the two.
//!
//! Everything that arrives over the wire passes one `TryFrom<pb::X>` conversion that validates it
//! (shapes against byte lengths, finite values, checksums, known enum values) and answers
//! `Status::invalid_argument` with the precise problem; code behind the edge never sees a `pb`
//! type. The crate also owns the [`WeightHub`] the learner publishes weights through, the server
//! helpers ([`serve_learner`], [`serve_selector`]: service + `grpc.health.v1` + reflection v1 and
//! v1alpha), the client helpers ([`connect_learner`], [`LearnerClient::watch_weights`]), the
//! control plane's access control ([`ServerSecurity`], [`ClientSecurity`]: a token on every RPC,
//! optional TLS). The benchmarks' gRPC service is not part of this contract (crate `terl-bench`).

#![warn(missing_docs)]

pub mod certs;
mod client;
mod dataset;
mod hub;
mod security;
mod server;
mod status;
mod weights;

/// Generated prost messages and tonic clients/servers for package `terl.v1`.
pub mod pb {
    #![allow(
        missing_docs,
        missing_debug_implementations,
        clippy::all,
        clippy::pedantic
    )]
    tonic::include_proto!("terl.v1");
}

pub use client::{
    check_health, connect_learner, connect_learner_with, connect_selector, connect_selector_with,
    follow_weights, follow_weights_with, ClientOptions, ConnectError, HealthError, LearnerClient,
    SecuredChannel, SelectorClient, Watcher, WeightsStream, LEARNER_SERVICE, SELECTOR_SERVICE,
};
pub use dataset::{EpisodeSummary, Metric, TepSample, ACTION_DIM, OBS_DIM};
pub use hub::{PublishError, WeightHub};
pub use security::{
    ClientSecurity, ClientTls, SecurityError, ServerSecurity, ServerTls, Token, TokenInterceptor,
    MAX_TOKEN_BYTES, MIN_TOKEN_BYTES, TOKEN_ENV,
};
pub use server::{
    bind, bind_secured, serve_learner, serve_learner_with, serve_selector, serve_selector_with,
    CheckpointRequest, CheckpointSaved, LearnerBackend, LearnerService, SelectorBackend,
    SelectorService, ServeError, ServeOptions, MAX_WATCHERS,
};
pub use status::{
    ActorStats, EvalResult, LearnerStatus, PlannerStatus, PlannerTask, PriorityStats,
    SelectorStatus, TaskEval, TaskSuccess,
};
pub use weights::{weights_crc32, Tensor, Weights, WeightsError, WeightsKind};

/// Encoded `FileDescriptorSet` of all terl.v1 protos (served by reflection; usable by MCAP
/// writers as the protobuf schema data).
pub const FILE_DESCRIPTOR_SET: &[u8] = tonic::include_file_descriptor_set!("terl_v1_descriptor");

/// Learner's default listen address (loopback: the control plane is not exposed by default).
pub const DEFAULT_LEARNER_ADDR: &str = "127.0.0.1:50051";
/// Selector's default listen address.
pub const DEFAULT_SELECTOR_ADDR: &str = "127.0.0.1:50052";

/// Message size limit of servers and clients, both directions: 64 MiB instead of tonic's 4 MiB.
/// The planner's weights (F and AN, ≈ 4.5 MB) exceed 4 MiB; 64 MiB leaves room for larger
/// networks while a runaway message still fails with `RESOURCE_EXHAUSTED`.
pub const DEFAULT_MAX_MESSAGE_BYTES: usize = 64 << 20;
