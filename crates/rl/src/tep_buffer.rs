//! The TEP dataset in memory: a ring buffer of selected transitions with their trajectory id and
//! step, sampled into [`TepBatch`]es with hindsight goals `s'` (a later state of the same
//! trajectory).
//!
//! Transitions arrive in *segments*: runs of transitions of one trajectory in increasing step
//! order (what a selector pushes after grouping a ranked batch by trajectory). Segments are stored
//! contiguously in push order, so "a later transition of the same trajectory" is "a later slot of
//! the same segment", found without any index. The hindsight goal of transition `i` is the
//! *next state* `s_{j+1}` of a later transition `j > i` of its segment, drawn uniformly; the data
//! distance from `s_i` to that goal is `step_j + 1 − step_i ≥ 2` steps (recorded as
//! [`TepBatch::gaps`]). Taking `s'` strictly after `s_{i+1}` keeps the bootstrapped term
//! `1 + F̃(s_{i+1}, s', ·)` away from the undefined `F̃(s, s, ·)`. A transition that is the last of
//! its segment is never drawn as `s_t` (it has no later state).
//!
//! Storage grows as transitions arrive (a 6M buffer of Meta-World transitions is ~2 GB when full)
//! and then overwrites the oldest slot; a segment whose head was overwritten keeps its tail.

use crate::error::SacError;
use rand::Rng;

/// How hindsight goals are drawn ([`TepBuffer::sample_into_with`]): with probability
/// `near_fraction` within `near_steps` transitions after `s_t` (never past its segment), otherwise
/// uniformly over the later transitions of the segment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GoalSampling {
    /// Probability of drawing the goal from the near window, in `[0, 1]`.
    pub near_fraction: f64,
    /// Width of the near window in transitions after `s_t` (at least 1).
    pub near_steps: u32,
}

impl GoalSampling {
    /// Uniform over the later states of the trajectory (the paper's hindsight goals).
    pub const UNIFORM: Self = Self {
        near_fraction: 0.0,
        near_steps: 1,
    };
}

/// A minibatch for [`crate::tep::Tep::update`]: rows `(s_t, a_t, s_{t+1}, s')`, row-major `f32`.
#[derive(Clone, Debug)]
pub struct TepBatch {
    /// Observation length of `obs`, `next_obs` and `goals` rows.
    pub obs_dim: usize,
    /// Action length of `actions` rows.
    pub act_dim: usize,
    /// States `s_t`, `[len, obs_dim]` row-major.
    pub obs: Vec<f32>,
    /// Actions `a_t`, `[len, act_dim]` row-major.
    pub actions: Vec<f32>,
    /// Next states `s_{t+1}`, `[len, obs_dim]` row-major.
    pub next_obs: Vec<f32>,
    /// Hindsight goal state `s'` of each row.
    pub goals: Vec<f32>,
    /// Steps from `s_t` to `s'` along the trajectory (diagnostics and tests).
    pub gaps: Vec<u32>,
}

impl TepBatch {
    /// An empty batch with room for `capacity` rows (pushing within it does not allocate).
    pub fn with_capacity(capacity: usize, obs_dim: usize, act_dim: usize) -> Self {
        Self {
            obs_dim,
            act_dim,
            obs: Vec::with_capacity(capacity * obs_dim),
            actions: Vec::with_capacity(capacity * act_dim),
            next_obs: Vec::with_capacity(capacity * obs_dim),
            goals: Vec::with_capacity(capacity * obs_dim),
            gaps: Vec::with_capacity(capacity),
        }
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.gaps.len()
    }

    /// Whether the batch has no rows.
    pub fn is_empty(&self) -> bool {
        self.gaps.is_empty()
    }

    /// Removes all rows, keeping the storage.
    pub fn clear(&mut self) {
        self.obs.clear();
        self.actions.clear();
        self.next_obs.clear();
        self.goals.clear();
        self.gaps.clear();
    }

