//! Staging: transition batches out of the transport, validated, into replay.
//!
//! Batches taken out of the transport wait here, one queue per actor, until the rate limiter
//! lets them into replay; a batch with an unknown task id or a non-finite value is rejected as
//! a whole (it comes from a broken actor) and counted.

use std::collections::{BTreeMap, VecDeque};
use std::time::Instant;

use terl_rl::replay::MultiTaskReplay;
use terl_transport::{
    flags, Message, MessageSource, RateLimiter, TransitionBatch, TransportError,
    TRANSITIONS_PER_BATCH,
};

use crate::status::Counters;

/// Batches loaded into replay per round at most, so updates and status are never starved.
const MAX_BATCHES_PER_ROUND: usize = 16;

/// Batches taken out of the transport and not yet in replay, one queue per actor.
///
/// iceoryx2's subscriber always serves the first publisher that has data, so under
/// back-pressure (the rate limiter refusing inserts) a learner that received one batch at a
/// time would only ever hear from one actor and starve the rest. Instead, whenever at most
/// `low_water` batches are staged, the learner empties every actor's shared-memory queue into
/// the staging area (at most `low_water` more, one queue's worth per actor), and inserts into
/// replay round-robin over actors. Every actor thus delivers its queue once per cycle.
#[derive(Debug)]
pub(crate) struct Staging {
    low_water: usize,
    queues: BTreeMap<u16, VecDeque<Box<TransitionBatch>>>,
    staged: usize,
    cursor: u16,
    free: Vec<Box<TransitionBatch>>,
}

impl Staging {
    /// `low_water`: batches staged below which the transport is drained again (the learner
    /// uses actors × `[cluster] buffer_batches`, one full queue per actor).
    pub(crate) fn new(low_water: usize) -> Self {
        Self {
            low_water: low_water.max(1),
            queues: BTreeMap::new(),
            staged: 0,
            cursor: 0,
            free: Vec::new(),
        }
    }

    /// Drains the source when the staging area is low; true if anything arrived.
    pub(crate) fn fill(
        &mut self,
        source: &mut dyn MessageSource<TransitionBatch>,
    ) -> Result<bool, TransportError> {
        if self.staged > self.low_water {
            return Ok(false);
        }
        let mut got = false;
        while self.staged < 2 * self.low_water {
            let mut b = self.free.pop().unwrap_or_else(TransitionBatch::empty);
            if !source.try_receive_into(&mut b)? {
                self.free.push(b);
                break;
            }
            got = true;
            self.staged += 1;
            self.queues.entry(b.actor_id).or_default().push_back(b);
        }
        Ok(got)
    }

    /// The next batch, round-robin over actors.
    pub(crate) fn next(&mut self) -> Option<Box<TransitionBatch>> {
        let key = self
            .queues
            .range(self.cursor..)
            .chain(self.queues.range(..self.cursor))
            .find(|(_, q)| !q.is_empty())
            .map(|(&k, _)| k)?;
        self.cursor = key.wrapping_add(1);
        self.staged -= 1;
        self.queues.get_mut(&key).and_then(VecDeque::pop_front)
    }

    pub(crate) fn recycle(&mut self, b: Box<TransitionBatch>) {
        if self.free.len() < 2 * self.low_water {
            self.free.push(b);
        }
    }

    /// One round: drains the source when low, then loads staged batches into replay while the
    /// limiter allows inserts (at most [`MAX_BATCHES_PER_ROUND`]); batches the limiter refuses
    /// stay staged (actors meet back-pressure). `policy_version` is the learner's newest
    /// published version (for staleness). True if anything arrived or was loaded.
    pub(crate) fn round(
        &mut self,
        source: &mut dyn MessageSource<TransitionBatch>,
        limiter: &mut RateLimiter,
        num_tasks: usize,
        replay: &mut MultiTaskReplay,
        c: &mut Counters,
        policy_version: u64,
    ) -> Result<bool, TransportError> {
        let mut busy = self.fill(source)?;
        for _ in 0..MAX_BATCHES_PER_ROUND {
            if !limiter.can_insert(TRANSITIONS_PER_BATCH as u64) {
                break;
            }
            let Some(b) = self.next() else { break };
            let n = ingest(&b, num_tasks, replay, c, policy_version);
            self.recycle(b);
            limiter.record_insert(n);
            busy = true;
        }
        Ok(busy)
    }
}

/// Whether every transition of `batch` names one of the run's `num_tasks` tasks and holds
/// only finite values.
pub(crate) fn valid(batch: &TransitionBatch, num_tasks: usize) -> bool {
    batch.as_slice().iter().all(|t| {
        (t.task as usize) < num_tasks
            && t.reward.is_finite()
            && t.obs
                .iter()
                .chain(&t.next_obs)
                .chain(&t.action)
                .all(|v| v.is_finite())
    })
}

