//! Per-task replay: one ring buffer per task in contiguous `f32` arrays, sampled into a
//! preallocated [`Batch`] without allocating, with each batch split evenly across tasks.

use crate::batch::Batch;
use rand::Rng;

/// One task's ring buffer.
#[derive(Clone, Debug)]
pub struct TaskReplay {
    capacity: usize,
    obs_dim: usize,
    act_dim: usize,
    obs: Vec<f32>,
    actions: Vec<f32>,
    rewards: Vec<f32>,
    next_obs: Vec<f32>,
    terminated: Vec<bool>,
    len: usize,
    next: usize,
}

impl TaskReplay {
    /// Storage for `capacity` transitions, allocated up front.
    pub fn new(capacity: usize, obs_dim: usize, act_dim: usize) -> Self {
        assert!(capacity > 0, "replay capacity must be positive");
        Self {
            capacity,
            obs_dim,
            act_dim,
            obs: vec![0.0; capacity * obs_dim],
            actions: vec![0.0; capacity * act_dim],
            rewards: vec![0.0; capacity],
            next_obs: vec![0.0; capacity * obs_dim],
            terminated: vec![false; capacity],
            len: 0,
            next: 0,
        }
    }

    /// Transitions stored, at most the capacity.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no transition has been stored.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Adds a transition, overwriting the oldest once full.
    pub fn push(
        &mut self,
        obs: &[f32],
        action: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
    ) {
        let (i, o, a) = (self.next, self.obs_dim, self.act_dim);
        self.obs[i * o..(i + 1) * o].copy_from_slice(obs);
        self.actions[i * a..(i + 1) * a].copy_from_slice(action);
        self.rewards[i] = reward;
        self.next_obs[i * o..(i + 1) * o].copy_from_slice(next_obs);
        self.terminated[i] = terminated;
        self.next = (self.next + 1) % self.capacity;
        self.len = (self.len + 1).min(self.capacity);
    }

    fn push_row_into(&self, i: usize, task: u32, batch: &mut Batch) {
        let (o, a) = (self.obs_dim, self.act_dim);
        batch.push(
            &self.obs[i * o..(i + 1) * o],
            &self.actions[i * a..(i + 1) * a],
            self.rewards[i],
            &self.next_obs[i * o..(i + 1) * o],
            self.terminated[i],
            task,
        );
    }
}

/// Replay for all tasks.
#[derive(Clone, Debug)]
pub struct MultiTaskReplay {
    tasks: Vec<TaskReplay>,
    /// Which task gets the first of the leftover rows when the batch does not split evenly;
    /// rotates so no task is favoured over time.
    rotation: usize,
}

impl MultiTaskReplay {
    /// Empty ring buffers of `capacity_per_task` transitions for each of `num_tasks` tasks,
    /// allocated up front.
    ///
    /// # Panics
    /// If `capacity_per_task` is 0.
    pub fn new(num_tasks: usize, capacity_per_task: usize, obs_dim: usize, act_dim: usize) -> Self {
        Self {
            tasks: (0..num_tasks)
                .map(|_| TaskReplay::new(capacity_per_task, obs_dim, act_dim))
                .collect(),
            rotation: 0,
        }
    }

    /// Task `task`'s ring buffer (panics if `task >= num_tasks`).
    pub fn task(&self, task: usize) -> &TaskReplay {
        &self.tasks[task]
    }

    /// Adds a transition to task `task`'s ring buffer, overwriting its oldest once full:
    /// `obs` and `next_obs` of length `obs_dim`, `action` of length `act_dim`.
    pub fn push(
        &mut self,
        task: usize,
        obs: &[f32],
        action: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
    ) {
        self.tasks[task].push(obs, action, reward, next_obs, terminated);
    }

    /// Transitions stored over all tasks.
    pub fn total_len(&self) -> usize {
        self.tasks.iter().map(TaskReplay::len).sum()
    }

    /// Replaces `batch`'s rows with `batch_size` transitions drawn uniformly with replacement,
    /// `batch_size / k` from each of the `k` non-empty tasks (the remainder one each to rotating
    /// tasks). Does not allocate when `batch` has the capacity. Returns false if all are empty.
    pub fn sample_into(
        &mut self,
        batch_size: usize,
        rng: &mut impl Rng,
        batch: &mut Batch,
    ) -> bool {
        batch.clear();
        let nonempty = self.tasks.iter().filter(|t| !t.is_empty()).count();
        if nonempty == 0 {
            return false;
        }
        let (per_task, extra) = (batch_size / nonempty, batch_size % nonempty);
        let mut k = 0;
        for (task, buf) in self.tasks.iter().enumerate() {
            if buf.is_empty() {
                continue;
            }
            let take = per_task
                + usize::from((k + nonempty - self.rotation % nonempty) % nonempty < extra);
            for _ in 0..take {
                buf.push_row_into(rng.gen_range(0..buf.len), task as u32, batch);
            }
            k += 1;
        }
        self.rotation = self.rotation.wrapping_add(extra);
        true
    }
}
