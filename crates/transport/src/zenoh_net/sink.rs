//! The sending end of one stream over Zenoh: per-receiver credit accounts (one per link and
//! epoch), the overflow policy, and the linger on drop.

use super::*;

/// A sink's credit account with one receiver.
pub(super) struct Link {
    pub(super) generation: u64,
    pub(super) epoch: u64,
    pub(super) sent: u64,
    /// Zenoh knows the receiver's subscriber (a put before that would go nowhere).
    pub(super) matched: bool,
    pub(super) publisher: Publisher<'static>,
}

/// Sending end of one stream over Zenoh.
pub struct ZenohSink<M: Message> {
    pub(super) label: String,
    pub(super) id: u64,
    pub(super) session: Session,
    pub(super) policy: OverflowPolicy,
    pub(super) buffer: u64,
    pub(super) block_timeout: Duration,
    pub(super) cancel: Arc<AtomicBool>,
    pub(super) shared: Arc<Shared>,
    pub(super) links: HashMap<u64, Link>,
    pub(super) frame: Vec<u8>,
    pub(super) stats: Arc<TransportStats>,
    pub(super) _token: LivelinessToken,
    pub(super) _acks: Subscriber<()>,
    pub(super) _receivers: Subscriber<()>,
    pub(super) _topic: std::marker::PhantomData<fn(M)>,
}

impl<M: Message> core::fmt::Debug for ZenohSink<M> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ZenohSink")
            .field("service", &self.label)
            .field("id", &format_args!("{:016x}", self.id))
            .field("policy", &self.policy)
            .field("stats", &self.stats.snapshot())
            .finish()
    }
}

/// What waiting for credit at one receiver ended in.
pub(super) enum Credit {
    Granted,
    Gone,
    Full,
    GaveUp(TransportError),
}

impl<M: Message> ZenohSink<M> {
    /// Shared counters, for a metrics exporter that outlives borrowing the sink.
    pub fn stats_handle(&self) -> Arc<TransportStats> {
        Arc::clone(&self.stats)
    }

    /// The stream's key (`terl/<run_id>/<topic>`).
    pub fn service_name(&self) -> &str {
        &self.label
    }

    /// Acks of the wrong size received (counted, ignored).
    pub fn rejected(&self) -> u64 {
        self.shared.rejected.load(Ordering::Relaxed)
    }

    fn link(&mut self, receiver: u64, generation: u64) -> Result<&mut Link, TransportError> {
        let stale = self
            .links
            .get(&receiver)
            .is_some_and(|l| l.generation != generation);
        if stale {
            self.links.remove(&receiver);
        }
        if !self.links.contains_key(&receiver) {
            let key = format!("{}/to/{receiver:016x}", self.label);
            let publisher = self
                .session
                .declare_publisher(key.clone())
                .congestion_control(CongestionControl::Block)
                .wait()
                .map_err(|e| zenoh_err("declare publisher", &key, e))?;
            self.links.insert(
                receiver,
                Link {
                    generation,
                    epoch: rand::random(),
                    sent: 0,
                    matched: false,
                    publisher,
                },
            );
        }
        Ok(self.links.get_mut(&receiver).expect("inserted above"))
    }

    /// Waits until Zenoh routes this link's puts to the receiver's subscriber (its
    /// declaration travels separately from its liveliness token). `Ok(false)`: the receiver
    /// went away or never matched within [`MATCH_TIMEOUT`].
    fn matched(&mut self, receiver: u64) -> Result<bool, TransportError> {
        let link = self.links.get(&receiver).expect("link exists");
        if link.matched {
            return Ok(true);
        }
        let (shared, cancel) = (&self.shared, &self.cancel);
        let matched = wait_until_routed(&link.publisher, &self.label, || {
            !lock(&shared.state).peers.contains_key(&receiver) || cancel.load(Ordering::Relaxed)
        })?;
        self.links.get_mut(&receiver).expect("link exists").matched = matched;
        Ok(matched)
    }

