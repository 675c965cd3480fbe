//! The publisher side of one stream over shared memory: loans, back-pressure by policy, and
//! counted drops.

use super::*;

/// Publisher side of one stream over shared memory.
pub struct ShmSink<M: Message> {
    pub(super) label: String,
    pub(super) factory: PubSubFactory<ShmService, M, ()>,
    pub(super) publisher: Publisher<ShmService, M, ()>,
    pub(super) policy: OverflowPolicy,
    pub(super) block_timeout: Duration,
    /// Receivers found full, counted by the back-pressure handler.
    pub(super) full_hits: Arc<AtomicU64>,
    /// Set by `cancel_blocked_sends`: blocked sends give up.
    pub(super) cancel: Arc<AtomicBool>,
    pub(super) stats: Arc<TransportStats>,
    // Keeps the node alive as long as its ports.
    pub(super) _node: Arc<Node<ShmService>>,
}

impl<M: Message> core::fmt::Debug for ShmSink<M> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ShmSink")
            .field("service", &self.label)
            .field("policy", &self.policy)
            .field("stats", &self.stats.snapshot())
            .finish()
    }
}

/// Poll interval of a `Block` send waiting for a receiver that has not attached yet.
const UNATTACHED_RETRY: Duration = Duration::from_micros(200);

impl<M: Message> ShmSink<M> {
    /// A `Block` send gives up on a full receiver: the message is dropped and counted (and
    /// reported in the stamp of the next message).
    fn give_up(&self, message: &M) -> TransportError {
        self.stats.record_given_up(message.items());
        self.block_timeout_error()
    }

    fn block_timeout_error(&self) -> TransportError {
        if self.cancel.load(Ordering::Relaxed) {
            return TransportError::Cancelled(self.label.clone());
        }
        TransportError::BlockTimeout {
            service: self.label.clone(),
            waited: self.block_timeout,
        }
    }

    /// Shared counters, for a metrics exporter that outlives borrowing the sink.
    pub fn stats_handle(&self) -> Arc<TransportStats> {
        Arc::clone(&self.stats)
    }

    /// The iceoryx2 service this sink publishes on (`terl/<run_id>/<topic>`).
    pub fn service_name(&self) -> &str {
        &self.label
    }
}

impl<M: Message> MessageSink<M> for ShmSink<M> {
    fn send(&mut self, message: &M) -> Result<SendOutcome, TransportError> {
        let start = Instant::now();
        let mut saw_full = false;
        loop {
            let hits_before = self.full_hits.load(Ordering::Relaxed);
            let sample = self
                .publisher
                .loan_uninit()
                .map_err(|e| ipc_err("loan", &self.label, e))?;
            let mut sample = sample.write_payload(*message);
            sample.payload_mut().set_losses(self.stats.losses());
            let result = sample.send();
            // The handler runs when an attached receiver is full.
            let handler_saw_full = self.full_hits.load(Ordering::Relaxed) != hits_before;
            let delivered = match result {
                Ok(n) => n,
                Err(SendError::UnableToDeliver) => return Err(self.give_up(message)),
                Err(e) => return Err(ipc_err("send", &self.label, e)),
            };
            // A subscriber attaches its end of the queue on its first receive; until then
            // messages queue up to its buffer size and beyond that iceoryx2 reports 0
            // recipients instead of calling the handler. That is a full receiver too.
            let unattached_full = delivered == 0 && !handler_saw_full && self.receivers() > 0;
            if (handler_saw_full || unattached_full) && !saw_full {
                saw_full = true;
                self.stats.add_full_event();
            }
            let outcome = if unattached_full {
                match self.policy {
                    OverflowPolicy::DropNewest => SendOutcome::Full,
                    OverflowPolicy::Block
                        if start.elapsed() >= self.block_timeout
                            || self.cancel.load(Ordering::Relaxed) =>
                    {
                        return Err(self.give_up(message))
                    }
                    OverflowPolicy::Block => {
                        std::thread::sleep(UNATTACHED_RETRY);
                        continue;
                    }
                }
            } else if handler_saw_full && self.policy == OverflowPolicy::DropNewest {
                SendOutcome::Full
            } else if delivered == 0 {
                SendOutcome::NoReceiver
            } else {
                SendOutcome::Delivered
            };
            self.stats.record(outcome, message.items());
            return Ok(outcome);
        }
    }

    fn receivers(&self) -> usize {
        self.factory.dynamic_config().number_of_subscribers()
    }

    fn stats(&self) -> StatsSnapshot {
        self.stats.snapshot()
    }
}
