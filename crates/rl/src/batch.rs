//! A batch of transitions in contiguous row-major `f32` storage.

use crate::error::SacError;

/// Transitions `(s, a, r, s', terminated, task)`; rows are transitions. `terminated` is 1.0 only
/// for a true terminal state: a time-limit truncation stores 0.0 so the target bootstraps.
#[derive(Clone, Debug)]
pub struct Batch {
    /// Observation length of `obs` and `next_obs` rows (task one-hot not included).
    pub obs_dim: usize,
    /// Action length of `actions` rows.
    pub act_dim: usize,
    /// Observations `s`, `[len, obs_dim]` row-major.
    pub obs: Vec<f32>,
    /// Actions `a`, `[len, act_dim]` row-major, in `[-1, 1]`.
    pub actions: Vec<f32>,
    /// Rewards `r`, one per row.
    pub rewards: Vec<f32>,
    /// Next observations `s'`, `[len, obs_dim]` row-major.
    pub next_obs: Vec<f32>,
    /// 1.0 for a true terminal state, else 0.0, one per row.
    pub terminated: Vec<f32>,
    /// Task index of each row (selects the one-hot and the temperature).
    pub task_ids: Vec<u32>,
}

impl Batch {
    /// An empty batch with room for `capacity` rows (pushing within it does not allocate).
    pub fn with_capacity(capacity: usize, obs_dim: usize, act_dim: usize) -> Self {
        Self {
            obs_dim,
            act_dim,
            obs: Vec::with_capacity(capacity * obs_dim),
            actions: Vec::with_capacity(capacity * act_dim),
            rewards: Vec::with_capacity(capacity),
            next_obs: Vec::with_capacity(capacity * obs_dim),
            terminated: Vec::with_capacity(capacity),
            task_ids: Vec::with_capacity(capacity),
        }
    }

    /// Number of transitions (rows).
    pub fn len(&self) -> usize {
        self.rewards.len()
    }

    /// Whether the batch has no rows.
    pub fn is_empty(&self) -> bool {
        self.rewards.is_empty()
    }

    /// Removes all rows, keeping the storage.
    pub fn clear(&mut self) {
        self.obs.clear();
        self.actions.clear();
        self.rewards.clear();
        self.next_obs.clear();
        self.terminated.clear();
        self.task_ids.clear();
    }

    /// Appends one transition.
    pub fn push(
        &mut self,
        obs: &[f32],
        action: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
        task: u32,
    ) {
        debug_assert_eq!(obs.len(), self.obs_dim);
        debug_assert_eq!(action.len(), self.act_dim);
        self.obs.extend_from_slice(obs);
        self.actions.extend_from_slice(action);
        self.rewards.push(reward);
        self.next_obs.extend_from_slice(next_obs);
        self.terminated.push(if terminated { 1.0 } else { 0.0 });
        self.task_ids.push(task);
    }

    /// Checks that all arrays agree in length and every task id is below `num_tasks`.
    pub fn check_shape(&self, num_tasks: usize) -> Result<(), SacError> {
        let n = self.len();
        let ok = self.obs.len() == n * self.obs_dim
            && self.next_obs.len() == n * self.obs_dim
            && self.actions.len() == n * self.act_dim
            && self.terminated.len() == n
            && self.task_ids.len() == n;
        if !ok {
            return Err(SacError::Shape(format!(
                "batch arrays disagree in length for {n} rows"
            )));
        }
        if let Some(t) = self.task_ids.iter().find(|&&t| t as usize >= num_tasks) {
            return Err(SacError::Shape(format!(
                "task id {t} out of range for {num_tasks} tasks"
            )));
        }
        Ok(())
    }

    /// The first non-finite value, as an error naming the field and row.
    pub fn check_finite(&self) -> Result<(), SacError> {
        let find = |field: &'static str, v: &[f32], width: usize| -> Result<(), SacError> {
            match v.iter().position(|x| !x.is_finite()) {
                Some(i) => Err(SacError::NonFiniteBatch {
                    field,
                    row: i / width.max(1),
                }),
                None => Ok(()),
            }
        };
        find("obs", &self.obs, self.obs_dim)?;
        find("actions", &self.actions, self.act_dim)?;
        find("rewards", &self.rewards, 1)?;
        find("next_obs", &self.next_obs, self.obs_dim)?;
        find("terminated", &self.terminated, 1)
    }
}
