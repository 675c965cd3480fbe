//! Flow control: what happens when a receiver falls behind, how it is counted, and the
//! learner's update-to-data limiter.
//!
//! The chain of back-pressure, end to end:
//!
//! 1. The learner asks its [`RateLimiter`] before draining the transition source
//!    ([`RateLimiter::can_insert`]) and before each update ([`RateLimiter::can_sample`]).
//!    When training falls behind the configured ratio it stops draining.
//! 2. The subscriber's bounded buffer (`TransportConfig::buffer_batches`) fills up.
//! 3. The actor's next send meets a full buffer. What happens is the sink's
//!    [`OverflowPolicy`]: `Block` waits until the learner drains (the actor slows down to the
//!    learner's pace — nothing is lost), `DropNewest` returns [`SendOutcome::Full`] at once and
//!    the message is dropped. Either way the event is counted in [`TransportStats`]; nothing is
//!    ever overwritten or lost without a count (iceoryx2's "safe overflow", which silently
//!    replaces the oldest sample, is switched off).
//! 4. A `Block` send that is still waiting after the block timeout (the receiver stopped or
//!    stalled) gives up with `TransportError::BlockTimeout`; the message is dropped and counted
//!    in `dropped`/`dropped_items` exactly like a `DropNewest` drop.
//!
//! ## How a receiver learns what it lost
//!
//! A sender's counters alone would leave the loss visible only in the sender's own log. So the
//! transport **stamps every message it sends with its sink's cumulative [`Losses`]** (messages
//! and items given up on before this one: [`Message::set_losses`](crate::Message)). The first
//! message that gets through after an outage tells the receiver exactly how many messages, and
//! how many transitions/episodes/samples inside them, never reached it. A [`LossTracker`] on the
//! receiving side folds the stamps of every sender (keyed by sender id, e.g. the actor id) into
//! per-sender and total counts that survive sender restarts, and also counts gaps in each
//! sender's sequence numbers: messages *this* receiver never got, which on a stream with two
//! receivers (episodes: selector and learner) is the receiver's own share of the loss.
//! Losses after the last delivered message are reported with the next one; a sender that never
//! gets a message through again reports them only in its own log.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

/// What a sink does when a receiver's buffer is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OverflowPolicy {
    /// Wait until the receiver has room (up to the sink's block timeout, after which `send`
    /// fails with `TransportError::BlockTimeout` and the message is *not* delivered).
    /// Lossless; the sender runs at the receiver's pace.
    Block,
    /// Do not wait: the message is not delivered to the full receiver, `send` returns
    /// [`SendOutcome::Full`] and `dropped` is incremented.
    DropNewest,
}

/// Result of a successful `send`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SendOutcome {
    /// Delivered to every connected receiver.
    Delivered,
    /// At least one receiver's buffer was full and the policy (`DropNewest`) dropped the
    /// message for it. Counted in `dropped` and `full_events`.
    Full,
    /// No receiver was connected, so nobody got the message. Counted in `no_receiver`, and
    /// also in `dropped` once the port has had a receiver (the peer went away: a restarted
    /// learner, a link down past Zenoh's lease). Use `wait_for_receivers` at start-up so
    /// this only happens when a peer has gone.
    NoReceiver,
}

/// Lock-free counters shared between a port and whoever reports metrics.
#[derive(Debug, Default)]
pub struct TransportStats {
    sent: AtomicU64,
    received: AtomicU64,
    dropped: AtomicU64,
    dropped_items: AtomicU64,
    full_events: AtomicU64,
    no_receiver: AtomicU64,
    /// Whether any send has found a receiver (from then on, reaching nobody is a loss).
    had_receiver: AtomicBool,
}

/// A point-in-time copy of [`TransportStats`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StatsSnapshot {
    /// Messages handed to at least one receiver.
    pub sent: u64,
    /// Messages taken out of a source.
    pub received: u64,
    /// Messages lost: not delivered to a receiver because it was full (dropped at once by
    /// `DropNewest`, or given up on by a `Block` send after the block timeout,
    /// `TransportError::BlockTimeout`, or on shutdown, `TransportError::Cancelled`), or sent
    /// to nobody after the port had had a receiver (the receiver went away).
    pub dropped: u64,
    /// Items inside the `dropped` messages ([`Message::items`](crate::Message::items):
    /// transitions of a batch, 1 per episode, selected samples of a batch).
    pub dropped_items: u64,
    /// Sends that found a receiver's buffer full (whether they then blocked or dropped).
    pub full_events: u64,
    /// Sends that found no receiver connected (message reached nobody), before the first
    /// receiver as well as after one went away.
    pub no_receiver: u64,
}

