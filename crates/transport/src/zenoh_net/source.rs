//! The receiving end of one stream over Zenoh: frames decoded into a bounded queue and every
//! handed-out message acknowledged to its sender (one credit back).

use super::*;

pub(super) struct Incoming<M> {
    pub(super) sender: u64,
    pub(super) epoch: u64,
    pub(super) message: Box<M>,
}

/// Receiving end of one stream over Zenoh.
pub struct ZenohSource<M: Message> {
    pub(super) label: String,
    pub(super) id: u64,
    pub(super) prefix: String,
    pub(super) session: Session,
    pub(super) rx: Receiver<Incoming<M>>,
    pub(super) shared: Arc<Shared>,
    /// Sender id → (epoch, messages handed out in that epoch).
    pub(super) consumed: HashMap<u64, (u64, u64)>,
    pub(super) ack_publishers: HashMap<u64, Publisher<'static>>,
    pub(super) stats: Arc<TransportStats>,
    pub(super) _token: LivelinessToken,
    pub(super) _data: Subscriber<()>,
    pub(super) _senders: Subscriber<()>,
}

impl<M: Message> core::fmt::Debug for ZenohSource<M> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ZenohSource")
            .field("service", &self.label)
            .field("id", &format_args!("{:016x}", self.id))
            .field("stats", &self.stats.snapshot())
            .finish()
    }
}

impl<M: Message> ZenohSource<M> {
    /// Shared counters, for a metrics exporter that outlives borrowing the source.
    pub fn stats_handle(&self) -> Arc<TransportStats> {
        Arc::clone(&self.stats)
    }

    /// Frames of the wrong length, or beyond the queue's bound, received (counted, dropped).
    pub fn rejected(&self) -> u64 {
        self.shared.rejected.load(Ordering::Relaxed)
    }

    fn take(&mut self) -> Result<Option<Box<M>>, TransportError> {
        let incoming = match self.rx.try_recv() {
            Ok(i) => i,
            Err(crossbeam_channel::TryRecvError::Empty) => return Ok(None),
            Err(crossbeam_channel::TryRecvError::Disconnected) => {
                return Err(TransportError::Closed(self.label.clone()))
            }
        };
        self.stats.add_received(1);
        let entry = self
            .consumed
            .entry(incoming.sender)
            .or_insert((incoming.epoch, 0));
        if entry.0 != incoming.epoch {
            *entry = (incoming.epoch, 0);
        }
        entry.1 += 1;
        let consumed = entry.1;
        if !self.ack_publishers.contains_key(&incoming.sender) {
            let key = format!("{}/ack/{:016x}", self.prefix, incoming.sender);
            let publisher = self
                .session
                .declare_publisher(key.clone())
                .congestion_control(CongestionControl::Block)
                .wait()
                .map_err(|e| zenoh_err("declare publisher", &key, e))?;
            // As for a sink's data link: the first puts of a new publisher can be dropped
            // until Zenoh routes it to the subscriber (a client learns of it through its
            // router), and a sender whose first acks are all lost waits for credit forever.
            wait_until_routed(&publisher, &key, || false)?;
            self.ack_publishers.insert(incoming.sender, publisher);
        }
        let mut ack = [0u8; ACK_BYTES];
        ack[..8].copy_from_slice(&self.id.to_le_bytes());
        ack[8..16].copy_from_slice(&incoming.epoch.to_le_bytes());
        ack[16..].copy_from_slice(&consumed.to_le_bytes());
        self.ack_publishers[&incoming.sender]
            .put(ack.to_vec())
            .wait()
            .map_err(|e| zenoh_err("ack", &self.label, e))?;
        Ok(Some(incoming.message))
    }
}

impl<M: Message> MessageSource<M> for ZenohSource<M> {
    fn try_receive_into(&mut self, out: &mut M) -> Result<bool, TransportError> {
        Ok(match self.take()? {
            Some(m) => {
                *out = *m;
                true
            }
            None => false,
        })
    }

    fn try_receive(&mut self) -> Result<Option<Box<M>>, TransportError> {
        self.take()
    }

    fn senders(&self) -> usize {
        lock(&self.shared.state).peers.len()
    }

    fn stats(&self) -> StatsSnapshot {
        self.stats.snapshot()
    }
}

/// Decodes one frame into the source's queue, counting what cannot be used.
pub(super) fn deliver<M: Message>(shared: &Shared, tx: &Sender<Incoming<M>>, bytes: &[u8]) {
    let body = bytes.get(HEADER_BYTES..).unwrap_or_default();
    let (Some(sender), Some(epoch)) = (read_u64(bytes, 0), read_u64(bytes, 8)) else {
        shared.rejected.fetch_add(1, Ordering::Relaxed);
        return;
    };
    if body.len() != core::mem::size_of::<M>() {
        shared.rejected.fetch_add(1, Ordering::Relaxed);
        tracing::warn!(
            got = body.len(),
            want = core::mem::size_of::<M>(),
            "zenoh frame of the wrong length rejected (a sender of another version?)"
        );
        return;
    }
    let mut message = M::empty();
    bytemuck::bytes_of_mut(&mut *message).copy_from_slice(body);
    match tx.try_send(Incoming {
        sender,
        epoch,
        message,
    }) {
        Ok(()) => {}
        Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
            shared.rejected.fetch_add(1, Ordering::Relaxed);
        }
    }
}
