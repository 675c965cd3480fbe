//! The narrow seam: what actors, learner and selector see of the transport.
//!
//! Code above this seam is written against [`MessageSink`]/[`MessageSource`] (or the named
//! aliases [`TransitionSink`], [`EpisodeSource`], …) and a [`Transport`] that creates them,
//! so the same loop runs over shared memory in production and over the in-memory twin in
//! unit tests — and over a network tunnel later, as one more implementation.

use core::fmt::Debug;
use std::time::Duration;

use iceoryx2::prelude::ZeroCopySend;

use crate::actor_to_learner::TransitionBatch;
use crate::actor_to_selector::EpisodeSummary;
use crate::error::TransportError;
use crate::flow::{Losses, SendOutcome, StatsSnapshot};
use crate::selector_to_learner::SelectedBatch;

/// The three streams of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Topic {
    /// Actor → learner [`TransitionBatch`]es.
    Transitions,
    /// Actor → selector and learner [`EpisodeSummary`]s.
    Episodes,
    /// Selector → learner [`SelectedBatch`]es.
    Selected,
}

impl Topic {
    /// Every topic, in stream order.
    pub const ALL: [Topic; 3] = [Topic::Transitions, Topic::Episodes, Topic::Selected];

    /// Last component of the service name `terl/<run_id>/<name>`.
    pub fn name(self) -> &'static str {
        match self {
            Topic::Transitions => "transitions",
            Topic::Episodes => "episodes",
            Topic::Selected => "selected",
        }
    }
}

/// A fixed-layout message that can travel through shared memory.
///
/// `bytemuck::Pod` (no padding, any bit pattern valid) lets network transports send the
/// message as its bytes and check only the length on receipt.
pub trait Message: ZeroCopySend + bytemuck::Pod + Copy + Debug + Send + 'static {
    /// The stream this message type travels on.
    const TOPIC: Topic;
    /// A valid all-zero value, heap allocated (messages are tens to hundreds of KiB).
    fn empty() -> Box<Self>;
    /// Items the message carries, for loss counts: transitions of a batch, 1 per episode,
    /// selected samples of a batch.
    fn items(&self) -> u64;
    /// The sender's cumulative losses stamped on the message (see [`crate::flow`]).
    fn losses(&self) -> Losses;
    /// Stamps the sender's cumulative losses; the sinks do this on every send, so whatever the
    /// caller put there is overwritten.
    fn set_losses(&mut self, losses: Losses);
}

impl Message for TransitionBatch {
    const TOPIC: Topic = Topic::Transitions;
    fn empty() -> Box<Self> {
        Box::new(TransitionBatch::EMPTY)
    }
    fn items(&self) -> u64 {
        self.as_slice().len() as u64
    }
    fn losses(&self) -> Losses {
        self.losses
    }
    fn set_losses(&mut self, losses: Losses) {
        self.losses = losses;
    }
}

impl Message for EpisodeSummary {
    const TOPIC: Topic = Topic::Episodes;
    fn empty() -> Box<Self> {
        Box::new(EpisodeSummary::EMPTY)
    }
    fn items(&self) -> u64 {
        1
    }
    fn losses(&self) -> Losses {
        self.losses
    }
    fn set_losses(&mut self, losses: Losses) {
        self.losses = losses;
    }
}

impl Message for SelectedBatch {
    const TOPIC: Topic = Topic::Selected;
    fn empty() -> Box<Self> {
        Box::new(SelectedBatch::EMPTY)
    }
    fn items(&self) -> u64 {
        self.as_slice().len() as u64
    }
    fn losses(&self) -> Losses {
        self.losses
    }
    fn set_losses(&mut self, losses: Losses) {
        self.losses = losses;
    }
}

/// The sending end of one stream.
pub trait MessageSink<M: Message>: Send + Debug {
    /// Delivers `message` to every connected receiver, following the sink's
    /// [`OverflowPolicy`](crate::OverflowPolicy) when one is full. Never loses a message
    /// without saying so: see [`SendOutcome`]. What is delivered is `message` stamped with
    /// this sink's cumulative [`Losses`] before the send (the `losses` field is overwritten).
    /// A message given up on (`Full`, `BlockTimeout`, `Cancelled`) is counted in
    /// `dropped`/`dropped_items` and in the stamp of the next message.
    fn send(&mut self, message: &M) -> Result<SendOutcome, TransportError>;

    /// Number of receivers currently connected.
    fn receivers(&self) -> usize;