impl TransportStats {
    /// The current counters (each read atomically, not all at one instant).
    pub fn snapshot(&self) -> StatsSnapshot {
        StatsSnapshot {
            sent: self.sent.load(Ordering::Relaxed),
            received: self.received.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
            dropped_items: self.dropped_items.load(Ordering::Relaxed),
            full_events: self.full_events.load(Ordering::Relaxed),
            no_receiver: self.no_receiver.load(Ordering::Relaxed),
        }
    }

    pub(crate) fn add_received(&self, n: u64) {
        self.received.fetch_add(n, Ordering::Relaxed);
    }

    pub(crate) fn add_full_event(&self) {
        self.full_events.fetch_add(1, Ordering::Relaxed);
    }

    /// Records the outcome of one send of a message holding `items` items.
    pub(crate) fn record(&self, outcome: SendOutcome, items: u64) {
        let counter = match outcome {
            SendOutcome::Delivered => {
                self.had_receiver.store(true, Ordering::Relaxed);
                &self.sent
            }
            SendOutcome::Full => {
                self.had_receiver.store(true, Ordering::Relaxed);
                self.dropped_items.fetch_add(items, Ordering::Relaxed);
                &self.dropped
            }
            SendOutcome::NoReceiver => {
                if self.had_receiver.load(Ordering::Relaxed) {
                    self.dropped.fetch_add(1, Ordering::Relaxed);
                    self.dropped_items.fetch_add(items, Ordering::Relaxed);
                }
                &self.no_receiver
            }
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// Records a send that gave up on a full receiver with an error (block timeout or
    /// cancellation): the message of `items` items is dropped.
    pub(crate) fn record_given_up(&self, items: u64) {
        self.had_receiver.store(true, Ordering::Relaxed);
        self.dropped.fetch_add(1, Ordering::Relaxed);
        self.dropped_items.fetch_add(items, Ordering::Relaxed);
    }

    /// What the next message sent should be stamped with.
    pub fn losses(&self) -> Losses {
        Losses {
            messages: self.dropped.load(Ordering::Relaxed),
            items: self.dropped_items.load(Ordering::Relaxed),
        }
    }
}

/// A sender's cumulative losses on one stream, stamped by the transport on every message the
/// sender's sink sends (see the module docs): messages (and the items inside them) that the
/// sink gave up on because a receiver stayed full — `StatsSnapshot::dropped` and
/// `dropped_items` at the moment of sending. Counted since the sink was created, so a restarted
/// sender starts again at zero ([`LossTracker`] handles that). 16 bytes of plain data.
#[derive(
    Debug,
    Clone,
    Copy,
    Default,
    PartialEq,
    Eq,
    ZeroCopySend,
    bytemuck::Pod,
    bytemuck::Zeroable,
    Serialize,
    Deserialize,
)]
#[repr(C)]
pub struct Losses {
    /// Messages not delivered to at least one receiver.
    pub messages: u64,
    /// Items (transitions, episodes, selected samples) inside those messages.
    pub items: u64,
}

const _: () = assert!(core::mem::size_of::<Losses>() == 16);

impl Losses {
    /// No losses.
    pub const ZERO: Losses = Losses {
        messages: 0,
        items: 0,
    };

    fn saturating_add(self, other: Losses) -> Losses {
        Losses {
            messages: self.messages.saturating_add(other.messages),
            items: self.items.saturating_add(other.items),
        }
    }

    /// True when either count is below `other`'s (a cumulative count went backwards).
    fn below(self, other: Losses) -> bool {
        self.messages < other.messages || self.items < other.items
    }
}

/// What a receiver knows about one sender's losses (see [`LossTracker`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SenderLosses {
    /// Losses the sender reported (its stamps), summed over its restarts.
    pub reported: Losses,
    /// Messages this receiver never got: gaps in the sender's sequence numbers, counted from
    /// the first message received of each sender lifetime.
    pub missed: u64,
    /// Sender restarts seen (sequence number or stamp went backwards).
    pub restarts: u64,
}

