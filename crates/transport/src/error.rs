//! Errors of the transport, each saying what failed and what to do about it.

use std::time::Duration;

/// Anything that can go wrong creating or using a transport port.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The configuration is invalid (run id, counts, buffer sizes, Zenoh endpoints): what and why.
    #[error("invalid transport config: {0}")]
    Config(String),
    /// `/dev/shm` has less free space than the run's shared-memory segments need.
    #[error(
        "/dev/shm has {available_mib} MiB free but this run needs about {required_mib} MiB of \
         shared memory. Fix: start the container with `docker run --shm-size=1g …` (or \
         `shm_size: 1gb` in compose), or on a host `sudo mount -o remount,size=1G /dev/shm`; \
         or lower `buffer_batches`/`num_actors`."
    )]
    ShmTooSmall {
        /// Free space, in MiB (rounded down).
        available_mib: u64,
        /// What the run needs, in MiB (rounded up).
        required_mib: u64,
    },
    /// The free space of the shared-memory folder could not be read (`statvfs` failed).
    #[error("cannot inspect {path}: {source}")]
    ShmUnavailable {
        /// The folder inspected (normally `/dev/shm`).
        path: String,
        /// The underlying error.
        source: std::io::Error,
    },
    /// An iceoryx2 call failed.
    #[error("iceoryx2 {operation} failed for {service}: {detail}")]
    Ipc {
        /// What was attempted (e.g. `"node creation"`, `"publisher creation"`, `"send"`).
        operation: &'static str,
        /// The node or service name it was for (`terl/<run_id>/...`).
        service: String,
        /// iceoryx2's error, debug-formatted.
        detail: String,
    },
    /// A `Block` send waited the whole block timeout for room on a full receiver; the
    /// message was not delivered (and is counted as dropped).
    #[error(
        "send on {service} blocked for {waited:?} on a full receiver (is the receiver alive \
         and draining?); the message was not delivered"
    )]
    BlockTimeout {
        /// The service (stream) sent on.
        service: String,
        /// How long the send waited (the configured block timeout).
        waited: Duration,
    },
    /// Another live process holds this id on the run (see `claim_actor_id`).
    #[error(
        "{what} is already streaming to run {run_id}: another live process holds {service}. \
         Stop that process first, or start this one with an id no running process uses"
    )]
    IdInUse {
        /// The id, in words (e.g. `actor id 3`).
        what: String,
        /// The run it is held on.
        run_id: String,
        /// The claim's service name or key prefix (`terl/<run_id>/claims/actor-<id>`).
        service: String,
    },
    /// A Zenoh call failed.
    #[error("zenoh {operation} failed for {key}: {detail}")]
    Zenoh {
        /// What was attempted.
        operation: &'static str,
        /// The key expression it was for (`terl/<run_id>/...`).
        key: String,
        /// Zenoh's error message.
        detail: String,
    },
    /// Waiting for a peer or receivers gave up.
    #[error("timed out after {after:?} waiting for {what}")]
    Timeout {
        /// What was waited for, in words.
        what: String,
        /// How long it waited.
        after: Duration,
    },
    /// A send blocked on a full receiver was cancelled by `cancel_blocked_sends` (shutdown);
    /// names the service. The message was not delivered.
    #[error(
        "send on {0} was cancelled while blocked on a full receiver (shutdown); not delivered"
    )]
    Cancelled(String),
    /// The stream's in-process channel is disconnected (its other end is gone); names the
    /// stream.
    #[error("the channel {0} is closed")]
    Closed(String),
}
