//! Bulk data between TERL's processes: actors → learner transitions, actors → selector
//! (and learner) finished episodes, selector → learner selected samples.
//!
//! Messages are fixed-layout `#[repr(C)]` plain data (one file per direction:
//! [`actor_to_learner`], [`actor_to_selector`], [`selector_to_learner`]), never serialised.
//! Everything above this crate talks to the narrow seam in [`channel`], implemented three
//! times: [`shm`] over iceoryx2 shared memory between the processes of one host, [`zenoh_net`]
//! over Zenoh (TCP, through peers or a router) between hosts, and [`memory`] in-process for
//! tests; [`run_transport`] opens the one a run file names (`[cluster] transport`). [`flow`] documents
//! and implements flow control: explicit overflow policies, counted drops (stamped on the
//! next message, so receivers learn what never reached them), and the learner's
//! update-to-data rate limiter.

#![warn(missing_docs)]

pub mod actor_to_learner;
pub mod actor_to_selector;
pub mod channel;
pub mod config;
pub mod error;
pub mod flow;
pub mod memory;
pub mod run_transport;
pub mod selector_to_learner;
pub mod shm;
pub mod zenoh_net;

/// Meta-World observation and action widths (defined once, in `terl_spaces`).
pub use terl_spaces::{ACTION_DIM, OBS_DIM};

pub use actor_to_learner::{
    flags, Transition, TransitionBatch, ACTION_GAP_SCALE, TRANSITIONS_PER_BATCH,
};
pub use actor_to_selector::{EpisodeSummary, TrajectoryStep, MAX_EPISODE_STEPS, NO_VARIATION};
pub use channel::{
    EpisodeSink, EpisodeSource, HeldClaim, Message, MessageSink, MessageSource, SelectedSink,
    SelectedSource, ServiceTransport, Topic, TransitionSink, TransitionSource, Transport,
};
pub use config::{
    ServiceLimits, TransportConfig, TransportKind, ZenohConfig, ZenohMode, ZenohSecret, ZenohTls,
};
pub use error::TransportError;
pub use flow::{
    LossTracker, Losses, OverflowPolicy, RateLimiter, RateLimiterError, SendOutcome, SenderLosses,
    Staleness, StatsSnapshot, TransportStats,
};
pub use memory::{MemoryBus, MemoryClaim, MemoryTransport};
pub use run_transport::{ActorClaim, RunTransport};
pub use selector_to_learner::{SelectedBatch, SelectedSample, SELECTED_PER_BATCH};
pub use shm::{SenderClaim, ShmSink, ShmSource, ShmTransport, StaleCleanup};
pub use zenoh_net::{ZenohClaim, ZenohRouter, ZenohSink, ZenohSource, ZenohTransport};
