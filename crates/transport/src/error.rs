//! Errors of the transport, each saying what failed and what to do about it.

use std::time::Duration;

/// Anything that can go wrong creating or using a transport port.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error("invalid transport config: {0}")]
    Config(String),
    #[error(
        "/dev/shm has {available_mib} MiB free but this run needs about {required_mib} MiB of \
         shared memory. Fix: start the container with `docker run --shm-size=1g …` (or \
         `shm_size: 1gb` in compose), or on a host `sudo mount -o remount,size=1G /dev/shm`; \
         or lower `buffer_batches`/`num_actors`."
    )]
    ShmTooSmall {
        available_mib: u64,
        required_mib: u64,
    },
    #[error("cannot inspect {path}: {source}")]
    ShmUnavailable {
        path: String,
        source: std::io::Error,
    },
    #[error("iceoryx2 {operation} failed for {service}: {detail}")]
    Ipc {
        operation: &'static str,
        service: String,
        detail: String,
    },
    #[error(
        "send on {service} blocked for {waited:?} on a full receiver (is the receiver alive \
         and draining?); the message was not delivered"
    )]
    BlockTimeout { service: String, waited: Duration },
    #[error(
        "{what} is already streaming to run {run_id}: another live process holds {service}. \
         Stop that process first, or start this one with an id no running process uses"
    )]
    IdInUse {
        what: String,
        run_id: String,
        service: String,
    },
    #[error("timed out after {after:?} waiting for {what}")]
    Timeout { what: String, after: Duration },
    #[error(
        "send on {0} was cancelled while blocked on a full receiver (shutdown); not delivered"
    )]
    Cancelled(String),
    #[error("the channel {0} is closed")]
    Closed(String),
}