/// Receiver-side loss accounting over many senders, from the [`Losses`] stamp and the
/// per-sender sequence number of every message received.
///
/// Per sender: the stamp is cumulative over one sender lifetime, so the latest stamp is the
/// lifetime's total; when the sequence number or the stamp goes backwards the sender has
/// restarted (a new process counts from zero) and the previous lifetime's total is kept.
/// A gap in the sequence numbers (`sequence > previous + 1`) is `sequence − previous − 1`
/// messages this receiver never got. Senders must number their messages 0, 1, 2, … per
/// lifetime, counting messages that were not delivered too (as the actors do).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LossTracker {
    senders: std::collections::BTreeMap<u16, Tracked>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Tracked {
    /// Totals of earlier lifetimes plus gaps so far.
    base: SenderLosses,
    /// The current lifetime's latest stamp.
    stamp: Losses,
    last_sequence: Option<u64>,
}

impl LossTracker {
    /// A tracker that has seen no sender.
    pub fn new() -> Self {
        Self::default()
    }

    /// Records one received message of `sender` with its `sequence` number and `stamp`.
    /// Returns the gap before it (messages of this sender missed just before this one).
    pub fn observe(&mut self, sender: u16, sequence: u64, stamp: Losses) -> u64 {
        let t = self.senders.entry(sender).or_default();
        let mut gap = 0;
        match t.last_sequence {
            Some(last) if sequence <= last || stamp.below(t.stamp) => {
                // A new lifetime of this sender: keep the old one's total.
                t.base.reported = t.base.reported.saturating_add(t.stamp);
                t.base.restarts += 1;
            }
            Some(last) => gap = sequence - last - 1,
            None => {}
        }
        t.base.missed = t.base.missed.saturating_add(gap);
        t.stamp = stamp;
        t.last_sequence = Some(sequence);
        gap
    }

    /// Everything known about `sender` (zero when nothing was received from it).
    pub fn sender(&self, sender: u16) -> SenderLosses {
        self.senders
            .get(&sender)
            .map_or_else(SenderLosses::default, |t| SenderLosses {
                reported: t.base.reported.saturating_add(t.stamp),
                ..t.base
            })
    }

    /// Per sender, in sender id order.
    pub fn senders(&self) -> impl Iterator<Item = (u16, SenderLosses)> + '_ {
        self.senders.keys().map(|&id| (id, self.sender(id)))
    }

    /// Sum over senders.
    pub fn total(&self) -> SenderLosses {
        self.senders()
            .fold(SenderLosses::default(), |acc, (_, s)| SenderLosses {
                reported: acc.reported.saturating_add(s.reported),
                missed: acc.missed.saturating_add(s.missed),
                restarts: acc.restarts + s.restarts,
            })
    }
}

/// How long a `Block` send waits for room before giving up with an error, by default.
/// Long enough for a learner pause (checkpoint, evaluation), short enough that a wedged
/// learner surfaces as an error rather than a hung actor.
pub const DEFAULT_BLOCK_TIMEOUT: Duration = Duration::from_secs(30);

/// Errors in the rate limiter's configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RateLimiterError {
    /// `samples_per_insert` is not finite or not positive (the value given).
    #[error("samples_per_insert must be finite and > 0, got {0}")]
    SamplesPerInsert(f64),
    /// `error_buffer` is below `max(1, samples_per_insert)`, so neither inserts nor samples
    /// could proceed.
    #[error(
        "error_buffer {error_buffer} is too small: it must be at least max(1, samples_per_insert) \
         = {needed}, otherwise neither inserts nor samples can proceed (deadlock)"
    )]
    ErrorBuffer {
        /// The slack given, in samples.
        error_buffer: f64,
        /// The smallest slack accepted: `max(1, samples_per_insert)`.
        needed: f64,
    },
}

/// Keeps the ratio of samples (learner updates) to inserts (transitions added to replay)
/// near `samples_per_insert`, like Reverb's `SampleToInsertRatio` limiter.
///
/// With `diff = inserts · samples_per_insert − samples`, the limiter keeps `diff` within
/// `samples_per_insert · min_size_to_sample ± error_buffer` once `min_size_to_sample`
/// inserts have happened; before that, inserts are always allowed and samples never are.
/// A pure value: the learner calls `record_*` as it goes and asks `can_*` before acting.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RateLimiter {
    samples_per_insert: f64,
    min_size_to_sample: u64,
    error_buffer: f64,
    inserts: u64,
    samples: u64,
}