    /// Waits until at least `count` receivers are connected (start-up ordering: actors may
    /// come up before the learner). Errors with `TransportError::Timeout`.
    fn wait_for_receivers(&self, count: usize, timeout: Duration) -> Result<(), TransportError> {
        let start = std::time::Instant::now();
        while self.receivers() < count {
            if start.elapsed() >= timeout {
                return Err(TransportError::Timeout {
                    what: format!("{count} receiver(s) on {:?}", M::TOPIC),
                    after: timeout,
                });
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(())
    }

    /// A copy of this sink's counters (sent, dropped, full, no receiver).
    fn stats(&self) -> StatsSnapshot;
}

/// The receiving end of one stream.
pub trait MessageSource<M: Message>: Send + Debug {
    /// Copies the oldest pending message into `out`; `Ok(false)` when none is pending.
    /// Never blocks.
    fn try_receive_into(&mut self, out: &mut M) -> Result<bool, TransportError>;

    /// Allocating convenience around [`try_receive_into`](Self::try_receive_into).
    fn try_receive(&mut self) -> Result<Option<Box<M>>, TransportError> {
        let mut out = M::empty();
        Ok(self.try_receive_into(&mut out)?.then_some(out))
    }

    /// Number of senders currently connected.
    fn senders(&self) -> usize;

    /// A copy of this source's counters (`received` counts the messages taken out).
    fn stats(&self) -> StatsSnapshot;
}

/// Actor side of the transition stream.
pub trait TransitionSink: MessageSink<TransitionBatch> {}
impl<T: MessageSink<TransitionBatch> + ?Sized> TransitionSink for T {}
/// Learner side of the transition stream.
pub trait TransitionSource: MessageSource<TransitionBatch> {}
impl<T: MessageSource<TransitionBatch> + ?Sized> TransitionSource for T {}
/// Actor side of the episode stream.
pub trait EpisodeSink: MessageSink<EpisodeSummary> {}
impl<T: MessageSink<EpisodeSummary> + ?Sized> EpisodeSink for T {}
/// Selector (and learner) side of the episode stream.
pub trait EpisodeSource: MessageSource<EpisodeSummary> {}
impl<T: MessageSource<EpisodeSummary> + ?Sized> EpisodeSource for T {}
/// Selector side of the selected-sample stream.
pub trait SelectedSink: MessageSink<SelectedBatch> {}
impl<T: MessageSink<SelectedBatch> + ?Sized> SelectedSink for T {}
/// Learner side of the selected-sample stream.
pub trait SelectedSource: MessageSource<SelectedBatch> {}
impl<T: MessageSource<SelectedBatch> + ?Sized> SelectedSource for T {}

/// Creates sinks and sources for one run. One per process (or per thread in tests).
pub trait Transport: Debug {
    /// Opens a sending port on `M`'s topic ([`Message::TOPIC`]).
    fn sink<M: Message>(&self) -> Result<Box<dyn MessageSink<M>>, TransportError>;
    /// Opens a receiving port on `M`'s topic ([`Message::TOPIC`]).
    fn source<M: Message>(&self) -> Result<Box<dyn MessageSource<M>>, TransportError>;
    /// Shutdown: every send of this transport's sinks that is blocked on a full receiver
    /// (now or later) returns `TransportError::Cancelled` instead of waiting.
    fn cancel_blocked_sends(&self);
}

/// An actor id held by this process, for as long as the value lives.
pub trait HeldClaim: Send + Debug {
    /// `Some(why)` once another process is seen holding the same id since before this claim:
    /// two holders can meet only after a partition healed (a learner restarted before the
    /// earlier holder reconnected, a host came back after its lease expired). The later
    /// holder must then stop streaming under the id. Shared memory and the in-memory twin,
    /// whose claims are exact on one host: always `None`.
    fn superseded(&self) -> Option<String> {
        None
    }
}

/// What a service needs of its transport beyond sinks and sources: holding an actor id,
/// removing what dead processes left, and the main loop's wait. [`crate::RunTransport`]
/// (shared memory or Zenoh, one per process) and [`crate::MemoryTransport`] (every service of
/// a test in one process, on one [`crate::memory::MemoryBus`]) implement it, so the learner,
/// selector and actor loops run unchanged over either.
pub trait ServiceTransport: Transport + Send + Sync + 'static {
    /// An actor id held for as long as this value lives.
    type Claim: HeldClaim;

    /// Claims `actor_id` on this run so no two actors stream under one id; errors with
    /// [`TransportError::IdInUse`] while another live holder has it.
    fn claim_actor_id(&self, actor_id: u16) -> Result<Self::Claim, TransportError>;

    /// Removes the resources dead processes left (e.g. a killed learner's subscription, so it
    /// shows as no receiver); what was removed.
    fn cleanup_dead_nodes(&self) -> crate::StaleCleanup;

    /// Sleeps for `cycle`; `false` when the process should stop.
    fn wait(&self, cycle: Duration) -> bool;
}
