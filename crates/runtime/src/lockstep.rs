//! The schedule of a reproducible cluster run (`[cluster] reproducible = true`): the same run
//! file, seed and learner thread count (`[sac] threads = "auto"` counts the machine's cores)
//! give the same run bit for bit, whatever the machine's load.
//!
//! Asynchronous runs are not reproducible: which transitions the learner has when it samples,
//! how many updates ran when an actor picks up new weights and which policy version acts on
//! which step all depend on timing. The schedule fixes all three, as functions of counts only:
//!
//! - **Rounds.** Each actor sends its transitions in batches of `B` =
//!   [`terl_transport::TRANSITIONS_PER_BATCH`] numbered 0, 1, 2, … Round `r` is batch `r` of
//!   every actor; the learner loads a round into replay only once all `A` actors' batch `r` is
//!   there, in actor order. After round `r` replay has received `(r + 1)·A·B` transitions.
//! - **Updates at fixed transition counts.** After loading round `r` the learner runs updates
//!   until it has run [`Lockstep::updates_after_round`] in all: `⌊(T − warm-up)·ρ⌋` for
//!   `T` transitions received and update-to-data ratio `ρ` (none before the warm-up), the
//!   ratio the asynchronous rate limiter keeps on average.
//! - **Policy versions fixed by the transition count, with a lag.** The learner publishes the
//!   policy after every `P`-th round ([`Lockstep::publishes_after`]; `P` rounds hold at least
//!   `publish_every_updates` updates) and names it by its update count. An actor filling its
//!   batch `k` acts with the version published after the newest publication round at or before
//!   `k − L` ([`Lockstep::policy_version_for_batch`]); it waits for it if it has not arrived,
//!   and acts uniformly at random while there is none (warm-up). The lag `L` lets actors step
//!   `L` rounds ahead of the learner, so acting and learning still overlap.
//!
//! The weight stream only ever holds the newest version, so the learner holds a new
//! publication back until every actor has sent its last batch that needs the previous one
//! ([`Lockstep::publish_needs_batches`]); an actor therefore always finds exactly the version it
//! needs, never a newer one. No step waits on another in a cycle: an actor filling batch `k`
//! needs rounds up to `k − L` learned and batches up to `k − 1` of every actor sent, and every
//! actor can send those without waiting for anything newer.

use terl_transport::TRANSITIONS_PER_BATCH;

use crate::RunConfig;

/// The counts-only schedule of a reproducible run of `A` actors; the learner and every actor
/// build the same one from the run file and the actor count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lockstep {
    /// Actors `A` (each sends one batch per round).
    actors: u64,
    /// Transitions per batch `B`.
    batch: u64,
    /// Transitions before the first update (`train.warmup_env_steps`).
    warmup: u64,
    /// Updates per received transition `ρ` ([`RunConfig::samples_per_insert`]).
    updates_per_transition: f64,
    /// Rounds between publications `P`.
    publish_every_rounds: u64,
    /// Rounds the actors' policy lags the transition count `L` (≥ 1).
    lag_rounds: u64,
}

impl Lockstep {
    /// The schedule of `run` with `num_actors` actors: `P = ⌈publish_every_updates / (A·B·ρ)⌉`
    /// rounds (at least 1) and `L = cluster.policy_lag_rounds`, or `P` when that is 0.
    pub fn new(run: &RunConfig, num_actors: usize) -> Self {
        let actors = num_actors.max(1) as u64;
        let batch = TRANSITIONS_PER_BATCH as u64;
        let rho = run.samples_per_insert();
        let per_round = actors as f64 * batch as f64 * rho;
        let publish_every_rounds =
            ((run.cluster.publish_every_updates as f64 / per_round).ceil() as u64).max(1);
        let lag_rounds = match run.cluster.policy_lag_rounds {
            0 => publish_every_rounds,
            l => l,
        };
        Self {
            actors,
            batch,
            warmup: run.train.warmup_env_steps,
            updates_per_transition: rho,
            publish_every_rounds,
            lag_rounds,
        }
    }

    /// Actors `A`.
    pub fn actors(&self) -> u64 {
        self.actors
    }

    /// Rounds between publications `P`.
    pub fn publish_every_rounds(&self) -> u64 {
        self.publish_every_rounds
    }

    /// The lag `L`, rounds.
    pub fn lag_rounds(&self) -> u64 {
        self.lag_rounds
    }

    /// Transitions in replay once round `round` is loaded: `(round + 1)·A·B`.
    pub fn transitions_after_round(&self, round: u64) -> u64 {
        (round + 1)
            .saturating_mul(self.actors)
            .saturating_mul(self.batch)
    }

    /// Updates run in all once round `round` is learned: `⌊(T − warm-up)·ρ⌋`, 0 until
    /// `T` = [`Self::transitions_after_round`] passes the warm-up.
    pub fn updates_after_round(&self, round: u64) -> u64 {
        let t = self.transitions_after_round(round);
        if t <= self.warmup {
            return 0;
        }
        ((t - self.warmup) as f64 * self.updates_per_transition).floor() as u64
    }

