//! A batch of Meta-World environments stepped in one call, for actors.
//!
//! Outputs are flat `f32` arrays (`E × 39` observations etc.) owned by the `VecEnv` and
//! overwritten by each step, so stepping allocates nothing. Finished episodes reset
//! automatically to a goal variation drawn at random from the task's 50; the observation that
//! ended the episode is kept in [`VecEnv::final_obs`] for bootstrapping.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::{Result, SimError};
use crate::metaworld::{goal_variations, Env, ACTION_DIM, OBS_DIM};

/// Summary of an episode that ended during the last step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeEnd {
    /// Index of the environment in the batch.
    pub env: usize,
    /// Index of its task in [`VecEnv::tasks`].
    pub task: usize,
    /// Sum of the episode's rewards.
    pub episode_return: f64,
    /// Steps of the episode, env steps.
    pub length: u32,
    /// Success at any step of the episode (Meta-World's evaluation rule).
    pub success: bool,
    /// Success at the final step.
    pub final_success: bool,
    /// The episode was cut short by a physics instability.
    pub unstable: bool,
}

/// `E` Meta-World environments with auto-reset.
#[derive(Debug)]
pub struct VecEnv {
    envs: Vec<Env>,
    tasks: Vec<&'static str>,
    env_task: Vec<usize>,
    variations: Vec<Vec<Vec<f64>>>,
    rng: ChaCha8Rng,
    obs: Vec<f32>,
    final_obs: Vec<f32>,
    rewards: Vec<f32>,
    success: Vec<bool>,
    truncated: Vec<bool>,
    unstable: Vec<bool>,
    returns: Vec<f64>,
    ever_success: Vec<bool>,
    /// Per environment, the index of its current episode's goal variation.
    variation: Vec<u32>,
    finished: Vec<EpisodeEnd>,
    instability_events: u64,
}

impl VecEnv {
    /// `env_tasks[i]` is the task of environment `i`; goal variations come from
    /// [`goal_variations`]`(task, seed)`, episode-to-variation draws from `seed` as well.
    pub fn new(env_tasks: &[&str], seed: u64) -> Result<Self> {
        if env_tasks.is_empty() {
            return Err(SimError::Length {
                what: "environment list",
                got: 0,
                expected: 1,
            });
        }
        let mut tasks: Vec<&'static str> = Vec::new();
        let mut env_task = Vec::with_capacity(env_tasks.len());
        let mut envs = Vec::with_capacity(env_tasks.len());
        for name in env_tasks {
            let env = Env::new(name)?;
            let canonical = env.name();
            let idx = match tasks.iter().position(|t| *t == canonical) {
                Some(i) => i,
                None => {
                    tasks.push(canonical);
                    tasks.len() - 1
                }
            };
            env_task.push(idx);
            envs.push(env);
        }
        let variations = tasks
            .iter()
            .map(|t| goal_variations(t, seed))
            .collect::<Result<Vec<_>>>()?;
        let n = envs.len();
        let mut v = Self {
            envs,
            tasks,
            env_task,
            variations,
            rng: ChaCha8Rng::seed_from_u64(seed.wrapping_add(0x9e37_79b9_7f4a_7c15)),
            obs: vec![0.0; n * OBS_DIM],
            final_obs: vec![0.0; n * OBS_DIM],
            rewards: vec![0.0; n],
            success: vec![false; n],
            truncated: vec![false; n],
            unstable: vec![false; n],
            returns: vec![0.0; n],
            ever_success: vec![false; n],
            variation: vec![0; n],
            finished: Vec::with_capacity(n),
            instability_events: 0,
        };
        for i in 0..n {
            v.reset_env(i)?;
        }
        Ok(v)
    }

    /// Builds `num_envs` environments spread evenly over `tasks` (round robin).
    pub fn round_robin(tasks: &[&str], num_envs: usize, seed: u64) -> Result<Self> {
        if tasks.is_empty() {
            return Err(SimError::Length {
                what: "task list",
                got: 0,
                expected: 1,
            });
        }
        let list: Vec<&str> = (0..num_envs).map(|i| tasks[i % tasks.len()]).collect();
        Self::new(&list, seed)
    }

    fn reset_env(&mut self, i: usize) -> Result<()> {
        let vars = &self.variations[self.env_task[i]];
        let k = self.rng.gen_range(0..vars.len());
        self.variation[i] = k as u32;
        let obs = self.envs[i].reset(&vars[k])?;
        for (dst, src) in self.obs[i * OBS_DIM..(i + 1) * OBS_DIM].iter_mut().zip(obs) {
            *dst = src as f32;
        }
        self.returns[i] = 0.0;
        self.ever_success[i] = false;
        Ok(())
    }

