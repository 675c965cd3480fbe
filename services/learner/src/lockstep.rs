//! The learner's side of a reproducible run (`[cluster] reproducible = true`, the schedule in
//! [`terl_runtime::Lockstep`]): transition batches wait per actor until every actor's batch of
//! the next round is there, are loaded into replay in actor order, and the round's updates run
//! before the next round is loaded; the policy is snapshotted after every publication round
//! and published once every actor has sent its last batch that acts with the previous version.
//!
//! Success windows are kept from the transitions' `SUCCESS` and `TRUNCATED` flags in the same
//! order, not from the episode stream (whose arrival beside the transitions depends on timing).
//! A lost, repeated, partial or foreign batch cannot be part of a reproducible run: it stops the
//! learner with an error that says which.

use std::collections::{BTreeMap, VecDeque};

use anyhow::Context;
use terl_runtime::Lockstep;
use terl_transport::{flags, Message, MessageSource, TransitionBatch, TRANSITIONS_PER_BATCH};
use terl_wire::{WeightHub, Weights, WeightsKind};

use crate::status::Counters;

/// Where the learner is in the current round.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Waiting for every actor's batch of the next round.
    Load,
    /// Round `round` is loaded; updates run until `target` in all.
    Update { round: u64, target: u64 },
}

/// Transition batches by actor, the round being learned and the publications held back.
#[derive(Debug)]
pub(crate) struct LockstepStaging {
    schedule: Lockstep,
    /// Per actor, batches received and not yet loaded, in sequence order.
    queues: Vec<VecDeque<Box<TransitionBatch>>>,
    /// Per actor, batches received so far (the next sequence number due).
    received: Vec<u64>,
    /// The next round to load.
    next_round: u64,
    phase: Phase,
    /// Updates run so far (attempts: a skipped non-finite batch counts, as in the schedule).
    updates: u64,
    /// Publications made and not yet released: `(round, weights)`.
    held: VecDeque<(u64, Weights)>,
    /// Per `(actor, environment)`, whether the running episode reported success.
    episode_success: BTreeMap<(u16, u16), bool>,
    free: Vec<Box<TransitionBatch>>,
}

impl LockstepStaging {
    /// The staging of `schedule` (its actor count sizes the queues).
    pub(crate) fn new(schedule: Lockstep) -> Self {
        let actors = schedule.actors() as usize;
        Self {
            schedule,
            queues: (0..actors).map(|_| VecDeque::new()).collect(),
            received: vec![0; actors],
            next_round: 0,
            phase: Phase::Load,
            updates: 0,
            held: VecDeque::new(),
            episode_success: BTreeMap::new(),
            free: Vec::new(),
        }
    }

    /// Whether the learner is between rounds (the budget check and the final checkpoint only
    /// happen there, so every run stops at the same point).
    pub(crate) fn between_rounds(&self) -> bool {
        self.phase == Phase::Load
    }

    /// Rounds loaded and learned so far.
    #[cfg(test)]
    pub(crate) fn rounds(&self) -> u64 {
        self.next_round
    }