    /// Appends one row.
    pub fn push(&mut self, obs: &[f32], action: &[f32], next_obs: &[f32], goal: &[f32], gap: u32) {
        debug_assert_eq!(obs.len(), self.obs_dim);
        debug_assert_eq!(action.len(), self.act_dim);
        self.obs.extend_from_slice(obs);
        self.actions.extend_from_slice(action);
        self.next_obs.extend_from_slice(next_obs);
        self.goals.extend_from_slice(goal);
        self.gaps.push(gap);
    }

    /// Checks that all arrays agree with `len()` rows.
    pub fn check_shape(&self) -> Result<(), SacError> {
        let (n, o, a) = (self.len(), self.obs_dim, self.act_dim);
        if self.obs.len() != n * o
            || self.next_obs.len() != n * o
            || self.goals.len() != n * o
            || self.actions.len() != n * a
        {
            return Err(SacError::Shape(format!(
                "TEP batch arrays disagree with {n} rows of obs {o} / act {a}"
            )));
        }
        Ok(())
    }

    /// Rejects NaN or infinity anywhere.
    pub fn check_finite(&self) -> Result<(), SacError> {
        for (field, data, w) in [
            ("obs", &self.obs, self.obs_dim),
            ("actions", &self.actions, self.act_dim),
            ("next_obs", &self.next_obs, self.obs_dim),
            ("goals", &self.goals, self.obs_dim),
        ] {
            if let Some(i) = data.iter().position(|v| !v.is_finite()) {
                return Err(SacError::NonFiniteBatch { field, row: i / w });
            }
        }
        Ok(())
    }
}

/// Ring buffer of TEP transitions (see the module docs).
#[derive(Clone, Debug)]
pub struct TepBuffer {
    capacity: usize,
    obs_dim: usize,
    act_dim: usize,
    obs: Vec<f32>,
    actions: Vec<f32>,
    next_obs: Vec<f32>,
    tasks: Vec<u32>,
    trajectories: Vec<u64>,
    steps: Vec<u32>,
    /// Sequence number of the last transition of this slot's segment.
    segment_end: Vec<u64>,
    /// Transitions pushed so far; slot of sequence number `q` is `q % capacity`.
    pushed: u64,
}

impl TepBuffer {
    /// An empty buffer holding at most `capacity` transitions; storage grows as they arrive.
    ///
    /// # Panics
    /// If `capacity` is 0.
    pub fn new(capacity: usize, obs_dim: usize, act_dim: usize) -> Self {
        assert!(capacity > 0, "TEP buffer capacity must be positive");
        Self {
            capacity,
            obs_dim,
            act_dim,
            obs: Vec::new(),
            actions: Vec::new(),
            next_obs: Vec::new(),
            tasks: Vec::new(),
            trajectories: Vec::new(),
            steps: Vec::new(),
            segment_end: Vec::new(),
            pushed: 0,
        }
    }

    /// Transitions stored, at most [`Self::capacity`].
    pub fn len(&self) -> usize {
        self.tasks.len()
    }

    /// Whether no transition has been stored.
    pub fn is_empty(&self) -> bool {
        self.tasks.is_empty()
    }

