//! The in-memory twin of the shared-memory transport, for tests of the logic above the seam.
//!
//! Same contract as [`crate::shm`]: every subscriber gets every message sent after it
//! subscribed (broadcast, no history), each subscriber has a bounded buffer of the
//! configured size, a full buffer is handled by the same [`OverflowPolicy`] and counted the
//! same way, publisher/subscriber limits are enforced, and run ids keep streams apart.

use std::any::Any;
use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, SendTimeoutError, Sender, TrySendError};

use crate::channel::{Message, MessageSink, MessageSource, ServiceTransport, Transport};
use crate::config::TransportConfig;
use crate::error::TransportError;
use crate::flow::{OverflowPolicy, SendOutcome, StatsSnapshot, TransportStats};

/// The "host": shared by every [`MemoryTransport`] that should see each other's streams.
#[derive(Debug, Clone, Default)]
pub struct MemoryBus {
    topics: Arc<Mutex<HashMap<String, TopicState>>>,
    next_id: Arc<AtomicU64>,
    /// Actor ids held, as `terl/<run_id>/claims/actor-<id>`.
    claims: Arc<Mutex<HashSet<String>>>,
}

#[derive(Default)]
struct TopicState {
    publishers: usize,
    /// `(subscriber id, Sender<Box<M>>)`, type-erased because one map holds all topics.
    subscribers: Vec<(u64, Box<dyn Any + Send>)>,
}

impl core::fmt::Debug for TopicState {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("TopicState")
            .field("publishers", &self.publishers)
            .field("subscribers", &self.subscribers.len())
            .finish()
    }
}

impl MemoryBus {
    fn lock(&self) -> MutexGuard<'_, HashMap<String, TopicState>> {
        // A panic while holding the lock leaves plain counters behind; keep going.
        self.topics.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// An in-process transport for one run on a [`MemoryBus`].
#[derive(Debug, Clone)]
pub struct MemoryTransport {
    bus: MemoryBus,
    config: TransportConfig,
    cancel: Arc<AtomicBool>,
}

impl MemoryTransport {
    /// A transport on its own fresh bus.
    pub fn new(config: TransportConfig) -> Result<Self, TransportError> {
        Self::on_bus(MemoryBus::default(), config)
    }

    /// A transport sharing `bus` with others (like processes sharing a host).
    pub fn on_bus(bus: MemoryBus, config: TransportConfig) -> Result<Self, TransportError> {
        config.validate()?;
        Ok(Self {
            bus,
            config,
            cancel: Arc::default(),
        })
    }

    /// The bus this transport's sinks and sources meet on.
    pub fn bus(&self) -> &MemoryBus {
        &self.bus
    }

    /// The configuration this transport was created with.
    pub fn config(&self) -> &TransportConfig {
        &self.config
    }

    /// A sink with the config's overflow policy.
    pub fn memory_sink<M: Message>(&self) -> Result<MemorySink<M>, TransportError> {
        self.memory_sink_with(self.config.overflow)
    }

    /// A sink with overflow policy `policy`; [`TransportError::Ipc`] when the topic already has its
    /// `max_publishers`.
    pub fn memory_sink_with<M: Message>(
        &self,
        policy: OverflowPolicy,
    ) -> Result<MemorySink<M>, TransportError> {
        let label = self.config.service_name(M::TOPIC);
        let limits = self.config.limits(M::TOPIC);
        let mut topics = self.bus.lock();
        let state = topics.entry(label.clone()).or_default();
        if state.publishers >= limits.max_publishers {
            return Err(TransportError::Ipc {
                operation: "publisher creation",
                service: label,
                detail: "ExceedsMaxSupportedPublishers".into(),
            });
        }
        state.publishers += 1;
        drop(topics);
        Ok(MemorySink {
            bus: self.bus.clone(),
            label,
            policy,
            config: self.config.clone(),
            cancel: Arc::clone(&self.cancel),
            stats: Arc::default(),
            _topic: std::marker::PhantomData,
        })
    }

