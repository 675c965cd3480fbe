//! The transport a run file chooses (`[cluster] transport = "shm" | "zenoh"`), behind one
//! type the services open.

use std::time::Duration;

use crate::channel::{HeldClaim, Message, MessageSink, MessageSource, ServiceTransport, Transport};
use crate::config::{TransportConfig, TransportKind};
use crate::error::TransportError;
use crate::shm::{SenderClaim, ShmTransport};
use crate::zenoh_net::{ZenohClaim, ZenohTransport};

/// Shared memory or Zenoh, as `TransportConfig::transport` says.
#[derive(Debug)]
pub enum RunTransport {
    /// iceoryx2 shared memory (`transport = "shm"`): every process on one host.
    Shm(ShmTransport),
    /// Zenoh over TCP (`transport = "zenoh"`): processes on several hosts.
    Zenoh(ZenohTransport),
}

/// An actor id held by this process (see [`RunTransport::claim_actor_id`]).
#[derive(Debug)]
pub enum ActorClaim {
    /// The claim over shared memory.
    Shm(Box<SenderClaim>),
    /// The claim over Zenoh.
    Zenoh(ZenohClaim),
}

impl HeldClaim for ActorClaim {
    fn superseded(&self) -> Option<String> {
        match self {
            Self::Shm(c) => c.superseded(),
            Self::Zenoh(c) => c.superseded(),
        }
    }
}

impl RunTransport {
    /// Opens this process's end of the run's streams with the engine `config.transport`
    /// names. `role` names the process (`learner`, `selector`, `actor-3`).
    pub fn open(config: TransportConfig, role: &str) -> Result<Self, TransportError> {
        Ok(match config.transport {
            TransportKind::Shm => Self::Shm(ShmTransport::open(config, role)?),
            TransportKind::Zenoh => Self::Zenoh(ZenohTransport::open(config, role)?),
        })
    }

    /// Which engine this is.
    pub fn kind(&self) -> TransportKind {
        match self {
            Self::Shm(_) => TransportKind::Shm,
            Self::Zenoh(_) => TransportKind::Zenoh,
        }
    }

    /// Claims `actor_id` on this run so no two processes stream under one id; errors with
    /// [`TransportError::IdInUse`] while another live process holds it.
    pub fn claim_actor_id(&self, actor_id: u16) -> Result<ActorClaim, TransportError> {
        Ok(match self {
            Self::Shm(t) => ActorClaim::Shm(Box::new(t.claim_actor_id(actor_id)?)),
            Self::Zenoh(t) => ActorClaim::Zenoh(t.claim_actor_id(actor_id)?),
        })
    }

    /// Removes the resources dead processes left (shared memory: iceoryx2's dead-node
    /// cleanup, e.g. the subscription of a learner killed with SIGKILL). Zenoh: nothing to do
    /// (a dead process's liveliness tokens vanish with its session).
    pub fn cleanup_dead_nodes(&self) -> crate::StaleCleanup {
        match self {
            Self::Shm(t) => t.cleanup_dead_nodes(),
            Self::Zenoh(_) => crate::StaleCleanup::default(),
        }
    }

    /// Sleeps for `cycle`; `false` when the process should stop (shared memory: iceoryx2's
    /// node wait; Zenoh: always `true`).
    pub fn wait(&self, cycle: Duration) -> bool {
        match self {
            Self::Shm(t) => t.wait(cycle),
            Self::Zenoh(_) => {
                std::thread::sleep(cycle);
                true
            }
        }
    }
}

impl Transport for RunTransport {
    fn sink<M: Message>(&self) -> Result<Box<dyn MessageSink<M>>, TransportError> {
        match self {
            Self::Shm(t) => t.sink(),
            Self::Zenoh(t) => t.sink(),
        }
    }

    fn source<M: Message>(&self) -> Result<Box<dyn MessageSource<M>>, TransportError> {
        match self {
            Self::Shm(t) => t.source(),
            Self::Zenoh(t) => t.source(),
        }
    }

    fn cancel_blocked_sends(&self) {
        match self {
            Self::Shm(t) => t.cancel_blocked_sends(),
            Self::Zenoh(t) => t.cancel_blocked_sends(),
        }
    }
}

impl ServiceTransport for RunTransport {
    type Claim = ActorClaim;

    fn claim_actor_id(&self, actor_id: u16) -> Result<ActorClaim, TransportError> {
        RunTransport::claim_actor_id(self, actor_id)
    }

    fn cleanup_dead_nodes(&self) -> crate::StaleCleanup {
        RunTransport::cleanup_dead_nodes(self)
    }

    fn wait(&self, cycle: Duration) -> bool {
        RunTransport::wait(self, cycle)
    }
}