    /// Takes everything the transport has, checking each batch's actor and sequence number;
    /// true if anything arrived. Bounded: past the warm-up an actor that keeps to the schedule
    /// is at most [`Lockstep::max_batches_ahead`] batches ahead of the rounds loaded (it waits
    /// for versions the learner has not made).
    ///
    /// # Errors
    /// A batch of an actor id outside the run, out of sequence (one was lost: a stall longer
    /// than `block_timeout_secs`, or a restarted actor), not full, or too far ahead; or the
    /// transport's error.
    pub(crate) fn fill(
        &mut self,
        source: &mut dyn MessageSource<TransitionBatch>,
    ) -> anyhow::Result<bool> {
        let mut got = false;
        loop {
            let mut b = self.free.pop().unwrap_or_else(TransitionBatch::empty);
            if !source.try_receive_into(&mut b)? {
                self.free.push(b);
                return Ok(got);
            }
            got = true;
            let actor = usize::from(b.actor_id);
            anyhow::ensure!(
                actor < self.queues.len(),
                "reproducible run: a batch of actor {actor}, but the run has {} actors",
                self.queues.len()
            );
            let due = self.received[actor];
            anyhow::ensure!(
                b.sequence == due,
                "reproducible run: batch {} of actor {actor} arrived where batch {due} was due \
                 (a batch was lost — a learner stall longer than cluster.block_timeout_secs — or \
                 the actor restarted); the run cannot stay reproducible",
                b.sequence
            );
            anyhow::ensure!(
                b.as_slice().len() == TRANSITIONS_PER_BATCH,
                "reproducible run: batch {due} of actor {actor} holds {} transitions, not {}",
                b.as_slice().len(),
                TRANSITIONS_PER_BATCH
            );
            // An actor fills batch `due` with the version of its policy round, which the
            // learner must have made already.
            if let Some(round) = self.schedule.policy_round_for_batch(due) {
                anyhow::ensure!(
                    round < self.next_round,
                    "reproducible run: actor {actor} sent batch {due}, which acts with the policy \
                     of round {round}, with only {} rounds learned: it does not keep to the \
                     schedule (another policy_lag_rounds or publish_every_updates in its run \
                     file?)",
                    self.next_round
                );
            }
            self.received[actor] += 1;
            self.queues[actor].push_back(b);
        }
    }

    /// Loads the next round into replay when every actor's batch of it is there (through
    /// `load`, which validates and counts one batch), and keeps the success windows from its
    /// transitions; true if a round was loaded.
    pub(crate) fn load_round(
        &mut self,
        c: &mut Counters,
        mut load: impl FnMut(&TransitionBatch, &mut Counters) -> u64,
    ) -> bool {
        if self.phase != Phase::Load || self.queues.iter().any(VecDeque::is_empty) {
            return false;
        }
        let round = self.next_round;
        for a in 0..self.queues.len() {
            let b = self.queues[a].pop_front().expect("checked non-empty");
            if load(&b, c) > 0 {
                for t in b.as_slice() {
                    let ended = self
                        .episode_success
                        .entry((t.actor_id, t.env_index))
                        .or_default();
                    *ended |= t.flags & flags::SUCCESS != 0;
                    if t.flags & flags::TRUNCATED != 0 {
                        c.episode(t.task as usize, *ended);
                        *ended = false;
                    }
                }
            }
            if self.free.len() < self.queues.len() * 2 {
                self.free.push(b);
            }
        }
        self.phase = Phase::Update {
            round,
            target: self.schedule.updates_after_round(round),
        };
        true
    }

    /// Updates still due in the current round (0 while loading).
    pub(crate) fn updates_due(&self) -> u64 {
        match self.phase {
            Phase::Load => 0,
            Phase::Update { target, .. } => target.saturating_sub(self.updates),
        }
    }

    /// Counts `n` updates run (or skipped for a non-finite batch).
    pub(crate) fn record_updates(&mut self, n: u64) {
        self.updates += n;
    }

    /// Ends the current round once its updates ran: on a publication round `snapshot` makes the
    /// policy's weights message for the version (the update count) it is given, which is held
    /// back until [`Self::release`] may publish it. Returns the version made, if any.
    ///
    /// # Errors
    /// `snapshot`'s.
    pub(crate) fn finish_round(
        &mut self,
        snapshot: impl FnOnce(u64) -> anyhow::Result<Weights>,
    ) -> anyhow::Result<Option<u64>> {
        let Phase::Update { round, target } = self.phase else {
            return Ok(None);
        };
        if self.updates < target {
            return Ok(None);
        }
        self.phase = Phase::Load;
        self.next_round = round + 1;
        if !self.schedule.publishes_after(round) {
            return Ok(None);
        }
        let weights = snapshot(target).context("snapshotting the policy")?;
        self.held.push_back((round, weights));
        Ok(Some(target))
    }