    /// A source on `M`'s topic; [`TransportError::Ipc`] when the topic already has its
    /// `max_subscribers`.
    pub fn memory_source<M: Message>(&self) -> Result<MemorySource<M>, TransportError> {
        let label = self.config.service_name(M::TOPIC);
        let limits = self.config.limits(M::TOPIC);
        let mut topics = self.bus.lock();
        let state = topics.entry(label.clone()).or_default();
        if state.subscribers.len() >= limits.max_subscribers {
            return Err(TransportError::Ipc {
                operation: "subscriber creation",
                service: label,
                detail: "ExceedsMaxSupportedSubscribers".into(),
            });
        }
        let (tx, rx) = crossbeam_channel::bounded::<Box<M>>(limits.subscriber_buffer);
        let id = self.bus.next_id.fetch_add(1, Ordering::Relaxed);
        state.subscribers.push((id, Box::new(tx)));
        drop(topics);
        Ok(MemorySource {
            bus: self.bus.clone(),
            label,
            id,
            rx,
            stats: Arc::default(),
        })
    }
}

impl Transport for MemoryTransport {
    fn sink<M: Message>(&self) -> Result<Box<dyn MessageSink<M>>, TransportError> {
        Ok(Box::new(self.memory_sink::<M>()?))
    }

    fn source<M: Message>(&self) -> Result<Box<dyn MessageSource<M>>, TransportError> {
        Ok(Box::new(self.memory_source::<M>()?))
    }

    fn cancel_blocked_sends(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

impl ServiceTransport for MemoryTransport {
    type Claim = MemoryClaim;

    /// Like the shared-memory claim: one holder per actor id and run on this bus, released
    /// when the [`MemoryClaim`] is dropped.
    fn claim_actor_id(&self, actor_id: u16) -> Result<MemoryClaim, TransportError> {
        let label = format!("terl/{}/claims/actor-{actor_id}", self.config.run_id);
        let mut claims = self.bus.claims.lock().unwrap_or_else(|e| e.into_inner());
        if !claims.insert(label.clone()) {
            return Err(TransportError::IdInUse {
                what: format!("actor id {actor_id}"),
                run_id: self.config.run_id.clone(),
                service: label,
            });
        }
        Ok(MemoryClaim {
            claims: Arc::clone(&self.bus.claims),
            label,
        })
    }

    /// Nothing to do: in one process nothing outlives its holder.
    fn cleanup_dead_nodes(&self) -> crate::StaleCleanup {
        crate::StaleCleanup::default()
    }

    fn wait(&self, cycle: Duration) -> bool {
        std::thread::sleep(cycle);
        true
    }
}

/// An actor id held on a [`MemoryBus`] (see [`MemoryTransport`]'s `claim_actor_id`);
/// released when dropped.
#[derive(Debug)]
pub struct MemoryClaim {
    claims: Arc<Mutex<HashSet<String>>>,
    label: String,
}

impl crate::channel::HeldClaim for MemoryClaim {}

impl Drop for MemoryClaim {
    fn drop(&mut self) {
        self.claims
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .remove(&self.label);
    }
}

/// In-memory publisher.
#[derive(Debug)]
pub struct MemorySink<M: Message> {
    bus: MemoryBus,
    label: String,
    policy: OverflowPolicy,
    config: TransportConfig,
    cancel: Arc<AtomicBool>,
    stats: Arc<TransportStats>,
    _topic: std::marker::PhantomData<fn(M)>,
}

impl<M: Message> MemorySink<M> {
    fn subscriber_senders(&self) -> Vec<Sender<Box<M>>> {
        let topics = self.bus.lock();
        topics
            .get(&self.label)
            .map(|state| {
                state
                    .subscribers
                    .iter()
                    .filter_map(|(_, tx)| tx.downcast_ref::<Sender<Box<M>>>().cloned())
                    .collect()
            })
            .unwrap_or_default()
    }
}

/// Slice of a blocked send between checks of the cancel flag.
const CANCEL_POLL: Duration = Duration::from_millis(5);

impl<M: Message> MemorySink<M> {
    /// Waits for room; `Ok(false)` when the receiver went away meanwhile.
    fn block_until_sent(
        &self,
        tx: &Sender<Box<M>>,
        mut boxed: Box<M>,
    ) -> Result<bool, TransportError> {
        let start = Instant::now();
        loop {
            if self.cancel.load(Ordering::Relaxed) {
                return Err(TransportError::Cancelled(self.label.clone()));
            }
            let left = self.config.block_timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(TransportError::BlockTimeout {
                    service: self.label.clone(),
                    waited: self.config.block_timeout,
                });
            }
            match tx.send_timeout(boxed, left.min(CANCEL_POLL)) {
                Ok(()) => return Ok(true),
                Err(SendTimeoutError::Disconnected(_)) => return Ok(false),
                Err(SendTimeoutError::Timeout(back)) => boxed = back,
            }
        }
    }
}

impl<M: Message> MessageSink<M> for MemorySink<M> {
    fn send(&mut self, message: &M) -> Result<SendOutcome, TransportError> {
        let senders = self.subscriber_senders();
        let mut delivered = 0;
        let mut dropped = false;
        let mut stamped = *message;
        stamped.set_losses(self.stats.losses());
        // Like iceoryx2: a receiver given up on does not stop delivery to the others.
        let mut gave_up = None;
        for tx in senders {
            match tx.try_send(Box::new(stamped)) {
                Ok(()) => delivered += 1,
                Err(TrySendError::Disconnected(_)) => {}
                Err(TrySendError::Full(boxed)) => {
                    self.stats.add_full_event();
                    match self.policy {
                        OverflowPolicy::DropNewest => dropped = true,
                        OverflowPolicy::Block => match self.block_until_sent(&tx, boxed) {
                            Ok(true) => delivered += 1,
                            Ok(false) => {}
                            Err(e) => gave_up = Some(e),
                        },
                    }
                }
            }
        }
        if let Some(e) = gave_up {
            // Dropped for a full receiver: counted, and reported in the next message's stamp.
            self.stats.record_given_up(message.items());
            return Err(e);
        }
        let outcome = if dropped {
            SendOutcome::Full
        } else if delivered == 0 {
            SendOutcome::NoReceiver
        } else {
            SendOutcome::Delivered
        };
        self.stats.record(outcome, message.items());
        Ok(outcome)
    }

