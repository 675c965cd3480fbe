//! Actor → learner: environment transitions, batched.
//!
//! One shared-memory sample carries up to [`TRANSITIONS_PER_BATCH`] transitions so the
//! per-message cost (loan, queue push, wake-up) is paid once per batch, not per step. The
//! layout is `#[repr(C)]` plain data with explicit padding: what the actor writes is
//! byte-for-byte what the learner reads, no serialisation.

use iceoryx2::prelude::*;

use crate::flow::Losses;
use crate::{ACTION_DIM, OBS_DIM};

/// Transitions in one [`TransitionBatch`]: 64 × 352 B ≈ 22 KiB per shared-memory sample.
pub const TRANSITIONS_PER_BATCH: usize = 64;

/// Bits of [`Transition::flags`].
pub mod flags {
    /// The episode hit its step limit (bootstrap from `next_obs`).
    pub const TRUNCATED: u8 = 1 << 0;
    /// The episode ended in a terminal state (do not bootstrap).
    pub const TERMINATED: u8 = 1 << 1;
    /// The task reported success at this step.
    pub const SUCCESS: u8 = 1 << 2;
    /// The action came from TERL guidance (Action Network), not the policy.
    pub const GUIDED: u8 = 1 << 3;
    /// TERL guidance could act at this step: planner weights loaded and the task validated by
    /// the learner's gate ([`super::Transition::guidance_probability`] is then σ^N).
    pub const GUIDANCE_ACTIVE: u8 = 1 << 4;
    /// The guidance decision compared `f_t` with `f_{t−1}` (F evaluated on both steps).
    pub const COMPARED: u8 = 1 << 5;
    /// With [`COMPARED`]: `f_t ≥ f_{t−1}`, the condition of Eq. 15 under which the planner may
    /// act (the policy's action does not bring the goal nearer by F's estimate).
    pub const NOT_IMPROVING: u8 = 1 << 6;
}

/// Full scale of [`Transition::action_gap`]: the largest `‖a − b‖₂` of two actions in
/// `[-1, 1]^ACTION_DIM` (2·√4 = 4).
pub const ACTION_GAP_SCALE: f64 = 4.0;

/// One environment step `(s, a, r, s')` with the bookkeeping the learner needs.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Transition {
    /// Version of the policy weights that chose `action`; the learner reports staleness
    /// (its update count minus this) on what it trains on.
    pub policy_version: u64,
    /// Meta-World observation `s` the action was chosen in (39 floats, without the task one-hot).
    pub obs: [f32; OBS_DIM],
    /// Observation `s'` the action reached (at the step limit the episode's true last observation,
    /// not the reset one).
    pub next_obs: [f32; OBS_DIM],
    /// Executed action `a`, in Meta-World's action space `[-1, 1]^ACTION_DIM`.
    pub action: [f32; ACTION_DIM],
    /// Reward `r` of the step, as the environment returned it.
    pub reward: f32,
    /// Actor process that produced the step.
    pub actor_id: u16,
    /// Environment index inside that actor.
    pub env_index: u16,
    /// Task index into the run's task list.
    pub task: u16,
    /// [`flags`] bits.
    pub flags: u8,
    /// Explicit padding so the layout has no uninitialised bytes.
    pub reserved: u8,
    /// σ^N of TERL guidance at this step (Eq. 15) in units of 1/65535 (0 without
    /// [`flags::GUIDANCE_ACTIVE`]); read it with [`Transition::guidance_probability`].
    pub guidance_probability_q: u16,
    /// Guided steps: `‖AN(s, g) − π(s)‖₂` in units of [`ACTION_GAP_SCALE`]/65535; read it with
    /// [`Transition::action_gap`].
    pub action_gap_q: u16,
}

const _: () = assert!(core::mem::size_of::<Transition>() == 352);
const _: () = assert!(core::mem::align_of::<Transition>() == 8);

impl Transition {
    /// An all-zero transition (valid plain data, used to initialise batches).
    pub const ZERO: Transition = Transition {
        policy_version: 0,
        obs: [0.0; OBS_DIM],
        next_obs: [0.0; OBS_DIM],
        action: [0.0; ACTION_DIM],
        reward: 0.0,
        actor_id: 0,
        env_index: 0,
        task: 0,
        flags: 0,
        reserved: 0,
        guidance_probability_q: 0,
        action_gap_q: 0,
    };

    /// Whether [`flags::TRUNCATED`] is set.
    pub fn truncated(&self) -> bool {
        self.flags & flags::TRUNCATED != 0
    }
    /// Whether [`flags::TERMINATED`] is set.
    pub fn terminated(&self) -> bool {
        self.flags & flags::TERMINATED != 0
    }
    /// Whether [`flags::SUCCESS`] is set.
    pub fn success(&self) -> bool {
        self.flags & flags::SUCCESS != 0
    }
    /// Whether [`flags::GUIDED`] is set.
    pub fn guided(&self) -> bool {
        self.flags & flags::GUIDED != 0
    }

    /// σ^N at this step, in [0, 1] (0 when guidance could not act).
    pub fn guidance_probability(&self) -> f64 {
        f64::from(self.guidance_probability_q) / f64::from(u16::MAX)
    }