    /// Publishes the held versions every actor is ready for (it has sent every batch that acts
    /// with the version before); the number published.
    ///
    /// # Errors
    /// The hub's (a message over its size limit).
    pub(crate) fn release(&mut self, hub: &WeightHub) -> anyhow::Result<usize> {
        let sent_by_all = self.received.iter().copied().min().unwrap_or(0);
        let mut n = 0;
        while let Some((round, _)) = self.held.front() {
            if sent_by_all < self.schedule.publish_needs_batches(*round) {
                break;
            }
            let (_, weights) = self.held.pop_front().expect("checked");
            debug_assert_eq!(weights.kind(), WeightsKind::Policy);
            hub.publish(&weights)?;
            n += 1;
        }
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terl_transport::{MemoryTransport, Transition, Transport, TransportConfig, OBS_DIM};

    fn run_config(publish_every_updates: u64) -> terl_runtime::RunConfig {
        let mut run: terl_runtime::RunConfig =
            toml::from_str("tasks = \"reach\"\nnum_envs = 10\n").unwrap();
        run.cluster.publish_every_updates = publish_every_updates;
        run.train.warmup_env_steps = 0;
        run
    }

    fn weights(version: u64) -> anyhow::Result<Weights> {
        let t = terl_wire::Tensor::new("w", vec![1], vec![version as f32])?;
        Ok(Weights::new(
            WeightsKind::Policy,
            version,
            version,
            vec![t],
        )?)
    }

    fn batch(actor: u16, sequence: u64, truncate_at: Option<usize>) -> TransitionBatch {
        let mut b = TransitionBatch::EMPTY;
        b.actor_id = actor;
        b.sequence = sequence;
        for k in 0..TRANSITIONS_PER_BATCH {
            let mut t = Transition::ZERO;
            t.actor_id = actor;
            t.obs = [k as f32 * 0.01; OBS_DIM];
            if Some(k) == truncate_at {
                t.flags = flags::TRUNCATED | flags::SUCCESS;
            }
            assert!(b.push(t));
        }
        b
    }

    /// Rounds wait for every actor and load in actor order whatever order batches arrive in;
    /// a lost batch stops the run naming the actor and the batch.
    #[test]
    fn rounds_load_in_actor_order_and_a_lost_batch_is_an_error() {
        // Too far ahead: with lag 1, batch 1 acts with round 0's policy, not yet made.
        let transport = MemoryTransport::new(TransportConfig::new("lockstep-ahead", 2)).unwrap();
        let mut source = transport.source::<TransitionBatch>().unwrap();
        let mut sink = transport.sink::<TransitionBatch>().unwrap();
        let mut staging = LockstepStaging::new(Lockstep::new(&run_config(1), 2));
        sink.send(&batch(1, 0, None)).unwrap();
        sink.send(&batch(1, 1, None)).unwrap();
        let e = staging.fill(source.as_mut()).unwrap_err().to_string();
        assert!(
            e.contains("actor 1 sent batch 1") && e.contains("round 0"),
            "{e}"
        );

        let mut run = run_config(1);
        run.cluster.policy_lag_rounds = 3;
        let schedule = Lockstep::new(&run, 2);
        let transport = MemoryTransport::new(TransportConfig::new("lockstep-order", 2)).unwrap();
        let mut source = transport.source::<TransitionBatch>().unwrap();
        let mut sink = transport.sink::<TransitionBatch>().unwrap();
        let mut staging = LockstepStaging::new(schedule);
        let mut c = Counters::new(1, 10, std::time::Instant::now());
        // Actor 1 is ahead by two batches, actor 0 behind.
        for b in [batch(1, 0, None), batch(1, 1, Some(3)), batch(0, 0, None)] {
            sink.send(&b).unwrap();
        }
        assert!(staging.fill(source.as_mut()).unwrap());
        let mut order = Vec::new();
        assert!(staging.load_round(&mut c, |b, _| {
            order.push((b.actor_id, b.sequence));
            64
        }));
        assert_eq!(order, [(0, 0), (1, 0)]);
        // Updates of round 0 first: the next round does not load before they ran.
        assert!(staging.updates_due() > 0);
        assert!(!staging.load_round(&mut c, |_, _| 64));
        staging.record_updates(staging.updates_due());
        // Round 0 is a publication round (P = 1): version 12 = ⌊128 · 0.1⌋.
        assert_eq!(staging.finish_round(weights).unwrap(), Some(12));
        // Round 1 waits for actor 0.
        assert!(!staging.load_round(&mut c, |_, _| 64));
        sink.send(&batch(0, 1, None)).unwrap();
        staging.fill(source.as_mut()).unwrap();
        assert!(staging.load_round(&mut c, |_, _| 64));
        // The truncated successful step of actor 1 closed one successful episode.
        assert_eq!(c.windows[0].iter().collect::<Vec<_>>(), [true]);

        // Actor 0's batch 3 where 2 was due.
        sink.send(&batch(0, 3, None)).unwrap();
        let e = staging.fill(source.as_mut()).unwrap_err().to_string();
        assert!(
            e.contains("batch 3 of actor 0") && e.contains("batch 2 was due"),
            "{e}"
        );
    }

    /// A publication is held until every actor sent the last batch that acts with the previous
    /// version, then goes out once.
    #[test]
    fn publications_wait_for_every_actor() {
        let mut run = run_config(1);
        run.cluster.policy_lag_rounds = 2;
        let schedule = Lockstep::new(&run, 2);
        // ρ = 0.1, 2 actors: 12.8 updates per round, a publication every round.
        assert_eq!(
            (schedule.publish_every_rounds(), schedule.lag_rounds()),
            (1, 2)
        );
        let transport = MemoryTransport::new(TransportConfig::new("lockstep-hold", 2)).unwrap();
        let mut source = transport.source::<TransitionBatch>().unwrap();
        let mut sink = transport.sink::<TransitionBatch>().unwrap();
        let mut staging = LockstepStaging::new(schedule);
        let mut c = Counters::new(1, 10, std::time::Instant::now());
        let hub = WeightHub::new();
        for a in 0..2 {
            sink.send(&batch(a, 0, None)).unwrap();
        }
        staging.fill(source.as_mut()).unwrap();
        assert!(staging.load_round(&mut c, |_, _| 64));
        staging.record_updates(staging.updates_due());
        assert_eq!(staging.finish_round(weights).unwrap(), Some(12));
        // Round 0's version goes out once both sent batches 0 and 1 (0 + L = 2 batches each).
        assert_eq!(staging.release(&hub).unwrap(), 0);
        sink.send(&batch(0, 1, None)).unwrap();
        staging.fill(source.as_mut()).unwrap();
        assert_eq!(
            staging.release(&hub).unwrap(),
            0,
            "actor 1 has sent one batch"
        );
        assert_eq!(hub.latest_version(WeightsKind::Policy), 0);
        sink.send(&batch(1, 1, None)).unwrap();
        staging.fill(source.as_mut()).unwrap();
        assert_eq!(staging.release(&hub).unwrap(), 1);
        assert_eq!(hub.latest_version(WeightsKind::Policy), 12);
        assert_eq!(staging.release(&hub).unwrap(), 0, "published once");
        // Round 1 (both batches 1 are there) makes version 25, held for batch 2 of each.
        assert!(staging.load_round(&mut c, |_, _| 64));
        staging.record_updates(staging.updates_due());
        assert_eq!(staging.finish_round(weights).unwrap(), Some(25));
        assert_eq!(staging.release(&hub).unwrap(), 0);
        assert_eq!(staging.rounds(), 2);
    }
}
