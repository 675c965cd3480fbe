//! Meta-World [`VecEnv`] behind the trainer's environment seam ([`VecEnvironment`]).

use anyhow::Result;
use terl_rl::env::{StepBuffers, VecEnvironment};
use terl_sim::{VecEnv, ACTION_DIM, OBS_DIM};

/// Meta-World [`VecEnv`] behind the trainer's environment seam.
pub struct MetaWorldVec {
    inner: VecEnv,
    num_tasks: usize,
    task_ids: Vec<usize>,
}

impl std::fmt::Debug for MetaWorldVec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MetaWorldVec")
            .field("num_envs", &self.inner.num_envs())
            .finish()
    }
}

impl MetaWorldVec {
    /// `num_envs` environments over `tasks`; task ids are positions in `tasks`.
    pub fn new(tasks: &[&str], num_envs: usize, seed: u64) -> Result<Self> {
        let inner = VecEnv::round_robin(tasks, num_envs, seed)?;
        Ok(Self::wrap(inner, tasks))
    }

    /// One environment per entry of `env_tasks` (e.g. an actor's share of the run), each a
    /// task of `tasks`; task ids are positions in `tasks` (the run's task list), so
    /// [`VecEnvironment::num_tasks`] is `tasks.len()`.
    pub fn with_envs(tasks: &[&str], env_tasks: &[&str], seed: u64) -> Result<Self> {
        let inner = VecEnv::new(env_tasks, seed)?;
        Ok(Self::wrap(inner, tasks))
    }

    fn wrap(inner: VecEnv, tasks: &[&str]) -> Self {
        let task_ids = inner
            .env_tasks()
            .iter()
            .map(|&k| {
                let name = inner.tasks()[k];
                tasks
                    .iter()
                    .position(|t| terl_sim::metaworld::task_set(t).is_ok_and(|s| s == [name]))
                    .expect("task of the list")
            })
            .collect();
        Self {
            inner,
            num_tasks: tasks.len(),
            task_ids,
        }
    }

    /// The wrapped environments.
    pub fn inner(&self) -> &VecEnv {
        &self.inner
    }

    /// The wrapped environments, e.g. to break one in a test.
    #[doc(hidden)]
    pub fn inner_mut(&mut self) -> &mut VecEnv {
        &mut self.inner
    }
}

impl VecEnvironment for MetaWorldVec {
    type Error = terl_sim::SimError;

    fn num_envs(&self) -> usize {
        self.inner.num_envs()
    }
    fn obs_dim(&self) -> usize {
        OBS_DIM
    }
    fn act_dim(&self) -> usize {
        ACTION_DIM
    }
    fn num_tasks(&self) -> usize {
        self.num_tasks
    }
    fn task_ids(&self) -> &[usize] {
        &self.task_ids
    }
    fn reset_all(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), Self::Error> {
        self.inner.reset_all_seeded(seed)?;
        obs.copy_from_slice(self.inner.obs());
        Ok(())
    }
    fn variation(&self, env: usize) -> Option<u32> {
        Some(self.inner.variation(env))
    }

    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), Self::Error> {
        self.inner.step(actions)?;
        let v = &self.inner;
        out.obs.copy_from_slice(v.obs());
        for i in 0..v.num_envs() {
            let row = i * OBS_DIM..(i + 1) * OBS_DIM;
            if v.truncated()[i] {
                out.final_obs[row.clone()].copy_from_slice(&v.final_obs()[row]);
            } else {
                out.final_obs[row.clone()].copy_from_slice(&v.obs()[row]);
            }
        }
        out.reward.copy_from_slice(v.rewards());
        out.truncated.copy_from_slice(v.truncated());
        out.terminated.fill(false);
        out.success.copy_from_slice(v.success());
        out.unstable.copy_from_slice(v.unstable());
        Ok(())
    }
}
