//! Data that never reached the learner, as the senders report it.
//!
//! A send that stays blocked on a full receiver for `[cluster] block_timeout_secs` (the
//! learner stopped or stalled) is given up: the message is dropped and the sender's transport
//! counts it. Every message then carries its sender's cumulative counts
//! ([`terl_transport::Losses`], stamped by the transport), so the first batch an actor gets
//! through after an outage tells the learner exactly how many batches and transitions were
//! lost on the way. [`Inbound`] keeps one [`LossTracker`] per stream (actor transitions, actor
//! episodes, selector selections), keyed by sender, and puts the counts into the status
//! (per actor in `ActorStats`, summed in `LearnerStatus`), from where the metrics log takes
//! them (`transport/*`). An actor that restarts counts from zero again; the tracker keeps the
//! earlier process's counts.

use terl_transport::{EpisodeSummary, LossTracker, Message, SelectedBatch, TransitionBatch};
use terl_wire::{ActorStats, LearnerStatus};

/// Sender id of the one selector on the selected-sample stream.
const SELECTOR: u16 = 0;

/// Loss stamps seen on everything the learner received.
#[derive(Debug, Default)]
pub(crate) struct Inbound {
    transitions: LossTracker,
    episodes: LossTracker,
    selected: LossTracker,
    /// Totals already logged, so each increase is logged once.
    logged: (u64, u64, u64),
    /// Transition batches missed already logged.
    missed_logged: u64,
}

impl Inbound {
    pub(crate) fn batch(&mut self, b: &TransitionBatch) {
        self.transitions.observe(b.actor_id, b.sequence, b.losses());
    }

    pub(crate) fn episode(&mut self, e: &EpisodeSummary) {
        self.episodes
            .observe(e.actor_id, e.episode_index, e.losses());
    }

    pub(crate) fn selected(&mut self, s: &SelectedBatch) {
        self.selected.observe(SELECTOR, s.sequence, s.losses());
    }

    /// Writes the counts into `status` (an `ActorStats` entry is added for an actor known only
    /// from its episodes) and logs a warning when a total grew.
    pub(crate) fn fill(&mut self, status: &mut LearnerStatus) {
        let ids: std::collections::BTreeSet<u16> = self
            .transitions
            .senders()
            .chain(self.episodes.senders())
            .map(|(id, _)| id)
            .collect();
        for id in ids {
            let pos = match status
                .actors
                .iter()
                .position(|a| a.actor_id == u32::from(id))
            {
                Some(pos) => pos,
                None => {
                    status.actors.push(ActorStats {
                        actor_id: u32::from(id),
                        ..ActorStats::default()
                    });
                    status.actors.len() - 1
                }
            };
            let a = &mut status.actors[pos];
            let t = self.transitions.sender(id).reported;
            a.transition_batches_dropped = t.messages;
            a.transitions_dropped = t.items;
            a.episodes_dropped = self.episodes.sender(id).reported.messages;
        }
        status.actors.sort_by_key(|a| a.actor_id);
        let t = self.transitions.total().reported;
        status.transition_batches_dropped = t.messages;
        status.transitions_dropped = t.items;
        status.episodes_dropped = self.episodes.total().reported.messages;
        let s = self.selected.total().reported;
        status.selected_batches_dropped = s.messages;
        status.selected_samples_dropped = s.items;
        let missed = self.transitions.total().missed;
        status.transition_batches_missed = missed;
        if missed > self.missed_logged {
            self.missed_logged = missed;
            tracing::warn!(
                transition_batches_missed = missed,
                "transition batches lost in transit (gaps in the actors' sequence numbers: a \
                 connection to an actor's host closed with batches in flight; totals so far)"
            );
        }
        let now = (t.items, status.episodes_dropped, s.items);
        if now != self.logged {
            self.logged = now;
            tracing::warn!(
                transition_batches_dropped = t.messages,
                transitions_dropped = t.items,
                episodes_dropped = status.episodes_dropped,
                selected_samples_dropped = s.items,
                "senders report data that never arrived: a receiver stayed full for longer \
                 than cluster.block_timeout_secs (totals so far)"
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terl_transport::Losses;

    /// Batches that never arrived although sent (a gap in an actor's sequence numbers) are
    /// in the status, summed over actors.
    #[test]
    fn gaps_in_sequence_numbers_reach_the_status() {
        let mut inbound = Inbound::default();
        for (actor, sequence) in [(0u16, 0u64), (0, 1), (0, 4), (1, 0), (1, 2), (0, 5)] {
            let mut b = TransitionBatch::EMPTY;
            b.actor_id = actor;
            b.sequence = sequence;
            inbound.batch(&b);
        }
        let mut status = LearnerStatus::default();
        inbound.fill(&mut status);
        assert_eq!(status.transition_batches_missed, 3);
        assert_eq!(status.transition_batches_dropped, 0);
    }

    #[test]
    fn stamps_reach_the_status_per_actor_and_summed() {
        let mut inbound = Inbound::default();
        let mut b = TransitionBatch::EMPTY;
        b.actor_id = 1;
        b.sequence = 4;
        b.set_losses(Losses {
            messages: 2,
            items: 128,
        });
        inbound.batch(&b);
        let mut e = EpisodeSummary::EMPTY;
        e.actor_id = 3;
        e.episode_index = 9;
        e.set_losses(Losses {
            messages: 5,
            items: 5,
        });
        inbound.episode(&e);
        let mut s = SelectedBatch::EMPTY;
        s.sequence = 2;
        s.set_losses(Losses {
            messages: 1,
            items: 512,
        });
        inbound.selected(&s);
        let mut status = LearnerStatus {
            actors: vec![ActorStats {
                actor_id: 1,
                env_steps: 640,
                ..ActorStats::default()
            }],
            ..LearnerStatus::default()
        };
        inbound.fill(&mut status);
        let ids: Vec<u32> = status.actors.iter().map(|a| a.actor_id).collect();
        assert_eq!(ids, [1, 3]);
        let a1 = &status.actors[0];
        assert_eq!(
            (
                a1.env_steps,
                a1.transition_batches_dropped,
                a1.transitions_dropped
            ),
            (640, 2, 128)
        );
        assert_eq!(status.actors[1].episodes_dropped, 5);
        assert_eq!(
            (
                status.transition_batches_dropped,
                status.transitions_dropped,
                status.episodes_dropped,
                status.selected_batches_dropped,
                status.selected_samples_dropped
            ),
            (2, 128, 5, 1, 512)
        );
    }
}
