//! The environment seam: a vector of environments stepped together, with auto-reset.
//!
//! The trainer needs exactly this from an environment; the Meta-World adapter (crates/sim
//! through the CLI) and the toy point mass ([`crate::toy`]) implement it.

/// Per-step outputs of a [`VecEnvironment`], one entry (or row) per environment.
#[derive(Clone, Debug, Default)]
pub struct StepBuffers {
    /// Observation to act from next (rows × obs_dim): after an episode ended, the first
    /// observation of the new episode (auto-reset).
    pub obs: Vec<f32>,
    /// Observation reached by this step's action (rows × obs_dim): what replay stores as `s'`,
    /// also when the episode ended.
    pub final_obs: Vec<f32>,
    /// Reward of this step, one per environment.
    pub reward: Vec<f32>,
    /// The episode reached a true terminal state: the target does not bootstrap.
    pub terminated: Vec<bool>,
    /// The episode hit its time limit: it ends but the target still bootstraps.
    pub truncated: Vec<bool>,
    /// The task's success criterion holds after this step (Meta-World's `info["success"]`).
    pub success: Vec<bool>,
    /// The step is not a transition of the task's dynamics (the physics blew up and the
    /// episode was cut short, `truncated` is set too): the trainer does not store it.
    pub unstable: Vec<bool>,
}

impl StepBuffers {
    /// Buffers for `num_envs` environments.
    pub fn new(num_envs: usize, obs_dim: usize) -> Self {
        Self {
            obs: vec![0.0; num_envs * obs_dim],
            final_obs: vec![0.0; num_envs * obs_dim],
            reward: vec![0.0; num_envs],
            terminated: vec![false; num_envs],
            truncated: vec![false; num_envs],
            success: vec![false; num_envs],
            unstable: vec![false; num_envs],
        }
    }
}

/// A fixed set of environments, each bound to one task, stepped in lockstep.
pub trait VecEnvironment {
    /// Error of a reset or step.
    type Error: std::error::Error + Send + Sync + 'static;

    /// Number of environments (rows of every per-step buffer).
    fn num_envs(&self) -> usize;
    /// Observation size without any task id.
    fn obs_dim(&self) -> usize;
    /// Action size; actions are in `[-1, 1]`.
    fn act_dim(&self) -> usize;
    /// Number of tasks (the one-hot size).
    fn num_tasks(&self) -> usize;
    /// Task id of each environment.
    fn task_ids(&self) -> &[usize];
    /// Resets every environment (seeded), writing the first observations (rows × obs_dim).
    fn reset_all(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), Self::Error>;
    /// Steps every environment with `actions` (rows × act_dim) and resets those whose episode
    /// ended (see [`StepBuffers`]).
    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), Self::Error>;
    /// The goal variation environment `env`'s current episode runs on, where the environment
    /// has numbered variations (Meta-World: an index into the task's 50); `None` by default.
    fn variation(&self, env: usize) -> Option<u32> {
        let _ = env;
        None
    }
}