    /// Waits (per the policy) until `receiver` can take one more message of this link.
    fn credit(&self, receiver: u64, epoch: u64, sent: u64, saw_full: &mut bool) -> Credit {
        let start = Instant::now();
        let mut state = lock(&self.shared.state);
        loop {
            if !state.peers.contains_key(&receiver) {
                return Credit::Gone;
            }
            if sent.saturating_sub(state.consumed(receiver, epoch)) < self.buffer {
                return Credit::Granted;
            }
            if !*saw_full {
                *saw_full = true;
                self.stats.add_full_event();
            }
            match self.policy {
                OverflowPolicy::DropNewest => return Credit::Full,
                OverflowPolicy::Block => {
                    if self.cancel.load(Ordering::Relaxed) {
                        return Credit::GaveUp(TransportError::Cancelled(self.label.clone()));
                    }
                    let left = self.block_timeout.saturating_sub(start.elapsed());
                    if left.is_zero() {
                        return Credit::GaveUp(TransportError::BlockTimeout {
                            service: self.label.clone(),
                            waited: self.block_timeout,
                        });
                    }
                    state = self
                        .shared
                        .wake
                        .wait_timeout(state, left.min(BLOCK_POLL))
                        .unwrap_or_else(|e| e.into_inner())
                        .0;
                }
            }
        }
    }
}

impl<M: Message> ZenohSink<M> {
    /// Messages handed to Zenoh that a live receiver has not yet consumed (this epoch).
    fn unconsumed(&self, state: &PortState) -> u64 {
        self.links
            .iter()
            .filter(|(id, _)| state.peers.contains_key(id))
            .map(|(id, link)| link.sent.saturating_sub(state.consumed(*id, link.epoch)))
            .sum()
    }
}

/// Lingers up to [`SINK_LINGER`] (less once cancelled) until every live receiver has
/// consumed what this sink sent; what is still outstanding after that is lost with the
/// session and shows at the receiver as a gap in the sequence numbers.
impl<M: Message> Drop for ZenohSink<M> {
    fn drop(&mut self) {
        let start = Instant::now();
        let mut state = lock(&self.shared.state);
        loop {
            let outstanding = self.unconsumed(&state);
            if outstanding == 0 || self.cancel.load(Ordering::Relaxed) {
                return;
            }
            let left = SINK_LINGER.saturating_sub(start.elapsed());
            if left.is_zero() {
                tracing::debug!(
                    service = %self.label,
                    outstanding,
                    "sink closed with messages its receivers had not consumed"
                );
                return;
            }
            state = self
                .shared
                .wake
                .wait_timeout(state, left.min(BLOCK_POLL))
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

impl<M: Message> MessageSink<M> for ZenohSink<M> {
    fn send(&mut self, message: &M) -> Result<SendOutcome, TransportError> {
        let receivers: Vec<(u64, u64)> = {
            let state = lock(&self.shared.state);
            state.peers.iter().map(|(&id, &g)| (id, g)).collect()
        };
        self.links
            .retain(|id, _| receivers.iter().any(|(r, _)| r == id));
        self.frame[..8].copy_from_slice(&self.id.to_le_bytes());
        self.frame[HEADER_BYTES..].copy_from_slice(bytemuck::bytes_of(message));
        let losses = self.stats.losses();
        // Stamp in place: the frame holds a copy of the message.
        let body: &mut M = bytemuck::from_bytes_mut(&mut self.frame[HEADER_BYTES..]);
        body.set_losses(losses);
        let (mut delivered, mut dropped, mut gave_up, mut saw_full) = (0, false, None, false);
        // Like iceoryx2: a receiver given up on does not stop delivery to the others.
        for (receiver, generation) in receivers {
            let (epoch, sent) = {
                let link = self.link(receiver, generation)?;
                (link.epoch, link.sent)
            };
            if !self.matched(receiver)? {
                tracing::warn!(
                    service = %self.label,
                    receiver = format_args!("{receiver:016x}"),
                    "a receiver's token is live but its subscriber never became reachable"
                );
                continue;
            }
            match self.credit(receiver, epoch, sent, &mut saw_full) {
                Credit::Granted => {}
                Credit::Gone => continue,
                Credit::Full => {
                    dropped = true;
                    continue;
                }
                Credit::GaveUp(e) => {
                    gave_up = Some(e);
                    continue;
                }
            }
            self.frame[8..HEADER_BYTES].copy_from_slice(&epoch.to_le_bytes());
            let frame = self.frame.clone();
            let link = self.links.get_mut(&receiver).expect("created above");
            link.publisher
                .put(frame)
                .wait()
                .map_err(|e| zenoh_err("put", &self.label, e))?;
            link.sent += 1;
            delivered += 1;
        }
        if let Some(e) = gave_up {
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
        lock(&self.shared.state).peers.len()
    }

    fn stats(&self) -> StatsSnapshot {
        self.stats.snapshot()
    }
}