impl RateLimiter {
    /// `samples_per_insert`: learner updates per inserted transition (the update-to-data
    /// ratio). `min_size_to_sample`: inserts before the first update. `error_buffer`: slack
    /// around the target, in samples; must be ≥ max(1, samples_per_insert).
    pub fn new(
        samples_per_insert: f64,
        min_size_to_sample: u64,
        error_buffer: f64,
    ) -> Result<Self, RateLimiterError> {
        if !(samples_per_insert.is_finite() && samples_per_insert > 0.0) {
            return Err(RateLimiterError::SamplesPerInsert(samples_per_insert));
        }
        let needed = samples_per_insert.max(1.0);
        if error_buffer.is_nan() || error_buffer < needed {
            return Err(RateLimiterError::ErrorBuffer {
                error_buffer,
                needed,
            });
        }
        Ok(Self {
            samples_per_insert,
            min_size_to_sample,
            error_buffer,
            inserts: 0,
            samples: 0,
        })
    }

    fn diff_after(&self, inserts: u64, samples: u64) -> f64 {
        inserts as f64 * self.samples_per_insert - samples as f64
    }

    fn target(&self) -> f64 {
        self.samples_per_insert * self.min_size_to_sample as f64
    }

    /// May `n` more transitions be inserted without running too far ahead of training?
    pub fn can_insert(&self, n: u64) -> bool {
        let inserts = self.inserts + n;
        if inserts <= self.min_size_to_sample {
            return true;
        }
        self.diff_after(inserts, self.samples) <= self.target() + self.error_buffer
    }

    /// May `n` more updates run without training too often on the same data?
    pub fn can_sample(&self, n: u64) -> bool {
        if self.inserts < self.min_size_to_sample {
            return false;
        }
        self.diff_after(self.inserts, self.samples + n) >= self.target() - self.error_buffer
    }

    /// Counts `n` inserted transitions.
    pub fn record_insert(&mut self, n: u64) {
        self.inserts += n;
    }

    /// Counts `n` learner updates.
    pub fn record_sample(&mut self, n: u64) {
        self.samples += n;
    }

    /// Transitions inserted so far.
    pub fn inserts(&self) -> u64 {
        self.inserts
    }

    /// Updates (samples) so far.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// The target ratio of updates to inserted transitions.
    pub fn samples_per_insert(&self) -> f64 {
        self.samples_per_insert
    }
}

/// Running staleness of trained-on data: how many policy versions behind the learner's
/// current version the transitions were when they were used.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Staleness {
    /// Transitions recorded.
    pub count: u64,
    /// Sum of their staleness, in policy versions (`sum / count` is the mean).
    pub sum: u64,
    /// Largest staleness recorded, in policy versions.
    pub max: u64,
}

impl Staleness {
    /// Records a transition produced by `policy_version` while the learner is at `current`.
    pub fn record(&mut self, current: u64, policy_version: u64) {
        let behind = current.saturating_sub(policy_version);
        self.count += 1;
        self.sum += behind;
        self.max = self.max.max(behind);
    }

    /// Mean versions behind (0 when nothing was recorded).
    pub fn mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum as f64 / self.count as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_deadlocking_configs() {
        assert!(RateLimiter::new(0.0, 10, 5.0).is_err());
        assert!(RateLimiter::new(f64::NAN, 10, 5.0).is_err());
        assert!(RateLimiter::new(4.0, 10, 3.9).is_err());
        assert!(RateLimiter::new(0.25, 10, 0.5).is_err());
        assert!(RateLimiter::new(0.25, 10, 1.0).is_ok());
    }

    #[test]
    fn warm_up_allows_inserts_and_no_samples() {
        let mut rl = RateLimiter::new(1.0, 100, 10.0).unwrap();
        assert!(!rl.can_sample(1));
        for _ in 0..99 {
            assert!(rl.can_insert(1));
            rl.record_insert(1);
        }
        assert!(!rl.can_sample(1));
        rl.record_insert(1);
        assert!(rl.can_sample(1));
    }

