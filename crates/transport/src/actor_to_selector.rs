//! Actor → selector (and learner): one finished episode with the trajectory the selector
//! scores (GAE + entropy priority), as fixed-size plain data.

use iceoryx2::prelude::*;

use crate::flow::Losses;
use crate::{ACTION_DIM, OBS_DIM};

/// Meta-World episodes are 500 steps (`terl_spaces::MAX_PATH_LENGTH`); the trajectory array
/// holds one full episode.
pub const MAX_EPISODE_STEPS: usize = terl_spaces::MAX_PATH_LENGTH as usize;

/// One step of a stored trajectory: the state, the executed action and its reward.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct TrajectoryStep {
    /// Observation the action was chosen in (39 floats, without the task one-hot).
    pub obs: [f32; OBS_DIM],
    /// Executed action, in Meta-World's action space `[-1, 1]^ACTION_DIM`.
    pub action: [f32; ACTION_DIM],
    /// Reward of the step, as the environment returned it.
    pub reward: f32,
}

const _: () = assert!(core::mem::size_of::<TrajectoryStep>() == 4 * (OBS_DIM + ACTION_DIM + 1));

impl TrajectoryStep {
    /// An all-zero step (valid plain data, used to initialise trajectories).
    pub const ZERO: TrajectoryStep = TrajectoryStep {
        obs: [0.0; OBS_DIM],
        action: [0.0; ACTION_DIM],
        reward: 0.0,
    };
}

/// A finished episode: summary statistics plus up to [`MAX_EPISODE_STEPS`] steps.
#[derive(Debug, Clone, Copy, ZeroCopySend, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct EpisodeSummary {
    /// Policy version the episode started with (actors may pick up new weights mid-episode).
    pub policy_version: u64,
    /// Per-actor episode counter, starting at 0 (also incremented for episodes that were not
    /// delivered, so a receiver sees the gap).
    pub episode_index: u64,
    /// The actor's cumulative losses before this episode: episodes (`messages` = `items`) its
    /// earlier sends gave up on because a receiver (selector or learner) stayed full. Stamped
    /// by the transport on send (see [`crate::flow`]).
    pub losses: Losses,
    /// Sum of rewards.
    pub episode_return: f32,
    /// Number of steps taken (≥ `trajectory_len`; equal unless the trajectory was cut).
    pub length: u32,
    /// Number of valid entries in `trajectory`.
    pub trajectory_len: u32,
    /// Actor process that ran the episode.
    pub actor_id: u16,
    /// Environment index inside that actor.
    pub env_index: u16,
    /// Task index into the run's task list.
    pub task: u16,
    /// 1 if the task reported success at any step, else 0.
    pub success: u8,
    /// Explicit padding so the layout has no uninitialised bytes.
    pub reserved0: u8,
    /// Steps that executed the Action Network's action (TERL guidance).
    pub guided_steps: u16,
    /// 1 + the index of the first step after which the task reported success; 0: none (or
    /// not recorded). See [`EpisodeSummary::first_success_index`].
    pub first_success: u16,
    /// Observation after the last step (s_T), so GAE can bootstrap on truncation.
    pub final_obs: [f32; OBS_DIM],
    /// The steps in order; entries from `trajectory_len` on are unused.
    pub trajectory: [TrajectoryStep; MAX_EPISODE_STEPS],
    /// The goal variation the episode ran on (index into the task's 50 variations of the run's
    /// `variation_seed`, `goal_variations` in `terl-sim`'s Meta-World module); [`NO_VARIATION`]: unknown.
    /// Also the tail padding to the 8-byte alignment, so every byte is data.
    pub variation: u32,
}

/// [`EpisodeSummary::variation`] of an episode whose goal variation is not known.
pub const NO_VARIATION: u32 = u32::MAX;

const _: () = assert!(
    core::mem::size_of::<EpisodeSummary>()
        == 56 + 4 * OBS_DIM + MAX_EPISODE_STEPS * core::mem::size_of::<TrajectoryStep>() + 4
);

impl EpisodeSummary {
    /// An episode with no steps, no success and an unknown goal variation ([`NO_VARIATION`]).
    pub const EMPTY: EpisodeSummary = EpisodeSummary {
        policy_version: 0,
        episode_index: 0,
        losses: Losses::ZERO,
        episode_return: 0.0,
        length: 0,
        trajectory_len: 0,
        actor_id: 0,
        env_index: 0,
        task: 0,
        success: 0,
        reserved0: 0,
        guided_steps: 0,
        first_success: 0,
        final_obs: [0.0; OBS_DIM],
        trajectory: [TrajectoryStep::ZERO; MAX_EPISODE_STEPS],
        variation: NO_VARIATION,
    };

    /// The valid trajectory steps.
    pub fn steps(&self) -> &[TrajectoryStep] {
        &self.trajectory[..(self.trajectory_len as usize).min(MAX_EPISODE_STEPS)]
    }

    /// Whether the task reported success at any step.
    pub fn succeeded(&self) -> bool {
        self.success != 0
    }

    /// Index of the first step after which the task reported success, when recorded.
    pub fn first_success_index(&self) -> Option<usize> {
        (self.first_success > 0).then(|| usize::from(self.first_success) - 1)
    }

    /// The goal variation, when recorded.
    pub fn variation(&self) -> Option<u32> {
        (self.variation != NO_VARIATION).then_some(self.variation)
    }

    /// Records that the task reports success after the step about to be pushed (the first
    /// such step is kept).
    pub fn mark_success_at_next_step(&mut self) {
        if self.first_success == 0 && (self.trajectory_len as usize) < MAX_EPISODE_STEPS {
            self.first_success = (self.trajectory_len + 1) as u16;
        }
    }

    /// Appends a step; `false` (and nothing changes) when the trajectory is full.
    #[must_use = "a full trajectory drops the step"]
    pub fn push_step(&mut self, step: TrajectoryStep) -> bool {
        let len = self.trajectory_len as usize;
        if len >= MAX_EPISODE_STEPS {
            return false;
        }
        self.trajectory[len] = step;
        self.trajectory_len += 1;
        true
    }
}

impl PartialEq for EpisodeSummary {
    /// Equal when summary fields and the valid steps match (the loss stamp, which the
    /// transport sets, is ignored).
    fn eq(&self, other: &Self) -> bool {
        self.policy_version == other.policy_version
            && self.episode_index == other.episode_index
            && self.episode_return == other.episode_return
            && self.length == other.length
            && self.actor_id == other.actor_id
            && self.env_index == other.env_index
            && self.task == other.task
            && self.success == other.success
            && self.first_success == other.first_success
            && self.variation == other.variation
            && self.final_obs == other.final_obs
            && self.steps() == other.steps()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Message;

    #[test]
    fn the_first_success_is_kept_and_unset_records_read_as_none() {
        let mut e = EpisodeSummary::empty();
        assert_eq!(e.first_success_index(), None);
        assert_eq!(e.variation(), None);
        for t in 0..6 {
            if t >= 3 {
                e.mark_success_at_next_step();
            }
            assert!(e.push_step(TrajectoryStep::ZERO));
        }
        assert_eq!(e.first_success_index(), Some(3));
        e.variation = 49;
        assert_eq!(e.variation(), Some(49));
    }
}
