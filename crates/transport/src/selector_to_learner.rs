//! Selector → learner: transitions chosen by PTR priority for the TEP dataset, in the
//! paper's batches of 512.

use iceoryx2::prelude::*;

use crate::flow::Losses;
use crate::{ACTION_DIM, OBS_DIM};

/// PTR scores and forwards transitions in batches of 512 (paper IV.A).
pub const SELECTED_PER_BATCH: usize = 512;

/// One selected transition with where it came from and its priority.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct SelectedSample {
    /// Globally unique trajectory id: `(actor_id << 48) | episode_index` by convention,
    /// so TEP can draw hindsight goals s' from later steps of the same trajectory.
    pub trajectory_id: u64,
    /// Observation `s` of the step (39 floats, without the task one-hot).
    pub obs: [f32; OBS_DIM],
    /// Observation `s'` the action reached.
    pub next_obs: [f32; OBS_DIM],
    /// Executed action `a`, in Meta-World's action space `[-1, 1]^ACTION_DIM`.
    pub action: [f32; ACTION_DIM],
    /// Reward `r` of the step.
    pub reward: f32,
    /// `P = 0.6 · mean(GAE) + 0.4 · entropy`.
    pub priority: f32,
    /// Step index inside the trajectory (0-based).
    pub step_index: u16,
    /// Task index into the run's task list.
    pub task: u16,
    /// The goal variation of the sample's episode ([`crate::NO_VARIATION`] as `u16::MAX`:
    /// unknown).
    pub variation: u16,
    /// 1 if the task reports success after this step, else 0.
    pub success: u8,
    /// Explicit padding so the layout has no uninitialised bytes.
    pub reserved: u8,
}

const _: () = assert!(core::mem::size_of::<SelectedSample>() == 352);

impl SelectedSample {
    /// An all-zero sample with an unknown goal variation (used to initialise batches).
    pub const ZERO: SelectedSample = SelectedSample {
        trajectory_id: 0,
        obs: [0.0; OBS_DIM],
        next_obs: [0.0; OBS_DIM],
        action: [0.0; ACTION_DIM],
        reward: 0.0,
        priority: 0.0,
        step_index: 0,
        task: 0,
        variation: u16::MAX,
        success: 0,
        reserved: 0,
    };

    /// The goal variation of the sample's episode, when recorded.
    pub fn variation(&self) -> Option<u32> {
        (self.variation != u16::MAX).then_some(u32::from(self.variation))
    }

    /// Whether the task reports success after this step.
    pub fn succeeded(&self) -> bool {
        self.success != 0
    }
}

/// Up to [`SELECTED_PER_BATCH`] selected samples; only the first `len` are meaningful.
#[derive(Debug, Clone, Copy, ZeroCopySend, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct SelectedBatch {
    /// Number of valid entries in `samples`.
    pub len: u32,
    /// Explicit padding so the layout has no uninitialised bytes.
    pub reserved: u32,
    /// Selector-side sequence number, incremented per batch (also for batches that were not
    /// delivered).
    pub sequence: u64,
    /// The selector's cumulative losses before this batch: batches (`messages`) and samples
    /// (`items`) not delivered because the learner stayed full. Stamped by the transport.
    pub losses: Losses,
    /// The samples; entries from `len` on are unused.
    pub samples: [SelectedSample; SELECTED_PER_BATCH],
}

const _: () = assert!(core::mem::size_of::<SelectedBatch>() == 32 + 352 * SELECTED_PER_BATCH);

impl SelectedBatch {
    /// A batch with no samples (`len` 0, sequence 0, no losses).
    pub const EMPTY: SelectedBatch = SelectedBatch {
        len: 0,
        reserved: 0,
        sequence: 0,
        losses: Losses::ZERO,
        samples: [SelectedSample::ZERO; SELECTED_PER_BATCH],
    };

    /// The valid samples.
    pub fn as_slice(&self) -> &[SelectedSample] {
        &self.samples[..(self.len as usize).min(SELECTED_PER_BATCH)]
    }

    /// Appends `s`; `false` (and nothing changes) when the batch is full.
    #[must_use = "a full batch drops the sample: send it first"]
    pub fn push(&mut self, s: SelectedSample) -> bool {
        if self.len as usize >= SELECTED_PER_BATCH {
            return false;
        }
        self.samples[self.len as usize] = s;
        self.len += 1;
        true
    }
}

impl PartialEq for SelectedBatch {
    fn eq(&self, other: &Self) -> bool {
        self.len == other.len
            && self.sequence == other.sequence
            && self.as_slice() == other.as_slice()
    }
}
