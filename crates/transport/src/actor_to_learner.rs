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
}

/// One environment step `(s, a, r, s')` with the bookkeeping the learner needs.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
pub struct Transition {
    /// Version of the policy weights that chose `action`; the learner reports staleness
    /// (its update count minus this) on what it trains on.
    pub policy_version: u64,
    pub obs: [f32; OBS_DIM],
    pub next_obs: [f32; OBS_DIM],
    pub action: [f32; ACTION_DIM],
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
    pub reserved: [u8; 5],
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
        reserved: [0; 5],
    };

    pub fn truncated(&self) -> bool {
        self.flags & flags::TRUNCATED != 0
    }
    pub fn terminated(&self) -> bool {
        self.flags & flags::TERMINATED != 0
    }
    pub fn success(&self) -> bool {
        self.flags & flags::SUCCESS != 0
    }
    pub fn guided(&self) -> bool {
        self.flags & flags::GUIDED != 0
    }
}

/// Up to [`TRANSITIONS_PER_BATCH`] transitions; only the first `len` are meaningful.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
pub struct TransitionBatch {
    /// Number of valid entries in `transitions`.
    pub len: u32,
    /// Actor that sent the batch (also in each transition; here for cheap routing/metrics).
    pub actor_id: u16,
    pub reserved: u16,
    /// Per-publisher sequence number, starting at 0 and incremented per batch (also for
    /// batches that were not delivered), so a receiver can detect gaps and reordering.
    pub sequence: u64,
    /// The sender's cumulative losses before this batch: batches (`messages`) and transitions
    /// (`items`) its earlier sends gave up on because the receiver stayed full. Stamped by the
    /// transport on send (see [`crate::flow`]).
    pub losses: Losses,
    pub transitions: [Transition; TRANSITIONS_PER_BATCH],
}

const _: () = assert!(core::mem::size_of::<TransitionBatch>() == 32 + 352 * TRANSITIONS_PER_BATCH);

impl TransitionBatch {
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