    /// Most transitions the buffer holds before overwriting the oldest.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Transitions pushed since creation (including overwritten ones).
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    /// Adds a segment of one trajectory: `steps` strictly increasing, `obs`/`next_obs` row-major
    /// `steps.len() × obs_dim`, `actions` `steps.len() × act_dim`. A segment longer than the
    /// buffer keeps its last `capacity` transitions.
    pub fn push_segment(
        &mut self,
        task: u32,
        trajectory: u64,
        steps: &[u32],
        obs: &[f32],
        actions: &[f32],
        next_obs: &[f32],
    ) -> Result<(), SacError> {
        let (n, o, a) = (steps.len(), self.obs_dim, self.act_dim);
        if obs.len() != n * o || next_obs.len() != n * o || actions.len() != n * a {
            return Err(SacError::Shape(format!(
                "segment of {n} steps with {} obs / {} next_obs / {} action values",
                obs.len(),
                next_obs.len(),
                actions.len()
            )));
        }
        if steps.windows(2).any(|w| w[1] <= w[0]) {
            return Err(SacError::Shape(
                "segment steps must be strictly increasing".into(),
            ));
        }
        let skip = n.saturating_sub(self.capacity);
        let first = self.pushed;
        let end = first + (n - skip) as u64 - 1;
        for k in skip..n {
            let q = self.pushed;
            let slot = (q % self.capacity as u64) as usize;
            let ro = &obs[k * o..(k + 1) * o];
            let rn = &next_obs[k * o..(k + 1) * o];
            let ra = &actions[k * a..(k + 1) * a];
            if slot == self.tasks.len() {
                self.obs.extend_from_slice(ro);
                self.next_obs.extend_from_slice(rn);
                self.actions.extend_from_slice(ra);
                self.tasks.push(task);
                self.trajectories.push(trajectory);
                self.steps.push(steps[k]);
                self.segment_end.push(end);
            } else {
                self.obs[slot * o..(slot + 1) * o].copy_from_slice(ro);
                self.next_obs[slot * o..(slot + 1) * o].copy_from_slice(rn);
                self.actions[slot * a..(slot + 1) * a].copy_from_slice(ra);
                self.tasks[slot] = task;
                self.trajectories[slot] = trajectory;
                self.steps[slot] = steps[k];
                self.segment_end[slot] = end;
            }
            self.pushed += 1;
        }
        Ok(())
    }

    /// `(task, trajectory, step)` of the transition in `slot`.
    pub fn meta(&self, slot: usize) -> (u32, u64, u32) {
        (self.tasks[slot], self.trajectories[slot], self.steps[slot])
    }

    /// Fills `batch` with `rows` hindsight rows drawn uniformly over transitions that have a
    /// later transition in their segment, goals uniform over the later ones
    /// ([`GoalSampling::UNIFORM`]). Fails if none is found within `64·rows` draws.
    pub fn sample_into(
        &self,
        rows: usize,
        rng: &mut impl Rng,
        batch: &mut TepBatch,
    ) -> Result<(), SacError> {
        self.sample_into_with(rows, rng, batch, GoalSampling::UNIFORM)
    }

    /// [`TepBuffer::sample_into`] with the goals drawn as `sampling` says (one more uniform draw
    /// per row when `sampling.near_fraction > 0`).
    pub fn sample_into_with(
        &self,
        rows: usize,
        rng: &mut impl Rng,
        batch: &mut TepBatch,
        sampling: GoalSampling,
    ) -> Result<(), SacError> {
        assert_eq!(
            (batch.obs_dim, batch.act_dim),
            (self.obs_dim, self.act_dim),
            "batch built for other dimensions"
        );
        batch.clear();
        let len = self.len() as u64;
        if len == 0 {
            return Err(SacError::Shape("TEP buffer is empty".into()));
        }
        let oldest = self.pushed - len;
        let (o, a, cap) = (self.obs_dim, self.act_dim, self.capacity as u64);
        let mut attempts = 0usize;
        while batch.len() < rows {
            attempts += 1;
            if attempts > 64 * rows.max(1) {
                return Err(SacError::Shape(
                    "TEP buffer has (almost) no transition with a later state of its trajectory"
                        .into(),
                ));
            }
            let qi = rng.gen_range(oldest..self.pushed);
            let i = (qi % cap) as usize;
            let end = self.segment_end[i];
            if end <= qi {
                continue;
            }
            let near = sampling.near_fraction > 0.0 && rng.gen::<f64>() < sampling.near_fraction;
            let last = if near {
                end.min(qi + u64::from(sampling.near_steps.max(1)))
            } else {
                end
            };
            let qj = rng.gen_range(qi + 1..=last);
            let j = (qj % cap) as usize;
            let gap = self.steps[j] + 1 - self.steps[i];
            batch.push(
                &self.obs[i * o..(i + 1) * o],
                &self.actions[i * a..(i + 1) * a],
                &self.next_obs[i * o..(i + 1) * o],
                &self.next_obs[j * o..(j + 1) * o],
                gap,
            );
        }
        Ok(())
    }
}