/// Loads a batch into replay and counts it (env steps, per-actor tracks, guidance, staleness,
/// loss stamps); the number of transitions loaded. Rejects (0, `rejected_batches` + 1) a batch
/// that is not [`valid`].
pub(crate) fn ingest(
    batch: &TransitionBatch,
    num_tasks: usize,
    replay: &mut MultiTaskReplay,
    c: &mut Counters,
    policy_version: u64,
) -> u64 {
    c.inbound.batch(batch);
    if !valid(batch, num_tasks) {
        c.rejected_batches += 1;
        return 0;
    }
    let ts = batch.as_slice();
    let now = Instant::now();
    for t in ts {
        let guided = t.flags & flags::GUIDED != 0;
        c.guidance_window[t.task as usize].record(t);
        c.guided_steps += u64::from(guided);
        replay.push(
            t.task as usize,
            &t.obs,
            &t.action,
            t.reward,
            &t.next_obs,
            t.terminated(),
        );
        c.staleness.record(policy_version, t.policy_version);
    }
    let n = ts.len() as u64;
    c.env_steps += n;
    let track = c.actors.entry(batch.actor_id).or_default();
    track.env_steps += n;
    if let Some(last) = ts.last() {
        track.policy_version = last.policy_version;
    }
    track.last_seen = Some(now);
    n
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use terl_transport::{Transition, Transport, TransportConfig, ACTION_DIM, OBS_DIM};

    /// A batch of `n` finite transitions of `task` from `actor`.
    pub(crate) fn batch(actor: u16, task: u16, n: usize, policy_version: u64) -> TransitionBatch {
        let mut b = TransitionBatch::EMPTY;
        b.actor_id = actor;
        for k in 0..n {
            let x = k as f32 * 0.01;
            let pushed = b.push(Transition {
                policy_version,
                obs: [x; OBS_DIM],
                next_obs: [x + 0.01; OBS_DIM],
                action: [0.1; ACTION_DIM],
                reward: x,
                actor_id: actor,
                env_index: 0,
                task,
                flags: if k % 2 == 0 { flags::GUIDED } else { 0 },
                reserved: 0,
                guidance_probability_q: 0,
                action_gap_q: 0,
            });
            assert!(pushed);
        }
        b
    }

    #[test]
    fn invalid_batches_are_rejected_whole_and_counted() {
        let mut replay = MultiTaskReplay::new(2, 1000, OBS_DIM, ACTION_DIM);
        let mut c = Counters::new(2, 10, Instant::now());
        assert_eq!(ingest(&batch(3, 1, 20, 4), 2, &mut replay, &mut c, 6), 20);
        assert_eq!(
            (c.env_steps, c.guided_steps, c.rejected_batches),
            (20, 10, 0)
        );
        assert_eq!(c.actors[&3].env_steps, 20);
        assert_eq!(c.actors[&3].policy_version, 4);
        let g = c.guidance_window[1];
        assert_eq!((g.guided, g.steps, g.active, g.compared), (10, 20, 0, 0));

        let bad_task = batch(3, 2, 20, 4);
        let mut nan_obs = batch(3, 0, 20, 4);
        nan_obs.transitions[7].obs[5] = f32::NAN;
        let mut inf_reward = batch(3, 0, 20, 4);
        inf_reward.transitions[19].reward = f32::INFINITY;
        let mut nan_action = batch(3, 0, 20, 4);
        nan_action.transitions[0].action[3] = f32::NAN;
        for (k, b) in [bad_task, nan_obs, inf_reward, nan_action]
            .iter()
            .enumerate()
        {
            assert!(!valid(b, 2), "batch {k}");
            assert_eq!(ingest(b, 2, &mut replay, &mut c, 6), 0, "batch {k}");
        }
        // Nothing of the rejected batches reached replay or the counts.
        assert_eq!(c.rejected_batches, 4);
        assert_eq!(replay.total_len(), 20);
        assert_eq!(c.env_steps, 20);
        assert_eq!(c.actors[&3].env_steps, 20);
    }

    /// Under back-pressure every actor is heard: staged batches go into replay round-robin
    /// over actors, and the limiter's refusals leave the rest staged.
    #[test]
    fn staged_batches_enter_replay_round_robin_while_the_limiter_allows() {
        let transport =
            terl_transport::MemoryTransport::new(TransportConfig::new("staging-test", 2)).unwrap();
        let mut source = transport.source::<TransitionBatch>().unwrap();
        let mut sink = transport.sink::<TransitionBatch>().unwrap();
        for (actor, count) in [(0u16, 3), (1, 1)] {
            for _ in 0..count {
                sink.send(&batch(actor, 0, TRANSITIONS_PER_BATCH, 0))
                    .unwrap();
            }
        }
        let mut staging = Staging::new(8);
        assert!(staging.fill(source.as_mut()).unwrap());
        let mut order = Vec::new();
        while let Some(b) = staging.next() {
            order.push(b.actor_id);
            staging.recycle(b);
        }
        assert_eq!(order, [0, 1, 0, 0]);

        for _ in 0..4 {
            sink.send(&batch(1, 1, TRANSITIONS_PER_BATCH, 0)).unwrap();
        }
        // Warm-up of two batches, one sample per insert, slack of one batch, no samples taken:
        // the limiter admits three batches, never the fourth.
        let mut limiter = RateLimiter::new(
            1.0,
            2 * TRANSITIONS_PER_BATCH as u64,
            TRANSITIONS_PER_BATCH as f64,
        )
        .unwrap();
        let mut replay = MultiTaskReplay::new(2, 10_000, OBS_DIM, ACTION_DIM);
        let mut c = Counters::new(2, 10, Instant::now());
        assert!(staging
            .round(source.as_mut(), &mut limiter, 2, &mut replay, &mut c, 0)
            .unwrap());
        let loaded = replay.total_len();
        assert_eq!(loaded, 3 * TRANSITIONS_PER_BATCH);
        assert_eq!(c.env_steps, loaded as u64);
        assert!(staging.next().is_some(), "refused batches stay staged");
    }
}