    #[test]
    fn keeps_ratio_within_error_buffer() {
        // 0.5 updates per transition, 1000 warm-up inserts, ±20 updates slack.
        let mut rl = RateLimiter::new(0.5, 1000, 20.0).unwrap();
        rl.record_insert(1000);
        // An eager learner: samples as long as allowed, inserts only when forced.
        // An eager actor: inserts as long as allowed.
        let mut steps = 0;
        while steps < 100_000 {
            let mut progressed = false;
            if rl.can_insert(1) {
                rl.record_insert(1);
                progressed = true;
            }
            if rl.can_sample(1) {
                rl.record_sample(1);
                progressed = true;
            }
            assert!(progressed, "limiter deadlocked at {rl:?}");
            let diff = rl.inserts() as f64 * 0.5 - rl.samples() as f64;
            assert!(
                (diff - 500.0).abs() <= 20.0 + 0.5,
                "diff {diff} out of band"
            );
            steps += 1;
        }
        let ratio = rl.samples() as f64 / (rl.inserts() - 1000) as f64;
        assert!((ratio - 0.5).abs() < 0.01, "ratio {ratio}");
    }

    #[test]
    fn blocks_inserts_when_learner_stalls() {
        let mut rl = RateLimiter::new(2.0, 10, 4.0).unwrap();
        rl.record_insert(10);
        // target diff = 20, max diff = 24: two more inserts (diff 24) then stop.
        assert!(rl.can_insert(2));
        assert!(!rl.can_insert(3));
        rl.record_insert(2);
        assert!(!rl.can_insert(1));
        rl.record_sample(2);
        assert!(rl.can_insert(1));
    }

    #[test]
    fn blocks_samples_when_actors_stall() {
        let mut rl = RateLimiter::new(1.0, 10, 3.0).unwrap();
        rl.record_insert(10);
        // diff 10, min diff 7: three updates then stop.
        assert!(rl.can_sample(3));
        assert!(!rl.can_sample(4));
        rl.record_sample(3);
        assert!(!rl.can_sample(1));
        rl.record_insert(1);
        assert!(rl.can_sample(1));
    }

    #[test]
    fn staleness_mean_and_max() {
        let mut s = Staleness::default();
        assert_eq!(s.mean(), 0.0);
        s.record(10, 7);
        s.record(10, 10);
        s.record(3, 5); // actor ahead of a restarted learner: clamps at 0
        assert_eq!(s.max, 3);
        assert_eq!(s.mean(), 1.0);
    }

    #[test]
    fn stats_count_each_outcome() {
        let stats = TransportStats::default();
        // Before any receiver: reaching nobody is not a loss (start-up).
        stats.record(SendOutcome::NoReceiver, 64);
        assert_eq!(stats.losses(), Losses::default());
        stats.record(SendOutcome::Delivered, 64);
        stats.record(SendOutcome::Delivered, 64);
        stats.record(SendOutcome::Full, 7);
        stats.record_given_up(3);
        // After one: the receiver went away and the message is lost.
        stats.record(SendOutcome::NoReceiver, 40);
        stats.add_full_event();
        stats.add_received(5);
        let s = stats.snapshot();
        assert_eq!(
            (s.sent, s.dropped, s.no_receiver, s.full_events, s.received),
            (2, 3, 2, 1, 5)
        );
        assert_eq!(s.dropped_items, 50);
        assert_eq!(
            stats.losses(),
            Losses {
                messages: 3,
                items: 50
            }
        );
    }

    fn losses(messages: u64, items: u64) -> Losses {
        Losses { messages, items }
    }

    #[test]
    fn tracker_counts_stamps_gaps_and_restarts() {
        let mut t = LossTracker::new();
        assert_eq!(t.observe(0, 0, Losses::ZERO), 0);
        assert_eq!(t.observe(0, 1, Losses::ZERO), 0);
        // Sequences 2..=4 timed out; the actor says so on sequence 5.
        assert_eq!(t.observe(0, 5, losses(3, 192)), 3);
        assert_eq!(t.observe(1, 0, Losses::ZERO), 0);
        let a = t.sender(0);
        assert_eq!((a.reported, a.missed, a.restarts), (losses(3, 192), 3, 0));
        // Actor 0 restarts: sequence and stamp start again; the first lifetime is kept.
        assert_eq!(t.observe(0, 0, Losses::ZERO), 0);
        assert_eq!(t.observe(0, 2, losses(1, 64)), 1);
        let a = t.sender(0);
        assert_eq!((a.reported, a.missed, a.restarts), (losses(4, 256), 4, 1));
        let total = t.total();
        assert_eq!((total.reported, total.missed), (losses(4, 256), 4));
        assert_eq!(t.sender(9), SenderLosses::default());
        assert_eq!(t.senders().count(), 2);
    }
}
