//! The subscriber side of one stream over shared memory.

use super::*;

/// Subscriber side of one stream over shared memory.
pub struct ShmSource<M: Message> {
    pub(super) label: String,
    pub(super) factory: PubSubFactory<ShmService, M, ()>,
    pub(super) subscriber: Subscriber<ShmService, M, ()>,
    pub(super) stats: Arc<TransportStats>,
    pub(super) _node: Arc<Node<ShmService>>,
}

impl<M: Message> core::fmt::Debug for ShmSource<M> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ShmSource")
            .field("service", &self.label)
            .field("stats", &self.stats.snapshot())
            .finish()
    }
}

impl<M: Message> ShmSource<M> {
    /// Shared counters, for a metrics exporter that outlives borrowing the source.
    pub fn stats_handle(&self) -> Arc<TransportStats> {
        Arc::clone(&self.stats)
    }

    /// Zero-copy receive: runs `f` on the message in shared memory and releases it.
    pub fn try_receive_with<R>(
        &mut self,
        f: impl FnOnce(&M) -> R,
    ) -> Result<Option<R>, TransportError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => {
                self.stats.add_received(1);
                Ok(Some(f(sample.payload())))
            }
            Ok(None) => Ok(None),
            Err(e) => Err(ipc_err("receive", &self.label, e)),
        }
    }
}

impl<M: Message> MessageSource<M> for ShmSource<M> {
    fn try_receive_into(&mut self, out: &mut M) -> Result<bool, TransportError> {
        Ok(self.try_receive_with(|m| *out = *m)?.is_some())
    }

    fn senders(&self) -> usize {
        self.factory.dynamic_config().number_of_publishers()
    }

    fn stats(&self) -> StatsSnapshot {
        self.stats.snapshot()
    }
}