    /// The index (into its task's [`goal_variations`]) of the goal variation environment `i`'s
    /// current episode runs on.
    ///
    /// # Panics
    /// If `i` is not below [`VecEnv::num_envs`].
    pub fn variation(&self, i: usize) -> u32 {
        self.variation[i]
    }

    /// Re-seeds the episode-to-variation draws, then resets every environment.
    pub fn reset_all_seeded(&mut self, seed: u64) -> Result<()> {
        self.rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(0x9e37_79b9_7f4a_7c15));
        self.reset_all()
    }

    /// Resets every environment (new variations).
    pub fn reset_all(&mut self) -> Result<()> {
        for i in 0..self.envs.len() {
            self.reset_env(i)?;
        }
        Ok(())
    }

    /// Steps all environments with `actions` (`E × 4`, row-major). The whole batch is checked
    /// before any environment moves: a wrong length or a non-finite value is an error and
    /// nothing is stepped.
    pub fn step(&mut self, actions: &[f32]) -> Result<()> {
        let n = self.envs.len();
        if actions.len() != n * ACTION_DIM {
            return Err(SimError::Length {
                what: "action batch",
                got: actions.len(),
                expected: n * ACTION_DIM,
            });
        }
        if let Some(index) = actions.iter().position(|a| !a.is_finite()) {
            return Err(SimError::NonFinite {
                what: "action batch",
                index,
            });
        }
        self.finished.clear();
        for i in 0..n {
            let step = self.envs[i].step(&actions[i * ACTION_DIM..(i + 1) * ACTION_DIM])?;
            let row = i * OBS_DIM..(i + 1) * OBS_DIM;
            for (dst, src) in self.obs[row.clone()].iter_mut().zip(step.obs) {
                *dst = src as f32;
            }
            self.rewards[i] = step.reward as f32;
            self.success[i] = step.success;
            self.truncated[i] = step.truncated;
            self.unstable[i] = step.unstable;
            self.returns[i] += step.reward;
            self.ever_success[i] |= step.success;
            if step.truncated {
                self.final_obs[row.clone()].copy_from_slice(&self.obs[row]);
                if step.unstable {
                    self.instability_events += 1;
                }
                self.finished.push(EpisodeEnd {
                    env: i,
                    task: self.env_task[i],
                    episode_return: self.returns[i],
                    length: self.envs[i].steps(),
                    success: self.ever_success[i],
                    final_success: step.success,
                    unstable: step.unstable,
                });
                self.reset_env(i)?;
            }
        }
        Ok(())
    }

    /// The environments, e.g. to inspect one (see also [`Env`]).
    pub fn env(&self, i: usize) -> &Env {
        &self.envs[i]
    }
    #[doc(hidden)]
    pub fn env_mut(&mut self, i: usize) -> &mut Env {
        &mut self.envs[i]
    }

    /// Number of environments.
    pub fn num_envs(&self) -> usize {
        self.envs.len()
    }
    /// Distinct tasks, in order of first appearance.
    pub fn tasks(&self) -> &[&'static str] {
        &self.tasks
    }
    /// Task index (into [`Self::tasks`]) of each environment.
    pub fn env_tasks(&self) -> &[usize] {
        &self.env_task
    }
    /// Current observations (`E × 39`); after an auto-reset, the new episode's first one.
    pub fn obs(&self) -> &[f32] {
        &self.obs
    }
    /// Observations that ended an episode in the last step (valid where `truncated`).
    pub fn final_obs(&self) -> &[f32] {
        &self.final_obs
    }
    /// Rewards of the last step, one per environment.
    pub fn rewards(&self) -> &[f32] {
        &self.rewards
    }
    /// Success flags of the last step, one per environment.
    pub fn success(&self) -> &[bool] {
        &self.success
    }
    /// Time-limit truncation (Meta-World never terminates an episode early); also set when
    /// the physics went unstable (see [`Self::unstable`]).
    pub fn truncated(&self) -> &[bool] {
        &self.truncated
    }
    /// The last step's physics went unstable (MuJoCo reported a bad qpos/qvel/qacc or the
    /// observation was non-finite): the episode was cut short, its last observation has its
    /// non-finite values zeroed and its reward is 0. That step is not a transition of the task's
    /// dynamics, so learners must not store it (the trainer and the actor drop it and count it).
    pub fn unstable(&self) -> &[bool] {
        &self.unstable
    }
    /// Episodes that ended in the last step.
    pub fn finished(&self) -> &[EpisodeEnd] {
        &self.finished
    }
    /// Physics instabilities seen (each cut an episode short and reset that env).
    pub fn instability_events(&self) -> u64 {
        self.instability_events
    }
}