    /// `‖AN − π‖₂` of a guided step, in [0, [`ACTION_GAP_SCALE`]].
    pub fn action_gap(&self) -> f64 {
        f64::from(self.action_gap_q) * ACTION_GAP_SCALE / f64::from(u16::MAX)
    }

    /// Stores σ^N (`p`, clamped to [0, 1]; NaN as 0) to within 1/131070.
    pub fn set_guidance_probability(&mut self, p: f64) {
        self.guidance_probability_q = quantize(p, 1.0);
    }

    /// Stores `‖AN − π‖₂` (clamped to [0, [`ACTION_GAP_SCALE`]]; NaN as 0) to within
    /// `ACTION_GAP_SCALE`/131070.
    pub fn set_action_gap(&mut self, gap: f64) {
        self.action_gap_q = quantize(gap, ACTION_GAP_SCALE);
    }
}

/// `x / full_scale` in units of 1/65535, rounded, clamped to `0..=u16::MAX`; NaN → 0.
fn quantize(x: f64, full_scale: f64) -> u16 {
    let q = (x / full_scale * f64::from(u16::MAX)).round();
    if q.is_nan() {
        0
    } else {
        q.clamp(0.0, f64::from(u16::MAX)) as u16
    }
}

/// Up to [`TRANSITIONS_PER_BATCH`] transitions; only the first `len` are meaningful.
#[derive(Debug, Clone, Copy, ZeroCopySend, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct TransitionBatch {
    /// Number of valid entries in `transitions`.
    pub len: u32,
    /// Actor that sent the batch (also in each transition; here for cheap routing/metrics).
    pub actor_id: u16,
    /// Explicit padding so the layout has no uninitialised bytes.
    pub reserved: u16,
    /// Per-publisher sequence number, starting at 0 and incremented per batch (also for
    /// batches that were not delivered), so a receiver can detect gaps and reordering.
    pub sequence: u64,
    /// The sender's cumulative losses before this batch: batches (`messages`) and transitions
    /// (`items`) its earlier sends gave up on because the receiver stayed full. Stamped by the
    /// transport on send (see [`crate::flow`]).
    pub losses: Losses,
    /// The transitions; entries from `len` on are unused.
    pub transitions: [Transition; TRANSITIONS_PER_BATCH],
}

const _: () = assert!(core::mem::size_of::<TransitionBatch>() == 32 + 352 * TRANSITIONS_PER_BATCH);

impl TransitionBatch {
    /// A batch with no transitions (`len` 0, sequence 0, no losses).
    pub const EMPTY: TransitionBatch = TransitionBatch {
        len: 0,
        actor_id: 0,
        reserved: 0,
        sequence: 0,
        losses: Losses::ZERO,
        transitions: [Transition::ZERO; TRANSITIONS_PER_BATCH],
    };

    /// The valid transitions.
    pub fn as_slice(&self) -> &[Transition] {
        &self.transitions[..(self.len as usize).min(TRANSITIONS_PER_BATCH)]
    }

    /// Whether all [`TRANSITIONS_PER_BATCH`] entries are used.
    pub fn is_full(&self) -> bool {
        self.len as usize >= TRANSITIONS_PER_BATCH
    }

    /// Appends `t`; `false` (and nothing changes) when the batch is full.
    #[must_use = "a full batch drops the transition: send it and clear first"]
    pub fn push(&mut self, t: Transition) -> bool {
        if self.is_full() {
            return false;
        }
        self.transitions[self.len as usize] = t;
        self.len += 1;
        true
    }

    /// Empties the batch (keeps `actor_id`, advances nothing).
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

impl PartialEq for TransitionBatch {
    /// Equal when header and the valid transitions match (ignores stale tail entries and the
    /// loss stamp, which the transport sets).
    fn eq(&self, other: &Self) -> bool {
        self.len == other.len
            && self.actor_id == other.actor_id
            && self.sequence == other.sequence
            && self.as_slice() == other.as_slice()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guidance_fields_round_trip_within_their_resolution_and_clamp() {
        let mut t = Transition::ZERO;
        for k in 0..=1000 {
            let p = f64::from(k) / 1000.0;
            t.set_guidance_probability(p);
            assert!(
                (t.guidance_probability() - p).abs() <= 0.5 / 65535.0 + 1e-12,
                "{p}"
            );
            let gap = p * ACTION_GAP_SCALE;
            t.set_action_gap(gap);
            assert!(
                (t.action_gap() - gap).abs() <= 2.0 / 65535.0 + 1e-12,
                "{gap}"
            );
        }
        t.set_guidance_probability(1.5);
        assert_eq!(t.guidance_probability(), 1.0);
        t.set_guidance_probability(-0.2);
        assert_eq!(t.guidance_probability(), 0.0);
        t.set_action_gap(f64::NAN);
        assert_eq!(t.action_gap(), 0.0);
        t.set_action_gap(f64::INFINITY);
        assert_eq!(t.action_gap(), ACTION_GAP_SCALE);
        // σ^N = 0.9^N of a late episode stays distinguishable from 0.
        t.set_guidance_probability(0.9f64.powi(50));
        assert!(t.guidance_probability() > 0.0);
    }
}