    fn receivers(&self) -> usize {
        let topics = self.bus.lock();
        topics.get(&self.label).map_or(0, |s| s.subscribers.len())
    }

    fn stats(&self) -> StatsSnapshot {
        self.stats.snapshot()
    }
}

impl<M: Message> Drop for MemorySink<M> {
    fn drop(&mut self) {
        if let Some(state) = self.bus.lock().get_mut(&self.label) {
            state.publishers = state.publishers.saturating_sub(1);
        }
    }
}

/// In-memory subscriber.
#[derive(Debug)]
pub struct MemorySource<M: Message> {
    bus: MemoryBus,
    label: String,
    id: u64,
    rx: Receiver<Box<M>>,
    stats: Arc<TransportStats>,
}

impl<M: Message> MessageSource<M> for MemorySource<M> {
    fn try_receive_into(&mut self, out: &mut M) -> Result<bool, TransportError> {
        match self.rx.try_recv() {
            Ok(message) => {
                *out = *message;
                self.stats.add_received(1);
                Ok(true)
            }
            Err(crossbeam_channel::TryRecvError::Empty) => Ok(false),
            Err(crossbeam_channel::TryRecvError::Disconnected) => {
                Err(TransportError::Closed(self.label.clone()))
            }
        }
    }

    fn try_receive(&mut self) -> Result<Option<Box<M>>, TransportError> {
        match self.rx.try_recv() {
            Ok(message) => {
                self.stats.add_received(1);
                Ok(Some(message))
            }
            Err(crossbeam_channel::TryRecvError::Empty) => Ok(None),
            Err(crossbeam_channel::TryRecvError::Disconnected) => {
                Err(TransportError::Closed(self.label.clone()))
            }
        }
    }

    fn senders(&self) -> usize {
        let topics = self.bus.lock();
        topics.get(&self.label).map_or(0, |s| s.publishers)
    }

    fn stats(&self) -> StatsSnapshot {
        self.stats.snapshot()
    }
}

impl<M: Message> Drop for MemorySource<M> {
    fn drop(&mut self) {
        if let Some(state) = self.bus.lock().get_mut(&self.label) {
            state.subscribers.retain(|(id, _)| *id != self.id);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One holder per actor id and run on a bus; another run on the same bus, or the same id
    /// after the holder dropped its claim, is free.
    #[test]
    fn an_actor_id_is_held_once_per_run_until_the_claim_is_dropped() {
        let bus = MemoryBus::default();
        let a = MemoryTransport::on_bus(bus.clone(), TransportConfig::new("claims-a", 2)).unwrap();
        let b = MemoryTransport::on_bus(bus.clone(), TransportConfig::new("claims-a", 2)).unwrap();
        let other = MemoryTransport::on_bus(bus, TransportConfig::new("claims-b", 2)).unwrap();
        let held = a.claim_actor_id(0).unwrap();
        match b.claim_actor_id(0) {
            Err(TransportError::IdInUse { what, run_id, .. }) => {
                assert_eq!((what.as_str(), run_id.as_str()), ("actor id 0", "claims-a"));
            }
            other => panic!("{other:?}"),
        }
        let _one = b.claim_actor_id(1).unwrap();
        let _elsewhere = other.claim_actor_id(0).unwrap();
        drop(held);
        let _again = b.claim_actor_id(0).unwrap();
    }
}