    /// Whether the learner publishes the policy once round `round` is learned: every `P`-th
    /// round after the first update. Consecutive publications differ by at least one update,
    /// so the version (the update count) always grows.
    pub fn publishes_after(&self, round: u64) -> bool {
        (round + 1).is_multiple_of(self.publish_every_rounds) && self.updates_after_round(round) > 0
    }

    /// The publication round whose policy acts on an actor's batch `batch`: the newest
    /// publication round at or before `batch − L`; `None` before the first (random actions).
    pub fn policy_round_for_batch(&self, batch: u64) -> Option<u64> {
        let newest = batch.checked_sub(self.lag_rounds)?;
        let periods = (newest + 1) / self.publish_every_rounds;
        let round = periods
            .checked_mul(self.publish_every_rounds)?
            .checked_sub(1)?;
        self.publishes_after(round).then_some(round)
    }

    /// The policy version an actor acts with while filling its batch `batch`: the update count
    /// of [`Self::policy_round_for_batch`]; 0 (random actions) before the first publication.
    pub fn policy_version_for_batch(&self, batch: u64) -> u64 {
        self.policy_round_for_batch(batch)
            .map_or(0, |r| self.updates_after_round(r))
    }

    /// Batches the learner must have received from every actor before it may publish the
    /// version of publication round `round`: `round + L`, so every actor has sent the last
    /// batch that acts with the previous version (batch `round + L − 1`).
    pub fn publish_needs_batches(&self, round: u64) -> u64 {
        round.saturating_add(self.lag_rounds)
    }

    /// How many batches an actor can have sent beyond the rounds the learner has loaded when
    /// it keeps to the schedule (`L + P`): a learner receiving more from one actor sees a
    /// broken actor, not a slow learner.
    pub fn max_batches_ahead(&self) -> u64 {
        self.lag_rounds + self.publish_every_rounds
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn schedule(actors: usize, publish_every_updates: u64, lag: u64, warmup: u64) -> Lockstep {
        let mut run: RunConfig = toml::from_str("tasks = \"reach\"\nnum_envs = 10\n").unwrap();
        run.cluster.publish_every_updates = publish_every_updates;
        run.cluster.policy_lag_rounds = lag;
        run.train.warmup_env_steps = warmup;
        run.train.updates_per_vec_step = 1.0;
        Lockstep::new(&run, actors)
    }

    /// The schedule against a direct simulation of its definition: the policy of each batch is
    /// the newest publication at least `L` rounds old, versions grow, and the hold-back rule
    /// never withholds a version an actor is waiting for.
    #[test]
    fn versions_follow_the_definition_and_never_wait_in_a_cycle() {
        for (actors, every, lag, warmup) in [
            (1, 20, 0, 10_000),
            (2, 20, 0, 640),
            (3, 1, 1, 0),
            (2, 100, 7, 0),
        ] {
            let s = schedule(actors, every, lag, warmup);
            let (p, l) = (s.publish_every_rounds(), s.lag_rounds());
            // P rounds hold at least publish_every_updates updates (ρ = 0.1).
            let per_round = actors as f64 * 64.0 * 0.1;
            assert!(
                p as f64 * per_round >= every as f64,
                "{p} rounds of {per_round}"
            );
            assert!((p as f64 - 1.0) * per_round < every as f64);
            let publications: Vec<u64> = (0..2000).filter(|&r| s.publishes_after(r)).collect();
            assert!(!publications.is_empty());
            for w in publications.windows(2) {
                assert_eq!(w[1] - w[0], p);
                assert!(s.updates_after_round(w[1]) > s.updates_after_round(w[0]));
            }
            for k in 0..1500u64 {
                let direct = publications.iter().copied().filter(|&r| r + l <= k).max();
                assert_eq!(s.policy_round_for_batch(k), direct, "batch {k}");
                // The version batch k needs is published once every actor sent batches
                // through `round + L - 1` ≤ k - 1: an actor filling batch k has.
                if let Some(r) = direct {
                    assert!(s.publish_needs_batches(r) <= k);
                    // The next publication waits for batch k itself: the version cannot be
                    // replaced before this actor used it.
                    assert!(s.publish_needs_batches(r + p) > k);
                }
            }
        }
    }

    /// Updates follow the update-to-data ratio after the warm-up, as the rate limiter's target.
    #[test]
    fn updates_start_after_the_warm_up_at_the_ratio() {
        let s = schedule(1, 20, 0, 10_000);
        // 64 transitions per round, ρ = 0.1.
        assert_eq!(s.updates_after_round(155), 0); // 9984 transitions
        assert_eq!(s.updates_after_round(156), 4); // 10048: ⌊48·0.1⌋
        assert_eq!(
            s.updates_after_round(1000),
            ((64_064 - 10_000) as f64 * 0.1) as u64
        );
        assert_eq!(s.transitions_after_round(0), 64);
    }
}
