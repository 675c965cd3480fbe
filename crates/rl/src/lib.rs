//! Multi-task SAC (MTSAC), pure: no I/O except the explicit checkpoint functions.
//!
//! Why this crate exists: it is the learning core shared by the single-process trainer, the
//! learner service and the benchmarks (crate `terl-bench`). It owns the algorithm and its data
//! (replay), not where data comes from: environments plug in through [`env::VecEnvironment`],
//! weights leave as flat `f32` vectors or named tensors, and losses are plain functions of a
//! [`Batch`].
//!
//! - [`SacConfig`]: every hyper-parameter, serde/TOML;
//! - [`Sac`]: networks, optimisers and the update (critics, actor, per-task temperature, targets);
//! - [`care`]: CARE's context-based encoder (mixture of state encoders under task attention),
//!   the third algorithm of the paper's Table I, in front of the same SAC heads;
//! - [`Policy`]: inference-only policy for actors (fast small-batch `act`);
//! - [`replay::MultiTaskReplay`]: per-task ring buffers in contiguous `f32` storage;
//! - [`rollout`]: the one environment loop (act, step, hand transitions to a sink) of the
//!   trainer and the actors;
//! - [`train`]: the single-process training loop over a [`env::VecEnvironment`];
//! - [`success::SuccessWindow`]: a task's rolling success rate;
//! - [`names`]: names of the tensors that cross process boundaries;
//! - [`toy`]: a multi-task 2-D point-mass environment for fast learning tests;
//! - [`ptr`]: PTR selection (GAE, priority, ranking in batches, success gate);
//! - [`tep`], [`tep_buffer`]: the TEP planner (F, AN, targets, update) and its dataset buffer;
//! - [`guidance`]: the TERL guidance rule and goal states;
//! - [`value`]: `V(s)` and policy entropy from published weights, for PTR scoring.

#![warn(missing_docs)]

pub mod batch;
pub mod care;
pub mod config;
pub mod env;
pub mod error;
pub mod guidance;
pub mod limits;
pub mod names;
pub mod planner_eval;
pub mod policy;
pub mod ptr;
pub mod replay;
pub mod rollout;
pub mod sac;
mod small_mlp;
pub mod success;
pub mod tep;
pub mod tep_buffer;
pub mod toy;
pub mod train;
pub mod value;

pub use batch::Batch;
pub use care::{CareConfig, CareContext, CareNet};
pub use config::{auto_threads, NetInit, SacConfig};
pub use error::SacError;
pub use policy::{Policy, PolicySpec};
pub use sac::{Sac, UpdateStats};
pub use success::SuccessWindow;
pub use tep::{FTarget, GoalLoss, Planner, Tep, TepConfig, TepStats};
pub use tep_buffer::{GoalSampling, TepBatch, TepBuffer};
